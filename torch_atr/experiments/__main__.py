"""``python -m torch_atr.experiments {all,sensiac-like,unseen,studies,visible} --out DIR [--quick | --full]
[--init blind|truth] [--workers N | --ray ADDRESS] [--frames N] [--particles N] [--vehicles ...]
[--ranges ...] [--methods ...] [--seed S] [--scene key=value ...] [key=value ...]``

sensiac-like runs the SENSIAC-like grid (8 test vehicles × 1000-3500 m × Methods I-IV; ``--quick``:
the T-72 at 1000 and 2500 m, 24 frames; ``--full``: 1000 frames, the thesis's length, on a 50 m
circle that stays in view at every range). unseen runs the held-out real meshes (never trained on)
at 1000-2500 m with Method I (``--quick``: a tank and a truck at 1000 m). studies changes one
thing at a time against a Method I baseline at 1000 and 2500 m: particles, 4000-5000 m, day,
an occluding berm, sweeping turrets (it sets particles, ranges, methods and scene itself). visible
runs thesis 6.3 on the simulator's visible band: a camera calibrated from rendered checkerboards,
a held-out car and SUV tracked in 3D with Methods I-IV, and a van tracked without a camera
(``--quick``: 8 frames at half resolution, Methods I and IV; it takes --init, --frames,
--particles, --methods, --seed, --checkpoint, --workers and tracker overrides). Each writes
DIR/report.md, DIR/results.json (and the figures). Finished sequences are kept in DIR/sequences/
and not re-run; ``--ray ADDRESS`` runs them as tasks of a Ray cluster instead of local processes.
all runs the four, each into DIR/NAME/, and writes one DIR/report.md of them all (it takes
--quick, --init, --seed, --checkpoint and --workers). ``key=value`` are tracker config overrides
(``motion.sigma2_alpha=1.0``; not filter.particles, filter.method or init.mode, which --particles,
--methods and --init set); ``--scene key=value`` overrides the simulator's scene (day:
``night=false``; an occluder, a turning turret).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import time
from pathlib import Path

from torch_atr.cli import ArgumentParser, console_logging, run_main
from torch_atr.config import ConfigError, check_seed, override_leaves
from torch_atr.experiments.combined import COMBINED_FORMAT, EXPERIMENTS, write_combined_report
from torch_atr.experiments.report import (REPORT_FORMAT, claimed_report_folder, is_report_folder, mean_recognition,
                                          report_format, write_report)
from torch_atr.experiments.sensiac_like import FULL, QUICK, SensiacLikeConfig, run_all, worker_model
from torch_atr.experiments.studies import STUDIES_FORMAT, run_studies, study_configs, write_studies_report
from torch_atr.experiments.unseen import UNSEEN_FORMAT, unseen_fields, write_unseen_report
from torch_atr.io import RUN_CLAIM, OutputExistsError, claim_of
from torch_atr.tracking import TrackerConfig
from torch_atr.validate import show

log = logging.getLogger("experiments")
# Tracker keys each experiment sets from its own options (and states in its report), laid under the overrides.
SET_BY_OPTIONS = {"filter.particles": "--particles", "filter.method": "--methods", "init.mode": "--init"}


def main(argv: list[str] | None = None) -> dict:
    parser = ArgumentParser(prog="python -m torch_atr.experiments", description=__doc__,
                            formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("experiment", choices=["all", *EXPERIMENTS])
    parser.add_argument("--out", required=True, help="the report folder (resumed when it holds a run of ours)")
    size = parser.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="the CI-sized run")
    size.add_argument("--full", action="store_true", help="1000 frames per sequence on a 50 m circle")
    parser.add_argument("--init", choices=["blind", "truth"])
    where = parser.add_mutually_exclusive_group()  # Ray runs one task per CPU of its cluster
    where.add_argument("--workers", type=int, default=0, help="worker processes (0: one per core)")
    where.add_argument("--ray", metavar="ADDRESS", help="run the sequences on this Ray cluster ('local': start one "
                       "here; needs the [ray] extra)")
    parser.add_argument("--frames", type=int)
    parser.add_argument("--particles", type=int)
    # A list option given twice takes both lists (argparse's default, "store", kept the last alone).
    parser.add_argument("--vehicles", nargs="+", action="extend")
    parser.add_argument("--ranges", nargs="+", type=float, action="extend")
    parser.add_argument("--methods", nargs="+", action="extend")
    parser.add_argument("--seed", type=int)
    parser.add_argument("--checkpoint")
    parser.add_argument("--scene", nargs="+", action="extend", default=[], metavar="KEY=VALUE",
                        help="simulator scene overrides: night=false, occluder_width_m=3, turret_sweep_deg=60")
    parser.add_argument("overrides", nargs="*", help="tracker config overrides, key=value")
    args = parser.parse_intermixed_args(argv)  # overrides after options too: plain parse_args gives them to none
    for key in ("out", "checkpoint"):  # ~ as a shell would, which leaves --out=~/exp as written (a folder '~')
        if getattr(args, key) is not None:
            setattr(args, key, os.path.expanduser(getattr(args, key)))
    if args.workers < 0:  # else ProcessPoolExecutor's "max_workers must be greater than 0", once OUT/ was made
        raise ConfigError(f"--workers must be 0 (one per core) or more; got {args.workers}")
    if not args.out.strip():  # Path('') is '.': the report went into the current folder
        raise ConfigError(f"--out must be a folder path; got {show(args.out)}")
    if args.seed is not None:  # else torch's "Overflow when unpacking long long", in a worker or the calibration
        check_seed("--seed", args.seed)
    check_tracker_overrides(args.overrides)
    check_scene_overrides(args.scene)
    console_logging()
    if args.experiment == "unseen":
        fields = unseen_fields(args.quick) | (dict(FULL) if args.full else {})
    else:
        fields = dict(QUICK) if args.quick else dict(FULL) if args.full else {}
    given = {"init": args.init, "frames": args.frames, "particles": args.particles, "seed": args.seed,
             "checkpoint": args.checkpoint, "vehicles": args.vehicles and tuple(args.vehicles),
             "ranges_m": args.ranges and tuple(args.ranges),
             "methods": args.methods and tuple(dict.fromkeys(args.methods))}  # each method once: I I tracked twice
    given = {k: v for k, v in given.items() if v is not None}
    out = Path(args.out)
    if args.experiment == "all":
        return _all(args, out)
    if args.experiment == "studies":
        return _studies(args, given, out)
    if args.experiment == "visible":
        return _visible(args, given, out)
    cfg = SensiacLikeConfig(**(fields | given), tracker=tuple(args.overrides), scene=tuple(args.scene))
    expected = UNSEEN_FORMAT if args.experiment == "unseen" else REPORT_FORMAT
    _check_out(out, expected)
    model = worker_model(cfg.checkpoint)  # read before the report folder is made: a bad file is named before any work
    start = time.perf_counter()
    with claimed_report_folder(out, expected):  # a run that fails leaves none of the empty folders it made
        results = run_all(cfg, out, args.workers, ray_address=args.ray)
    if args.experiment == "unseen":
        agg = write_unseen_report(out, cfg, results, time.perf_counter() - start)
        log.info("wrote %s: report.md, results.json; config %s", out, dataclasses.asdict(cfg))
        return agg
    agg = write_report(out, cfg, results, model, time.perf_counter() - start)
    log.info("recognition (mean over groups and ranges): %s",
             ", ".join(f"{m} {v:.0f} %" for m, v in mean_recognition(agg).items()))
    log.info("wrote %s: report.md, results.json, figures; config %s", out, dataclasses.asdict(cfg))
    return agg


def check_tracker_overrides(overrides: list[str]) -> None:
    """ConfigError for tracker ``overrides`` (key=value) that set a key twice to two values, as track.py
    refuses them, or that set a key of ``SET_BY_OPTIONS``: the experiment lays its own values under the
    overrides, so the override would win while the report stated the option's (every column of Table
    6.1 run with filter.method=IV; the studies' 250 to 16 000 particles all run with filter.particles)."""
    for item in overrides:
        if item.startswith("tracker."):  # track.py's form: its config holds the tracker's under tracker
            raise ConfigError(f"override {show(item)}: the experiments take the tracker's own keys; give "
                              f"{show(item.removeprefix('tracker.'))}")
    for item, key, _ in override_leaves(TrackerConfig, overrides, unique=True):
        if key in SET_BY_OPTIONS:
            raise ConfigError(f"override {show(item)}: {key} is set by the experiment from {SET_BY_OPTIONS[key]} "
                              f"(and stated in its report); not by an override")


def check_scene_overrides(overrides: list[str]) -> None:
    """ConfigError for ``--scene`` overrides (key=value) that set a key twice to two values (the later won)."""
    from torch_atr.data.synthetic import SceneConfig

    override_leaves(SceneConfig, overrides, "scene override", unique=True)


def _check_out(out: Path, expected: str) -> None:
    """``OutputExistsError`` unless ``out`` is absent, empty or a folder of this experiment: its
    results.json, where there is one, of format ``expected`` (another experiment's would be replaced);
    its claim (an interrupted run) naming ``expected`` (another experiment's run would be claimed)."""
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not is_report_folder(out))):
        raise OutputExistsError(f"{out} exists and is not an experiment's folder (it has no results.json or "
                                f"{RUN_CLAIM} of ours); choose another --out")
    written = report_format(out)
    if written is not None and written != expected:
        raise OutputExistsError(f"{out} holds another experiment's report ({out / 'results.json'}: format "
                                f"{written}); choose another --out")
    claimed = claim_of(out)
    if written is None and claimed is not None and claimed != expected:
        raise OutputExistsError(f"{out} holds another experiment's unfinished run ({out / RUN_CLAIM}: "
                                f"{claimed}); choose another --out, or resume that experiment there")


def _studies(args: argparse.Namespace, given: dict, out: Path) -> list[dict]:
    fixed = [f"--{k}" for k in ("particles", "ranges", "methods", "scene", "full") if getattr(args, k)]
    if fixed:
        raise ConfigError(f"studies: {', '.join(fixed)} cannot be given; each study sets them itself")
    configs = study_configs(args.quick, **given, tracker=tuple(args.overrides))
    _check_out(out, STUDIES_FORMAT)
    for checkpoint in {c.checkpoint for c in configs.values()}:  # a bad file is named before any folder is made
        worker_model(checkpoint)
    start = time.perf_counter()
    with claimed_report_folder(out, STUDIES_FORMAT, tuple(f"{name}/sequences" for name in configs)):
        results = run_studies(out, configs, args.workers, ray_address=args.ray)
    rows = write_studies_report(out, configs, results, time.perf_counter() - start)
    log.info("wrote %s: report.md, results.json", out)
    return rows


def _visible(args: argparse.Namespace, given: dict, out: Path) -> dict:
    from torch_atr.experiments.visible import QUICK as VISIBLE_QUICK
    from torch_atr.experiments.visible import VISIBLE_FORMAT, VisibleConfig, run_visible, write_visible_report

    fixed = [f"--{k}" for k in ("full", "ray", "vehicles", "ranges", "scene") if getattr(args, k)]
    if fixed:
        raise ConfigError(f"visible: {', '.join(fixed)} cannot be given; the experiment sets its vehicles and scenes")
    cfg = VisibleConfig(**((dict(VISIBLE_QUICK) if args.quick else {}) | given), tracker=tuple(args.overrides))
    _check_out(out, VISIBLE_FORMAT)
    model = worker_model(cfg.checkpoint)  # read before the report folder is made: a bad file is named before any work
    start = time.perf_counter()
    with claimed_report_folder(out, VISIBLE_FORMAT):  # a run that fails leaves none of the empty folders it made
        calibration, drawn, results = run_visible(cfg, out, args.workers)
    agg = write_visible_report(out, cfg, calibration, drawn, results, model, time.perf_counter() - start)
    log.info("wrote %s: report.md, results.json, figures; config %s", out, dataclasses.asdict(cfg))
    return agg


def _all(args: argparse.Namespace, out: Path) -> dict:
    passed = {"--init": args.init, "--seed": args.seed, "--checkpoint": args.checkpoint}
    given = [f"--{k}" for k in ("full", "ray", "frames", "particles", "vehicles", "ranges", "methods", "scene")
             if getattr(args, k)] + (["tracker overrides (key=value)"] if args.overrides else [])
    if given:
        raise ConfigError(f"all: {', '.join(given)} cannot be given; run that experiment alone to change it")
    _check_out(out, COMBINED_FORMAT)
    common = ["--workers", str(args.workers), *(["--quick"] if args.quick else []),
              *(a for k, v in passed.items() if v is not None for a in (k, str(v)))]
    start = time.perf_counter()
    with claimed_report_folder(out, COMBINED_FORMAT, runs=()):
        outcomes = {name: main([name, "--out", str(out / name), *common]) for name in EXPERIMENTS}
    write_combined_report(out, EXPERIMENTS, time.perf_counter() - start)
    log.info("wrote %s: report.md, results.json over %s", out, ", ".join(EXPERIMENTS))
    return outcomes


if __name__ == "__main__":
    run_main(main, prog="python -m torch_atr.experiments")
