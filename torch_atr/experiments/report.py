"""The report of an experiment: ``report.md``, ``results.json`` and the figures, written atomically.

- Table 6.1's analogue: the percentage of frames recognised per class group (tanks, APCs, SUVs,
  pick-ups, then any other class run) and range, the four methods as ``I/II/III/IV`` like the thesis, beside its numbers
  where it gives them (1000 m and 3500 m);
- Fig. 6.8's analogue: mean horizontal, range and aspect errors per range per method, as a figure
  (``errors_by_range.png``) and a table;
- Fig. 6.10's analogue: α over time at 1000 m for every vehicle, with the class arcs
  (``identity_1000m.png``);
- run time, frames per second, the exact config and the package version.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import numpy as np

import torch_atr
from torch_atr.experiments.sensiac_like import GROUPS, SensiacLikeConfig, aggregate
from torch_atr.io import RUN_CLAIM, atomic_write_text, claim_of, created_folders, write_claim
from torch_atr.viz import class_arc_bands, pyplot, save_figures, span_run

REPORT_FORMAT = "torch_atr.sensiac_like_report"

# Table 6.1 of the thesis (Method I / II / III / IV, % of frames), the ranges it prints.
THESIS_TABLE_6_1 = {"1000": {"tank": (96, 94, 91, 90), "apc": (94, 92, 89, 88), "suv": (100, 100, 99, 99),
                             "pickup": (100, 100, 100, 99)},
                    "3500": {"tank": (68, 62, 58, 57), "apc": (70, 65, 64, 62), "suv": (78, 76, 75, 70),
                             "pickup": (73, 72, 70, 65)}}
GROUP_TITLES = {"tank": "Tanks", "apc": "APCs", "suv": "SUVs", "pickup": "Pick-ups"}
MEASURES = (("horizontal_error_m", "horizontal error (m)"), ("range_error_m", "range error (m)"),
            ("aspect_error_rad", "aspect error (rad)"))


def scene_note(cfg: SensiacLikeConfig) -> str:
    """", scene night=false, ..." for a run with scene overrides; "" without."""
    return f", scene {', '.join(cfg.scene)}" if cfg.scene else ""


def errors_figure(agg: dict, cfg: SensiacLikeConfig):
    """Mean errors per range, one line per method (Fig. 6.8). Returns a Figure."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    ranges = [f"{r:g}" for r in cfg.ranges_m]
    for ax, (measure, label) in zip(axes, MEASURES):
        for method in cfg.methods:
            values = [agg["errors"][measure][r][method] for r in ranges]
            ax.plot(cfg.ranges_m, [math.nan if v is None else v for v in values], "o-", label=f"Method {method}")
        ax.set(xlabel="range (m)", ylabel=label, title=label.split(" (")[0])
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    vehicles = f"{len(cfg.vehicles)} test vehicle" + ("s" if len(cfg.vehicles) != 1 else "")
    fig.suptitle(f"Mean tracking errors over the {vehicles} per range "
                 f"({cfg.init} start, {cfg.frames} frames, {cfg.particles} particles)")
    fig.tight_layout()
    return fig


def identity_figure(results: list[dict], model, range_m: float = 1000.0):
    """α over time for every vehicle at ``range_m`` with Method I (Fig. 6.10). Returns a Figure or None."""
    rows = [r for r in results if r["range_m"] == range_m and "I" in r["methods"]]
    if not rows:
        return None
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(10, 5))
    class_arc_bands(ax, model)  # keyed in class order, as alpha_over_time.png
    for k, r in enumerate(rows):
        method = r["methods"]["I"]
        ax.plot(method["time_s"], [math.nan if a is None else a for a in method["alpha"]], ".", ms=2,
                clip_on=False, color=plt.get_cmap("Dark2")(k % 8), label=f"{r['vehicle']} ({r['class']}): "
                + ", ".join(method["metrics"]["best_matches"]))
    span_run(ax, np.concatenate([np.asarray(r["methods"]["I"]["time_s"], dtype=np.float64) for r in rows]))
    ax.set(xlabel="time (s)", ylabel="identity α (rad)", ylim=(0, 2 * math.pi),
           title=f"Identity over time at {range_m:g} m, Method I\n(legend: each vehicle's two best-matching "
                 "training vehicles)")
    ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=7, markerscale=4)
    fig.tight_layout()
    return fig


def _recognition_table(agg: dict, cfg: SensiacLikeConfig) -> list[str]:
    groups = list(agg["recognition"])  # Table 6.1's, then other classes (no thesis number: —)
    lines = ["| range (m) | " + " | ".join(GROUP_TITLES.get(g, g) for g in groups) + " |",
             "|---" * (len(groups) + 1) + "|"]
    for range_m in cfg.ranges_m:
        r = f"{range_m:g}"
        cells = ["/".join(f"{agg['recognition'][g][r][m]:.0f}" for m in cfg.methods) for g in groups]
        lines.append(f"| {r} (ours) | " + " | ".join(cells) + " |")
        if r in THESIS_TABLE_6_1 and tuple(cfg.methods) == ("I", "II", "III", "IV"):
            lines.append(f"| {r} (thesis, SENSIAC) | " + " | ".join(
                "/".join(str(v) for v in THESIS_TABLE_6_1[r][g]) if g in GROUPS else "—" for g in groups) + " |")
    return lines


def _errors_table(agg: dict, cfg: SensiacLikeConfig) -> list[str]:
    lines = ["| range (m) | " + " | ".join(f"{label} {'/'.join(cfg.methods)}" for _, label in MEASURES) + " |",
             "|---" * 4 + "|"]
    for range_m in cfg.ranges_m:
        r = f"{range_m:g}"
        cells = ["/".join("—" if agg["errors"][m][r][k] is None else f"{agg['errors'][m][r][k]:.2f}"
                          for k in cfg.methods) for m, _ in MEASURES]
        lines.append(f"| {r} | " + " | ".join(cells) + " |")
    return lines


def _error_coverage(results: list[dict], cfg: SensiacLikeConfig) -> list[str]:
    """A line for each range and method whose error means leave out vehicles without an estimate
    (never tracked: recognition counts them as 0 %, the errors cannot)."""
    lines = []
    for range_m in cfg.ranges_m:
        cell = [r for r in results if r["range_m"] == range_m]
        for m in cfg.methods:
            known = sum(r["methods"][m]["metrics"]["horizontal_error_m"] is not None for r in cell)
            if known < len(cell):
                lines.append(f"- At {range_m:g} m, Method {m}'s errors average {known} of the {len(cell)} vehicles: "
                             "the others had no estimate (recognition counts them as 0 %).")
    return [*lines, ""] if lines else []


def write_report(out: Path, cfg: SensiacLikeConfig, results: list[dict], model, wall_s: float) -> dict:
    """``results.json``, ``report.md`` and the figures in ``out``; returns the aggregate."""
    agg = aggregate(results, cfg)
    summary = {"format": REPORT_FORMAT, "torch_atr_version": torch_atr.__version__,
               "config": dataclasses.asdict(cfg), "wall_s": wall_s, "aggregate": agg,
               "sequences": [{k: v for k, v in r.items() if k != "config"} for r in results]}
    atomic_write_text(json.dumps(summary, indent=1) + "\n", out / "results.json")
    figures = {"errors_by_range": errors_figure(agg, cfg)}
    identity = identity_figure(results, model)
    if identity is not None:
        figures["identity_1000m"] = identity
    save_figures(figures, out)
    frames = sum(len(r["methods"][m]["alpha"]) for r in results for m in r["methods"])
    lines = [
        "# SENSIAC-like experiment (thesis chapter 6.2) on the simulator",
        "",
        f"{len(cfg.vehicles)} vehicle(s) × {len(cfg.ranges_m)} range(s) × Methods {', '.join(cfg.methods)}; "
        f"{cfg.frames} frames per sequence on a {cfg.circle_diameter_m:g} m circle, {cfg.particles} particles, "
        f"{cfg.init} start, seed {cfg.seed}{scene_note(cfg)}; "
        f"torch_atr {torch_atr.__version__}. Ours is a simulator, the thesis's is SENSIAC's real infrared "
        "footage: the numbers sit side by side, they are not the same experiment.",
        "",
        "## Recognition: % of frames whose α lies in the true class's arc (Table 6.1), Methods "
        + "/".join(cfg.methods),
        "",
        *_recognition_table(agg, cfg),
        "",
        "## Mean tracking errors over the vehicles (Fig. 6.8)",
        "",
        *_errors_table(agg, cfg),
        "",
        *_error_coverage(results, cfg),
        "![errors by range](errors_by_range.png)",
        "",
        *(["## Identity over time at 1000 m (Fig. 6.10)", "", "![identity](identity_1000m.png)", ""]
          if "identity_1000m" in figures else []),
        "## Run",
        "",
        f"- {len(results)} sequences, {frames} tracked frames; wall time {wall_s:.0f} s (this run; sequences "
        "kept from an earlier run are not re-run).",
        "- tracking frames per second (segmentation included), per method: "
        + ", ".join(f"{m} {agg['frames_per_second'][m]:.1f}" for m in cfg.methods) + ".",
        "- config: `" + json.dumps(dataclasses.asdict(cfg)) + "`.",
        "",
    ]
    atomic_write_text("\n".join(lines), out / "report.md")
    return agg


def report_format(path: Path) -> str | None:
    """The ``format`` of the folder ``path``'s results.json; None where it has none (no file, not
    JSON, no format)."""
    try:
        written = json.loads((path / "results.json").read_text(encoding="utf-8")).get("format")
    except (OSError, ValueError, AttributeError):
        return None
    return written if isinstance(written, str) else None


def is_report_folder(path: Path) -> bool:
    """True for a folder an experiment wrote (its results.json is ours) or is writing (its claim).
    A folder's name or layout says nothing: a user's own sequences/ beside their report.md and
    results.json had them replaced."""
    written = report_format(path)
    return any(f is not None and f.startswith("torch_atr.") for f in (written, claim_of(path)))  # not track.py's


@contextmanager
def claimed_report_folder(out: Path, report: str, runs: tuple[str, ...] = ("sequences",)) -> Iterator[Path]:
    """Make ``out`` and its ``runs`` folders, and claim ``out`` (:func:`~torch_atr.io.write_claim`) for
    the experiment whose report format is ``report`` before any work, so that an interrupted run's
    folder is known as ours and resumed.
    If the block raises before anything but the claim and the empty folders were written, the claim
    and the folders it made go."""
    with ExitStack() as made:
        for folder in (out, *(out / run for run in runs)):
            made.enter_context(created_folders(folder))
            folder.mkdir(parents=True, exist_ok=True)
        claim = out / RUN_CLAIM
        fresh = not claim.exists()
        write_claim(out, report)
        try:
            yield out
        except BaseException:
            if fresh and not any(f.is_file() and f != claim for f in out.rglob("*")):
                claim.unlink(missing_ok=True)
            raise


def mean_recognition(agg: dict) -> dict:
    """Recognition per method averaged over groups and ranges (a one-line summary)."""
    cells = [cell for group in agg["recognition"].values() for cell in group.values()]
    return {m: float(np.mean([c[m] for c in cells])) for m in cells[0]} if cells else {}
