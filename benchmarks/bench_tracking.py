"""Tracking and recognition quality on simulated test-split sequences: the tracker issue's bars.

For each vehicle, start (truth as the thesis, or blind) and method, one seeded run of ``--frames``
frames with ``--particles`` particles on the simulator (night, SENSIAC-like camera, the run
centred on the circle's near point) gives the mean horizontal, range and aspect errors, the
fraction of frames recognised, the frames to convergence (10 frames in a row within 1 m, 0.3 rad
and on the true class) and the errors after the first ``--settle`` frames (what a blind start
is held to). Every run is what ``python track.py`` does with the same settings.

    python benchmarks/bench_tracking.py [--vehicles t_72 isuzu_rodeo] [--ranges 1000] [--methods I II III IV]
        [--inits truth blind] [--frames 300] [--particles 1000] [--seed 0] [--device cpu] [--set key=value ...]
        [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import logging
import time

import torch

from torch_atr.config import load_config
from torch_atr.data.synthetic import SceneConfig, SyntheticSequence
from torch_atr.io import atomic_write_text
from torch_atr.model.generative import load_checkpoint
from torch_atr.tracking import Tracker, TrackerConfig
from torch_atr.tracking.job import run_summary
from torch_atr.training import trained_catalog, training_templates

log = logging.getLogger("bench_tracking")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vehicles", nargs="+", default=["t_72", "isuzu_rodeo"])
    parser.add_argument("--ranges", nargs="+", type=float, default=[1000.0])
    parser.add_argument("--methods", nargs="+", default=["I", "II", "III", "IV"])
    parser.add_argument("--inits", nargs="+", default=["truth", "blind"])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--particles", type=int, default=1000)
    parser.add_argument("--settle", type=int, default=60, help="frames left out of the settled errors")
    parser.add_argument("--seed", type=int, default=0, help="the scene's and the tracker's seed")
    parser.add_argument("--checkpoint", default="checkpoints/default.pt")
    parser.add_argument("--device", default="cpu", help="where the particles live (segmentation stays on the CPU)")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="tracker config overrides")
    parser.add_argument("--json", help="also write every number here")
    args = parser.parse_args()
    if not 0 <= args.settle < args.frames:
        parser.error(f"--settle ({args.settle}) must be at least 0 and below --frames ({args.frames})")
    logging.basicConfig(level=logging.INFO, format="%(message)s")

    model, extra = load_checkpoint(args.checkpoint)
    templates = training_templates(model, trained_catalog(extra)) if "IV" in args.methods else None
    results = []
    log.info("%-12s %5s %-6s %-4s | %7s %7s %7s %6s | %7s %7s %6s | %5s %6s", "vehicle", "range", "start", "meth",
             "horiz m", "range m", "asp rad", "recog", "horiz60", "asp60", "rec60", "conv", "frm/s")
    for vehicle in args.vehicles:
        for range_m in args.ranges:
            seq = SyntheticSequence(vehicle, SceneConfig(range_m=range_m, frames=args.frames, seed=args.seed))
            for init in args.inits:
                for method in args.methods:
                    cfg = load_config(TrackerConfig, None, [f"filter.particles={args.particles}",
                                                            f"filter.method={method}", f"init.mode={init}",
                                                            *args.set])
                    tracker = Tracker(model, seq.camera, cfg, device=args.device, seed=args.seed,
                                      templates=templates if method == "IV" else None)
                    start = time.perf_counter()
                    result = tracker.run(seq, progress=False, snapshots=0)
                    m = run_summary(result, model, args.settle)
                    s = m["settled"]
                    results.append({"vehicle": vehicle, "range_m": range_m, "init": init, "method": method,
                                    "wall_s": time.perf_counter() - start, **m})
                    log.info("%-12s %5.0f %-6s %-4s | %7.2f %7.1f %7.2f %6.2f | %7.2f %7.2f %6.2f | %5s %6.1f",
                             vehicle, range_m, init, method, m["horizontal_error_m"], m["range_error_m"],
                             m["aspect_error_rad"], m["recognition_accuracy"], s["horizontal_error_m"],
                             s["aspect_error_rad"], s["recognition_accuracy"], m["frames_to_convergence"],
                             m["frames_per_second"])
    if args.json:
        atomic_write_text(json.dumps({"args": vars(args), "runs": results, "threads": torch.get_num_threads()},
                                     indent=2), args.json)


if __name__ == "__main__":
    main()
