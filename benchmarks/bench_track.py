"""Tracking speed: frames per second of the batched filter against particle count, a per-particle
reference of Table 5.1 written here, and where the time goes.

Frames of a simulated sequence (the held-out T-72 at 1000 m by night) are made first, so the
simulator is not timed. Each run starts from the truth (the thesis's start) and steps through
the frames; the first ``--skip`` frames are not counted. A step includes everything a live
tracker does per frame: segmentation (MOG2 with the tracker's feedback), the frame's distance,
prediction, views, predicted shapes (Method I), windows, likelihoods, estimates, overlap and
resampling. The reference does one step of Table 5.1 the straightforward way — a Python loop over
particles, each with its own prediction, view, model query (full size, pooled), window and
likelihood — on the same frames, segmentation included, always on the CPU; the speed-up is the
ratio of the two medians at the same particle count, measured in this run (with ``--device cuda``,
the GPU's filter against the CPU's loop). The tracker's segmentation is also timed alone (no
particles, the true window as its prediction), the floor under every row: back to back, and
with its calls a frame period apart, idle in between, as a live camera feeds them (slower:
docs/tracking.md, "Speed across hosts"); with ``--segmentation-gaps`` also with that many
milliseconds of busy waiting between calls; and inside the step, between the filter's tensor
operations. Frames per second are the median
step's; the rate over all timed frames (the first ``--skip`` left out) is printed beside it, since the
median does not see the frames that update the background (every 5th:
``segmentation.learning_interval``), whose median step is printed apart from the others'. The track
starts on the truth, so re-detection's search, which follows a blind start only (by default 10
frames after it), is in neither: ``python track.py`` times a blind start's run with it.

    python benchmarks/bench_track.py [--particles 250 500 1000 2000 4000 8000 16000] [--frames 60]
        [--device cpu] [--checkpoint checkpoints/default.pt] [--set filter.likelihood_px=16]
        [--segmentation-gaps 1 3 12 33] [--json OUT] [--overwrite]

Every option is checked before the frames are made; ``--json`` refuses an existing file unless
it is an earlier output of this benchmark and ``--overwrite`` is given.
"""

from __future__ import annotations

import argparse
import cProfile
import logging
import math
import pstats
import statistics
import time
from pathlib import Path

import torch
import torch.nn.functional as F

from torch_atr.cli import run_main
from torch_atr.config import ConfigError, load_config
from torch_atr.data.synthetic import SceneConfig, SyntheticSequence
from torch_atr.model import GenerativeShapeModel
from torch_atr.pose import VehiclePose, view_of_pose
from torch_atr.segmentation import ForegroundSegmenter
from torch_atr.shape import signed_distance_px
from torch_atr.tracking import Tracker, TrackerConfig
from torch_atr.tracking.motion import MotionConfig
from torch_atr.tracking.observation import project_windows

from benchlib import SHIPPED, check_at_least, json_output, write_json

log = logging.getLogger("bench_track")
NAME = Path(__file__).stem
PROFILE_WARMUP = 5  # frames stepped before the profiler starts

# Functions whose cumulative time makes the profile (name in the cProfile table -> stage).
STAGES = {"__call__": "segmentation (MOG2, gain, blob)", "frame_distance": "frame distance (EDT near the blob)",
          "_predict": "prediction (eq. 5.1, 5.3)", "_predicted_region": "predicted region",
          "_log_likelihood": "likelihoods (eq. 5.2), of which:", "_views": "  views Θ of the particles",
          "observe_windows": "  windows and their samples",
          "squared_errors": "  predicted shapes and errors (Method I)",
          "_estimate": "estimates", "_overlap": "overlap (placed silhouette)", "resample": "resampling",
          "_redetect": "re-detection (its share of every frame)"}


def tracker_config(n: int, overrides: list[str]) -> TrackerConfig:
    return load_config(TrackerConfig, None, [f"filter.particles={n}", "init.mode=truth", *overrides])


class TimedSegmenter:
    """A tracker's segmenter that keeps each call's wall time (s) in ``times``: the segmentation as
    it runs inside the step, between the filter's tensor operations, without a profiler."""

    def __init__(self, segmenter: ForegroundSegmenter):
        self.segmenter, self.times = segmenter, []

    def __call__(self, *args, **kwargs):
        start = time.perf_counter()
        mask = self.segmenter(*args, **kwargs)
        self.times.append(time.perf_counter() - start)
        return mask

    def __getattr__(self, name: str):
        return getattr(self.segmenter, name)


def tracker_fps(model, seq, frames, n: int, device: str, skip: int, overrides: list[str]
                ) -> tuple[float, list[float], list[float]]:
    """Median frames per second of the batched tracker with n particles, the step times (s) and the
    segmentation's times inside them (s)."""
    cfg = tracker_config(n, overrides)
    tracker = Tracker(model, seq.camera, cfg, device=device, seed=0)
    tracker.warm_up(seq.warmup_frames(50))
    tracker.segmenter = TimedSegmenter(tracker.segmenter)
    tracker.initialise(seq.truth(0))
    times = []
    for frame in frames:
        start = time.perf_counter()
        tracker.step(frame)
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        times.append(time.perf_counter() - start)
    return 1.0 / statistics.median(times[skip:]), times[skip:], tracker.segmenter.times[skip:]


def reference_step(model, camera, mask, particles: list[list[float]], motion: MotionConfig, dt: float,
                   sigma: float, L: int, g: torch.Generator) -> list[list[float]]:
    """One step of Table 5.1 a particle at a time: predict, weigh, normalise, estimate, resample."""
    D = signed_distance_px(mask)[None, None]
    H, W = mask.shape
    tpl = model.template
    std = motion.std_per_step(dt).tolist()
    log_w = []
    moved = []
    for x, y, z, h, v, a in particles:  # 1.1: draw X_t ~ p(X_t | X_{t-1}), α_t ~ p(α_t | α_{t-1})
        w = torch.randn(6, generator=g).tolist()
        p = [x + v * math.sin(h) * dt + std[0] * w[0], y + std[1] * w[1], z + v * math.cos(h) * dt + std[2] * w[2],
             (h + std[3] * w[3]) % (2 * math.pi), v + std[4] * w[4], (a + std[5] * w[5]) % (2 * math.pi)]
        moved.append(p)
        theta, phi = view_of_pose(VehiclePose(p[0], p[1], p[2], p[3]), camera)  # 1.2: the weight, eq. 5.2
        yhat = model(torch.tensor([p[5]]), theta.reshape(1).float(), phi.reshape(1).float())
        yhat = F.avg_pool2d(yhat[None], tpl.size_px // L)[0, 0]
        uv, depth = camera.project(torch.tensor(p[:3], dtype=torch.float64))
        s = camera.fx * tpl.window_m / depth.item()
        k = (torch.arange(L) + 0.5) / L - 0.5
        gu = ((uv[0].item() + k * s + 0.5) * 2 / W - 1).expand(L, L)
        gv = ((uv[1].item() + k * s + 0.5) * 2 / H - 1)[:, None].expand(L, L)
        zz = F.grid_sample(D, torch.stack([gu, gv], -1)[None].float(), padding_mode="border", align_corners=False)[0, 0]
        zz = (zz * tpl.size_px / s).clamp(-tpl.tau_px, tpl.tau_px) / tpl.tau_px
        log_w.append(-float(((zz - yhat) ** 2).mean()) / (2 * sigma * sigma))
    top = max(log_w)  # 2: normalise
    weights = [math.exp(lw - top) for lw in log_w]
    total = sum(weights)
    weights = [wi / total for wi in weights]
    _ = [sum(wi * p[i] for wi, p in zip(weights, moved)) for i in range(5)]  # 3: the estimate
    out, c, j, n = [], weights[0], 0, len(moved)  # 4: systematic resampling
    u0 = torch.rand((), generator=g).item()
    for i in range(n):
        target = (i + u0) / n
        while target > c and j < n - 1:
            j += 1
            c += weights[j]
        out.append(list(moved[j]))
    return out


def warmed_segmenter(seq, tracker_cfg: TrackerConfig) -> ForegroundSegmenter:
    """The tracker's segmentation, warmed up on the sequence's target-free frames."""
    seg = ForegroundSegmenter(tracker_cfg.segmentation)
    seg.warm_up(seq.warmup_frames(tracker_cfg.segmentation.warmup_frames))
    return seg


def reference_fps(model, seq, frames, n: int, tracker_cfg: TrackerConfig) -> float:
    """Frames per second of the per-particle reference (segmentation included), over len(frames) frames."""
    seg = warmed_segmenter(seq, tracker_cfg)
    t = seq.truth(0)
    g = torch.Generator().manual_seed(0)
    particles = [[t.x + r[0], t.y + r[1], t.z + r[2], t.heading, 1.0, 0.5]
                 for r in torch.randn(n, 3, generator=g).tolist()]
    times = []
    for frame in frames:
        start = time.perf_counter()
        mask = seg(frame)
        with torch.no_grad():
            particles = reference_step(model, seq.camera, mask, particles, tracker_cfg.motion, 1 / seq.fps,
                                       tracker_cfg.filter.sigma, tracker_cfg.filter.likelihood_px, g)
        times.append(time.perf_counter() - start)
    return 1.0 / statistics.median(times)


def busy_wait(seconds: float) -> None:
    """Keep the CPU busy, touching no memory, for ``seconds``."""
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def truth_regions(model, seq, count: int) -> list[tuple[tuple[float, float], tuple[float, float, float, float]]]:
    """Per frame, the true window's centre (u, v) and box (u0, v0, u1, v1) in pixels: a perfect
    prediction, what the tracker's ``_predicted_region`` gives the segmenter with no spread."""
    truths = [seq.truth(i) for i in range(count)]
    uv, side = project_windows(seq.camera, torch.tensor([[t.x, t.y, t.z] for t in truths]),
                               model.template.window_m)
    return [(tuple(c), tuple(c0 + c1)) for c, c0, c1 in zip(uv.tolist(), (uv - side / 2).tolist(),
                                                             (uv + side / 2).tolist())]


def segmentation_ms(seq, frames, tracker_cfg: TrackerConfig, regions, between=None) -> float:
    """Median milliseconds of the tracker's segmentation alone (its settings, given the true
    ``regions`` as its prediction: :func:`truth_regions`), outside the profiler: the floor under
    every frame's time, whatever the particle count. ``between(last_s)``, if given, runs before
    every call but the first, given the last call's seconds: idle or busy time between the calls
    (a live camera's period, the filter's share)."""
    seg = warmed_segmenter(seq, tracker_cfg)
    times = []
    for frame, (near, box) in zip(frames, regions):
        if times and between is not None:
            between(times[-1])
        start = time.perf_counter()
        seg(frame, near=near, exclude=box)
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def profile(model, seq, frames, n: int, device: str, overrides: list[str]) -> dict[str, float]:
    """Milliseconds per frame in each stage (cumulative, cProfile) at n particles."""
    cfg = tracker_config(n, overrides)
    tracker = Tracker(model, seq.camera, cfg, device=device, seed=0)
    tracker.warm_up(seq.warmup_frames(50))
    tracker.initialise(seq.truth(0))
    for frame in frames[:PROFILE_WARMUP]:
        tracker.step(frame)
    prof = cProfile.Profile()
    prof.enable()
    for frame in frames[PROFILE_WARMUP:]:
        tracker.step(frame)
    prof.disable()
    stats = pstats.Stats(prof).stats
    count = len(frames) - PROFILE_WARMUP
    out = {}
    for (path, _, name), (_, _, _, cumulative, _) in stats.items():
        if name in STAGES and "torch_atr" in path and not (name == "__call__" and "segmentation" not in path):
            out[STAGES[name]] = out.get(STAGES[name], 0.0) + 1e3 * cumulative / count
    out["whole step"] = 1e3 * sum(v[3] for (p, _, name), v in stats.items() if name == "step" and "filter" in p) / count
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--particles", type=int, nargs="+", default=[250, 500, 1000, 2000, 4000, 8000, 16000],
                        metavar="N", help="the particle counts of the batched filter's runs")
    parser.add_argument("--frames", type=int, default=60, metavar="N",
                        help="frames per run (the simulator makes them first)")
    parser.add_argument("--skip", type=int, default=5, metavar="N", help="frames not counted at the start of each run")
    parser.add_argument("--reference-frames", type=int, default=3, metavar="N",
                        help="frames of the per-particle reference")
    parser.add_argument("--reference-particles", type=int, default=1000, metavar="N",
                        help="particles of the reference, the speed-up and the profile")
    parser.add_argument("--device", default="cpu", help="where the batched filter's particles live: cpu, cuda, ...")
    parser.add_argument("--checkpoint", default=str(SHIPPED), metavar="PATH",
                        help="the trained model (default: the shipped one)")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="tracker config overrides, e.g. filter.likelihood_px=16")
    parser.add_argument("--segmentation-gaps", type=float, nargs="*", default=[], metavar="MS",
                        help="also time the segmentation alone with this much busy waiting (ms) between its calls")
    parser.add_argument("--json", metavar="OUT", help="also write the numbers here")
    parser.add_argument("--overwrite", action="store_true", help="replace an earlier --json of this benchmark")
    args = parser.parse_args(argv)
    check_at_least("segmentation-gaps", args.segmentation_gaps, 0)
    if any(gap > 1e3 for gap in args.segmentation_gaps):
        raise ConfigError(f"--segmentation-gaps must be at most 1000 ms; got {max(args.segmentation_gaps):g}")
    for flag in ("particles", "reference_particles", "reference_frames"):
        check_at_least(flag.replace("_", "-"), getattr(args, flag), 1)
    check_at_least("skip", args.skip, 0)
    if args.reference_frames > args.frames:
        raise ConfigError(f"--reference-frames {args.reference_frames} is more than the --frames {args.frames} made; "
                          f"give --frames {args.reference_frames} or fewer reference frames")
    if args.frames <= max(args.skip, PROFILE_WARMUP):
        raise ConfigError(f"--frames {args.frames} must exceed --skip ({args.skip}) and {PROFILE_WARMUP} (the "
                          f"profile's unprofiled frames); give --frames {max(args.skip, PROFILE_WARMUP) + 1} or more")

    # Everything a run could refuse before the frames are made: the model and device, the output,
    # and the trackers' settings (the --set overrides; filter.likelihood_px against the model).
    model = GenerativeShapeModel.from_checkpoint(args.checkpoint, map_location=args.device)
    seq = SyntheticSequence("t_72", SceneConfig(frames=args.frames))
    configs = [tracker_config(n, args.set) for n in dict.fromkeys(args.particles + [args.reference_particles])]
    Tracker(model, seq.camera, configs[-1], device=args.device)  # what it refuses does not depend on the count
    out = json_output(args.json, args.overwrite, NAME)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    frames = [seq.frame(i) for i in range(args.frames)]
    log.info("T-72 at 1000 m, %d frames of %dx%d, device %s, %d torch threads, overrides %s", args.frames,
             seq.cfg.width, seq.cfg.height, args.device, torch.get_num_threads(), args.set or "none")
    rows, in_step_ms = [], {}
    seg_cfg = configs[-1].segmentation  # step k (from 0) updates the background when k % interval == 0
    updates = [seg_cfg.learning_rate > 0 and k % seg_cfg.learning_interval == 0 for k in range(args.frames)]
    for n in args.particles:
        fps, times, seg_times = tracker_fps(model, seq, frames, n, args.device, args.skip, args.set)
        in_step_ms[n] = 1e3 * statistics.median(seg_times)
        split = [[t for t, u in zip(times, updates[args.skip:]) if u == kind] for kind in (True, False)]
        updating, other = (1e3 * statistics.median(part) if part else None for part in split)
        rows.append({"particles": n, "frames_per_second": fps, "particles_per_second": fps * n,
                     "frames_per_second_mean": len(times) / sum(times),
                     "ms_per_frame_p90": 1e3 * sorted(times)[int(0.9 * (len(times) - 1))],
                     "ms_per_frame_updating_background": updating, "ms_per_frame_other": other})
        log.info("N = %6d: %7.1f frames/s (%.2e particles/s; %.1f frames/s over all timed frames), 90th percentile "
                 "%.1f ms; median step %s ms on frames that update the background, %s ms on the others", n, fps,
                 fps * n, rows[-1]["frames_per_second_mean"], rows[-1]["ms_per_frame_p90"],
                 "-" if updating is None else f"{updating:.1f}", "-" if other is None else f"{other:.1f}")
    n_ref = args.reference_particles
    ref = reference_fps(model.cpu(), seq, frames[:args.reference_frames], n_ref,  # each Tracker moved it to --device
                        tracker_config(n_ref, args.set))
    if n_ref in in_step_ms:
        batched = next(r["frames_per_second"] for r in rows if r["particles"] == n_ref)
    else:
        batched, _, seg_times = tracker_fps(model, seq, frames, n_ref, args.device, args.skip, args.set)
        in_step_ms[n_ref] = 1e3 * statistics.median(seg_times)
    log.info("per-particle reference at N = %d: %.3f frames/s; the batched filter is %.0fx faster", n_ref, ref,
             batched / ref)
    regions = truth_regions(model, seq, len(frames))
    seg_ms = segmentation_ms(seq, frames, tracker_config(n_ref, args.set), regions)
    period = 1 / seq.fps  # a live camera: each call starts a frame period after the last, idle in between
    live_ms = segmentation_ms(seq, frames, tracker_config(n_ref, args.set), regions,
                              lambda last: time.sleep(max(period - last, 0.0)))
    log.info("segmentation alone (MOG2 with the tracker's settings, the true window as its prediction, on the "
             "CPU): %.1f ms per frame back to back, "
             "%.1f ms with the calls %.0f ms apart as a live camera feeds them (medians of %d); inside the step at "
             "N = %d: %.1f ms (docs/tracking.md, \"Speed across hosts\")", seg_ms, live_ms, 1e3 / seq.fps,
             len(frames), n_ref, in_step_ms[n_ref])
    gap_ms = {gap: segmentation_ms(seq, frames, tracker_config(n_ref, args.set), regions,
                                   lambda _, gap=gap: busy_wait(gap / 1e3)) for gap in args.segmentation_gaps}
    for gap, ms in gap_ms.items():
        log.info("segmentation alone with %g ms of busy waiting before each call: %.1f ms", gap, ms)
    stages = profile(model, seq, frames, n_ref, args.device, args.set)
    log.info("where the time goes at N = %d (ms per frame, cumulative):", n_ref)
    for name, ms in sorted(stages.items(), key=lambda kv: -kv[1]):
        log.info("  %-38s %6.2f", name, ms)
    if out is not None:
        write_json({"runs": rows,
                    "reference": {"particles": n_ref, "frames_per_second": ref, "speed_up": batched / ref},
                    "segmentation_ms": seg_ms, "segmentation_live_ms": live_ms, "segmentation_busy_gap_ms": gap_ms,
                    "segmentation_in_step_ms": in_step_ms, "profile_ms": stages, "threads": torch.get_num_threads()},
                   out, NAME)


if __name__ == "__main__":
    run_main(main)
