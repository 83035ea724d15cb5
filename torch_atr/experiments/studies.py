"""Studies beyond the thesis: one setting changed at a time against a baseline, Method I.

The baseline is the SENSIAC-like grid's 8 test vehicles at 1000 and 2500 m (night, 1000
particles, blind start, 150 frames), tracked with Method I. Each study changes one thing:

- particles: 250, 4000 and 16 000 instead of 1000;
- range: 4000, 4500 and 5000 m, which the thesis did not report;
- day: the simulator's low-contrast day scene instead of night;
- occlusion: a 12 m wide, 1 m high berm 20 m in front of the middle of the drive;
- turret: every turret sweeping ±60° every 8 s.

The quick run (``QUICK``: the T-72 at 1000 m, 12 frames) takes fewer particles (``QUICK_PARTICLES``)
and 4000 m alone for the range study; the report's rows name the particles and ranges each setting ran.

Each setting is a grid of its own in ``OUT/<setting>/`` (resumable, through
:func:`~torch_atr.experiments.sensiac_like.run_all`); ``OUT/report.md`` and ``OUT/results.json``
hold one row per setting and range: recognition, mean errors and frames per second.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import torch_atr
from torch_atr.experiments.report import MEASURES
from torch_atr.experiments.sensiac_like import (SensiacLikeConfig, mean_or_none, pooled_frames_per_second,
                                              run_all)
from torch_atr.io import atomic_write_text

STUDIES_FORMAT = "torch_atr.studies_report"
BASELINE = {"methods": ("I",), "ranges_m": (1000.0, 2500.0)}
# name -> (what changes, {particles} and {ranges} filled in by study_label from the config run;
# SensiacLikeConfig fields on top of BASELINE). The names, and the folders, keep the full run's numbers.
SETTINGS = {
    "baseline": ("night, {particles} particles", {}),
    "particles_250": ("{particles} particles", {"particles": 250}),
    "particles_4000": ("{particles} particles", {"particles": 4000}),
    "particles_16000": ("{particles} particles", {"particles": 16000}),
    "range_4000_5000": ("{ranges} m", {"ranges_m": (4000.0, 4500.0, 5000.0)}),
    "day": ("day scene (low contrast)", {"scene": ("night=false",)}),
    "occlusion": ("12 m x 1 m berm in front", {"scene": ("occluder_width_m=12", "occluder_height_m=1.0")}),
    "turret": ("turrets sweeping ±60°", {"scene": ("turret_sweep_deg=60",)}),
}
QUICK = {"vehicles": ("t_72",), "ranges_m": (1000.0,), "frames": 12, "particles": 200}
QUICK_PARTICLES = {"particles_250": 100, "particles_4000": 400, "particles_16000": 800}


def study_configs(quick: bool = False, **given) -> dict[str, SensiacLikeConfig]:
    """Every setting's config; ``quick``: the CI-sized one (the T-72 at 1000 m, 12 frames).
    ``given`` fields (init, seed, checkpoint, frames) apply to every setting."""
    configs = {}
    for name, (_, fields) in SETTINGS.items():
        merged = {**BASELINE, **(QUICK if quick else {}), **given, **fields}
        if quick:
            merged["ranges_m"] = (4000.0,) if name.startswith("range") else QUICK["ranges_m"]
            merged["particles"] = QUICK_PARTICLES.get(name, QUICK["particles"])
        configs[name] = SensiacLikeConfig(**merged)
    return configs


def study_label(name: str, cfg: SensiacLikeConfig) -> str:
    """What setting ``name`` changes, as the report's rows say it, with the particles and ranges
    ``cfg`` runs (a quick run's are not the full run's): "night, 200 particles", "4000-5000 m"."""
    ranges = "-".join(f"{r:g}" for r in sorted({min(cfg.ranges_m), max(cfg.ranges_m)}))
    return SETTINGS[name][0].format(particles=cfg.particles, ranges=ranges)


def run_studies(out: Path, configs: dict[str, SensiacLikeConfig], workers: int = 0,
                ray_address: str | None = None) -> dict[str, list[dict]]:
    """Run every setting's grid in ``out/<setting>`` (resumable); its results by setting."""
    return {name: run_all(cfg, out / name, workers, ray_address=ray_address) for name, cfg in configs.items()}


def study_rows(configs: dict[str, SensiacLikeConfig], results: dict[str, list[dict]]) -> list[dict]:
    """One row per setting and range: {"setting", "change" (:func:`study_label`), "range_m", "sequences",
    "recognition_pct" (mean over the vehicles of % of frames on the true class; vehicles of a class the
    model does not know have none, and a row of only those None), the MEASURES' means, "frames_per_second"}."""
    rows = []
    for name, seqs in results.items():
        for range_m in sorted({r["range_m"] for r in seqs}):
            metrics = [r["methods"]["I"]["metrics"] for r in seqs if r["range_m"] == range_m]
            row = {"setting": name, "change": study_label(name, configs[name]), "range_m": range_m,
                   "sequences": len(metrics),
                   "recognition_pct": mean_or_none([None if m["recognition_accuracy"] is None
                                                    else 100 * m["recognition_accuracy"] for m in metrics])}
            row.update({k: mean_or_none([m[k] for m in metrics]) for k, _ in MEASURES})
            row["frames_per_second"] = pooled_frames_per_second(metrics)
            rows.append(row)
    return rows


def write_studies_report(out: Path, configs: dict[str, SensiacLikeConfig], results: dict[str, list[dict]],
                         wall_s: float) -> list[dict]:
    """``results.json`` and ``report.md`` in ``out``, atomically; returns the rows."""
    rows = study_rows(configs, results)
    summary = {"format": STUDIES_FORMAT, "torch_atr_version": torch_atr.__version__, "wall_s": wall_s,
               "configs": {n: dataclasses.asdict(c) for n, c in configs.items()}, "rows": rows}
    atomic_write_text(json.dumps(summary, indent=1) + "\n", out / "results.json")
    base = configs["baseline"]
    lines = ["# Studies beyond the thesis, on the simulator", "",
             f"{len(base.vehicles)} test vehicle(s), Method I, {base.frames} frames per sequence, {base.init} start, "
             f"seed {base.seed}; each row changes one thing against the baseline; torch_atr {torch_atr.__version__}.",
             "", "| setting | range (m) | recognition (%) | " + " | ".join(label for _, label in MEASURES)
             + " | frames/s |", "|---" * (4 + len(MEASURES)) + "|"]
    for row in rows:
        errors = " | ".join("—" if row[k] is None else f"{row[k]:.2f}" for k, _ in MEASURES)
        recognition = "—" if row["recognition_pct"] is None else f"{row['recognition_pct']:.0f}"
        lines.append(f"| {row['change']} | {row['range_m']:g} | {recognition} | {errors} | "
                     f"{row['frames_per_second']:.1f} |")
    lines += ["", f"Wall time {wall_s:.0f} s (this run; sequences kept from an earlier run are not re-run). "
              "Each setting's sequences and config are in its folder.", ""]
    atomic_write_text("\n".join(lines), out / "report.md")
    return rows
