"""Track and recognise a vehicle in an image sequence (thesis chapters 5 and 6.2).

    python track.py [--sequence SPEC] [--checkpoint PATH] [--method I|II|III|IV] [--particles N]
                    [--init blind|truth] [--device cpu|cuda] [--out runs/NAME] [--frames N]
                    [--tensorboard] [--video] [--overwrite] [--config configs/track.yaml] [key=value ...]

With no arguments it tracks a built-in simulated sequence (the held-out T-72 at 1000 m, 300
frames) with the shipped checkpoint. Steps: open the sequence and the model; warm up the
background model; initialise the particles (blind from the first blob, or from the truth);
run the particle filter over the frames; write ``estimates.csv``, ``config.yaml``, the figures
and last ``metrics.json``, which marks the run folder finished (README, "Command line").
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import os
import shlex
from pathlib import Path

from torch_atr import viz
from torch_atr.cli import REPO, ArgumentParser, console_logging, in_repo, run_main
from torch_atr.config import load_config
from torch_atr.data import open_sequence
from torch_atr.io import check_output_dir, claimed_output_dir
from torch_atr.model import GenerativeShapeModel
from torch_atr.model.generative import load_checkpoint
from torch_atr.tracking.blob import BlobTracker
from torch_atr.tracking.filter import Tracker
from torch_atr.tracking.job import CONVERGED_FRAMES, TrackConfig, absolute_spec, is_track_run, write_metrics, write_run
from torch_atr.training import trained_catalog, training_templates
from torch_atr.validate import cut

log = logging.getLogger("track")
OUTPUTS = ("metrics.json", "estimates.csv", "config.yaml", *(f"{name}.png" for name in viz.TRACK_FIGURES),
           "overlay.mp4")  # a run's files, all replaced; the folder's other files stay
# The summary line's errors: label, metrics.json key, format, unit.
ERRORS = (("horizontal", "horizontal_error_m", ".2f", "m"), ("range", "range_error_m", ".1f", "m"),
          ("aspect", "aspect_error_rad", ".2f", "rad"))

# Command-line flags: the config key each sets, its metavar and what it means (defaults: configs/track.yaml).
FLAGS = {
    "sequence": ("sequence", "SPEC", "what to track, as open_sequence takes it: a folder, video:FILE, "
                                     "sensiac:FILE.arf, synthetic:vehicle=NAME,range=M,..."),
    "checkpoint": ("checkpoint", "PATH", "the trained model"),
    "method": ("tracker.filter.method", "I|II|III|IV", "view and identity continuous (I) or snapped"),
    "particles": ("tracker.filter.particles", "N", "the number of particles"),
    "init": ("tracker.init.mode", "blind|truth", "start from the first blob and the camera, or from frame 0's truth"),
    "device": ("device", "DEVICE", "where the particles live: cpu, cuda, cuda:1, ..."),
    "out": ("out", "DIR", "the run folder"),
    "frames": ("frames", "N", "track only the first N frames"),
}


def main(argv: list[str] | None = None) -> dict:
    parser = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=str(REPO / "configs" / "track.yaml"), metavar="YAML",
                        help="the config whose keys the flags and overrides set (default: configs/track.yaml)")
    for flag, (key, metavar, meaning) in FLAGS.items():
        parser.add_argument(f"--{flag}", metavar=metavar, help=f"{meaning} (sets {key})")
    parser.add_argument("--tensorboard", action="store_true", help="also log to TensorBoard in the run folder")
    parser.add_argument("--video", action="store_true", help="also write overlay.mp4")
    parser.add_argument("--overwrite", action="store_true", help="replace an earlier run in --out (only ours)")
    parser.add_argument("overrides", nargs="*", help="key=value overrides (tracker.filter.sigma=0.03)")
    args = parser.parse_intermixed_args(argv)  # flags may sit between the key=value overrides
    console_logging()
    # Each flag as the override it stands for; messages name it as given (--particles 0).
    given = {flag: getattr(args, flag) for flag in FLAGS if getattr(args, flag) is not None}
    flags = {f"{FLAGS[flag][0]}={value}": cut(f"--{flag} {shlex.quote(value)}") for flag, value in given.items()}
    flags |= {f"{name}=true": f"--{name}" for name in ("tensorboard", "video") if getattr(args, name)}
    cfg = load_config(TrackConfig, args.config, [*flags, *args.overrides], unique=True, labels=flags)

    # 1. The model, the sequence, the run folder and the tracker. A bad input is reported before
    # the run folder is checked (a typo in --sequence is not "runs/track exists"), and a value the
    # tracker refuses before the folder is claimed.
    model, extra = load_checkpoint(in_repo(cfg.checkpoint), map_location=cfg.device)
    with open_sequence(cfg.sequence) as sequence:  # closed (its video capture released) however the run ends
        # config.yaml names the files read by absolute paths: it reproduces the run from any folder.
        cfg = dataclasses.replace(cfg, checkpoint=os.path.abspath(in_repo(cfg.checkpoint)),
                                  sequence=absolute_spec(cfg.sequence))
        out = check_output_dir(cfg.out, args.overwrite, "metrics.json", is_track_run, "tracking run")
        tracker = make_tracker(cfg, model, trained_catalog(extra), sequence)
        with claimed_output_dir(out, "tracking run", replaces=OUTPUTS):
            return _track(cfg, model, tracker, sequence, out)


def make_tracker(cfg: TrackConfig, model: GenerativeShapeModel, catalog: str, sequence) -> Tracker | BlobTracker:
    """The tracker of ``cfg`` for ``sequence``: without a camera, view and identity on the normalised
    blob (thesis 6.3). ``catalog``: the model's training vehicles (Method IV renders them)."""
    templates = training_templates(model, catalog) if cfg.tracker.filter.method == "IV" else None
    options = dict(device=cfg.device, seed=cfg.seed, templates=templates)
    if sequence.camera is None:
        log.info("%s has no camera calibration: tracking view and identity on the blob, no 3D", sequence.name)
        return BlobTracker(model, cfg.tracker, **options)
    return Tracker(model, sequence.camera, cfg.tracker, **options)


def _track(cfg: TrackConfig, model: GenerativeShapeModel, tracker: Tracker | BlobTracker, sequence, out: Path
           ) -> dict:
    """Track ``sequence`` with ``tracker`` and write the run folder ``out``; returns the metrics."""
    # 2. Track: warm-up, initialisation and the particle filter over every frame (the video drawn as it goes).
    with contextlib.ExitStack() as stack:
        video = stack.enter_context(viz.OverlayVideo(out / "overlay.mp4", tracker)) if cfg.video else None
        result = tracker.run(sequence, cfg.frames, on_frame=video)
    metrics = result.metrics(model)  # its "settled" block from frame SETTLE_FRAMES (60) on

    # 3. The run folder: estimates, config and figures (TensorBoard on request), then the
    # metrics, which mark it finished: a run that fails or is killed before reads as interrupted.
    write_run(out, cfg, result)
    figures = viz.track_figures(result, model, sequence.name)
    viz.save_figures(figures, out)
    if cfg.tensorboard:
        viz.log_track_tensorboard(out, result, figures)
    write_metrics(out, metrics)

    log.info("%s: %d frames at %.1f frames/s, %d lost", sequence.name, metrics["frames"],
             metrics["frames_per_second"], metrics["lost_frames"])
    summary = truth_summary(metrics)
    if summary:
        log.info("%s", summary)
    if metrics["best_matches"]:
        overlap = metrics["overlap_ratio"]
        log.info("best matches: %s; overlap ratio %s", ", ".join(metrics["best_matches"]),
                 "n/a" if overlap is None else f"{overlap:.3f}")
    else:
        log.info("no estimate: no frame had a target to start on")
    written = ["estimates.csv", "metrics.json", "config.yaml", *(f"{n}.png" for n in figures)]
    written += ["overlay.mp4"] * cfg.video
    written += [f"TensorBoard events (tensorboard --logdir {shlex.quote(str(out.parent))})"] * cfg.tensorboard
    log.info("wrote %s: %s", out, ", ".join(written))
    return metrics


def truth_summary(metrics: dict) -> str:
    """The summary's measures against the truth, those the sequence's truth allows ("" for none): a
    sequence may know positions but no class, or a class alone."""
    errors = ", ".join(f"{label} {metrics[key]:{spec}} {unit}" for label, key, spec, unit in ERRORS
                       if metrics[key] is not None)
    parts = [errors]
    if metrics["recognition_accuracy"] is not None:
        converged, mirrored = metrics["frames_to_convergence"], metrics["frames_to_convergence_up_to_mirror"]
        if converged is not None:
            convergence = f"converged at frame {converged}"
        elif metrics["first_frame"] + metrics["frames"] >= CONVERGED_FRAMES:
            convergence = "never converged"
        else:
            convergence = f"too short to converge ({CONVERGED_FRAMES} frames in a row)"
        if mirrored is not None and mirrored != converged:  # a stretch on the mirror branch θ̂ ≈ π − θ
            convergence += f" (at frame {mirrored} up to the mirror θ ↔ π − θ)"
        parts += [f"recognition {round(metrics['recognition_accuracy'], 3)}", convergence]
    return "; ".join(part for part in parts if part)


if __name__ == "__main__":
    run_main(main)
