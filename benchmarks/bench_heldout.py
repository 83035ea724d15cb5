"""Recognition of real vehicles the model never saw: a static α search on the held-out meshes.

    python benchmarks/bench_heldout.py [--checkpoint checkpoints/default.pt] [--grid 720] [--json OUT]
        [--figure docs/recognition_failures.png --overwrite] [--catalog-dir DIR] [--min-thickness 0.05]
        [--running-gear benchmarks/chrono_running_gear.yaml]

Each held-out mesh (``torch_atr/vehicles/heldout.yaml``, files under ``shared/data/meshes``) is
rendered at 30 azimuths every 12° at 5° elevation, in the model's template window. For 720
evenly spaced α, the reconstruction y(α, Θ) > 0 is compared with each view (IoU,
:func:`torch_atr.evaluation.alpha_grid_iou`):

- single view: the class of the α with the best IoU for that one view (what per-frame
  recognition sees);
- whole vehicle: the class of the α with the best mean IoU over the 30 views.

Meshes of class "unknown" (``truck/``, ``military_utility/``) are listed apart with the two
training vehicles nearest their best α, and not counted. Manifest entries with the same
geometry are counted once: two meshes are the same when their 30 silhouettes agree at mean
IoU >= 0.98 (the manifest lists one Quaternius tank twice, as a GLB and as an OBJ).

``--running-gear FILE`` (off by default) measures the Chrono vehicle bodies of the manifest as
vehicles rather than bodies: the wheels and tracks ``FILE`` gives (``benchmarks/running_gear.py``;
``benchmarks/chrono_running_gear.yaml`` holds Chrono's own, cited) are added to the named meshes in
their file frame, before the manifest's transform; everything else is measured as without it.

``--figure`` draws the meshes that are wrong in most single views beside the training
vehicles nearest their best α and nearest their best α within the true class (templates of
the catalog under ``--catalog-dir``). An existing ``--json`` or ``--figure`` is replaced only with
``--overwrite`` (the shipped figures in docs/ too), and only if this benchmark wrote it (a JSON) or
matplotlib did (a PNG). The state before issue 10 (docs/recognition_before.png)::

    mkdir -p /tmp/old && git show 82d7482:checkpoints/default.pt > /tmp/old/default_82d7482.pt
    git archive 82d7482 torch_atr/vehicles/catalog | tar -x -C /tmp/old
    python benchmarks/bench_heldout.py --checkpoint /tmp/old/default_82d7482.pt --min-thickness 0 \
        --catalog-dir /tmp/old/torch_atr/vehicles/catalog/train --figure docs/recognition_before.png --overwrite

Prints the per-mesh rows, then the per-class table (meshes on their true class, single views
on their true class, mean best IoU), the total over distinct geometries ("all 25") and over
every manifest entry as issue 10 counted them ("all entries 26").
"""

from __future__ import annotations

import argparse
import logging
import math
from pathlib import Path

import numpy as np
import torch

from torch_atr.cli import run_main
from torch_atr.config import ConfigError
from torch_atr.evaluation import alpha_grid_iou
from torch_atr.model import GenerativeShapeModel
from torch_atr.render import render_templates
from torch_atr.shape import iou
from torch_atr.vehicles import CLASS_NAMES, load_heldout_meshes
from torch_atr.vehicles.catalog import CATALOG_DIR, default_meshes_root, read_manifest
from torch_atr.vehicles.loader import MIN_THICKNESS_M
from torch_atr.viz import save_figures

from benchlib import REPO, SHIPPED, check_at_least, json_output, png_output, write_json
from running_gear import load_with_running_gear, read_running_gear

log = logging.getLogger("bench_heldout")
NAME = Path(__file__).stem
AZIMUTH_STEP_DEG, ELEVATION_DEG = 12.0, 5.0
SAME_GEOMETRY_IOU = 0.98


def views() -> tuple[torch.Tensor, torch.Tensor]:
    """The 30 benchmark views: theta (30,) every 12° from 0, phi (30,) at 5°, radians float64."""
    theta = torch.deg2rad(torch.arange(0.0, 360.0, AZIMUTH_STEP_DEG, dtype=torch.float64))
    return theta, torch.full_like(theta, math.radians(ELEVATION_DEG))


def duplicates(masks: torch.Tensor) -> dict[int, int]:
    """Index -> index of an earlier mesh with the same silhouettes (mean IoU >= 0.98); masks (B, V, H, W)."""
    out: dict[int, int] = {}
    for j in range(masks.shape[0]):
        for i in range(j):
            if i not in out and iou(masks[i], masks[j]).mean().item() >= SAME_GEOMETRY_IOU:
                out[j] = i
                break
    return out


def evaluate(model: GenerativeShapeModel, meshes: list, paths: list[str], grid: int) -> list[dict]:
    """One result row per mesh (manifest order): classes found per view and for the whole vehicle,
    and the training vehicle nearest the best α within the true class ("nearest_in_class")."""
    theta, phi = views()
    masks = torch.stack([render_templates(v, theta, phi, model.template) for v in meshes])  # (B, V, H, W)
    table = alpha_grid_iou(model, masks, theta, phi, grid)  # (B, A, V)
    alpha = torch.arange(grid, dtype=torch.float64) * (2 * math.pi / grid)
    alpha_class = model.classify(alpha).cpu()  # (A,)
    vehicle_class = torch.tensor(model.vehicle_classes)  # (K,)
    same = duplicates(masks)
    rows = []
    for b, (vehicle, path) in enumerate(zip(meshes, paths)):
        per_view = table[b].argmax(dim=0)  # (V,) best α index of each view
        score = table[b].mean(dim=1)  # (A,)
        best = score.argmax().item()
        nearest = model.nearest_vehicles(alpha[best:best + 1], 2)[0].tolist()
        row = {
            "path": path, "class": vehicle.cls, "alpha": round(alpha[best].item(), 4),
            "best_mean_iou": round(table[b, best].mean().item(), 4),
            "classified": CLASS_NAMES[alpha_class[best].item()],
            "nearest": [model.vehicle_names[k] for k in nearest],
            "view_classes": [CLASS_NAMES[c] for c in alpha_class[per_view].tolist()],
            "duplicate_of": paths[same[b]] if b in same else None,
        }
        if vehicle.cls in CLASS_NAMES:
            c = CLASS_NAMES.index(vehicle.cls)
            row["correct"] = row["classified"] == vehicle.cls
            row["views_correct"] = sum(k == vehicle.cls for k in row["view_classes"]) / len(per_view)
            in_class = score.masked_fill(alpha_class != c, -1.0).argmax().item()
            gap = model.identity.circular_distances(alpha[in_class:in_class + 1].to(model.alphas))[0].cpu()  # (K,)
            row["nearest_in_class"] = model.vehicle_names[gap.masked_fill(vehicle_class != c, math.inf).argmin().item()]
        rows.append(row)
    return rows


def wrap_name(name: str, width: int = 20) -> str:
    """A mesh's name on lines of at most ``width`` characters, broken after underscores where it can (a
    rotated row label longer than its row ran into the next one's)."""
    lines = [""]
    for part in name.replace("_", "_\n").split("\n"):
        if lines[-1] and len(lines[-1]) + len(part) > width:
            lines.append("")
        lines[-1] += part
    return "\n".join(lines)


def failure_figure(rows: list[dict], meshes: list, catalog_dir: Path, model: GenerativeShapeModel, title: str):
    """Meshes wrong in most single views, each beside the training vehicle nearest its best α and the one
    of its true class nearest its best α in that class: overlaid templates at three views. Returns a Figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    from torch_atr.vehicles import load_vehicle

    shown = [(r, m) for r, m in zip(rows, meshes)
             if r["class"] in CLASS_NAMES and r["duplicate_of"] is None and r["views_correct"] < 0.5]
    shown.sort(key=lambda rm: (CLASS_NAMES.index(rm[0]["class"]), rm[0]["path"]))
    cls_of = dict(zip(model.vehicle_names, (CLASS_NAMES[c] for c in model.vehicle_classes)))
    degrees = (0.0, 36.0, 84.0)
    theta = torch.deg2rad(torch.tensor(degrees, dtype=torch.float64))
    phi = torch.full_like(theta, math.radians(ELEVATION_DEG))
    colours = np.array([[1.0, 1.0, 1.0], [0.95, 0.5, 0.1], [0.15, 0.45, 0.9], [0.25, 0.25, 0.25]])
    ncol = 2 * len(degrees)
    fig, axes = plt.subplots(max(len(shown), 1), ncol, figsize=(2.0 * ncol, 1.5 * len(shown) + 1.2), squeeze=False)
    crop = slice(12, 52)  # the central 7.5 m of the 12 m window
    for i, (row, mesh) in enumerate(shown):
        real = render_templates(mesh, theta, phi, model.template)
        for j, name in enumerate((row["nearest"][0], row["nearest_in_class"])):
            train = render_templates(load_vehicle(catalog_dir / name / f"{name}.urdf"), theta, phi, model.template)
            for v, deg in enumerate(degrees):
                ax = axes[i, j * len(degrees) + v]
                code = real[v].long() + 2 * train[v].long()  # 0 neither, 1 real only, 2 training only, 3 both
                ax.imshow(colours[code.numpy()][crop, crop], interpolation="nearest")
                ax.set_xticks([])
                ax.set_yticks([])
                if i == 0:
                    which = "nearest α found" if j == 0 else "nearest in true class"
                    ax.set_title(f"{which}\nθ = {deg:g}°", fontsize=8)
                if v == 0:
                    ax.set_xlabel(f"{name} ({cls_of[name]})", fontsize=7, loc="left")
        axes[i, 0].set_ylabel(f"{wrap_name(Path(row['path']).stem)}\n{row['class']} → {row['classified']}\n"
                              f"share of single views\nin true class: {row['views_correct']:.2f}", fontsize=7)
    legend = [Patch(color=colours[k], label=label)
              for k, label in ((1, "real mesh only"), (2, "training vehicle only"), (3, "both"))]
    fig.legend(handles=legend, loc="lower center", ncol=3, fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.04, 1, 0.97))
    return fig


def summary(rows: list[dict]) -> dict[str, dict]:
    """Per class, "all" (each geometry once) and "all entries" (every manifest entry, as issue 10
    counted): meshes, meshes on class, mean single-view accuracy, mean best IoU."""
    known = [r for r in rows if r["class"] in CLASS_NAMES]
    counted = [r for r in known if r["duplicate_of"] is None]
    groups = {cls: [r for r in counted if r["class"] == cls] for cls in CLASS_NAMES}
    groups.update({"all": counted, "all entries": known})
    return {name: {"meshes": len(sel), "correct": sum(r["correct"] for r in sel),
                   "views_correct": sum(r["views_correct"] for r in sel) / len(sel),
                   "best_mean_iou": sum(r["best_mean_iou"] for r in sel) / len(sel)}
            for name, sel in groups.items() if sel}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", default=str(SHIPPED), help="the trained model (default: the shipped one)")
    parser.add_argument("--meshes", default=None, help="held-out meshes folder (default: shared/data/meshes)")
    parser.add_argument("--grid", type=int, default=720, help="number of α values searched")
    parser.add_argument("--json", type=Path, default=None, help="also write the rows and the summary here")
    parser.add_argument("--figure", type=Path, default=None, help="draw the meshes wrong in most views here (PNG)")
    parser.add_argument("--catalog-dir", type=Path, default=CATALOG_DIR / "train",
                        help="the checkpoint's training vehicles, <dir>/<name>/<name>.urdf (for --figure)")
    parser.add_argument("--min-thickness", type=float, default=MIN_THICKNESS_M,
                        help="thinner protrusions are trimmed from the meshes (0: keep them, as before issue 10)")
    parser.add_argument("--running-gear", type=Path, default=None,
                        help="YAML of wheels and tracks to add to named bodies in their file frame "
                             "(e.g. benchmarks/chrono_running_gear.yaml; default: none, the meshes as they are)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an earlier --json of this benchmark or a matplotlib --figure")
    args = parser.parse_args(argv)
    check_at_least("grid", args.grid, 1)
    check_at_least("min-thickness", args.min_thickness, 0)
    model = GenerativeShapeModel.from_checkpoint(args.checkpoint)
    if args.figure is not None:
        missing = [n for n in model.vehicle_names if not (args.catalog_dir / n / f"{n}.urdf").is_file()]
        if missing:
            raise ConfigError(f"--catalog-dir {args.catalog_dir} lacks {len(missing)} of the checkpoint's training "
                              f"vehicles, e.g. {missing[0]}/{missing[0]}.urdf (--figure draws them)")
    json_out = json_output(args.json, args.overwrite, NAME)
    figure = png_output(args.figure, args.overwrite, "figure")
    entries = read_manifest()
    gear = {} if args.running_gear is None else read_running_gear(args.running_gear, entries)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    meshes = load_heldout_meshes(args.meshes, [e for e in entries if e.path not in gear], args.min_thickness)
    if gear:
        root = default_meshes_root() if args.meshes is None else Path(args.meshes)
        bare = iter(meshes)
        meshes = [load_with_running_gear(root, e, gear[e.path], args.min_thickness) if e.path in gear else next(bare)
                  for e in entries]
        log.info("running gear from %s added to %d bodies: %s\n", args.running_gear, len(gear),
                 ", ".join(e.path for e in entries if e.path in gear))
    rows = evaluate(model, meshes, [e.path for e in entries], args.grid)

    known = sorted((r for r in rows if r["class"] in CLASS_NAMES), key=lambda r: (r["class"], r["path"]))
    unknown = sorted((r for r in rows if r["class"] not in CLASS_NAMES), key=lambda r: r["path"])
    log.info("%-46s %-8s %-8s %5s %6s  %s", "mesh", "class", "found", "IoU", "views", "nearest training vehicles")
    for r in known:
        note = f"  (same geometry as {r['duplicate_of']}: not counted)" if r["duplicate_of"] else ""
        log.info("%-46s %-8s %-8s %5.3f %6.2f  %s%s", r["path"], r["class"], r["classified"], r["best_mean_iou"],
                 r["views_correct"], ", ".join(r["nearest"]), note)
    log.info("out of the trained classes (not counted): class found and nearest training vehicles")
    for r in unknown:
        log.info("%-46s %-8s %-8s %5.3f %6s  %s", r["path"], r["class"], r["classified"], r["best_mean_iou"], "-",
                 ", ".join(r["nearest"]))
    table = summary(rows)
    log.info("\n| class | meshes on true class | single views on true class | best mean IoU |\n|---|---|---|---|")
    for name, s in table.items():
        label, bold = (f"{name} {s['meshes']}", "**") if name.startswith("all") else (name, "")
        log.info("| %s%s%s | %s%d/%d%s | %s%.3f%s | %.3f |", bold, label, bold, bold, s["correct"], s["meshes"], bold,
                 bold, s["views_correct"], bold, s["best_mean_iou"])
    if figure is not None:
        path = Path(args.checkpoint).resolve()
        shown_path = path.relative_to(REPO) if path.is_relative_to(REPO) else path.name
        fig = failure_figure(rows, meshes, args.catalog_dir, model,
                             f"Held-out real meshes wrong in most single views (static α search, {shown_path}): "
                             f"overlaid 64 x 64 templates, central 7.5 m, 5° elevation")
        save_figures({figure.stem: fig}, figure.parent)
        log.info("wrote %s", figure)
    if json_out is not None:
        extra = {} if args.running_gear is None else {"running_gear": str(args.running_gear)}
        write_json({"checkpoint": str(args.checkpoint), **extra, "rows": rows, "summary": table}, json_out, NAME)


if __name__ == "__main__":
    run_main(main)
