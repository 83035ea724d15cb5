"""Pose and identity without a camera (thesis 6.3, the cargo van): the window follows the blob.

An uncalibrated video has no 3D: no position, range or heading. A particle of
:class:`BlobTracker` is ``[θ, φ, α]``, the view and the identity, each a random walk (variances
per second: ``motion.sigma2_heading`` for θ, ``motion.sigma2_elevation`` for φ, which is
reflected into [0, π/2], and ``motion.sigma2_alpha``). Each frame the segmented blob fixes every
particle's window: the particle's predicted silhouette (y > 0 at the likelihood resolution) is
laid on the blob — its box scaled and shifted onto the blob's box (the blob normalised to the
hypothesis) — and the frame's distance is compared there with eq. 5.2 as in the 3D filter,
over the silhouette's box grown by τ, resampled to L × L. Comparing over the whole template window
instead favours the smallest silhouettes (a car fills less of its 12 m window than a tank, so its
boundary errors weigh less in the mean): every vehicle came out a car. The blind start scores a
grid of (α, θ, φ) hypotheses the same way and draws particles around the best of each class, as
the 3D filter's does: without a range, cars seen from above explain many first blobs best.
Everything else (segmentation, weights, resampling, estimates, lost frames, outputs) is
:class:`~torch_atr.tracking.Tracker`'s.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from torch_atr._checks import check_shape
from torch_atr.data.sequence import FrameTruth
from torch_atr.pose import wrap_angle
from torch_atr.tracking.estimates import circular_mean, class_posterior
from torch_atr.tracking.filter import FrameDistance, Tracker, TrackerConfig
from torch_atr.tracking.initialise import best_hypotheses, hypothesis_shares
from torch_atr.tracking.motion import MotionConfig
from torch_atr.tracking.observation import (blob_windows, cell_offsets, log_likelihood, mask_box, observe_windows,
                                            silhouette_boxes)
from torch_atr.tracking.resampling import effective_sample_size

THETA, PHI, ALPHA = range(3)
ELEVATIONS_DEG = (0.0, 10.0, 20.0, 30.0, 40.0)  # the blind start's φ hypotheses (the training elevations)
BOX_COLUMNS = ("blob_u0", "blob_v0", "blob_u1", "blob_v1")  # a row's blob box, the estimate laid on it (image px)


def wrap_views(particles: torch.Tensor) -> torch.Tensor:
    """[θ, φ, α] particles (N, 3) with θ and α wrapped to [0, 2π) and φ reflected into [0, π/2]
    (as often as it takes: a walk of a long gap between frames goes beyond ±π)."""
    check_shape("particles", particles, ("N", 3))
    out = particles.clone()
    out[:, THETA], out[:, ALPHA] = wrap_angle(out[:, THETA]), wrap_angle(out[:, ALPHA])
    half_pi, phi = math.pi / 2, out[:, PHI]
    phi = torch.where(phi.abs() > math.pi, torch.remainder(phi, math.pi), phi)  # the reflections repeat every π
    out[:, PHI] = half_pi - (half_pi - phi.abs()).abs()  # reflect at 0 and at π/2
    return out


def predict_views(particles: torch.Tensor, dt: float, cfg: MotionConfig, generator: torch.Generator | None = None
                  ) -> torch.Tensor:
    """Random walks on θ, φ and α (eq. 5.3 for α) over ``dt`` seconds: particles (N, 3) -> (N, 3)."""
    check_shape("particles", particles, ("N", 3))
    std = torch.tensor([cfg.sigma2_heading, cfg.sigma2_elevation, cfg.sigma2_alpha], dtype=torch.float64)
    std = std.mul(dt).sqrt().to(particles)
    return wrap_views(particles + torch.randn(particles.shape, generator=generator, dtype=particles.dtype,
                                              device=particles.device) * std)


class BlobTracker(Tracker):
    """Tracking of view and identity on the normalised blob of an uncalibrated sequence (module
    docstring). Same arguments as :class:`Tracker` without the camera; estimate rows carry θ, φ,
    α, the class, the nearest vehicles, the class posterior, the ESS, the overlap and the box of
    the blob the estimate is laid on (``BOX_COLUMNS``; none before the first blob), no x, y, z."""

    needs_camera = False

    def __init__(self, model, config: TrackerConfig | None = None, **kwargs):
        super().__init__(model, None, config, **kwargs)
        if self.cfg.adapt.every:
            raise ValueError("adapt.every > 0 (kernel-width adaptation) needs a calibrated camera")

    def _begin(self) -> None:
        super()._begin()
        self._blob_box: torch.Tensor | None = None  # the last blob's box (4,), image pixels
        # The last distance (_frame_distance, _covering), its mask and the window side its margin covers.
        self._distance, self._mask, self._margin_side = None, None, math.inf

    def initialise(self, truth: FrameTruth) -> None:
        """Particles around a truth's view (θ, φ) and its vehicle's α (or its class centre; for a class
        the model lacks, α uniform around the manifold)."""
        if not (math.isfinite(truth.theta) and math.isfinite(truth.phi)):
            raise ValueError(f"Truth initialisation without a camera needs the view theta, phi; got "
                             f"({truth.theta}, {truth.phi})")
        from torch_atr.tracking.initialise import start_alphas, truth_alpha

        alpha = truth_alpha(self.model, truth.vehicle, truth.vehicle_class, self.cfg.init.alpha)
        n, std = self.cfg.filter.particles, self.cfg.init.heading_std_rad
        noise = torch.randn(n, 3, generator=self.generator, dtype=self.dtype, device=self.device)
        views = torch.tensor([truth.theta, truth.phi], dtype=self.dtype, device=self.device) + noise[:, :2] * std
        self._reset_views(torch.cat([views, start_alphas(alpha, n, self.generator, views)[:, None]], dim=1))

    def reset(self, particles: torch.Tensor) -> None:
        """Start from given particles: (N, 3) [θ, φ, α] describing the coming frame (equal weights; the
        next :meth:`step` weighs them without a prediction first)."""
        check_shape("particles", particles, ("N", 3))
        if particles.shape[0] == 0 or not bool(particles.isfinite().all()):
            raise ValueError(f"Expected at least one particle [θ, φ, α], all finite; got {particles.shape[0]}")
        self._reset_views(particles.to(self.device, self.dtype))
        self._start, self._missed, self._unexplained = self._frames, 0, 0

    @torch.no_grad()
    def score(self, mask: np.ndarray, particles: torch.Tensor) -> torch.Tensor:
        """Eq. 5.2 of any particles (N, 3) [θ, φ, α] laid on the blob of a target mask (H, W), not
        empty, leaving the filter as it is. Returns (N,) log-likelihoods; higher is better."""
        mask = self._check_mask(mask)
        if not mask.any():
            raise ValueError("Expected a non-empty mask to score particles against")
        check_shape("particles", particles, ("N", 3))
        kept = self._blob_box
        try:
            return self._log_likelihood(self._frame_distance(mask, math.inf), particles.to(self.device, self.dtype))
        finally:
            self._blob_box = kept

    def silhouette_at(self, row: dict, shape: tuple[int, int]) -> torch.Tensor:
        """The estimate's silhouette laid on the row's blob box: (H, W) bool; none before the first blob. (On
        the tracker's last box, a run's overlay video drew every frame's estimate where the last frame's blob was.)"""
        if BOX_COLUMNS[0] not in row:
            return torch.zeros(tuple(shape), dtype=torch.bool, device=self.device)
        return super().silhouette_at(row, shape)

    def _unexplained_because(self, mask: np.ndarray, side: float) -> str:
        u0, v0, u1, v1 = mask_box(mask)
        return (f"Each silhouette is laid on the blob's box ({u1 - u0 + 1} x {v1 - v0 + 1} px): a vehicle unlike every "
                f"vehicle the model was trained on cannot be explained")

    def _reset_views(self, particles: torch.Tensor) -> None:
        self.particles = wrap_views(particles)
        self.log_weights = torch.full((particles.shape[0],), -math.log(particles.shape[0]), dtype=self.dtype,
                                      device=self.device)
        self._fresh = True

    def _predict(self, dt: float) -> torch.Tensor:
        return predict_views(self.particles, dt, self.cfg.motion, self.generator)

    def _predicted_region(self):
        """The last blob's centre and box (the blob moves little between frames), and its window."""
        if self._blob_box is None:
            return None, None, math.inf
        box = self._blob_box.tolist()
        side = max(box[2] - box[0], box[3] - box[1]) + 1
        return ((box[0] + box[2]) / 2, (box[1] + box[3]) / 2), tuple(box), 4.0 * side

    def _windows(self, particles: torch.Tensor, box: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Predicted shapes y (N, L, L) and their windows laid on the blob box (4,) (uv, side: (N, 2))."""
        y = self.appearance(particles[:, ALPHA], particles[:, THETA], particles[:, PHI])
        boxes = silhouette_boxes(y > 0)
        uv, side = blob_windows(boxes, box.to(boxes), self.appearance.size)
        return y, uv, side

    def _frame_distance(self, mask: np.ndarray, side: float) -> FrameDistance:
        """The mask's distance near the blob for windows up to ``side`` pixels (``Tracker._frame_distance``),
        kept with the mask and side: a window laid on the blob can be larger (:meth:`_covering`)."""
        self._mask, self._margin_side = mask, side
        self._distance = super()._frame_distance(mask, side)
        return self._distance

    def _covering(self, distance: FrameDistance, side: torch.Tensor) -> FrameDistance:
        """The mask's distance (``distance``, the last :meth:`_frame_distance`'s mask's) over a margin wide
        enough for the windows ``side`` (N, 2) pixels: the last one computed, transformed again when a window
        is wider. The predicted region's window (4 blob sides) is narrower than the window of a silhouette
        under a quarter of the template's side (a small car head-on: its 1.7 m of 12 m), and beyond the
        margin each cell read the region's edge, nearer than τ: a VW up laid on its own blob head-on scored
        −9.5 for −3.5. The widened distance is kept, as the caller's stays narrow: a second call in the
        frame (re-detection's hypotheses after the particles') was handed the narrow one back, −7.4 for −2.9."""
        if self._mask is None:
            return distance
        side = side.prod(dim=1).sqrt()  # as the window's τ is taken (observe_windows)
        side = side[side.isfinite()]
        largest = float(side.max()) if side.numel() else 0.0
        return self._frame_distance(self._mask, largest) if largest > self._margin_side else self._distance

    def _set_blob(self, distance: FrameDistance) -> None:
        """The blob's box from its distance map (positive inside), in frame pixels."""
        rows, cols = torch.nonzero(distance.signed > 0, as_tuple=True)
        u0, v0 = distance.origin
        self._blob_box = torch.stack([cols.min() + u0, rows.min() + v0, cols.max() + u0, rows.max() + v0]).to(
            self.dtype)

    def _log_likelihood(self, distance, particles: torch.Tensor) -> torch.Tensor:
        """Eq. 5.2 over each particle's silhouette box grown by τ (module docstring); −inf for an empty
        silhouette, as in the 3D filter's hypotheses. Returns (N,)."""
        self._set_blob(distance)
        y, uv, side = self._windows(particles, self._blob_box)
        distance = self._covering(distance, side)
        L, template = self.appearance.size, self.model.template
        margin = template.tau_px * L / template.size_px  # τ in L-pixels
        boxes = silhouette_boxes(y > 0)
        centre = (boxes[:, :2] + boxes[:, 2:]) / 2  # (N, 2) in L-pixel indices
        extent = boxes[:, 2:] - boxes[:, :2] + 1 + 2 * margin  # (N, 2) L-pixels
        steps = cell_offsets(L, y)
        u, v = centre[:, 0:1] + steps * extent[:, 0:1], centre[:, 1:2] + steps * extent[:, 1:2]  # (N, L) indices
        grid = torch.stack(torch.broadcast_tensors(((u + 0.5) * (2 / L) - 1)[:, None, :],
                                                   ((v + 0.5) * (2 / L) - 1)[:, :, None]), dim=-1)
        y_box = F.grid_sample(y[:, None], torch.nan_to_num(grid), padding_mode="border", align_corners=False)[:, 0]
        scale = side / L  # image px per L-pixel
        z = observe_windows(distance.signed, uv + (centre - (L - 1) / 2) * scale, extent * scale, template, L,
                            distance.origin, image_px=side.prod(dim=1).sqrt() / template.size_px)
        log_lik = log_likelihood(z.to(y_box), y_box, self.cfg.filter.sigma)
        laid = log_lik.isfinite() & boxes.isfinite().all(dim=1)  # an empty silhouette is laid nowhere
        return torch.where(laid, log_lik, -math.inf).to(self.dtype)

    def _initialise_blind(self, mask: np.ndarray, distance, frame: np.ndarray | None) -> None:
        """A grid of (α, θ, φ) hypotheses laid on the first blob; particles around the best of each class."""
        cfg = self.cfg.init
        alpha = torch.arange(cfg.alpha_steps, dtype=self.dtype, device=self.device) * (2 * math.pi / cfg.alpha_steps)
        theta = torch.arange(cfg.azimuth_steps, dtype=self.dtype, device=self.device) * (
            2 * math.pi / cfg.azimuth_steps)
        phi = torch.tensor(ELEVATIONS_DEG, dtype=self.dtype, device=self.device).deg2rad()
        grid = torch.cartesian_prod(theta, phi, alpha)  # (M, 3) [θ, φ, α]
        self._set_blob(distance)
        log_lik = self._log_likelihood(distance, grid)
        classes = self.model.classify(grid[:, ALPHA])
        n = self.cfg.filter.particles
        pick = hypothesis_shares(best_hypotheses(log_lik, cfg.hypotheses, classes), log_lik, n, classes)
        noise = torch.randn(n, 3, generator=self.generator, dtype=self.dtype, device=self.device)
        half_steps = torch.tensor([math.pi / cfg.azimuth_steps, math.radians(5.0), math.pi / cfg.alpha_steps],
                                  dtype=self.dtype, device=self.device)
        self._reset_views(grid[pick] + noise * half_steps)
        self._fresh = False  # weighed on this very frame

    def _redetect(self, mask, distance, frame, log_lik: torch.Tensor, views_only: bool = False
                  ) -> tuple[torch.Tensor, bool]:
        """No re-detection: its hypotheses are placed by the camera, which this tracker has none of."""
        return log_lik, False

    def _estimate(self) -> dict:
        model, p = self.model, self.particles
        w = self.log_weights.exp().to(torch.float64)
        p64 = p.to(torch.float64)
        theta, theta_r = circular_mean(p64[:, THETA], w)
        alpha, alpha_r = circular_mean(p64[:, ALPHA], w)
        alpha_t = alpha.to(self.dtype).reshape(1)
        posterior = class_posterior(model.classify(p[:, ALPHA]), w, len(model.class_names))
        nearest = model.nearest_vehicles(alpha_t, 2)[0].tolist()
        best = p64[int(w.argmax())]
        row = {"theta": theta, "phi": (w * p64[:, PHI]).sum(), "alpha": alpha, "theta_concentration": theta_r,
               "alpha_concentration": alpha_r, "class": model.class_names[int(model.classify(alpha_t))],
               "nearest_1": model.vehicle_names[nearest[0]], "nearest_2": model.vehicle_names[nearest[1]],
               **{f"p_{name}": posterior[c] for c, name in enumerate(model.class_names)},
               "best_theta": best[THETA], "best_phi": best[PHI], "best_alpha": best[ALPHA],
               "ess": effective_sample_size(w)}
        if self._blob_box is not None:
            row.update(zip(BOX_COLUMNS, self._blob_box))
        return {k: float(v) if isinstance(v, torch.Tensor) else v for k, v in row.items()}

    def _estimate_window(self, row: dict):
        est = torch.tensor([[row["theta"], row["phi"], row["alpha"]]], dtype=self.dtype, device=self.device)
        _, uv, side = self._windows(est, torch.tensor([row[k] for k in BOX_COLUMNS], dtype=self.dtype))
        return est[:, ALPHA], est[:, THETA], est[:, PHI], uv, side
