"""Typed configs: dataclass defaults <- YAML file <- ``key=value`` overrides.

Unknown keys and values of the wrong type are errors that name the key (and the file).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import yaml

T = TypeVar("T")


class ConfigError(ValueError):
    """A config file, key or value that does not fit its dataclass."""


@dataclass(frozen=True)
class TemplateConfig:
    """Training-template geometry (METHOD.md, "Templates").

    The window is a fixed world size centred on the vehicle's bounding-box centre, so the
    silhouette's size carries range at tracking time. 12 m holds the longest vehicle we ship
    (a tank with its gun forward, ~10 m in 3D diagonal) at any view; 64 px then gives
    0.19 m/px, so the smallest vehicle (a ~4 m, 1.4 m high car) still spans ~21 x 7 px from the
    side, and the clipped signed distance (tau = 6 px = 1.1 m) reaches across its height.
    """

    size_px: int = 64  # H = W, template pixels
    window_m: float = 12.0  # world size of the square window, metres
    tau_px: float = 6.0  # signed-distance clip, template pixels

    def __post_init__(self) -> None:
        if self.size_px < 8:
            raise ConfigError(f"template.size_px must be >= 8; got {self.size_px}")
        if not (self.window_m > 0 and math.isfinite(self.window_m)):
            raise ConfigError(f"template.window_m must be a positive number; got {self.window_m}")
        if not self.tau_px > 0:
            raise ConfigError(f"template.tau_px must be positive; got {self.tau_px}")

    @property
    def metres_per_px(self) -> float:
        return self.window_m / self.size_px


def _check_type(key: str, value: Any, tp: Any) -> Any:
    """Return ``value`` converted to ``tp`` where that is lossless, else raise ConfigError."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        for arm in typing.get_args(tp):
            try:
                return _check_type(key, value, arm)
            except ConfigError:
                continue
        raise ConfigError(f"{key}: {value!r} matches none of {tp}")
    if tp is type(None):
        if value is None:
            return None
        raise ConfigError(f"{key}: expected null; got {value!r}")
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{key}: expected a list; got {value!r}")
        args = typing.get_args(tp)
        arm = args[0] if args else Any
        items = [_check_type(f"{key}[{i}]", v, arm) for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if tp is Any:
        return value
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: expected a mapping; got {value!r}")
        return _build(tp, value, prefix=f"{key}.")
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{key}: expected true/false; got {value!r}")
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise ConfigError(f"{key}: expected an integer; got {value!r}")
    if tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        if isinstance(value, str):  # YAML 1.1 reads 1e-3 (no dot) as a string
            try:
                return float(value)
            except ValueError:
                pass
        raise ConfigError(f"{key}: expected a number; got {value!r}")
    if tp is str:
        if isinstance(value, str):
            return value
        raise ConfigError(f"{key}: expected a string; got {value!r}")
    raise ConfigError(f"{key}: unsupported config type {tp}")


def _build(cls: type[T], data: dict, prefix: str = "") -> T:
    hints = typing.get_type_hints(cls)
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - fields)
    if unknown:
        raise ConfigError(f"unknown config key(s) {', '.join(prefix + k for k in unknown)}; "
                          f"known: {', '.join(prefix + k for k in sorted(fields))}")
    kwargs = {k: _check_type(prefix + k, v, hints[k]) for k, v in data.items()}
    return cls(**kwargs)


def _set_dotted(data: dict, dotted: str, value: Any) -> None:
    parts = dotted.split(".")
    node = data
    for part in parts[:-1]:
        node = node.setdefault(part, {})
        if not isinstance(node, dict):
            raise ConfigError(f"override {dotted}: {part} is not a section")
    node[parts[-1]] = value


def load_config(cls: type[T], path: str | Path | None = None, overrides: list[str] | None = None) -> T:
    """Build ``cls`` from its defaults, a YAML file and ``key=value`` overrides.

    ``overrides`` use dotted keys for nested sections (``template.size_px=32``); values are
    parsed as YAML scalars. Raises :class:`ConfigError` naming the file or key at fault.
    """
    data: dict = {}
    if path is not None:
        path = Path(path)
        try:
            loaded = yaml.safe_load(path.read_text(encoding="utf-8"))
        except FileNotFoundError as exc:
            raise ConfigError(f"config file not found: {path}") from exc
        except yaml.YAMLError as exc:
            raise ConfigError(f"{path}: not valid YAML: {exc}") from exc
        if loaded is not None and not isinstance(loaded, dict):
            raise ConfigError(f"{path}: top level must be a mapping; got {type(loaded).__name__}")
        data = loaded or {}
    for item in overrides or []:
        key, sep, raw = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"override {item!r} is not of the form key=value")
        _set_dotted(data, key.strip(), yaml.safe_load(raw))
    try:
        return _build(cls, data)
    except ConfigError as exc:
        if path is not None:
            raise ConfigError(f"{path}: {exc}") from exc
        raise


@dataclass(frozen=True)
class ModelConfig:
    """Fitting the generative model (chapter 4; METHOD.md "Generative model").

    The RBF centres are the training views (Nc = V). ``ridge`` is λ of the regularised least
    squares of every Bᵏ (eq. 4.13) on templates in [−1, 1]; ``width_steps`` > 0 tunes the kernel
    widths on held-out views with Adam at ``width_lr`` before the final fit.
    """

    pixel_rank: int | None = 128  # r of the truncated pixel basis; null keeps all d pixels
    ridge: float = 1e-4  # λ
    init_width: float | None = None  # kernel width (chord); null: mean nearest-centre chord
    class_penalty: float | None = None  # a of eq. 4.8; null: (K + 1)·max D₀, keeps classes contiguous
    width_steps: int = 0  # Adam steps tuning the widths on validation views
    width_lr: float = 0.02  # Adam learning rate on log(width)

    def __post_init__(self) -> None:
        if self.pixel_rank is not None and self.pixel_rank < 1:
            raise ConfigError(f"model.pixel_rank must be >= 1 or null; got {self.pixel_rank}")
        if not (self.ridge >= 0 and math.isfinite(self.ridge)):
            raise ConfigError(f"model.ridge must be a number >= 0; got {self.ridge}")
        if self.init_width is not None and not (self.init_width > 0 and math.isfinite(self.init_width)):
            raise ConfigError(f"model.init_width must be positive or null; got {self.init_width}")
        if self.class_penalty is not None and not (self.class_penalty >= 0 and math.isfinite(self.class_penalty)):
            raise ConfigError(f"model.class_penalty must be >= 0 or null; got {self.class_penalty}")
        if self.width_steps < 0:
            raise ConfigError(f"model.width_steps must be >= 0; got {self.width_steps}")
        if not (self.width_lr > 0 and math.isfinite(self.width_lr)):
            raise ConfigError(f"model.width_lr must be positive; got {self.width_lr}")
