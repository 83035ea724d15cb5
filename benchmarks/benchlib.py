"""What the benchmark scripts share: the shipped checkpoint, argument checks and output files.

Every script's entry point runs through :func:`torch_atr.cli.run_main`, so a bad argument is one
line, ``bench_x.py: error: MESSAGE``, and exit status 2, before any work starts. An output
(``--json``, ``--figure``) is checked before the work too: its folder must exist and be
writable, and an existing file is replaced only with ``--overwrite`` and only when it is ours: a
JSON object that the same benchmark wrote (its ``"benchmark"`` key names the script), or a PNG
that matplotlib wrote (its ``Software`` text chunk). Outputs are written atomically.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

from torch_atr.config import ConfigError
from torch_atr.data.synthetic import SceneConfig, SyntheticSequence
from torch_atr.io import atomic_write_text, check_output_file, check_writable, strict_json
from torch_atr.validate import read_json_object, real

log = logging.getLogger("benchmarks")

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "checkpoints" / "default.pt"  # the default --checkpoint, wherever the script runs from
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MATPLOTLIB_PNG = b"tEXtSoftware\x00Matplotlib"  # the text chunk matplotlib writes before the pixels


def check_at_least(flag: str, values: float | list[float], low: float) -> None:
    """``validate.real`` of each of ``values`` (one or a list) naming ``--flag``: a finite number >= ``low``."""
    for value in values if isinstance(values, (list, tuple)) else [values]:
        real(f"--{flag}", value, lo=low)


def json_output(path: str | Path | None, overwrite: bool, benchmark: str) -> Path | None:
    """The ``--json`` path checked before the run (None when not asked for): see the module docstring."""
    if path is None:
        return None
    return _checked(check_output_file(path, overwrite, lambda p: _benchmark_of(p) == benchmark, f"{benchmark} JSON"))


def png_output(path: str | Path | None, overwrite: bool, flag: str) -> Path | None:
    """The PNG path of ``--flag`` checked before the run (None when not asked for): see the module docstring."""
    if path is None:
        return None
    if Path(path).suffix != ".png":
        raise ConfigError(f"--{flag} must be a .png file; got {path}")
    return _checked(check_output_file(path, overwrite, _is_matplotlib_png, "matplotlib PNG"))


def write_json(data: dict, path: Path, benchmark: str) -> None:
    """Write ``data`` to ``path`` atomically, marked as ``benchmark``'s (the key :func:`json_output` looks for),
    as strict JSON: a NaN or infinite number is written null (no value), which every reader, and
    the check of an earlier output before ``--overwrite``, takes."""
    atomic_write_text(json.dumps(strict_json({"benchmark": benchmark, **data}), indent=2, allow_nan=False) + "\n",
                      path)
    log.info("wrote %s", path)


def _checked(path: Path) -> Path:
    """``path`` once its folder is known to exist and to take files (a typo'd folder is not created)."""
    if not path.parent.is_dir():
        raise FileNotFoundError(f"cannot write {path}: the folder {path.parent} does not exist")
    check_writable(path)
    return path


def _benchmark_of(path: Path) -> str | None:
    """The ``"benchmark"`` key of the JSON object in ``path`` (None for anything else)."""
    try:
        return read_json_object(path, "").get("benchmark")
    except (OSError, ValueError):
        return None


def _is_matplotlib_png(path: Path) -> bool:
    with open(path, "rb") as fh:
        head = fh.read(4096)
    return head.startswith(PNG_SIGNATURE) and MATPLOTLIB_PNG in head


def sequence(vehicle: str, scene: SceneConfig, range_m: float) -> SyntheticSequence:
    """The simulated sequence of ``vehicle`` at ``range_m`` (``scene`` otherwise); ConfigError names a
    bad vehicle or range as the flags that gave them."""
    try:
        return SyntheticSequence(vehicle, dataclasses.replace(scene, range_m=range_m))
    except ValueError as exc:
        raise ConfigError(f"--vehicles {vehicle} --ranges {range_m:g}: {exc}") from None
