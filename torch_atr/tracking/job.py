"""``track.py``'s job: its typed config, the metrics of a run and the files it writes.

Outputs of a run folder (README, "Command line"): ``estimates.csv`` (one row per frame),
``config.yaml`` (the resolved config), PNG figures and, last, ``metrics.json``, each written
atomically.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from torch_atr.config import ConfigError, check_seed
from torch_atr.data.sequence import SPEC_RE, parse_spec_options, read_json_object
from torch_atr.evaluation import best_matches, frames_to_convergence, recognition_accuracy, tracking_errors
from torch_atr.io import atomic_write_csv, atomic_write_text
from torch_atr.tracking.filter import TrackerConfig, TrackResult, column, estimate_and_truth, row_errors
from torch_atr.validate import show

DEFAULT_SEQUENCE = "synthetic:vehicle=t_72,range=1000,frames=300,seed=0"
METRICS_FORMAT = "torch_atr.track_metrics"  # metrics.json's "format": marks a run folder as ours

# A frame is "on target" for frames_to_convergence when all three hold (the tracker issue's bars).
CONVERGED_HORIZONTAL_M = 1.0
CONVERGED_ASPECT_RAD = 0.3
CONVERGED_FRAMES = 10  # ... in this many frames in a row


@dataclass(frozen=True)
class TrackConfig:
    """``track.py``'s config: ``configs/track.yaml`` holds the defaults, ``key=value`` overrides them."""

    sequence: str = DEFAULT_SEQUENCE  # any open_sequence spec; the default is a built-in test-split sequence
    checkpoint: str = "checkpoints/default.pt"
    out: str = "runs/track"  # the run folder
    device: str = "cpu"  # cpu, cuda, cuda:1, mps, ...
    seed: int = 0
    frames: int | None = None  # track only the first frames; null: all
    tensorboard: bool = False  # also log scalars and figures to TensorBoard in the run folder
    video: bool = False  # also write overlay.mp4: every frame with the estimate's contour
    tracker: TrackerConfig = field(default_factory=TrackerConfig)

    def __post_init__(self) -> None:
        check_seed("seed", self.seed)
        if self.frames is not None and not 1 <= self.frames <= 10_000_000:
            raise ConfigError(f"frames must be null or in [1, 1e7]; got {self.frames!r}")
        if not self.sequence.strip():
            raise ConfigError("sequence must be a sequence spec; got an empty string")
        for key in ("checkpoint", "out"):
            path = getattr(self, key)
            if not path.strip():  # Path('') is '.': a blank out wrote the run's files into the current folder
                raise ConfigError(f"{key} must be a path; got {show(path)}")
            object.__setattr__(self, key, os.path.expanduser(path))  # ~ as a shell would, for paths from config files


def _absolute(path: str) -> str:
    """``path`` (``~`` expanded) as an absolute path, its symbolic links kept (a linked clip keeps its
    name); a glob's pattern kept."""
    return os.path.abspath(os.path.expanduser(path))


def absolute_spec(spec: str) -> str:
    """The open_sequence ``spec`` with the files it reads as absolute paths, so that it opens the same
    sequence from any folder: a folder (bare or ``folder:``), the file or glob and ``calib=`` of
    ``video:`` and ``sensiac:``, and a ``synthetic:`` ``vehicle=`` that is a file. A built-in name
    (``synthetic:vehicle=t_72,...``) and a spec of any other scheme stay as given."""
    m = SPEC_RE.fullmatch(spec)
    if m is None:
        return _absolute(spec)
    scheme, rest = m.groups()
    if scheme.lower() == "folder":
        return f"{scheme}:{_absolute(rest)}"
    if scheme.lower() in ("video", "sensiac"):
        target, options = parse_spec_options(rest)
        options = {k: _absolute(v) if k == "calib" else v for k, v in options.items()}
        return ",".join([f"{scheme}:{_absolute(target)}", *(f"{k}={v}" for k, v in options.items())])
    if scheme.lower() == "synthetic":
        _, options = parse_spec_options(rest, has_target=False)
        vehicle = options.get("vehicle", "")
        if os.path.isfile(vehicle):  # a file, as the simulator reads it (no ~); else a name, too long ones too
            options["vehicle"] = os.path.abspath(vehicle)
        return f"{scheme}:" + ",".join(f"{k}={v}" for k, v in options.items())
    return spec


def track_metrics(rows: list[dict], model, first: int = 0) -> dict:
    """Errors, recognition, best matches and overlap of estimate rows from frame ``first`` on;
    null where the sequence has no truth."""
    rows = rows[first:]
    overlap = column(rows, "overlap")
    return {**tracking_errors(*estimate_and_truth(rows)),
            "recognition_accuracy": recognition_accuracy(model, column(rows, "alpha"),
                                                         [r.get("true_class", "") for r in rows]),
            "best_matches": best_matches(model, column(rows, "alpha")),
            "overlap_ratio": float(np.nanmean(overlap)) if np.isfinite(overlap).any() else None,
            "frames": len(rows), "first_frame": first, "lost_frames": int(sum(r["lost"] for r in rows))}


def run_summary(result: TrackResult, model, settle_frames: int) -> dict:
    """``metrics.json``: the metrics over all frames, over the frames after ``settle_frames``
    (``settled``; None for a run no longer than that), the frames to convergence (and to convergence
    up to the silhouette's mirror θ ↔ π − θ, :func:`~torch_atr.evaluation.mirror_aspect_error`) and
    the speed."""
    rows = result.rows
    known = [r.get("true_class", "") in model.class_names for r in rows]
    ok = np.array([r.get("class") == r.get("true_class") for r in rows]) & np.array(known)
    errors = row_errors(rows)
    if np.isfinite(errors["horizontal_error_m"]).any():  # a bar no frame can be measured on (SENSIAC's truth
        ok &= errors["horizontal_error_m"] < CONVERGED_HORIZONTAL_M  # has no x) is left out
    summary = {"format": METRICS_FORMAT, **track_metrics(rows, model)}
    summary["settled"] = track_metrics(rows, model, settle_frames) if len(rows) > settle_frames else None
    for suffix, key in (("", "aspect_error_rad"), ("_up_to_mirror", "aspect_error_up_to_mirror_rad")):
        aspect = errors[key]
        on = ok & (aspect < CONVERGED_ASPECT_RAD) if np.isfinite(aspect).any() else ok
        summary[f"frames_to_convergence{suffix}"] = frames_to_convergence(on, CONVERGED_FRAMES) if any(known) else None
    summary["frames_per_second"] = result.frames_per_second
    return summary


def is_track_run(path: Path) -> bool:
    """True when ``path`` is a metrics.json written by track.py (its format is ours)."""
    try:
        return read_json_object(path, "").get("format") == METRICS_FORMAT
    except (OSError, ValueError):
        return False


def write_run(folder: Path, cfg: TrackConfig, result: TrackResult) -> None:
    """``estimates.csv`` and ``config.yaml`` in ``folder``, each atomically; ``metrics.json`` comes
    last (:func:`write_metrics`)."""
    atomic_write_csv(result.rows, folder / "estimates.csv")
    atomic_write_text(yaml.safe_dump(dataclasses.asdict(cfg), sort_keys=False), folder / "config.yaml")


def write_metrics(folder: Path, metrics: dict) -> None:
    """``metrics.json`` in ``folder``, atomically: the mark of a finished run (:func:`is_track_run`),
    so written after every other output; a run killed or failed before it reads as interrupted."""
    atomic_write_text(json.dumps(metrics, indent=2) + "\n", folder / "metrics.json")
