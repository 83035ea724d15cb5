"""Tracking and recognition quality on simulated test-split sequences: the tracker issue's bars.

For each vehicle, start (truth as the thesis, or blind) and method, one seeded run of ``--frames``
frames with ``--particles`` particles on the simulator (night, SENSIAC-like camera, the run
centred on the circle's near point) gives the mean horizontal, range and aspect errors, the
fraction of frames recognised, the frames to convergence (10 frames in a row within 1 m, 0.3 rad
and on the true class; "mirr": the same with an aspect of π − θ counted right, the silhouette's
mirror at a grazing view) and the errors after the first ``--settle`` frames (what a blind start
is held to). Every run is what ``python track.py`` does with the same settings.

    python benchmarks/bench_tracking.py [--vehicles t_72 isuzu_rodeo] [--ranges 1000] [--methods I II III IV]
        [--inits truth blind] [--frames 300] [--particles 1000] [--seed 0] [--device cpu] [--set key=value ...]
        [--json OUT] [--overwrite]

Every vehicle, method, start and setting is checked before the first run; ``--json`` refuses an
existing file unless it is an earlier output of this benchmark and ``--overwrite`` is given.
"""

from __future__ import annotations

import argparse
import itertools
import logging
import time
from pathlib import Path

import torch

from torch_atr.cli import run_main
from torch_atr.config import ConfigError, load_config
from torch_atr.data.synthetic import SceneConfig
from torch_atr.model.generative import load_checkpoint
from torch_atr.tracking import Tracker, TrackerConfig
from torch_atr.tracking.job import run_summary
from torch_atr.training import trained_catalog, training_templates

from benchlib import SHIPPED, check_at_least, json_output, sequence, write_json

log = logging.getLogger("bench_tracking")
NAME = Path(__file__).stem


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--vehicles", nargs="+", default=["t_72", "isuzu_rodeo"], metavar="NAME",
                        help="catalog names (either split) or URDF / mesh files")
    parser.add_argument("--ranges", nargs="+", type=float, default=[1000.0], metavar="M",
                        help="distances of the circle's centre, metres")
    parser.add_argument("--methods", nargs="+", default=["I", "II", "III", "IV"], metavar="METHOD",
                        help="filter.method values: I, II, III, IV")
    parser.add_argument("--inits", nargs="+", default=["truth", "blind"], metavar="MODE",
                        help="init.mode values: truth (the thesis's start) or blind")
    parser.add_argument("--frames", type=int, default=300, help="frames per run")
    parser.add_argument("--particles", type=int, default=1000, help="particles per run")
    parser.add_argument("--settle", type=int, default=60, help="frames left out of the settled errors")
    parser.add_argument("--seed", type=int, default=0, help="the scene's and the tracker's seed")
    parser.add_argument("--checkpoint", default=str(SHIPPED), help="the trained model (default: the shipped one)")
    parser.add_argument("--device", default="cpu", help="where the particles live (segmentation stays on the CPU)")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="tracker config overrides")
    parser.add_argument("--json", help="also write every number here")
    parser.add_argument("--overwrite", action="store_true", help="replace an earlier --json of this benchmark")
    args = parser.parse_args(argv)
    check_at_least("frames", args.frames, 1)
    check_at_least("particles", args.particles, 1)
    check_at_least("settle", args.settle, 0)
    if args.settle >= args.frames:
        raise ConfigError(f"--settle {args.settle} leaves none of the --frames {args.frames} for the settled errors; "
                          f"lower it, e.g. --settle {args.frames // 5}")

    # Everything a run could refuse, before the first run: the model and device, the settings of
    # each method and start, each vehicle at each range, the output; then the trackers themselves.
    model, extra = load_checkpoint(args.checkpoint, map_location=args.device)
    for flag, key, values in (("methods", "filter.method", args.methods), ("inits", "init.mode", args.inits)):
        for value in values:
            try:
                load_config(TrackerConfig, None, [f"{key}={value}"])
            except ConfigError as exc:
                raise ConfigError(f"--{flag} {value}: {exc}") from None
    configs = {(init, method): load_config(TrackerConfig, None, [  # ConfigError names a bad --set override
        f"filter.particles={args.particles}", f"filter.method={method}", f"init.mode={init}", *args.set])
        for init in args.inits for method in args.methods}
    for (init, method), cfg in configs.items():  # --set may not undo a flag: the JSON's args say what ran
        ran = {"--particles": (cfg.filter.particles, args.particles), "--methods": (cfg.filter.method, method),
               "--inits": (cfg.init.mode, init)}
        for flag, (value, asked) in ran.items():
            if value != asked:
                raise ConfigError(f"--set {' '.join(args.set)} sets {value!r} where {flag} gave {asked!r}; "
                                  f"give {flag} instead")
    sequences = {(vehicle, range_m): sequence(vehicle, SceneConfig(frames=args.frames, seed=args.seed), range_m)
                 for vehicle in args.vehicles for range_m in args.ranges}
    out = json_output(args.json, args.overwrite, NAME)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    templates = training_templates(model, trained_catalog(extra)) if "IV" in args.methods else None

    def tracker(seq, method: str, cfg: TrackerConfig) -> Tracker:
        return Tracker(model, seq.camera, cfg, device=args.device, seed=args.seed,
                       templates=templates if method == "IV" else None)

    first = next(iter(sequences.values()))
    for (_, method), cfg in configs.items():  # what a tracker refuses depends on its settings, not the scene
        tracker(first, method, cfg)

    settled = [f"{name}{args.settle}" for name in ("horiz", "asp", "rec")]
    log.info("%-12s %5s %-6s %-4s | %7s %7s %7s %6s | %8s %8s %7s | %5s %5s %6s", "vehicle", "range", "start", "meth",
             "horiz m", "range m", "asp rad", "recog", *settled, "conv", "mirr", "frm/s")
    results = []
    for ((vehicle, range_m), seq), ((init, method), cfg) in itertools.product(sequences.items(), configs.items()):
        start = time.perf_counter()
        result = tracker(seq, method, cfg).run(seq, progress=False, snapshots=0)  # one tracker alive at a time
        m = run_summary(result, model, args.settle)
        s = m["settled"]
        results.append({"vehicle": vehicle, "range_m": range_m, "init": init, "method": method,
                        "wall_s": time.perf_counter() - start, **m})
        cells = _cells((m["horizontal_error_m"], ".2f"), (m["range_error_m"], ".1f"), (m["aspect_error_rad"], ".2f"),
                       (m["recognition_accuracy"], ".2f"), (s["horizontal_error_m"], ".2f"),
                       (s["aspect_error_rad"], ".2f"), (s["recognition_accuracy"], ".2f"),
                       (m["frames_to_convergence"], "d"), (m["frames_to_convergence_up_to_mirror"], "d"))
        log.info("%-12s %5.0f %-6s %-4s | %7s %7s %7s %6s | %8s %8s %7s | %5s %5s %6.1f", vehicle, range_m, init,
                 method, *cells, m["frames_per_second"])
    if out is not None:
        write_json({"args": vars(args), "runs": results, "threads": torch.get_num_threads()}, out, NAME)
    return results


def _cells(*pairs: tuple[float | None, str]) -> list[str]:
    """Each (value, format) as text; "-" for None (no truth to score: a vehicle of no trained class,
    a run without an estimate; a run that never converged)."""
    return ["-" if value is None else format(value, spec) for value, spec in pairs]


if __name__ == "__main__":
    run_main(main)
