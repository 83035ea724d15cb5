"""Train the shape-based generative model (thesis chapter 4 and 6.1).

    python train.py [--config configs/default.yaml] [--overwrite] [key=value ...]
    python train.py catalog=PATH    # train on your own models: PATH/catalog.yaml lists them

Steps: render the training vehicles at the configured views and encode the silhouettes by the
clipped signed distance; fit the RBF view mappings, tune the kernel widths on held-out views
(optional), decompose the mapping tensor (HOSVD) and build the identity manifold; measure the
reconstructions; log pictures to TensorBoard; write the checkpoint (atomically) with the
resolved config and the report.

An existing checkpoint or run folder (<log_dir>/<name> with its report.json) is replaced only
with --overwrite; a file or folder that is not ours is never replaced, nor a file the run writes
itself (a checkpoint= at its report.json is refused). User errors print one line,
``train.py: error: ...``, and exit with status 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import time
from pathlib import Path

import torch

from torch_atr import viz
from torch_atr.cli import REPO, ArgumentParser, console_logging, run_main
from torch_atr.config import load_config
from torch_atr.evaluation import (fit_alpha, identity_distances, per_class_mean, rbf_mapping_iou,
                                  reconstruction_iou)
from torch_atr.io import (RUN_CLAIM, atomic_write_text, check_output_dir, check_output_file, check_writable,
                          claimed_output_dir, created_folders)
from torch_atr.model import GenerativeShapeModel
from torch_atr.model.generative import is_checkpoint
from torch_atr.model.rbf import RBFViewMapping
from torch_atr.training import (REPORT_FORMAT, TrainConfig, check_checkpoint_path, check_templates, is_train_report,
                                non_finite_keys, render_set)
from torch_atr.vehicles import CLASS_NAMES, load_catalog, load_catalog_folder

log = logging.getLogger("train")
FIGURES = tuple(f"{name}.png" for name in viz.MODEL_FIGURES)
# What the run writes into its run folder besides a checkpoint there: never the checkpoint's path.
RUN_FILES = ("report.json", *FIGURES, RUN_CLAIM, "events.out.tfevents.*")


def main(argv: list[str] | None = None) -> dict:
    parser = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default=str(REPO / "configs" / "default.yaml"),
                        help="YAML config (default: the repository's configs/default.yaml)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing checkpoint and run folder of ours (never anything else)")
    parser.add_argument("overrides", nargs="*", help="key=value overrides, dotted for sections (model.ridge=1e-3)")
    args = parser.parse_intermixed_args(argv)  # flags may sit between the key=value overrides
    console_logging()
    cfg = load_config(TrainConfig, args.config, args.overrides, unique=True)
    check_checkpoint_path(cfg.checkpoint_path, cfg.run_dir, RUN_FILES)
    # The training vehicles (the shipped split, or a folder of your own models): a bad catalog is
    # named first. Then refuse to replace outputs before spending minutes on training.
    vehicles = load_catalog("train") if cfg.catalog == "train" else load_catalog_folder(cfg.catalog)
    out_dir = check_output_dir(cfg.run_dir, args.overwrite, "report.json", is_train_report, "run")
    checkpoint = check_output_file(cfg.checkpoint_path, args.overwrite, is_checkpoint, "checkpoint")
    # The checkpoint's config says where it went and (absolute) which catalog Method IV re-renders.
    cfg = dataclasses.replace(cfg, checkpoint=str(checkpoint),
                              catalog=cfg.catalog if cfg.catalog == "train" else str(Path(cfg.catalog).resolve()))
    # A run that fails leaves none of the empty folders it made, for the checkpoint or the run.
    replaces = ("report.json", "model.pt", *FIGURES)  # the folder's other files stay
    with created_folders(checkpoint.parent), claimed_output_dir(out_dir, "run", replaces=replaces):
        check_writable(checkpoint)
        return _train(cfg, vehicles, out_dir, checkpoint)


def _train(cfg: TrainConfig, vehicles: list, out_dir: Path, checkpoint: Path) -> dict:
    """Render, fit, measure and write the run (module docstring); returns the report."""
    torch.manual_seed(cfg.seed)
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[stage] = round(now - clock, 2)
        log.info("%s: %.1f s", stage, now - clock)
        clock = now

    # 1. The training vehicles rendered at the training, validation and held-out views.
    names, classes = [v.name for v in vehicles], [CLASS_NAMES.index(v.cls) for v in vehicles]
    theta, phi = cfg.views.grid()
    masks, signed = render_set(vehicles, theta, phi, cfg.template, "training views")
    check_templates(vehicles, masks, cfg.template)
    theta_ho, phi_ho = cfg.views.held_out()
    masks_ho, _ = render_set(vehicles, theta_ho, phi_ho, cfg.template, "held-out views")
    val = {}
    if cfg.model.width_steps > 0:
        theta_val, phi_val = cfg.views.validation()
        _, signed_val = render_set(vehicles, theta_val, phi_val, cfg.template, "validation views")
        val = dict(val_templates=signed_val, val_theta=theta_val, val_phi=phi_val)
    lap("render")

    # 2. Fit (chapter 4), tuning the kernel widths on the validation views if configured. The
    # held-out IoU of the RBF mappings alone is measured with the initial and the final widths.
    initial = RBFViewMapping(theta, phi, cfg.model.init_width)
    held_out_before = rbf_mapping_iou(initial, signed, theta, phi, masks_ho, theta_ho, phi_ho, cfg.model.ridge)
    model = GenerativeShapeModel.fit(signed, theta, phi, names, classes, CLASS_NAMES, cfg.template, cfg.model, **val)
    held_out_after = rbf_mapping_iou(model.rbf, signed, theta, phi, masks_ho, theta_ho, phi_ho, cfg.model.ridge)
    lap("fit")

    # 3. Measures (issue 3's quality bars).
    train_iou = reconstruction_iou(model, masks, theta, phi)
    held_iou = reconstruction_iou(model, masks_ho, theta_ho, phi_ho)
    dist = identity_distances(model, signed, theta, phi)
    identity_ok = (dist.argmin(dim=1) == torch.arange(len(vehicles))).tolist()
    report = {
        "format": REPORT_FORMAT,
        "vehicles": len(vehicles), "views": len(theta), "pixel_rank": model.core.pixel_rank,
        # Relative error the truncated pixel basis adds: on the templates, and on the mappings 𝒞 (the
        # RBF weights, dominated by detail that changes fast with the view).
        "pixel_basis_error_templates": ((1 - model.project(signed).square().sum() / signed.square().sum())
                                        .clamp_min(0).sqrt().item()),
        "pixel_basis_error_mappings": model.core.relative_error.item(),
        "order": [names[k] for k in model.identity.order.tolist()],
        "train_iou": per_class_mean(train_iou.mean(1), classes, CLASS_NAMES),
        "held_out_iou": per_class_mean(held_iou.mean(1), classes, CLASS_NAMES),
        "held_out_iou_rbf_widths_initial": per_class_mean(held_out_before.mean(1), classes, CLASS_NAMES),
        "held_out_iou_rbf_widths_tuned": per_class_mean(held_out_after.mean(1), classes, CLASS_NAMES),
        "identity_self_match": {"all": all(identity_ok),
                                "mismatched": [names[k] for k, ok in enumerate(identity_ok) if not ok]},
    }
    lap("evaluate")
    if cfg.evaluate_test_split:
        test = load_catalog("test")
        _, signed_test = render_set(test, theta, phi, cfg.template, "test split")
        results = []
        for vehicle, sd in zip(test, signed_test):
            alpha, mse = fit_alpha(model, sd, theta, phi)
            a = torch.tensor([alpha])
            got = CLASS_NAMES[model.classify(a).item()]
            nearest = [names[k] for k in model.nearest_vehicles(a, 2)[0].tolist()]
            results.append({"vehicle": vehicle.name, "class": vehicle.cls, "alpha": round(alpha, 4),
                            "classified": got, "correct": got == vehicle.cls, "nearest": nearest, "mse": mse})
            log.info("test vehicle %-10s (%s): α = %.3f -> %s, nearest %s", vehicle.name, vehicle.cls, alpha, got,
                     nearest)
        report["test_split"] = results
        report["test_split_correct"] = sum(r["correct"] for r in results)
        lap("test split")

    # 4. Pictures: TensorBoard (scalars, histograms, images, figures) and the same images as PNGs.
    figures = viz.model_figures(model, masks, theta, phi, math.radians(cfg.views.azimuth_step_deg),
                                math.radians(cfg.views.elevation_step_deg))
    if cfg.tensorboard:
        from torch.utils.tensorboard import SummaryWriter

        with SummaryWriter(str(out_dir)) as writer:
            for step, loss in enumerate(model.width_history):
                writer.add_scalar("rbf/width_tuning_validation_mse", loss, step)
            writer.add_histogram("rbf/kernel_widths_chord", model.rbf.widths.detach())  # chord on the unit view sphere
            writer.add_scalar("iou/train", train_iou.mean().item())
            writer.add_scalar("iou/held_out", held_iou.mean().item())
            for name, fig in figures.items():
                writer.add_figure(name, fig, close=False)
    viz.save_figures(figures, out_dir)
    lap("figures")

    # 5. The checkpoint, self-describing: resolved config and report travel with the weights.
    history = model.width_history
    report["width_tuning_mse"] = {"first": history[0], "last": history[-1]} if history else None
    report["timings_s"] = timings
    bad = non_finite_keys(report)
    if bad:  # a NaN or infinite measure means the run failed: write nothing
        raise ValueError(f"the run failed: {', '.join(bad)} not finite; neither {checkpoint} nor the report was "
                         f"written")
    text = json.dumps(report, indent=2, allow_nan=False)
    model.save(checkpoint, extra={"config": dataclasses.asdict(cfg), "report": report})
    atomic_write_text(text, out_dir / "report.json")
    log.info("wrote %s (%.1f MB); train IoU %.3f, held-out IoU %.3f, identity self-match %s",
             checkpoint, checkpoint.stat().st_size / 1e6, report["train_iou"]["all"],
             report["held_out_iou"]["all"], report["identity_self_match"]["all"])
    return report


if __name__ == "__main__":
    run_main(main)
