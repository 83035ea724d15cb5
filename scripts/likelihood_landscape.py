"""Why did the tracker settle where it did? Score the frame against the truth and the estimate.

Tracks a simulated sequence (the bench's: 300 frames; 1000 particles, Method I, the tracker's
defaults) up to ``--frame``,
then scores that frame's segmented mask (eq. 5.2, ``Tracker.score``; higher is better) for:

- the estimate, as a particle;
- the true position, and the estimate's position, with the heading swept over the truth ± 1 rad
  and, at each heading, the best of 720 α (its class in brackets);
- with ``--classes``: the best per class over a grid around the truth (range −20 … +10 m, x ±0.6 m,
  y ±0.3 m, heading ±0.8 rad), every α.

    python scripts/likelihood_landscape.py --vehicle t_72 --seed 2 --frame 150 [--init truth] [--classes]
        [--set key=value ...]

The T-72 findings of docs/tracking.md (the README's "Measured: tracking") come from seeds 0 and 2 at
frame 150 (truth start) and seed 1 at frames 0 and 100 with ``--classes``, with the tracker's
defaults before re-detection's search at frame 10 (``--set redetect.every=0``); ``--set`` tries an
option, e.g. ``redetect.until=0`` (search all through the run).
"""

from __future__ import annotations

import argparse
import itertools
import logging
import math

import numpy as np
import torch

from torch_atr.config import load_config
from torch_atr.data.synthetic import SceneConfig, SyntheticSequence
from torch_atr.model import GenerativeShapeModel
from torch_atr.tracking import Tracker, TrackerConfig
from torch_atr.tracking.motion import ALPHA, HEADING, STATE_DIM, X, Y, Z

ALPHAS = torch.linspace(0, 2 * math.pi, 721)[:-1]


def with_every_alpha(x: float, y: float, z: float, heading: float) -> torch.Tensor:
    """(720, 6) particles at one pose, one per α of the grid."""
    p = torch.zeros(len(ALPHAS), STATE_DIM)
    p[:, X], p[:, Y], p[:, Z], p[:, HEADING], p[:, ALPHA] = x, y, z, heading, ALPHAS
    return p


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vehicle", default="t_72")
    parser.add_argument("--range", type=float, default=1000.0)
    parser.add_argument("--seed", type=int, default=0, help="the scene's and the tracker's seed")
    parser.add_argument("--frames", type=int, default=300, help="the sequence's length (the run is centred on "
                        "the circle's near point, so the length moves the trajectory)")
    parser.add_argument("--frame", type=int, default=150, help="the frame scored")
    parser.add_argument("--init", choices=["truth", "blind"], default="truth")
    parser.add_argument("--classes", action="store_true", help="also the best per class around the truth")
    parser.add_argument("--checkpoint", default="checkpoints/default.pt")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="tracker config overrides")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)

    model = GenerativeShapeModel.from_checkpoint(args.checkpoint)
    if not 0 <= args.frame < args.frames:
        parser.error(f"--frame must lie in [0, --frames); got {args.frame}")
    seq = SyntheticSequence(args.vehicle, SceneConfig(range_m=args.range, frames=args.frames, seed=args.seed))
    cfg = load_config(TrackerConfig, None, [f"init.mode={args.init}", *args.set])
    tracker = Tracker(model, seq.camera, cfg, seed=args.seed)
    row = tracker.run(seq, frames=args.frame + 1, progress=False, snapshots=0).rows[-1]
    truth, mask = seq.truth(args.frame), tracker.last_mask
    classes = model.classify(ALPHAS.to(model.alphas))

    def best(particles: torch.Tensor) -> str:
        scores = tracker.score(mask, particles)
        k = int(scores.argmax())
        return f"{float(scores[k]):7.1f} ({model.class_names[int(classes[k])]})"

    estimate = torch.tensor([[row[k] for k in ("x", "y", "z", "heading", "speed", "alpha")]])
    print(f"{args.vehicle} at {args.range:.0f} m, seed {args.seed}, frame {args.frame}: true view θ "
          f"{row['true_theta']:.2f} rad, estimate θ {row['theta']:.2f} rad, class {row['class']}")
    print(f"truth    x {truth.x:7.2f}  y {truth.y:6.2f}  z {truth.z:7.1f} m")
    print(f"estimate x {row['x']:7.2f}  y {row['y']:6.2f}  z {row['z']:7.1f} m, "
          f"score {float(tracker.score(mask, estimate)[0]):.1f}")
    print("heading − true (rad) | best over α at the true position | at the estimate's position")
    for dh in np.arange(-1.0, 1.001, 0.1):
        h = truth.heading + float(dh)
        print(f"{dh:+20.1f} | {best(with_every_alpha(truth.x, truth.y, truth.z, h)):>32} | "
              f"{best(with_every_alpha(row['x'], row['y'], row['z'], h)):>26}")
    if args.classes:
        print("range − true (m) | best per class over x ±0.6 m, y ±0.3 m, heading ±0.8 rad, every α")
        offsets = list(itertools.product((-0.6, -0.3, 0.0, 0.3, 0.6), (-0.3, 0.0, 0.3), np.arange(-0.8, 0.801, 0.1)))
        every_class = classes.cpu().repeat(len(offsets))
        for dz in (-20.0, -10.0, 0.0, 10.0):
            p = torch.cat([with_every_alpha(truth.x + dx, truth.y + dy, truth.z + dz, truth.heading + float(dh))
                           for dx, dy, dh in offsets])
            top = torch.full((len(model.class_names),), -math.inf).scatter_reduce(
                0, every_class, tracker.score(mask, p).cpu(), "amax")
            print(f"{dz:+16.0f} | " + "  ".join(f"{c} {float(v):6.1f}" for c, v in zip(model.class_names, top)))


if __name__ == "__main__":
    main()
