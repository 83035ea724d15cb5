"""Contact sheet of the IR scene simulator: does a simulated vehicle look like one at every range?

One row per range (1000 ... 3500 m in 500 m steps, and 5000 m): a fixed-size crop of the frame
around the target (contrast-stretched from the crop's 0.5 percentile to its maximum), the mask that the
background subtraction (MOG2 warmed up on target-free frames, thesis 3.1) segments from it,
the true mask, and the visible surface's parts (body, running gear, engine deck, exhaust). The
top row is the full 1000 m frame. Every crop has the same size in pixels, so the target's size
shows its range.

    python scripts/sim_contact_sheet.py --vehicle t_72 --out /tmp/sim_contact_sheet.png [--set night=false]
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 (after the backend is chosen)
import numpy as np  # noqa: E402

from torch_atr.config import load_config  # noqa: E402
from torch_atr.data.synthetic import PARTS, SceneConfig, SyntheticSequence  # noqa: E402
from torch_atr.segmentation import ForegroundSegmenter, SegmentationConfig  # noqa: E402
from torch_atr.shape import iou  # noqa: E402

log = logging.getLogger("sim_contact_sheet")

RANGES = (1000.0, 1500.0, 2000.0, 2500.0, 3000.0, 3500.0, 5000.0)
CROP = (96, 192)  # rows, columns of every crop
PART_COLOURS = {"grey": (0.55, 0.55, 0.55), "blue": (0.2, 0.45, 0.9), "orange": (0.95, 0.55, 0.1),
                "red": (0.9, 0.1, 0.1)}  # in PARTS order


def stretch(img: np.ndarray) -> np.ndarray:
    """Contrast-stretch to [0, 1] between the 0.5 percentile and the maximum (hot spots stay visible)."""
    lo, hi = np.percentile(img, 0.5), img.max()
    return np.clip((img.astype(np.float64) - lo) / max(hi - lo, 1.0), 0.0, 1.0)


def crop(img: np.ndarray, centre: tuple[float, float]) -> np.ndarray:
    """A CROP-sized window of ``img`` centred on (u, v), shifted to stay inside the image."""
    h, w = CROP
    v0 = int(np.clip(round(centre[1]) - h // 2, 0, img.shape[0] - h))
    u0 = int(np.clip(round(centre[0]) - w // 2, 0, img.shape[1] - w))
    return img[v0:v0 + h, u0:u0 + w]


def part_image(parts: np.ndarray) -> np.ndarray:
    """(H, W) PARTS indices (−1 off-target) -> (H, W, 3) PART_COLOURS on black."""
    out = np.zeros(parts.shape + (3,))
    on = parts >= 0
    out[on] = np.array(list(PART_COLOURS.values()))[parts[on]]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--vehicle", default="t_72", help="catalog name or URDF / mesh path")
    parser.add_argument("--frame", type=int, default=150, help="frame shown (the default run is centred on it)")
    parser.add_argument("--warmup", type=int, default=50, help="target-free frames for the background model")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="SceneConfig overrides")
    parser.add_argument("--out", type=Path, default=Path("/tmp/sim_contact_sheet.png"))
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    base = load_config(SceneConfig, overrides=args.set)

    fig = plt.figure(figsize=(13, 6 + 1.9 * len(RANGES)))
    grid = fig.add_gridspec(len(RANGES) + 1, 4, height_ratios=[6 / 1.9] + [1] * len(RANGES))
    full = fig.add_subplot(grid[0, :])
    rows = [[fig.add_subplot(grid[row, col]) for col in range(4)] for row in range(1, len(RANGES) + 1)]
    for ax in [full] + [ax for row in rows for ax in row]:
        ax.set_axis_off()
    for row, range_m in zip(rows, RANGES):
        seq = SyntheticSequence(args.vehicle, dataclasses.replace(base, range_m=range_m))
        segmenter = ForegroundSegmenter(SegmentationConfig(warmup_frames=args.warmup))
        segmenter.warm_up(seq.warmup_frames(args.warmup))
        frame = seq.frame(args.frame)
        truth = seq.truth(args.frame)
        segmented = segmenter(frame)
        visible = seq.visible_mask(args.frame)
        overlap = float(iou(segmented, visible))
        centre = (truth.u, truth.v)
        length = truth.u1 - truth.u0 + 1
        log.info("%5.0f m: target %3.0f x %3.0f px, PSF sigma %.2f px, IoU %.2f, view %.0f deg",
                 range_m, length, truth.v1 - truth.v0 + 1, seq.cfg.psf_sigma, overlap, np.degrees(truth.theta))
        if range_m == RANGES[0]:
            full.imshow(stretch(frame), cmap="gray", interpolation="nearest")
            full.set_title(f"{seq.name}, frame {args.frame}: the full {frame.shape[1]} x {frame.shape[0]} frame",
                           fontsize=9)
        cells = (
            (stretch(crop(frame, centre)), f"{range_m:.0f} m: frame (PSF σ {seq.cfg.psf_sigma:.2f} px)"),
            (crop(segmented, centre), f"segmented, IoU {overlap:.2f} vs visible"),
            (crop(seq.true_mask(args.frame), centre), f"true mask, {length:.0f} px long"),
            (part_image(crop(seq.part_map(args.frame), centre)),
             ", ".join(f"{p} {c}" for p, c in zip(PARTS, PART_COLOURS))),
        )
        for ax, (img, title) in zip(row, cells):
            ax.imshow(img, cmap="gray", interpolation="nearest", vmin=0, vmax=1)
            ax.set_title(title, fontsize=7)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    log.info("wrote %s", args.out)


if __name__ == "__main__":
    main()
