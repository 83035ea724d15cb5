"""Typed configs: dataclass defaults <- YAML file <- ``key=value`` overrides.

Unknown keys, repeated keys, values of the wrong type and non-finite numbers are errors that
name the key and the file or the override at fault. A message quotes a value, key or override whole
up to 240 characters, a longer one by its first 40, '…' and its length (``validate.cut``).
"""

from __future__ import annotations

import copy
import dataclasses
import datetime
import difflib
import math
import os
import re
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, TypeVar

import yaml

from torch_atr.validate import InputError, cut, read_text, show

T = TypeVar("T")

MAX_CONFIG_BYTES = 2 ** 20  # a config file is a few hundred bytes
MAX_TEMPLATE_PX = 512  # H = W of a template: 512² pixels x 150 views x 36 vehicles is already 5.7 GB in float32


class ConfigError(InputError):
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

    size_px: int = 64  # H = W, template pixels, in [8, 512]
    window_m: float = 12.0  # world size of the square window, metres, in [0.1, 1000]
    tau_px: float = 6.0  # signed-distance clip, template pixels, in [0.5, size_px]

    def __post_init__(self) -> None:
        if not 8 <= self.size_px <= MAX_TEMPLATE_PX:
            raise ConfigError(f"template.size_px must be in [8, {MAX_TEMPLATE_PX}]; got {show(self.size_px)}")
        if not 0.1 <= self.window_m <= 1000:
            raise ConfigError(f"template.window_m must be in [0.1, 1000] metres; got {self.window_m}")
        if not 0.5 <= self.tau_px <= self.size_px:
            raise ConfigError(f"template.tau_px must be in [0.5, size_px = {self.size_px}]; got {self.tau_px}")

    @property
    def metres_per_px(self) -> float:
        return self.window_m / self.size_px


# What YAML 1.1 reads from unquoted text that looks like another type: a number, yes/no/on/off, a date.
_UNQUOTED_TEXT = (int, float, datetime.date)
_KINDS = {bool: "true/false", int: "an integer", float: "a number", str: "text", type(None): "null"}


def _fixed_length(tp: Any) -> tuple | None:
    """The item types of a fixed-length ``tuple[A, B]``; None for a list or ``tuple[A, ...]``."""
    args = typing.get_args(tp)
    if typing.get_origin(tp) is not tuple or not args or args[-1] is Ellipsis:
        return None
    return args


def _describe(tp: Any) -> str:
    """A config type in words, for errors: an integer, a number, text, null, a list, a mapping."""
    if typing.get_origin(tp) in (list, tuple):
        fixed = _fixed_length(tp)
        return "a list" if fixed is None else f"a list of {len(fixed)}"
    return "a mapping" if dataclasses.is_dataclass(tp) else _KINDS.get(tp, str(tp))


def check_type(key: str, value: Any, tp: Any) -> Any:
    """Return ``value`` converted to ``tp`` where that is lossless, else raise ConfigError."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        for arm in typing.get_args(tp):
            try:
                return check_type(key, value, arm)
            except ConfigError as exc:
                if arm is str and isinstance(value, str):  # text its own arm refuses: that arm says why
                    raise exc from None
                continue
        arms = typing.get_args(tp)
        quote = " (quote it for text)" if str in arms and isinstance(value, _UNQUOTED_TEXT) else ""
        raise ConfigError(f"{key}: expected {' or '.join(_describe(arm) for arm in arms)}; got {show(value)}{quote}")
    if tp is type(None):
        if value is None:
            return None
        raise ConfigError(f"{key}: expected null; got {show(value)}")
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{key}: expected {_describe(tp)}; got {show(value)}")
        arms = _fixed_length(tp)
        if arms is None:
            args = typing.get_args(tp)
            arms = [args[0] if args else Any] * len(value)
        elif len(value) != len(arms):
            raise ConfigError(f"{key}: expected a list of {len(arms)} ({', '.join(_describe(a) for a in arms)}); "
                              f"got {show(value)}")
        items = [check_type(f"{key}[{i}]", v, arm) for i, (v, arm) in enumerate(zip(value, arms))]
        return tuple(items) if origin is tuple else items
    if tp is Any:
        return value
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: expected a mapping; got {show(value)}")
        return _build(tp, value, prefix=f"{key}.")
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{key}: expected true/false; got {show(value)}")
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise ConfigError(f"{key}: expected an integer; got {show(value)}")
    if tp is float:
        number = None
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            try:
                number = float(value)
            except OverflowError:  # an integer beyond float's range
                number = math.inf
        if number is None:
            raise ConfigError(f"{key}: expected a number; got {show(value)}")
        if not math.isfinite(number):
            raise ConfigError(f"{key}: expected a finite number; got {show(value)}")
        return number
    if tp is str:
        if isinstance(value, str) and "\0" in value:  # no path, spec, device or name holds one (open() refuses it)
            raise ConfigError(f"{key}: expected text without a NUL byte; got {show(value)}")
        if isinstance(value, str):
            return value
        quote = " (quote it for text)" if isinstance(value, _UNQUOTED_TEXT) else ""
        raise ConfigError(f"{key}: expected a string; got {show(value)}{quote}")
    raise ConfigError(f"{key}: unsupported config type {tp}")


def _field_default(field: dataclasses.Field) -> Any:
    """A dataclass field's default value (its factory called), or MISSING."""
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return dataclasses.MISSING


def _homes(cls: type, key: Any, prefix: str = "") -> list[str]:
    """The dotted paths of the fields named ``key`` in the sections below ``cls``, at any depth."""
    hints, homes = typing.get_type_hints(cls), []
    for field in dataclasses.fields(cls):
        section = hints[field.name]
        if dataclasses.is_dataclass(section):
            path = f"{prefix}{field.name}."
            homes += [path + str(key)] * (key in {f.name for f in dataclasses.fields(section)})
            homes += _homes(section, key, path)
    return homes


def _names_below(tp: Any) -> set[str]:
    """The names of the fields of the section ``tp`` and of the sections below it; none for a key that
    is not a section."""
    if not dataclasses.is_dataclass(tp):
        return set()
    hints = typing.get_type_hints(tp)
    return {name for f in dataclasses.fields(tp) for name in (f.name, *_names_below(hints[f.name]))}


def _nearest(key: str, names: list[str]) -> list[str]:
    """The names ``key`` most likely meant: those it begins (speed -> speed_frames, speed_mps, ...),
    else the closest spelling (partciles -> particles); [] when none is close."""
    return [name for name in names if name.startswith(key)][:3] or difflib.get_close_matches(key, names, n=1)


def _build(cls: type[T], data: dict, prefix: str = "", base: Any = None) -> T:
    """``cls`` from ``data``: the keys it gives on top of ``base`` (an instance of ``cls``; None:
    the class's defaults). A nested section builds on the field's own default, so a section whose
    default differs from its class's (``TrackerConfig.segmentation``) keeps the keys not given."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields), key=str)
    if unknown:
        below = sorted({name for key in fields for name in _names_below(hints[key])})
        homes = ([home for key in unknown for home in _homes(cls, key, prefix)]
                 or [prefix + near for key in unknown for near in _nearest(str(key), sorted(fields))]
                 or [home for key in unknown for near in difflib.get_close_matches(str(key), below, n=1)
                     for home in _homes(cls, near, prefix)])
        # A dotted key in a file (filter.particles: 10) is a path written as one name: the file nests it.
        dotted = [k for k in unknown if isinstance(k, str) and "." in k and _key_type(cls, k) is not None]
        hint = (f" (a file nests its sections: write {cut(dotted[0])} as "
                f"{' then '.join(cut(part) + ':' for part in dotted[0].split('.'))}, each indented below the one "
                f"before)" if dotted else f" (did you mean {' or '.join(homes)}?)" if homes else "")
        raise ConfigError(f"unknown config key(s) {', '.join(cut(prefix + str(k)) for k in unknown)}; "
                          f"known: {', '.join(prefix + k for k in sorted(fields))}{hint}")
    kwargs = {}
    for k, v in data.items():
        tp = hints[k]
        default = getattr(base, k) if base is not None else _field_default(fields[k])
        if dataclasses.is_dataclass(tp) and isinstance(v, dict) and isinstance(default, tp):
            kwargs[k] = _build(tp, v, f"{prefix}{k}.", default)
        else:
            kwargs[k] = check_type(prefix + k, v, tp)
    return cls(**kwargs) if base is None else dataclasses.replace(base, **kwargs)


def config_from_dict(cls: type[T], data: dict) -> T:
    """Build the config dataclass ``cls`` from plain data (e.g. a checkpoint's), with the checks
    of :func:`load_config`; ``ConfigError`` names the key."""
    if not isinstance(data, dict):
        raise ConfigError(f"expected a mapping of {cls.__name__} keys; got {show(data)}")
    return _build(cls, data)


class _UniqueKeyLoader(yaml.SafeLoader):
    """YAML's safe loader, refusing a key repeated in one mapping (plain YAML keeps the last)."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            first: dict = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    repeated = key in first
                except TypeError:  # an unhashable key: the base class reports it
                    continue
                if repeated:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"key {show(key)} repeated (first on line {first[key]})", key_node.start_mark)
                first[key] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep=deep)

    # YAML 1.1 reads 010 as octal 8 and 1:30 as base-60 90; YAML 1.2, and a reader of a config, as
    # 10 and as text (which a number's key then refuses, naming it).
    def construct_yaml_int(self, node):
        value = self.construct_scalar(node)
        if ":" in value:
            return value
        digits = value.replace("_", "").lstrip("+-")
        if len(digits) > 1 and digits[0] == "0" and digits[1].isdigit():
            return self._number(node, lambda: int(value.replace("_", ""), 10))
        return self._number(node, lambda: super(_UniqueKeyLoader, self).construct_yaml_int(node))

    def construct_yaml_float(self, node):
        value = self.construct_scalar(node)
        return value if ":" in value else self._number(node, lambda: super(_UniqueKeyLoader, self)
                                                             .construct_yaml_float(node))

    @staticmethod
    def _number(node, convert):
        """``convert()``; a value it cannot convert (an integer of more than 4300 digits, ``!!int abc``)
        or an integer too long to print in a message (a hexadecimal one of 5000 digits) raises a YAML
        error at the node naming the value, not int's bare ValueError."""
        try:
            number = convert()
        except (ValueError, IndexError) as exc:
            raise yaml.constructor.ConstructorError(None, None, f"{show(node.value)} is not a number ({exc})",
                                                    node.start_mark) from None
        if isinstance(number, int) and number.bit_length() > 3000:
            raise yaml.constructor.ConstructorError(None, None, f"{show(node.value)} is not a number a config "
                                                    "takes (more than 900 digits)", node.start_mark)
        return number


# YAML 1.1 reads a number with an exponent and no dot (1e-3, 5E+2) as text; YAML 1.2, and a reader
# of a config, as a number. Quoted, it stays text, as a quoted '5' does.
_UniqueKeyLoader.add_implicit_resolver("tag:yaml.org,2002:float", re.compile(r"^[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)"
                                                                            r"[eE][-+]?[0-9]+$"), list("-+0123456789."))


# YAML 1.1 has no integer 08 or 09 (not octal), so they were text while 010 read as 10: decimal too.
_UniqueKeyLoader.add_implicit_resolver("tag:yaml.org,2002:int", re.compile(r"^[-+]?0[0-9_]+$"),
                                       list("-+0"))
_UniqueKeyLoader.add_constructor("tag:yaml.org,2002:int", _UniqueKeyLoader.construct_yaml_int)
_UniqueKeyLoader.add_constructor("tag:yaml.org,2002:float", _UniqueKeyLoader.construct_yaml_float)


def parse_yaml(text: str):
    """``text`` parsed by the safe loader, refusing repeated keys."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except RecursionError:  # [[[[...]]]] thousands deep
        raise yaml.YAMLError("nested too deeply to read") from None


def read_yaml(path: Path):
    """A YAML file's content, read within ``MAX_CONFIG_BYTES`` as UTF-8 and parsed by :func:`parse_yaml`;
    ConfigError naming the file when it cannot be."""
    try:
        return parse_yaml(read_text(path, MAX_CONFIG_BYTES))
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {' '.join(str(exc).split())}") from None
    except InputError as exc:
        raise ConfigError(str(exc)) from None


def _set_dotted(data: dict, dotted: str, value: Any) -> None:
    parts = dotted.split(".")
    if not all(parts):
        raise ConfigError(f"{show(dotted)} is not a dotted key (empty part)")
    node = data
    for part in parts[:-1]:
        node = node.setdefault(part, {})
        if not isinstance(node, dict):
            raise ConfigError(f"{cut(part)} is not a section")
    node[parts[-1]] = value


def load_config(cls: type[T], path: str | Path | None = None, overrides: list[str] | None = None,
                what: str = "override", unique: bool = False, labels: dict[str, str] | None = None) -> T:
    """Build ``cls`` from its defaults, a YAML file and ``key=value`` overrides.

    ``overrides`` use dotted keys for nested sections (``template.size_px=32``); values are
    parsed as YAML scalars; a later one wins, so code can lay its own over defaults. With
    ``unique`` (the entry points' user input) a key set twice to two values is refused instead,
    since the later would win without a word. Raises :class:`ConfigError` naming the file (for a
    file that is bad on its own) or the override (``what`` names them in messages; ``labels``, an
    override a command-line flag stands for, as the user wrote it: ``--particles 0``) and the key at
    fault.
    """
    data: dict = {}
    if path is not None:
        if not str(path).strip():  # Path('') is '.', the current folder
            raise ConfigError(f"the config file must be a path; got {show(str(path))}")
        # ~ as a shell would, which leaves --config=~/c.yaml as written; an unknown ~user stays as written (not
        # found), where Path.expanduser raises RuntimeError
        path = Path(os.path.expanduser(path))
        if not path.exists():
            raise ConfigError(f"config file not found: {path}")
        loaded = read_yaml(path)
        if loaded is not None and not isinstance(loaded, dict):
            raise ConfigError(f"{path}: top level must be a mapping; got {type(loaded).__name__}")
        data = loaded or {}
        try:
            built = _build(cls, data)
        except ConfigError as exc:
            raise ConfigError(f"{path}: {exc}") from None
        if not overrides:
            return built
    base = copy.deepcopy(data)
    labels = labels or {}
    parsed = override_leaves(cls, overrides or [], what, unique, labels)
    for item, leaf, value in parsed:
        try:
            _set_dotted(data, leaf, value)
        except ConfigError as exc:  # a key below one the file gives a value (seed.x=1)
            raise ConfigError(f"{_named([item], what, labels, show)}: {exc}") from None
    try:
        return _build(cls, data)
    except ConfigError as exc:
        # Blame the overrides that fail on their own; else (a clash of several) those whose key the
        # message names; else all. A message may list every key of a section (a range check's help).
        alone = [item for item, key, value in parsed if not _builds_with(cls, base, key, value)]
        named = [item for item, key, _ in parsed if _mentions(str(exc), key)]
        at_fault = list(dict.fromkeys(alone or named or [item for item, _, _ in parsed]))  # a mapping's keys: once
        raise ConfigError(f"{_named(at_fault, what, labels, cut) if at_fault else 'config'}: {exc}") from None


def _named(items: list[str], what: str, labels: dict[str, str], quote: Callable[[str], str]) -> str:
    """The overrides ``items`` as a message names them, each quoted by ``quote``: ``override 'a=1'``,
    ``overrides a=1, b=2``; one a flag stands for (``labels``) as the user wrote it (``--particles 0``)."""
    if not any(item in labels for item in items):
        return f"{what}{'s' if len(items) > 1 else ''} {', '.join(map(quote, items))}"
    return ", ".join(labels.get(item) or f"{what} {quote(item)}" for item in items)


def override_leaves(cls: type, overrides: list[str], what: str = "override", unique: bool = False,
                    labels: dict[str, str] | None = None) -> list[tuple[str, str, Any]]:
    """The ``key=value`` ``overrides`` of ``cls`` as (override, dotted key, value), one per key set, in
    order: a mapping given for a section stands for each of its keys. With ``unique`` a key set twice
    to two values is refused. ConfigError names the override (``what``, or its ``labels`` entry) at
    fault: one not of the form key=value, a value that is not YAML, a path through a key that is not a
    section."""
    labels = labels or {}
    parsed: list[tuple[str, str, Any]] = []
    data: dict = {}  # the overrides laid out, so that a key below a value (seed.x=1) is refused
    for item in overrides:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"{_named([item], what, labels, show)} is not of the form key=value")
        try:
            leaves = _leaves(cls, key.strip(), _override_value(cls, key.strip(), raw))
            for leaf, value in leaves:
                _set_dotted(data, leaf, value)
        except yaml.YAMLError as exc:
            raise ConfigError(f"{_named([item], what, labels, show)}: not a YAML value: "
                              f"{' '.join(str(exc).split())}") from None
        except ConfigError as exc:
            raise ConfigError(f"{_named([item], what, labels, show)}: {exc}") from None
        for leaf, value in leaves:
            earlier = next((other for other, k, v in parsed if unique and k == leaf and v != value), None)
            if earlier is not None:
                both = (f"{what}s {show(earlier)} and {show(item)}" if earlier not in labels and item not in labels
                        else f"{_named([earlier], what, labels, show)} and {_named([item], what, labels, show)}")
                raise ConfigError(f"{both} both set {cut(leaf)}; give one")
            parsed.append((item, leaf, value))
    return parsed


def check_seed(key: str, seed: int) -> None:
    """Raise ConfigError unless ``seed`` is one torch's generators take: [0, 2**64 - 1]."""
    if not 0 <= seed < 2 ** 64:
        raise ConfigError(f"{key} must be in [0, 2**64 - 1]; got {show(seed)}")


def _key_type(cls: type, dotted: str) -> Any:
    """The type of the dotted key in ``cls`` (a section's dataclass, or a field's type); None if unknown."""
    tp: Any = cls
    for part in dotted.split("."):
        tp = typing.get_type_hints(tp).get(part) if dataclasses.is_dataclass(tp) else None
    return tp


def _leaves(cls: type, dotted: str, value: Any) -> list[tuple[str, Any]]:
    """An override as (dotted key, value) pairs: a mapping given for a section stands for each of its
    keys, merged into the section (``tracker={filter: {sigma: 0.05}}`` sets tracker.filter.sigma and
    keeps the section's other values, as a file's section does)."""
    if isinstance(value, dict) and dataclasses.is_dataclass(_key_type(cls, dotted)):
        return [leaf for key, sub in value.items() for leaf in _leaves(cls, f"{dotted}.{key}", sub)]
    return [(dotted, value)]


def _override_value(cls: type, dotted: str, raw: str) -> Any:
    """An override's value: YAML, except for a text key (``out``, ``sequence``, ``name``), which
    takes ``raw`` as written (a path holding ``#`` or ``: ``, a name like ``2024``) unless it is
    quoted YAML, or ``null`` / ``~`` where the key may be null."""
    tp = _key_type(cls, dotted)
    arms = set(typing.get_args(tp)) if typing.get_origin(tp) in (typing.Union, types.UnionType) else {tp}
    if str not in arms or not arms <= {str, type(None)} or raw.strip()[:1] in ("'", '"'):
        return parse_yaml(raw)
    return None if type(None) in arms and raw.strip() in ("null", "~") else raw


def _builds_with(cls: type, base: dict, dotted: str, value: Any) -> bool:
    """Whether ``cls`` builds from ``base`` (a file's data, or none) with the one override ``dotted`` = ``value``."""
    data = copy.deepcopy(base)
    try:
        _set_dotted(data, dotted, value)
        _build(cls, data)
    except ConfigError:
        return False
    return True


def _mentions(message: str, dotted: str) -> bool:
    """True if ``message`` names the key ``dotted`` or a dotted tail of it (``init.speed_frames``,
    ``speed_frames``) as a whole word: ``frames`` is not named by ``speed_frames``."""
    parts = dotted.split(".")
    return any(re.search(rf"(?<![\w.]){re.escape('.'.join(parts[i:]))}(?!\w)", message) for i in range(len(parts)))


@dataclass(frozen=True)
class ModelConfig:
    """Fitting the generative model (chapter 4; METHOD.md "Generative model").

    The RBF centres are the training views (Nc = V). ``ridge`` is λ of the regularised least
    squares of every Bᵏ (eq. 4.13) on templates in [−1, 1]; ``width_steps`` > 0 tunes the kernel
    widths on held-out views with Adam at ``width_lr`` before the final fit. The class defaults
    tune nothing, as :meth:`GenerativeShapeModel.fit` has no held-out views unless given them;
    ``TrainConfig.model`` defaults to the shipped model's 50 steps (configs/default.yaml).
    """

    pixel_rank: int | None = 128  # r of the truncated pixel basis, in [1, 512²]; null keeps all d pixels
    ridge: float = 1e-4  # λ in [0, 1000] (at λ = 1000 the training IoU is down to ~0.66)
    init_width: float | None = None  # kernel width (chord) in [0.001, 4]; null: mean nearest-centre chord
    class_penalty: float | None = None  # a of eq. 4.8 in [0, 1e12]; null: (K + 1)·max D₀, keeps classes contiguous
    width_steps: int = 0  # Adam steps tuning the widths on validation views, at most 100000
    width_lr: float = 0.05  # Adam learning rate on log(width), in (0, 10]

    def __post_init__(self) -> None:
        if self.pixel_rank is not None and not 1 <= self.pixel_rank <= MAX_TEMPLATE_PX ** 2:
            raise ConfigError(f"model.pixel_rank must be in [1, {MAX_TEMPLATE_PX ** 2}] or null; "
                              f"got {show(self.pixel_rank)}")
        if not 0 <= self.ridge <= 1000:
            raise ConfigError(f"model.ridge must be in [0, 1000]; got {self.ridge}")
        # Chords between unit view vectors are at most 2: wider kernels make every Ψ column alike.
        if self.init_width is not None and not 0.001 <= self.init_width <= 4:
            raise ConfigError(f"model.init_width must be in [0.001, 4] or null; got {self.init_width}")
        if self.class_penalty is not None and not 0 <= self.class_penalty <= 1e12:
            raise ConfigError(f"model.class_penalty must be in [0, 1e12] or null; got {self.class_penalty}")
        if not 0 <= self.width_steps <= 100_000:
            raise ConfigError(f"model.width_steps must be in [0, 100000]; got {show(self.width_steps)}")
        if not 0 < self.width_lr <= 10:
            raise ConfigError(f"model.width_lr must be in (0, 10]; got {self.width_lr}")
