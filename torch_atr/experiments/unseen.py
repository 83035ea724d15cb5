"""Unseen real vehicles: the held-out public meshes driven through the simulator and tracked.

Every mesh of the held-out manifest (``torch_atr/vehicles/heldout.yaml``, files under
``shared/data/meshes``; never trained on) drives the SENSIAC-like circle at 1000-2500 m and is
tracked from the simulated frames, by default with Method I. The sequences run through the same
resumable runner as the SENSIAC-like grid (:func:`~torch_atr.experiments.sensiac_like.run_all`);
a held-out mesh is named ``heldout:PATH`` in the config, PATH as in the manifest. The report:

- per mesh: % of frames on the true class per range, the tracking errors over the ranges, and
  the two training vehicles nearest the run's mean α at the nearest range;
- per class: the meshes' mean recognition per range;
- meshes outside the six classes (``truck/``, ``military_utility/``, class "unknown") with their
  two nearest training vehicles per range, as the thesis reports unknown targets.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import torch_atr
from torch_atr.experiments.report import MEASURES, scene_note
from torch_atr.experiments.sensiac_like import HELDOUT_PREFIX, SensiacLikeConfig, heldout_names, mean_or_none
from torch_atr.io import atomic_write_text

UNSEEN_FORMAT = "torch_atr.unseen_report"


def unseen_fields(quick: bool) -> dict:
    """The unseen grid's SensiacLikeConfig fields; ``quick``: a tank and a truck at 1000 m (CI)."""
    if quick:
        vehicles = (HELDOUT_PREFIX + "tank/quaternius_tank1.obj", HELDOUT_PREFIX + "truck/gazebo_fire_truck.obj")
        return {"vehicles": vehicles, "ranges_m": (1000.0,), "methods": ("I",), "frames": 24, "particles": 300}
    return {"vehicles": heldout_names(), "ranges_m": (1000.0, 1500.0, 2000.0, 2500.0), "methods": ("I",)}


def _cell(values: list) -> str:
    return "/".join("—" if v is None else f"{v:.0f}" for v in values)


def aggregate_unseen(results: list[dict], cfg: SensiacLikeConfig) -> dict:
    """The unseen report's tables from the sequences' results (``results.json``'s "aggregate").

    Returns {"meshes": {name: {"class", "recognition": {range: {method: % or None}}, "errors":
    {measure: {method: mean over ranges}}, "best_matches": {range: {method: [two names]}}}},
    "classes": {class: {range: {method: mean % over the class's meshes}}}}; "unknown" meshes have
    no recognition (None) and no class row.
    """
    meshes: dict = {}
    for r in results:
        mesh = meshes.setdefault(r["vehicle"], {"class": r["class"], "recognition": {}, "errors": {},
                                                "best_matches": {}})
        key = f"{r['range_m']:g}"
        mesh["recognition"][key] = {m: None if v["metrics"]["recognition_accuracy"] is None
                                    else 100 * v["metrics"]["recognition_accuracy"] for m, v in r["methods"].items()}
        mesh["best_matches"][key] = {m: v["metrics"]["best_matches"] for m, v in r["methods"].items()}
    for name, mesh in meshes.items():
        rows = [r for r in results if r["vehicle"] == name]
        for measure, _ in MEASURES:
            mesh["errors"][measure] = {}
            for m in cfg.methods:
                mesh["errors"][measure][m] = mean_or_none([r["methods"][m]["metrics"][measure] for r in rows])
    classes: dict = {}
    for cls in sorted({m["class"] for m in meshes.values()} - {"unknown"}):
        of_class = [m for m in meshes.values() if m["class"] == cls]
        classes[cls] = {f"{r:g}": {m: mean_or_none([x["recognition"][f"{r:g}"][m] for x in of_class])
                                   for m in cfg.methods}
                        for r in cfg.ranges_m}
    return {"meshes": meshes, "classes": classes}


def write_unseen_report(out: Path, cfg: SensiacLikeConfig, results: list[dict], wall_s: float) -> dict:
    """``results.json`` and ``report.md`` in ``out``, atomically; returns the aggregate."""
    agg = aggregate_unseen(results, cfg)
    summary = {"format": UNSEEN_FORMAT, "torch_atr_version": torch_atr.__version__,
               "config": dataclasses.asdict(cfg), "wall_s": wall_s, "aggregate": agg,
               "sequences": [{k: v for k, v in r.items() if k != "config"} for r in results]}
    atomic_write_text(json.dumps(summary, indent=1) + "\n", out / "results.json")
    ranges = [f"{r:g}" for r in cfg.ranges_m]
    methods = "/".join(cfg.methods)
    near = f"{min(cfg.ranges_m):g}"  # the ranges as the user listed them, in any order
    known = {n: m for n, m in agg["meshes"].items() if m["class"] != "unknown"}
    unknown = {n: m for n, m in agg["meshes"].items() if m["class"] == "unknown"}
    lines = [
        "# Unseen real vehicles on the simulator",
        "",
        f"{len(agg['meshes'])} held-out mesh(es) (never trained on) × {len(ranges)} range(s) × Methods "
        f"{', '.join(cfg.methods)}; {cfg.frames} frames per sequence on a {cfg.circle_diameter_m:g} m circle, "
        f"{cfg.particles} particles, {cfg.init} start, seed {cfg.seed}{scene_note(cfg)}; "
        f"torch_atr {torch_atr.__version__}.",
        "",
        f"## Recognition per mesh: % of frames on the true class, Methods {methods}",
        "",
        "| mesh | class | " + " | ".join(f"{r} m" for r in ranges) + " | "
        + " | ".join(f"{label} {methods}" for _, label in MEASURES) + f" | two best matches at {near} m |",
        "|---" * (len(ranges) + len(MEASURES) + 3) + "|",
    ]
    for name, mesh in known.items():
        lines.append(
            f"| {name.removeprefix(HELDOUT_PREFIX)} | {mesh['class']} | "
            + " | ".join(_cell([mesh["recognition"][r][m] for m in cfg.methods]) for r in ranges) + " | "
            + " | ".join("/".join("—" if mesh["errors"][k][m] is None else f"{mesh['errors'][k][m]:.2f}"
                                  for m in cfg.methods) for k, _ in MEASURES) + " | "
            + ", ".join(mesh["best_matches"][near][cfg.methods[0]]) + " |")
    lines += ["", f"## Per class: mean % of frames on the true class over the class's meshes, Methods {methods}", "",
              "| class | meshes | " + " | ".join(f"{r} m" for r in ranges) + " |",
              "|---" * (len(ranges) + 2) + "|"]
    for cls, cells in agg["classes"].items():
        count = sum(m["class"] == cls for m in known.values())
        lines.append(f"| {cls} | {count} | " + " | ".join(_cell([cells[r][m] for m in cfg.methods]) for r in ranges)
                     + " |")
    if unknown:
        lines += ["", f"## Outside the six classes: the two nearest training vehicles, Method {cfg.methods[0]}", "",
                  "| mesh | " + " | ".join(f"{r} m" for r in ranges) + " |", "|---" * (len(ranges) + 1) + "|"]
        for name, mesh in unknown.items():
            lines.append(f"| {name.removeprefix(HELDOUT_PREFIX)} | "
                         + " | ".join(", ".join(mesh["best_matches"][r][cfg.methods[0]]) for r in ranges) + " |")
    lines += ["", "## Run", "",
              f"- {len(results)} sequences; wall time {wall_s:.0f} s (this run; sequences kept from an earlier run "
              "are not re-run).",
              "- config: `" + json.dumps(dataclasses.asdict(cfg)) + "`.", ""]
    atomic_write_text("\n".join(lines), out / "report.md")
    return agg
