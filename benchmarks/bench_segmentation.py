"""Background subtraction on the IR scene simulator: IoU against the visible mask per vehicle and range.

For every vehicle and range, a ForegroundSegmenter (MOG2, thesis 3.1) learns the background from
``warmup_frames`` target-free frames (a ``--seg`` key, default 50), then segments ``--frames``
frames spread evenly over the run; the IoU of its mask with the simulator's visible mask
(torch_atr.shape.iou: 1 when both are empty) is averaged per (vehicle, range). Also timed:
frames per second of the simulator (target frames; warm-up frames are cheaper) and of the
segmenter (warm-up excluded). The table goes to the log; ``--json`` writes everything (an
earlier file of this benchmark is replaced only with ``--overwrite``).

    python benchmarks/bench_segmentation.py [--vehicles t_72 btr_70] [--ranges 1000 3500] [--json out.json]
        [--overwrite] [--set night=false noise_k=0.2] [--seg var_threshold=36 warmup_frames=50]
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
from pathlib import Path
import time

import numpy as np
import torch

from torch_atr.cli import run_main
from torch_atr.config import load_config
from torch_atr.data.synthetic import SceneConfig, SyntheticSequence
from torch_atr.segmentation import ForegroundSegmenter, SegmentationConfig
from torch_atr.shape import iou
from torch_atr.vehicles.specs import SPLITS

from benchlib import check_at_least, json_output, sequence, write_json

log = logging.getLogger("bench_segmentation")
NAME = Path(__file__).stem

RANGES = (1000.0, 1500.0, 2000.0, 2500.0, 3000.0, 3500.0)


def run(seq: SyntheticSequence, seg_cfg: SegmentationConfig, frames: int) -> dict:
    """IoU per frame and timings for one simulated sequence."""
    start = time.perf_counter()
    warm = list(seq.warmup_frames(seg_cfg.warmup_frames))
    warm_s = time.perf_counter() - start
    segmenter = ForegroundSegmenter(seg_cfg)
    segmenter.warm_up(warm)
    ious, sim_s, seg_s = [], 0.0, 0.0
    for i in np.linspace(0, len(seq) - 1, frames).round().astype(int):
        start = time.perf_counter()
        frame = seq.frame(int(i))
        sim_s += time.perf_counter() - start
        start = time.perf_counter()
        mask = segmenter(frame)
        seg_s += time.perf_counter() - start
        ious.append(float(iou(mask, seq.visible_mask(int(i)))))
    return {"iou": ious, "sim_s": sim_s, "warmup_s": warm_s, "seg_s": seg_s}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--vehicles", nargs="+", default=[s.name for s in SPLITS["test"]],
                        help="catalog names or URDF / mesh paths (default: the test split)")
    parser.add_argument("--ranges", nargs="+", type=float, default=list(RANGES), help="metres")
    parser.add_argument("--frames", type=int, default=30, help="segmented frames per sequence")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="SceneConfig overrides")
    parser.add_argument("--seg", nargs="*", default=[], metavar="KEY=VALUE", help="SegmentationConfig overrides")
    parser.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's)")
    parser.add_argument("--json", help="write the results to this JSON file")
    parser.add_argument("--overwrite", action="store_true", help="replace an earlier --json of this benchmark")
    args = parser.parse_args(argv)
    check_at_least("frames", args.frames, 1)
    if args.threads is not None:
        check_at_least("threads", args.threads, 1)
    scene = load_config(SceneConfig, overrides=args.set)
    seg_cfg = load_config(SegmentationConfig, overrides=args.seg)
    sequences = {v: {r: sequence(v, scene, r) for r in args.ranges} for v in args.vehicles}  # every name and range
    out = json_output(args.json, args.overwrite, NAME)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.threads is not None:
        torch.set_num_threads(args.threads)

    results = {v: {r: run(seq, seg_cfg, args.frames) for r, seq in row.items()} for v, row in sequences.items()}

    width = max(len(v) for v in args.vehicles + ["vehicle / range (m)"])
    log.info("IoU of the segmented mask with the visible mask (%d frames per cell, %s)", args.frames,
             "night" if scene.night else "day")
    log.info("%s %s", "vehicle / range (m)".ljust(width), " ".join(f"{r:>7.0f}" for r in args.ranges))
    for v, row in results.items():
        log.info("%s %s", v.ljust(width), " ".join(f"{np.mean(row[r]['iou']):7.3f}" for r in args.ranges))
    means = {r: float(np.mean([np.mean(results[v][r]["iou"]) for v in args.vehicles])) for r in args.ranges}
    log.info("%s %s", "mean".ljust(width), " ".join(f"{means[r]:7.3f}" for r in args.ranges))
    cells = [c for row in results.values() for c in row.values()]
    n_frames = args.frames * len(cells)
    sim_fps = n_frames / sum(c["sim_s"] for c in cells)
    warm_fps = seg_cfg.warmup_frames * len(cells) / sum(c["warmup_s"] for c in cells)
    seg_fps = n_frames / sum(c["seg_s"] for c in cells)
    log.info("simulator: %.1f frames/s (%d x %d), %.0f warm-up frames/s; segmenter: %.1f frames/s; "
             "torch %s, %d threads", sim_fps, scene.width, scene.height, warm_fps, seg_fps, torch.__version__,
             torch.get_num_threads())
    if out is not None:
        data = {"scene": dataclasses.asdict(scene), "segmentation": dataclasses.asdict(seg_cfg), "frames": args.frames,
               "iou": {v: {f"{r:g}": float(np.mean(row[r]["iou"])) for r in args.ranges}
                       for v, row in results.items()},
               "iou_min": {v: {f"{r:g}": float(np.min(row[r]["iou"])) for r in args.ranges}
                           for v, row in results.items()},
               "iou_mean_by_range": {f"{r:g}": m for r, m in means.items()},
               "simulator_fps": sim_fps, "warmup_fps": warm_fps, "segmenter_fps": seg_fps,
               "torch": torch.__version__, "threads": torch.get_num_threads()}
        write_json(data, out, NAME)


if __name__ == "__main__":
    run_main(main)
