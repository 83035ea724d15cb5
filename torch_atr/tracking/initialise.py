"""The first particles: from ground truth as the thesis does, or blind from the first blob.

Truth (Table 5.1 and chapter 6.2): X₀ʲ ~ N(X₀, diag(σ₀²)) around the first frame's truth, a small
positive speed (the thesis has no speed truth), and α₀ʲ at the true vehicle's αₖ when it is a
training vehicle, else at the centre of its class's arc; for a class the model lacks (a truck,
an "unknown" target) the identity is no part of the truth the start can use, and α₀ʲ is drawn
uniformly around the manifold.

Blind (what a real user has: one segmented blob and the camera). The range comes from the ground
plane when the camera's height above flat ground is known: the vehicle meets the ground in or
below the blob's lowest row, and the ray through that point meets the plane at the range. Pixel
centres are integer coordinates, and ``ground_row`` is the contact's offset in rows below the
centre of the lowest row. A pixel joins the blob when the vehicle covers enough of it, and the
fainter the target the more it must cover, so the contact lies lower for faint targets: measured
on the simulator's training vehicles (``scripts/ground_row.py``: 1000-5000 m, night and day, the
vehicle's sub-row position varied), the best offset is about 27.6 / C − 0.93 rows for a blob of
median contrast C grey levels against the background (−0.03 rows at 1000 m by night, 0.9 at
5000 m, 1.4 at 3000 m by day; residual σ 0.39 rows, where a row's quantisation alone gives 0.29).
``ground_row: null`` uses that; a number fixes the offset (0, the default: the row's centre;
0.5: its bottom edge). One row spans 18 m of range at 1000 m, 170 m at 3000 m, on the simulator.
The rule is not the default because tracked runs did not bear it out: on the blind SENSIAC-like
grid (night, 1000-3500 m), where its first ground rows are no better than the centre's (mean error
0.28 against 0.29 rows at that geometry: ``scripts/ground_row.py --grid``), Method I's mean range
error rose from 43 to 65 m (docs/tracking.md, "Choices behind the defaults"). The rule was fitted on
masks without thin parts (``segmentation.thin_threshold``), which by day join fainter pieces below
the blob: turn them off with it.

The first blob says nothing of the speed: the particles' signed speeds start at 0 ± ``speed_std_mps``,
and once the blob's track spans ``speed_frames`` frames (with the frames in a row before the start
whose blob was clear of the image's edge: a restart's missed frames) its motion across the line
of sight sets them (:func:`speeds_from_track`; a random walk of σ²_v = 1 (m/s)²/s alone took
about 60 frames to reach a vehicle's 5 m/s, and lost one at 10 m/s at 1000 m).

A blob that touches the image's edge is cut: its size, its lowest row and its shape lie (a
T-72 driving in from the side was started on a 16-pixel sliver as a car 500 m too far). The blind
start waits (no estimate, as before any blob) until the blob is ``border_px`` pixels clear of the
edge (:func:`clear_of_border`), or until it has waited ``border_wait`` frames that had a blob: a
target parked at the edge is then started on as it is.

Without the height, each hypothesis takes the range at which its silhouette has the blob's size,
which confuses a small vehicle near with a big one far (a car at 570 m for a tank at 1000 m,
measured), so give the height when you know it.

For every hypothesis (α, θ) of a coarse grid, at the elevation φ of the line of sight through the
blob, the silhouette y(α, θ, φ) > 0 of the tracker's method (Method II's nearest training vehicle,
IV's template) has a size and an offset from the window centre in template pixels; matching its
box to the blob's box at the range gives the window centre and so the position on that pixel's
ray, and the heading follows from θ and the bearing of the camera. Every hypothesis is then
scored by the observation likelihood, and the particles are drawn around the best ones (a
mixture: equal shares, jittered by about half a grid step).
"""

from __future__ import annotations

import logging
import math
import numbers
from dataclasses import dataclass

import numpy as np
import torch

from torch_atr._checks import check_shape
from torch_atr.camera import Camera
from torch_atr.config import ConfigError
from torch_atr.data.sequence import MAX_CAMERA_HEIGHT_M
from torch_atr.pose import camera_centre, wrap_angle
from torch_atr.tracking.appearance import ShapeAppearance
from torch_atr.tracking.motion import ALPHA, HEADING, SPEED, STATE_DIM, X, Z
from torch_atr.tracking.observation import (blob_windows, cut_edges, log_likelihood, observe_windows, observed_cells,
                                            project_windows)
from torch_atr.validate import integer, real

INIT_MODES = ("blind", "truth")
MAX_INIT_STD = 1e3  # the bound of InitConfig's spreads (range_std, relative; the others in their units)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class InitConfig:
    """How the first particles are drawn (module docstring)."""

    mode: str = "blind"  # "blind" (from the first blob and the camera) or "truth" (the thesis's)
    position_std_m: float = 1.0  # truth: σ of x, y, z around the truth (the thesis's N(X₀, 1))
    heading_std_rad: float = 0.1  # truth: σ of the heading around the truth
    speed_mps: float = 1.0  # truth: the initial speed, small and positive (no speed truth in the thesis)
    speed_std_mps: float = 1.0  # σ of the initial speed (truth), or of the unknown signed speed (blind; speed_frames)
    alpha: str = "vehicle"  # truth: "vehicle" (its αₖ if a training vehicle, else its class centre) or "class"
    alpha_steps: int = 72  # blind: α hypotheses evenly over [0, 2π)
    azimuth_steps: int = 36  # blind: θ hypotheses evenly over [0, 2π)
    hypotheses: int = 16  # blind: particles are drawn around this many best hypotheses, an equal share per class
    range_std: float = 0.01  # blind: relative σ of the range around a hypothesis's range
    camera_height_m: float | None = None  # blind: above flat ground; null: the sequence's, if it knows it
    ground_row: float | None = 0.0  # blind: contact in rows below the lowest blob row's centre; null: from contrast
    speed_frames: int = 10  # blind: speeds set once the blob's track spans this many frames; 0: off
    border_px: int = 2  # blind: start only on a blob this many pixels clear of the image's edge; 0: any blob
    border_wait: int = 150  # blind: ... or on a cut blob, after waiting this many frames that had one

    def __post_init__(self) -> None:
        if self.mode not in INIT_MODES:
            raise ConfigError(f"init.mode must be one of {', '.join(INIT_MODES)}; got {self.mode!r}")
        if self.alpha not in ("vehicle", "class"):
            raise ConfigError(f"init.alpha must be 'vehicle' or 'class'; got {self.alpha!r}")
        for key in ("position_std_m", "heading_std_rad", "speed_std_mps", "range_std"):
            value = getattr(self, key)
            if not (math.isfinite(value) and 0 <= value <= MAX_INIT_STD):
                raise ConfigError(f"init.{key} must be in [0, {MAX_INIT_STD:g}]; got {value!r}")
        if self.ground_row is not None and not (math.isfinite(self.ground_row) and -1 <= self.ground_row <= 2):
            raise ConfigError(f"init.ground_row must be in [-1, 2] rows or null; got {self.ground_row!r}")
        if self.camera_height_m is not None and not (math.isfinite(self.camera_height_m)
                                                     and 0 < self.camera_height_m <= MAX_CAMERA_HEIGHT_M):
            raise ConfigError(f"init.camera_height_m must be in (0, {MAX_CAMERA_HEIGHT_M:g}] metres or null; "
                              f"got {self.camera_height_m!r}")
        if not math.isfinite(self.speed_mps):
            raise ConfigError(f"init.speed_mps must be finite; got {self.speed_mps!r}")
        if not 0 <= self.speed_frames <= 10_000 or self.speed_frames == 1:
            raise ConfigError(f"init.speed_frames must be 0 (off) or in [2, 10000]; got {self.speed_frames!r}")
        for key in ("alpha_steps", "azimuth_steps", "hypotheses"):
            if not 1 <= getattr(self, key) <= 10_000:
                raise ConfigError(f"init.{key} must be in [1, 10000]; got {getattr(self, key)!r}")
        for key in ("border_px", "border_wait"):
            if not 0 <= getattr(self, key) <= 10_000_000:
                raise ConfigError(f"init.{key} must be in [0, 1e7]; got {getattr(self, key)!r}")

    def contact_row(self, contrast: float = math.nan) -> float:
        """The ground contact in rows below the centre of the blob's lowest row: ``ground_row``, or
        for null :func:`ground_row_from_contrast` of the blob's median contrast (grey levels)."""
        return ground_row_from_contrast(contrast) if self.ground_row is None else self.ground_row


GROUND_ROW_CONTRAST = 27.6  # grey levels: the contact's offset is about this / C − GROUND_ROW_BIAS rows ...
GROUND_ROW_BIAS = 0.93  # ... (module docstring; fitted by scripts/ground_row.py on training vehicles)


def ground_row_from_contrast(contrast: float) -> float:
    """The ground contact's offset in rows below the centre of the blob's lowest row, for a blob of
    median contrast ``contrast`` grey levels (module docstring), within [−0.5, 2]; 0 (the row's
    centre) when the contrast is unknown (NaN) or not positive."""
    if not (math.isfinite(contrast) and contrast > 0):
        return 0.0
    return min(max(GROUND_ROW_CONTRAST / contrast - GROUND_ROW_BIAS, -0.5), 2.0)


def clear_of_border(mask: np.ndarray, margin: int) -> bool:
    """Whether the blob ``mask`` (H, W) bool has no pixel within ``margin`` pixels of the image's
    edge, i.e. it is not cut by the edge (module docstring). ``margin`` 0: always; 1: no pixel on
    the edge itself."""
    return not any(cut_edges(mask, margin))


def blob_column(mask: np.ndarray) -> float:
    """The mean column of the blob ``mask`` (H, W) bool, not empty: its centre across the image in
    pixels (the blob's track for :func:`speeds_from_track`)."""
    if not (isinstance(mask, np.ndarray) and mask.ndim == 2 and mask.any()):
        raise ValueError(f"Expected mask to be a non-empty (H, W) array; got {getattr(mask, 'shape', type(mask))}")
    columns = mask.sum(axis=0)
    return float(columns @ np.arange(columns.shape[0])) / float(columns.sum())


def truth_alpha(model, vehicle: str, vehicle_class: str, mode: str = "vehicle") -> float | None:
    """α₀ of the thesis's initialisation: the vehicle's αₖ (``mode="vehicle"`` and a training
    vehicle) or the centre of its class's arc; None for a class the model lacks or has no training
    vehicle of (a truck, an "unknown" target, a model trained on one's own catalog without tanks:
    its identity is not part of the truth the start can use)."""
    if mode == "vehicle" and vehicle in model.vehicle_names:
        return float(model.alphas[model.vehicle_names.index(vehicle)])
    c = model.class_names.index(vehicle_class) if vehicle_class in model.class_names else None
    arcs = [(start, end) for label, start, end in model.identity.class_arcs() if label == c]
    if not arcs:  # a misspelt class ("Tank") is said louder than "unknown"
        level = logging.INFO if vehicle_class in ("", "unknown") else logging.WARNING
        why = "not one of the model's" if c is None else "which no training vehicle of the model has; its classes:"
        log.log(level, "truth start: vehicle %r of class %r, %s %s: α spread over the whole manifold", vehicle,
                vehicle_class, why, model.class_names)
        return None
    start, end = max(arcs, key=lambda arc: arc[1] - arc[0])  # its longest arc (classes are contiguous)
    return (start + end) / 2 % (2 * math.pi)


def start_alphas(alpha: float | None, n: int, generator: torch.Generator | None, like: torch.Tensor) -> torch.Tensor:
    """(n,) α₀ of a truth start in ``like``'s dtype and device: ``alpha`` in every particle, or drawn
    uniformly on [0, 2π) where it is None (a class the model lacks, :func:`truth_alpha`)."""
    if alpha is None:
        return 2 * math.pi * torch.rand(n, generator=generator, dtype=like.dtype, device=like.device)
    return torch.full((n,), alpha, dtype=like.dtype, device=like.device)


def truth_particles(position: torch.Tensor, heading: float, alpha: float | None, n: int, cfg: InitConfig,
                    generator: torch.Generator | None = None) -> torch.Tensor:
    """Particles around a known state (module docstring).

    position: (3,) the vehicle's centre in the world frame (float tensor, its dtype and device are
    the particles'); heading, alpha: radians (alpha None: unknown, drawn uniformly on [0, 2π));
    n: N. Returns (N, 6).
    """
    check_shape("position", position, (3,))
    noise = torch.randn(n, STATE_DIM, generator=generator, dtype=position.dtype, device=position.device)
    std = torch.tensor([cfg.position_std_m] * 3 + [cfg.heading_std_rad, cfg.speed_std_mps, 0.0]).to(position)
    out = torch.cat([position, position.new_tensor([heading, cfg.speed_mps, 0.0])]) + noise * std
    out[:, ALPHA] = start_alphas(alpha, n, generator, position)
    out[:, HEADING] = wrap_angle(out[:, HEADING])
    out[:, ALPHA] = wrap_angle(out[:, ALPHA])
    return out


def ground_depth(camera: Camera, pixel: torch.Tensor, camera_height_m: float) -> float:
    """Depth (along the optical axis) at which the ray through ``pixel`` (2,) meets flat ground
    ``camera_height_m`` below the camera centre (world y = c_y − height); NaN if it never does.
    InputError (a ValueError) unless the height is a finite number of metres > 0 (at 0 every ray met the ground at
    the camera, depth 0; below it, behind the camera)."""
    check_shape("pixel", pixel, (2,))
    camera_height_m = real("camera_height_m (the camera's height above the ground, metres)", camera_height_m,
                           lo=0, lo_open=True)
    R, t = camera.R.to(pixel), camera.t.to(pixel)
    ray = R.T @ camera.pixel_rays(camera.undistort(pixel))  # world direction
    if not float(ray[1]) < 0:
        return math.nan
    point = camera_centre(camera).to(pixel) + ray * (-camera_height_m / ray[1])
    return float((R @ point + t)[2])


class HypothesisGrid:
    """The blind start's (α, θ) grid and the boxes of its silhouettes, kept for the last elevation φ:
    a later call within ``tolerance`` radians of it reuses them (re-detection searches the same grid
    every few frames, and at a steady elevation their cost, most of a search's, need not be paid
    again). The silhouettes are the ones the appearance's method compares
    (:meth:`ShapeAppearance.grid_boxes`): Method II's a training vehicle's, IV's the templates.

    Args:
        appearance: the predicted shapes (its model and method); cfg: the grid sizes
            (``alpha_steps``, ``azimuth_steps``).
        tolerance: radians of φ within which the boxes are reused (0: only at the same φ).
    """

    def __init__(self, appearance: ShapeAppearance, cfg: InitConfig, tolerance: float = 0.0):
        self.appearance, self.tolerance = appearance, tolerance
        device = appearance.windows.device
        self.alpha = torch.arange(cfg.alpha_steps, dtype=torch.float64, device=device) * (2 * math.pi / cfg.alpha_steps)
        self.theta = torch.arange(cfg.azimuth_steps, dtype=torch.float64, device=device) * (
            2 * math.pi / cfg.azimuth_steps)
        self._phi, self._boxes = math.nan, None

    def boxes(self, phi: float) -> torch.Tensor:
        """(A·B, 4) float64 silhouette boxes [c0, r0, c1, r1] in template pixels, α-major, at ``phi``."""
        if not abs(phi - self._phi) <= self.tolerance:
            t = self.theta
            self._phi, self._boxes = phi, self.appearance.grid_boxes(self.alpha, t, t.new_full(t.shape, phi)).to(
                torch.float64)
        return self._boxes

    def forget(self) -> None:
        """Drop the kept boxes (after the model's shapes change)."""
        self._phi, self._boxes = math.nan, None


def blind_hypotheses(blob: torch.Tensor, distance: torch.Tensor, camera: Camera, appearance: ShapeAppearance,
                     cfg: InitConfig, sigma: float, camera_height_m: float = math.nan, contrast: float = math.nan,
                     origin: tuple[int, int] = (0, 0), known_depth: float = math.nan,
                     grid: HypothesisGrid | None = None, alpha_index: torch.Tensor | None = None,
                     cut: tuple[bool, bool, bool, bool] = (False, False, False, False)
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """Score a grid of (α, θ) hypotheses against one blob (module docstring).

    Args:
        blob: (H, W) bool tensor, the target blob (non-empty).
        distance: (H, W) the frame's signed distance in image pixels, or a region of it whose
            (0, 0) is the frame pixel ``origin`` (``observation.frame_distance``).
        camera: the scene's camera (sensor-like, ground-levelled world frame).
        appearance: the predicted shapes (its model and method).
        cfg: the grid sizes; sigma: the likelihood σ.
        camera_height_m: the camera's height above flat ground, > 0 (NaN: unknown, ranges from sizes).
        contrast: the blob's median contrast in grey levels, for ``cfg.ground_row`` null
            (:func:`ground_row_from_contrast`; NaN: unknown, the lowest row's centre).
        origin: (u0, v0) the frame pixel of ``distance[0, 0]`` when it is a region.
        known_depth: the range to place every hypothesis at (depth along the optical axis, m), e.g.
            a tracker's estimate; NaN: from the ground, or from the blob's size. At or behind the camera
            (≤ 0) every hypothesis has log-likelihood −inf.
        grid: the (α, θ) grid's silhouette boxes, kept between calls (default: computed here).
        alpha_index: (A,) the grid's α to score (indices into ``grid.alpha``); default all of them.
        cut: (left, top, right, bottom), the image edges that cut the blob (``observation.cut_edges``):
            the cells of a window beyond them are left out of its likelihood, as the filter leaves
            them out (``Tracker``'s likelihood), so that re-detection compares like with like.
    Returns:
        states: (M, 6) one particle per hypothesis (speed 0), M = A × azimuth_steps (α-major),
        float64 on the appearance's device; log_lik: (M,) their log-likelihoods (−inf for a
        hypothesis whose silhouette is empty).
    """
    check_shape("blob", blob, ("H", "W"))
    if blob.dtype != torch.bool:
        raise ValueError(f"Expected blob to be a bool tensor; got dtype {blob.dtype}")
    check_shape("distance", distance, (None, None))
    if alpha_index is not None:
        check_shape("alpha_index", alpha_index, ("A",))
    model = appearance.model
    if len(cut) != 4:
        raise ValueError(f"Expected cut, the edges (left, top, right, bottom) that cut the blob, to hold 4 flags; "
                         f"got {cut!r}")
    device, dtype = appearance.windows.device, torch.float64
    rows, cols = torch.nonzero(blob, as_tuple=True)
    if rows.numel() == 0:
        raise ValueError("blind initialisation needs a non-empty blob")
    blob_box = torch.stack([cols.min(), rows.min(), cols.max(), rows.max()]).to(dtype=dtype, device=device)
    R, t, K = (camera.R.to(device, dtype), camera.t.to(device, dtype), camera.K.to(device, dtype))
    ray = R.T @ camera.pixel_rays(camera.undistort((blob_box[:2] + blob_box[2:]) / 2))  # through the blob centre
    phi = torch.asin((-ray[1] / ray.norm()).clamp(-1, 1))  # elevation of the camera seen from the target
    grid = HypothesisGrid(appearance, cfg) if grid is None else grid
    alpha, theta, boxes = grid.alpha.to(device, dtype), grid.theta.to(device, dtype), grid.boxes(float(phi))
    if alpha_index is not None:
        alpha_index = alpha_index.to(device)
        alpha, boxes = alpha[alpha_index], boxes.view(alpha.shape[0], -1, 4)[alpha_index].reshape(-1, 4)
    A, B, S = alpha.shape[0], theta.shape[0], model.template.size_px
    # Range: from the ground at the contact below the blob's lowest row, else where the silhouette has the blob's size.
    contact = torch.stack([(blob_box[0] + blob_box[2]) / 2, blob_box[3] + cfg.contact_row(contrast)])
    unknown = isinstance(camera_height_m, numbers.Real) and math.isnan(camera_height_m)
    ground = known_depth if math.isfinite(known_depth) else (
        math.nan if unknown else ground_depth(camera, contact, camera_height_m))
    f = torch.stack([K[0, 0], K[1, 1]])
    if math.isfinite(ground):
        side = (f * model.template.window_m / ground)[None]  # (1, 2): every window alike
    else:  # the range z where the silhouette has the blob's size: its sides' geometric mean is √(fx fy) W / z
        side = blob_windows(boxes, blob_box, S)[1] * (f / f.prod().sqrt())  # (fx, fy) W / z: 1 for square pixels
    centre_px, side = blob_windows(boxes, blob_box, S, side)
    depth = f[0] * model.template.window_m / side[:, 0]
    sensor = camera.pixel_rays(camera.undistort(centre_px)) * depth[:, None]  # (M, 3), z = depth
    position = (sensor - t) @ R  # world frame: Rᵀ (p_s − t)
    to_camera = camera_centre(camera).to(position) - position
    bearing = torch.atan2(to_camera[:, 0], to_camera[:, 2])  # of the camera, seen from the vehicle
    th = theta.repeat(A)
    states = torch.zeros(A * B, STATE_DIM, dtype=dtype, device=device)
    states[:, X:Z + 1] = position
    states[:, HEADING] = wrap_angle(th + bearing)  # θ = h − bearing
    states[:, ALPHA] = alpha.repeat_interleave(B)
    valid = (depth > 0) & states.isfinite().all(dim=1)  # an empty silhouette places nothing
    states = torch.where(valid[:, None], states, 0.0)
    uv, side = project_windows(camera, states[:, X:Z + 1], model.template.window_m)
    L, phis = appearance.size, phi.expand(A * B)
    z = observe_windows(distance, uv, side, model.template, L, origin)
    with torch.no_grad():
        y = appearance(states[:, ALPHA], th, phis).to(z)
        log_lik = log_likelihood(z, y, sigma)
        if any(cut):  # the cells beyond an edge that cuts the blob marginalised out, as the filter's likelihood does
            columns, rows = observed_cells(uv, side, L, (camera.height, camera.width), cut)
            partly = ~(columns.all(dim=1) & rows.all(dim=1))
            observed = rows[partly, :, None] & columns[partly, None, :]
            sse = appearance.squared_errors(z[partly], states[partly, ALPHA], th[partly], phis[partly], observed)
            log_lik[partly] = (-sse / (L * L * 2.0 * sigma * sigma)).to(log_lik)  # NaN where no cell is observed
    log_lik = torch.where(valid & ~log_lik.isnan(), log_lik, -math.inf)
    return states, log_lik


def _ranked(log_lik: torch.Tensor, stable: bool = False) -> torch.Tensor:
    """(M,) indices of ``log_lik`` (M,), best first; a value not finite ranks with −inf, last (a plain
    descending sort puts NaN first). ``stable``: ties keep their order."""
    return torch.where(log_lik.isfinite(), log_lik, -math.inf).argsort(descending=True, stable=stable)


def best_hypotheses(log_lik: torch.Tensor, count: int, classes: torch.Tensor | None = None) -> torch.Tensor:
    """Indices of the best hypotheses, grouped by class (ascending), best first within each class.

    With classes, each class keeps its best ``count // C`` hypotheses (at least one; C the
    classes with a finite hypothesis), so one frame's blob does not decide the class alone
    (measured: the T-72's first blob put all 16 best hypotheses on APCs with one scene seed of
    three; on uncalibrated blobs, cars took 14–16 of the best 16 for six of the eight test
    vehicles, and the BTR-70 then tracked as a car); the next frames' weights do. Without, the
    ``count`` best.

    Args:
        log_lik: (M,) hypotheses' log-likelihoods, M ≥ 1, −inf (or NaN) for invalid ones; count: how
            many to keep, ≥ 1; classes: (M,) the class of each hypothesis, or None.
    Returns:
        (K,) int64 indices into log_lik, K ≥ 1: only finite ones while any is (the best one otherwise).
    """
    check_shape("log_lik", log_lik, ("M",))
    if log_lik.shape[0] == 0:
        raise ValueError("Expected at least one hypothesis to choose from; got none")
    integer("count (the hypotheses to keep)", count, lo=1)
    order = _ranked(log_lik)[:max(1, int(log_lik.isfinite().sum()))]
    if classes is None:
        return order[:count]
    check_shape("classes", classes, (log_lik.shape[0],))
    present = classes[order].unique()
    per_class = max(1, count // len(present))
    return torch.cat([order[classes[order] == c][:per_class] for c in present])


def hypothesis_shares(best: torch.Tensor, log_lik: torch.Tensor, n: int, classes: torch.Tensor | None = None
                      ) -> torch.Tensor:
    """The hypothesis each of ``n`` particles is drawn around: the ``best`` in equal shares, in
    their order (the first take one more where K does not divide n). With fewer particles than
    hypotheses, each class's best comes first, the best class first, then each class's second
    best, ...: one particle goes to the best of all (it went to the first class's best, whatever
    it scored: a single particle started a tank on an SUV's blob).

    best: (K,) from :func:`best_hypotheses` with the same ``log_lik`` (M,) and ``classes`` (M,)
    (or None). Returns (n,) int64 indices into log_lik.
    """
    check_shape("log_lik", log_lik, ("M",))
    check_shape("best", best, ("K",))
    if classes is not None:
        check_shape("classes", classes, (log_lik.shape[0],))
    if n < best.shape[0]:
        order = _ranked(log_lik[best], stable=True)
        if classes is not None:  # each hypothesis's rank within its class (best_hypotheses groups them)
            grouped = classes[best]
            rank = torch.arange(best.shape[0], device=best.device) - torch.searchsorted(grouped, grouped)
            order = order[rank[order].argsort(stable=True)]
        best = best[order[:n]]
    return best[torch.arange(n, device=best.device) % best.shape[0]]


def blind_particles(states: torch.Tensor, log_lik: torch.Tensor, n: int, cfg: InitConfig, camera: Camera,
                    generator: torch.Generator | None = None, classes: torch.Tensor | None = None) -> torch.Tensor:
    """N particles around the best hypotheses (:func:`best_hypotheses`), in equal shares.

    states: (M, 6) and log_lik: (M,) from :func:`blind_hypotheses`; camera: the scene's camera;
    classes: (M,) the class of each hypothesis's α, or None. The jitter: α and h by half a grid
    step, the range by ``range_std`` (relative, along the line of sight from the camera centre),
    the signed speed by ``speed_std_mps``. Returns (N, 6) on ``states``' device and dtype.
    """
    check_shape("states", states, ("M", STATE_DIM))
    check_shape("log_lik", log_lik, (states.shape[0],))
    pick = hypothesis_shares(best_hypotheses(log_lik, cfg.hypotheses, classes), log_lik, n, classes)
    out = states[pick].clone()
    noise = torch.randn(n, 4, generator=generator, dtype=states.dtype, device=states.device)
    origin = camera_centre(camera).to(states)
    out[:, X:Z + 1] = origin + (out[:, X:Z + 1] - origin) * (1 + cfg.range_std * noise[:, 0:1])
    out[:, HEADING] = wrap_angle(out[:, HEADING] + noise[:, 1] * math.pi / cfg.azimuth_steps)
    out[:, ALPHA] = wrap_angle(out[:, ALPHA] + noise[:, 2] * math.pi / cfg.alpha_steps)
    out[:, SPEED] = noise[:, 3] * cfg.speed_std_mps
    return out


SPEED_MEASUREMENT_FLOOR_MPS = 0.1  # the lateral velocity's σ is at least this (the blob's outline changes)


def speeds_from_track(times: torch.Tensor, lateral: torch.Tensor, axis: torch.Tensor, heading: torch.Tensor,
                      speed: torch.Tensor, prior_std: float) -> torch.Tensor:
    """The particles' speeds given the blob's motion across the line of sight since a blind start.

    The blob's column is measured to a fraction of a pixel every frame (centimetres at 1000 m),
    while the range converges slowly (one image row is 18 m at 1000 m) and the particles' speeds
    lag (they start near 0 and follow only by the speed noise). The least-squares slope u ± σ_u of
    the lateral positions over time measures v·s, with s the lateral component of the heading's unit
    vector; each particle's speed is the posterior mean of v under its prior N(v₀, σ₀²):

        v = (v₀/σ₀² + s u/σ_u²) / (1/σ₀² + s²/σ_u²),   σ_u = max(slope's standard error, 0.1 m/s)

    so a particle seen side-on takes u/s, one heading along the line of sight keeps v₀.

    Args:
        times: (T,) seconds, T >= 3, finite, not all equal.
        lateral: (T,) metres, the blob's position along ``axis``, finite.
        axis: (3,) unit vector of the camera's x axis in the world frame.
        heading: (N,) radians, from +z towards +x.
        speed: (N,) m/s, the prior means v₀.
        prior_std: σ₀ in m/s, >= 0 (0: the speeds stay v₀).
    Returns:
        (N,) speeds in m/s, ``speed``'s dtype and device.
    """
    check_shape("times", times, ("T",))
    check_shape("lateral", lateral, (times.shape[0],))
    check_shape("axis", axis, (3,))
    check_shape("heading", heading, ("N",))
    check_shape("speed", speed, (heading.shape[0],))
    if times.shape[0] < 3:
        raise ValueError(f"Expected at least 3 track points; got {times.shape[0]}")
    if not bool(times.isfinite().all() and lateral.isfinite().all()):
        raise ValueError("Expected finite track times and lateral positions")
    if not (math.isfinite(prior_std) and prior_std >= 0):
        raise ValueError(f"Expected a finite prior_std >= 0; got {prior_std!r}")
    if prior_std == 0:
        return speed.clone()
    t = times.to(torch.float64) - times.to(torch.float64).mean()
    sxx = float(t.square().sum())
    if not sxx > 0:
        raise ValueError("Expected track points at different times")
    y = lateral.to(torch.float64)
    slope = float((t * y).sum()) / sxx
    residual = y - y.mean() - slope * t
    se = math.sqrt(float(residual.square().sum()) / (t.shape[0] - 2) / sxx)
    var_u = max(se, SPEED_MEASUREMENT_FLOOR_MPS) ** 2
    axis = axis.to(speed)
    s = axis[0] * heading.sin() + axis[2] * heading.cos()
    precision = 1 / prior_std ** 2
    return (speed * precision + s * slope / var_u) / (precision + s.square() / var_u)
