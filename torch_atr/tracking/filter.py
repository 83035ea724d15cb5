"""Joint tracking and recognition: the particle filter of Table 5.1 on tensors.

Per frame (Table 5.1, with the segmentation of chapter 3.1 in front):

1. predict every particle with the motion model (eq. 5.1) and the identity random walk (eq. 5.3);
2. segment the frame: the background model skips the predicted target box, the global gain is
   compensated, and the blob nearest the predicted centre is kept;
3. weigh: the blob's signed distance in image pixels, sampled in each particle's window and
   compared with its predicted shape (Methods I–IV; cells beyond an image edge that cuts the blob
   left out), eq. 5.2 in log space, normalised by log-sum-exp; on the frames ``RedetectConfig``
   names (by default once, 10 frames after the track's start) the blob is also searched as at
   the blind start, and the worst-explaining particles are redrawn around hypotheses that beat
   them all;
4. estimate (Table 5.1 step 3): weighted means, circular means of h and α, the maximum-weight
   particle, the class posterior, the two nearest training vehicles, the ESS and the view Θ;
5. resample (step 4) when the ESS falls below ``resample_ess`` · N (1.0: every frame, the
   thesis's SIR filter), on frames whose weights changed: a frame lost or without a blob leaves
   them as they were, and resampling those would only lose particles.

After a blind start the speeds are unknown: once the blob's track spans ``init.speed_frames``
frames (10 by default) every particle's speed is set from the blob's motion across the line of
sight over them (``initialise.speeds_from_track``), before which they follow only their random
walk from about 0. The track holds the frames whose blob is clear of the image's edge (a cut
blob's centre lags the vehicle), from the start on and the frames in a row before it: a restart
after ``redetect.restart`` missed frames has them, and sets the speeds at once.

A frame gives no observation when its mask is empty or covers more than ``max_foreground`` of the
image, and is lost when no particle of nonzero weight reaches a log-likelihood of
:data:`LOST_LOG_LIKELIHOOD` (where the likelihood underflows in float32, whatever the model's dtype;
a particle whose window sees nothing of the image, behind the camera or wholly outside it, has
none), or (``redetect.restart``) when its blob is clear of the image's
edge and lies outside the box of the particles' predicted windows: the filter then keeps its prediction,
leaves the weights as they are (normalised again if a re-detection redrew particles on that frame)
and flags the frame ``lost``. Estimates are never NaN once the filter is
initialised.

The blind start waits for a blob clear of the image's edge (``init.border_px``; a blob the edge
cuts has the wrong size and shape: ``initialise`` module docstring); until it starts, frames are
lost and have no estimate, as before any blob. After ``redetect.restart`` lost frames in a row
whose blob, clear of the edge, no predicted window reaches, the blind start runs again on that
blob (a new start: re-detection and the speeds follow it): a track put on the wrong blob, or
outrun by its target, is not left beside it.

Everything per particle is a tensor operation on the particles' device; the only Python loops
run over frames and over the ≤ K spline spans of the appearance model.
"""

from __future__ import annotations

import itertools
import logging
import math
import numbers
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Callable, NamedTuple

import numpy as np
import torch

from torch_atr._checks import check_device, check_shape
from torch_atr.camera import Camera
from torch_atr.config import ConfigError
from torch_atr.data.sequence import FrameTruth, Sequence, check_camera_height
from torch_atr.evaluation import frame_errors
from torch_atr.model import GenerativeShapeModel
from torch_atr.model.generative import LOG_WIDTH_RANGE
from torch_atr.pose import VehiclePose, camera_centre, check_sensor_like, view_of_pose
from torch_atr.segmentation import ForegroundSegmenter, SegmentationConfig, static_background_frames
from torch_atr.tracking.appearance import METHODS, ShapeAppearance
from torch_atr.tracking.estimates import (
    circular_mean,
    class_posterior,
    weighted_mean_cov,
)
from torch_atr.tracking.ground import half_heights, interpolate_periodic
from torch_atr.tracking.initialise import (
    HypothesisGrid,
    MAX_INIT_STD,
    InitConfig,
    blind_hypotheses,
    blind_particles,
    blob_column,
    clear_of_border,
    speeds_from_track,
    truth_alpha,
    truth_particles,
)
from torch_atr.tracking.motion import (
    ALPHA,
    HEADING,
    SPEED,
    STATE_DIM,
    MotionConfig,
    X,
    Y,
    Z,
    predict,
)
from torch_atr.tracking.observation import (
    cut_edges,
    frame_distance,
    mask_box,
    observe_windows,
    observed_cells,
    place_silhouette,
    project_windows,
    sees_image,
)
from torch_atr.tracking.resampling import SCHEMES, effective_sample_size, resample
from torch_atr.validate import integer, show

log = logging.getLogger(__name__)


class FrameDistance(NamedTuple):
    """A frame's observation as the likelihood reads it (:meth:`Tracker._frame_distance`)."""

    signed: torch.Tensor  # (h, w) the blob's signed distance in image pixels, near the blob
    origin: tuple[int, int]  # (u0, v0) the frame pixel of signed[0, 0]
    cut: tuple[bool, bool, bool, bool]  # the image edges (left, top, right, bottom) that cut the blob


# Particles weighed at once (_log_likelihood), by device type: 2048 keeps a block in the CPU's
# cache; an accelerator wants few, large launches (an H200 at 100 000 particles: 6.0 frames/s in
# blocks of 2048, 39 in one of 65 536; benchmarks/bench_track.py).
_BLOCK_CPU = 2048
_BLOCK_ACCELERATOR = 65536
_GRID_TOLERANCE = 0.01  # rad: re-detection reuses the grid's silhouette boxes within this of their elevation
LOST_LOG_LIKELIHOOD = math.log(torch.finfo(torch.float32).tiny)  # ≈ −87.3: a frame none reaches is lost
_UNEXPLAINED_WARNING = 10  # frames in a row whose blob no particle explains before the tracker says why


@dataclass(frozen=True)
class FilterConfig:
    """The particle filter's own settings (module docstring)."""

    particles: int = 1000  # N
    method: str = "I"  # appearance: I, II, III or IV (METHOD.md "Methods")
    sigma: float = 0.02  # σ of the likelihood eq. 5.2, in template units (signed distances in [−1, 1])
    likelihood_px: int = 32  # L: the L x L grid compared per particle (divides the template size)
    resample: str = "systematic"  # systematic, stratified, residual or multinomial
    resample_ess: float = 1.0  # resample when ESS < resample_ess · N; 1.0: every frame it weighs (the thesis's SIR)
    max_foreground: float = 0.5  # a mask covering more of the frame is no observation (a global change)
    ground_contact: bool = False  # y = ground + H(α)/2 when the camera's height is known (tracking.ground)
    fps: float = 30.0  # frame rate for a sequence that states none

    def __post_init__(self) -> None:
        checks = {
            "particles": 1 <= self.particles <= 10_000_000,
            "method": self.method in METHODS,
            "sigma": math.isfinite(self.sigma) and 1e-4 <= self.sigma <= 1e3,
            "likelihood_px": 1 <= self.likelihood_px <= 512,
            "resample": self.resample in SCHEMES,
            "resample_ess": 0 <= self.resample_ess <= 1,
            "max_foreground": 0 < self.max_foreground <= 1,
            "fps": math.isfinite(self.fps) and 0 < self.fps <= 10_000,
        }
        bad = [f"{k}={show(getattr(self, k))}" for k, ok in checks.items() if not ok]
        if bad:
            raise ConfigError("filter: bad value(s) " + ", ".join(bad) + f" (particles in [1, 1e7]; method in "
                              f"{METHODS}; sigma in [1e-4, 1e3]; likelihood_px in [1, 512]; resample in {SCHEMES}; "
                              "resample_ess in [0, 1]; max_foreground in (0, 1]; fps in (0, 1e4])")


@dataclass(frozen=True)
class AdaptConfig:
    """Online kernel-width adaptation (the design card's "fine-tune kernel widths by gradient
    descent on reconstruction loss"): every ``every`` frames, ``steps`` Adam steps at ``lr`` on
    log(width) reduce the squared error between the predicted shape at the estimate and the
    observation there. 0 turns it off (the default: measured, it did not help; docs/tracking.md)."""

    every: int = 0
    steps: int = 3
    lr: float = 0.01

    def __post_init__(self) -> None:
        if not (0 <= self.every and 1 <= self.steps <= 1000 and math.isfinite(self.lr) and 0 < self.lr <= 1):
            raise ConfigError(f"adapt: expected every >= 0, steps in [1, 1000], lr in (0, 1]; got {self}")


@dataclass(frozen=True)
class RedetectConfig:
    """Re-detection, a data-driven proposal (as in the boosted particle filter, Okuma et al. 2004):
    every ``every`` frames the blob is searched as at the blind start
    (``initialise.blind_hypotheses``), and when hypotheses explain the frame better than every
    particle by more than ``margin`` (log-likelihood), the ``share`` of the particles that explain
    it worst are redrawn around the best of them (``initialise.blind_particles``) and weighed with
    the rest. With ``keep_range`` the hypotheses are placed at the estimated range and the redrawn
    particles spread over the particles' range spread (the blob's lowest row, which places the
    blind start, is 18 m of range at 1000 m); their speed is the estimated velocity along their
    heading. Searches are made ``every``, 2 ``every``, ... frames after the track's start, up to
    ``until`` frames after it (0: to the end). ``every`` 0 turns it off; the blob tracker (no
    camera) has none. It follows a blind start or :meth:`Tracker.reset`; after the thesis's start
    on the truth (:meth:`Tracker.initialise`) only with ``after_truth``, since that start is right
    by construction and the search, which mends a wrong one, only costs there (below).

    Measured (docs/tracking.md): the default, one search 10 frames after the start,
    mends a blind start that one frame's blob put on the wrong class (the blind T-72 at 1000 m
    over 10 seeds: recognised in 99 % of frames, not 80 %, converging within 60 frames in 10
    runs, not 8) and changes nothing on the blind SENSIAC-like grid, the unseen meshes or the
    studies beyond a few cells; from the truth it put the grid's tanks at 3000–3500 m on the APC
    arc (38 % of frames recognised, 98–100 % without it). Searching on through the run
    (``until`` 0) trusts one frame's blob every ``every`` frames, and a blob the scene corrupts
    is then fitted by the wrong vehicle: behind a berm, recognition at 1000 m fell from 93 to
    61 %, and by day from 40 to 23 %. Each search costs about 57 ms at 1000 particles on 2 cores.

    Later searches (``later_every`` > 0, off by default) come every ``later_every`` frames after
    ``until``, for long runs: a blind start at a head-on or tail-on view can settle on the wrong
    class, and the α walk alone never leaves it. A T-72 at 1000 m started blind near tail-on (a
    1000-frame lap of a 50 m circle from 70°) was an APC in every frame; with ``later_every``
    300 the search at frame 300 put it on the tank arc for the remaining 70 % of frames (aspect
    1.57 -> 1.15 rad). Over the 8 test vehicles' laps at 1000 and 2000 m (seed 0) they changed 5
    of 16 and the means little: recognition 78.5 -> 78.0 % (the 2S3 at 2000 m 100 -> 82 %, the
    T-72 there 0 -> 10 %), aspect 1.18 -> 1.10 rad, horizontal 0.73 -> 0.70 m (2026-11-27;
    docs/tracking.md, "The defaults as they stand, measured").

    View searches (``view_every`` > 0, off by default) come every ``view_every`` frames after any
    start, all through the run (a frame of the full search above has no view search). They score
    the view alone: the 36 θ of the grid at the grid's α nearest to the particles' circular mean
    and its two neighbours (108 hypotheses, a few ms); the particles they redraw take α values of
    the particles (drawn by weight), so the search itself does not move the identity (the α walk
    at the new view may). They mend a heading that went the wrong way round where the silhouette
    is symmetric (head-on or tail-on) and then could not come back, the shape's mirror image
    fitted with the window shifted: on 1000-frame laps at 1000 and 2000 m (8 test vehicles, 2
    scene seeds) they fired in 8 of 32 and lowered Method I's aspect error in all 8 (the 2S3 at
    1000 m 1.87 -> 0.41 rad), mean 1.19 -> 1.04 rad; the 300-frame bars' runs never fired; behind
    a berm one sequence in 16 lost recognition at the new view; over the full 1000-frame run
    Method I's aspect fell 1.17 -> 1.09 rad and its recognition 76.1 -> 74.6 % (2026-11-27;
    docs/experiments.md, "With view searches").
    What they cannot mend is θ against π − θ: at a grazing view the two silhouettes are the same.

    Restarts (``restart`` > 0) mend a track that no longer sees its blob at all, which no search
    can (the searches run only on the frames above, and with ``keep_range`` at the estimate's
    range): a frame whose blob is clear of the image's edge (``init.border_px``) and lies outside
    the box of the particles' predicted windows (3σ of their centres plus half the largest
    window, as the segmenter is given) is lost, and ``restart`` such frames in a row (frames with
    no blob neither count nor break the run) start the track blind again on the blob. Needs a
    camera (the blob tracker lays its windows on the blob). Measured: a T-72 at 1000 m started
    blind on a sliver at the image's edge (``init.border_px`` 0) sat beside its blob, a car 500 m
    too far, for 70 frames; the restart put it back on the tank 10 frames after the windows left
    the blob (horizontal error after frame 60: 0.28 m, 42 m without)."""

    every: int = 10  # frames between searches; 0: off
    margin: float = 5.0  # log-likelihood by which a hypothesis must beat every particle
    share: float = 0.2  # of the particles redrawn
    keep_range: bool = True  # place the hypotheses at the estimated range (else: the blob's ground row)
    until: int = 10  # the last frame searched, counted from the track's start; 0: to the end
    later_every: int = 0  # after until, frames between further searches (k = later_every, 2 later_every, ...); 0: none
    after_truth: bool = False  # also search after a start on the truth (Tracker.initialise)
    view_every: int = 0  # frames between searches of the view alone (the estimate's identity kept); 0: off
    restart: int = 10  # lost frames in a row whose blob no predicted window reaches before a blind restart; 0: off

    def __post_init__(self) -> None:
        if not (0 <= self.every and 0 <= self.until and 0 <= self.later_every and 0 <= self.view_every
                and 0 <= self.restart and math.isfinite(self.margin) and self.margin >= 0 and 0 < self.share <= 1):
            raise ConfigError(f"redetect: expected every, until, later_every, view_every and restart >= 0, "
                              f"margin >= 0, share in (0, 1]; got {self}")
        if 0 < self.until < self.every:
            raise ConfigError(f"redetect.every={self.every} is after redetect.until={self.until}, so no frame would be "
                              f"searched; set until=0 to search all through the run, or every=0 for no search")

    def searches(self, k: int) -> bool:
        """Whether the k-th frame after the track's start (k = 0: the start itself) is searched."""
        if k > self.until > 0 and self.later_every > 0:
            return k % self.later_every == 0
        return self.every > 0 and k > 0 and k % self.every == 0 and (self.until == 0 or k <= self.until)

    def view_searches(self, k: int) -> bool:
        """Whether the k-th frame after the track's start is searched for the view alone."""
        return self.view_every > 0 and k > 0 and k % self.view_every == 0


def tracker_segmentation() -> SegmentationConfig:
    """The segmentation the tracker defaults to: the frozen thesis model plus feedback (the
    background keeps learning away from the predicted target every 5th frame, gain compensated),
    and thin parts found at MOG2 threshold 9 (a far tank's gun; docs/experiments.md, "Where we are behind")."""
    return SegmentationConfig(learning_rate=0.01, learning_interval=5, compensate_gain=True, thin_threshold=9.0)


@dataclass(frozen=True)
class TrackerConfig:
    """Everything :class:`Tracker` needs besides the model and the camera."""

    filter: FilterConfig = field(default_factory=FilterConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    init: InitConfig = field(default_factory=InitConfig)
    segmentation: SegmentationConfig = field(default_factory=tracker_segmentation)
    adapt: AdaptConfig = field(default_factory=AdaptConfig)
    redetect: RedetectConfig = field(default_factory=RedetectConfig)


_LINEAR = ("x", "y", "z", "speed")  # the estimate's linear quantities (std_*, cov_*), in weighted_mean_cov's order
_PAIRS = tuple(map(list, zip(*itertools.combinations(range(4), 2))))  # (rows, columns) of cov's upper triangle
SETTLE_FRAMES = 60  # TrackResult.metrics' and metrics.json's "settled" block: after a blind start's first 2 s


@dataclass
class TrackResult:
    """What :meth:`Tracker.run` returns.

    Attributes:
        rows: one dict per frame (the columns of ``estimates.csv``; README, "Command line").
        snapshots: a few frames for figures: dicts with ``frame`` (index), ``image`` (H, W) uint8,
            ``mask`` (H, W) bool segmented and ``silhouette`` (H, W) bool the placed estimate.
        seconds: wall time of the tracking loop (segmentation included, reading frames excluded).
    """

    rows: list[dict]
    snapshots: list[dict]
    seconds: float

    def column(self, name: str) -> np.ndarray:
        """One column over the frames: (T,) float64, NaN where a row lacks it, or (T,) str for a
        text column (``class``, ``nearest_1``, ``true_vehicle``, ...), "" where a row lacks it.
        ValueError naming the columns when no row has it (a typo would read as a run without
        estimates)."""
        if self.rows and not any(name in row for row in self.rows):
            columns = ", ".join(dict.fromkeys(key for row in self.rows for key in row))
            raise ValueError(f"No row has a column {name!r}; columns: {columns}")
        if any(isinstance(row.get(name), str) for row in self.rows):
            return np.array([row.get(name, "") for row in self.rows], dtype=str)
        return column(self.rows, name)

    @property
    def frames_per_second(self) -> float:
        return len(self.rows) / self.seconds if self.seconds > 0 else math.nan

    def metrics(self, model: GenerativeShapeModel, settle_frames: int = SETTLE_FRAMES) -> dict:
        """What ``metrics.json`` holds for this run (README, "Command line"): the errors, recognition,
        best matches, overlap and convergence over all frames and, as ``settled``, from frame
        ``settle_frames`` on, the frames per second; None where the truth is unknown. ``model``: the
        run's (its classes and training vehicles)."""
        from torch_atr.tracking.job import run_summary  # job builds on this module

        return run_summary(self, model, integer("settle_frames", settle_frames, lo=0))


class Tracker:
    """The joint tracker and recogniser (module docstring).

    Args:
        model: the generative shape model (moved to ``device``).
        camera: the scene's calibrated camera, with a sensor-like, ground-levelled world frame.
        config: the settings; ``TrackerConfig()`` if None.
        device: where the particles live (``"cpu"``, ``"cuda"``, a ``torch.device``); default
            the model's device.
        seed: seeds the tracker's generator: the same seed and frames give the same run on the same device,
            torch thread count and CPU model (BLAS products and long sums split by thread).
        templates: (K, V, S, S) training templates for Method IV (see ``ShapeAppearance``).

    Use :meth:`run` on a whole sequence, or :meth:`warm_up`, optionally :meth:`initialise`, and
    :meth:`step` per frame for live use; a blind start by hand needs ``init.camera_height_m`` for
    its ranges (:meth:`run` takes the sequence's).
    """

    needs_camera = True  # BlobTracker tracks without one

    def __init__(self, model: GenerativeShapeModel, camera: Camera, config: TrackerConfig | None = None, *,
                 device: str | torch.device | None = None, seed: int = 0, templates: torch.Tensor | None = None):
        if not isinstance(model, GenerativeShapeModel):
            raise ValueError(f"Expected model to be a GenerativeShapeModel (GenerativeShapeModel.from_checkpoint("
                             f"path)); got {type(model).__name__}")
        if self.needs_camera and not isinstance(camera, Camera):
            raise ValueError(f"Expected camera to be a Camera; got {type(camera).__name__} (an uncalibrated sequence: "
                             f"track its blob with torch_atr.tracking.BlobTracker)")
        if self.needs_camera:
            check_sensor_like(camera)  # before any work: it was found only once the first blob was placed
        if config is not None and not isinstance(config, TrackerConfig):
            raise ValueError(f"Expected config to be a TrackerConfig (load_config(TrackerConfig, path, overrides)); "
                             f"got {type(config).__name__}")
        if isinstance(seed, bool) or not isinstance(seed, numbers.Integral):
            raise ValueError(f"Expected seed to be an integer; got {seed!r}")
        self.cfg = TrackerConfig() if config is None else config
        self.device = check_device(device) if device is not None else model.alphas.device
        self.model = model.to(self.device)
        self.camera = camera
        fc = self.cfg.filter
        if self.cfg.adapt.every and fc.method == "IV":
            raise ConfigError("adapt.every > 0 tunes the model's kernel widths, but method IV compares the training "
                              "templates themselves: use method I, II or III, or adapt.every=0")
        size = model.template.size_px
        if size % fc.likelihood_px:
            fits = [d for d in range(size, 0, -1) if size % d == 0][:3]
            raise ConfigError(f"filter.likelihood_px={fc.likelihood_px} must divide the model's template size {size} "
                              f"(e.g. {', '.join(map(str, fits))})")
        self.appearance = ShapeAppearance(self.model, fc.method, fc.likelihood_px, templates).to(self.device)
        self.segmenter = ForegroundSegmenter(self.cfg.segmentation)
        self.seed = int(seed)
        self.generator = torch.Generator(self.device)
        self.dtype = self.model.alphas.dtype
        self.dt = 1.0 / fc.fps
        height = self.cfg.init.camera_height_m
        self.camera_height_m = math.nan if height is None else height  # above the ground (blind start)
        self._half_heights: torch.Tensor | None = None  # H(α)/2 on a grid of α (ground contact)
        self._begin()
        self._optimiser = (torch.optim.Adam([self.model.rbf.log_width], lr=self.cfg.adapt.lr)
                           if self.cfg.adapt.every else None)
        self._adapt_undone = 0  # adaptations undone as diverged (_adapt)
        self._grid = HypothesisGrid(self.appearance, self.cfg.init, _GRID_TOLERANCE)  # blind start, re-detection

    def _begin(self) -> None:
        """A track's state before its first frame: no particles, frame 0 at 0 s, the generator seeded."""
        self.generator.manual_seed(self.seed)
        self.particles: torch.Tensor | None = None  # (N, 6)
        self.log_weights: torch.Tensor | None = None  # (N,), normalised
        self.last_mask: np.ndarray | None = None  # the segmented target mask of the last frame
        self._frames = 0
        self._start = 0  # the frame the track started at (reset); re-detection counts from it
        self._searching = True  # whether re-detection follows the current start
        self._clock = 0.0  # seconds from the first frame to the current one
        # (frame, s, blob column) of the latest frames in a row whose blob was clear of the edge, and of the
        # current start's track while its speeds are unknown (None: known)
        self._recent: deque[tuple[int, float, float]] = deque(maxlen=max(self.cfg.init.speed_frames, 1))
        self._track: list[tuple[int, float, float]] | None = None
        self._fresh = False  # the particles describe the coming frame (just initialised): no prediction
        self._cut_frames = 0  # frames the blind start has waited on a blob cut by the image's edge
        self._missed = 0  # lost frames in a row whose blob no predicted window reaches (redetect.restart)
        self._unexplained = 0  # frames in a row whose blob no particle explains (every likelihood underflows)

    # --- set-up -----------------------------------------------------------------------------
    def warm_up(self, frames) -> None:
        """Learn the background from target-free frames (thesis 3.1): an iterable of frames of the
        camera's image size."""
        segmenter = ForegroundSegmenter(self.cfg.segmentation)
        segmenter.warm_up(frames)
        if self.camera is not None and segmenter.frame_size != (self.camera.height, self.camera.width):
            raise ValueError(f"Expected frames of the camera's image size {(self.camera.height, self.camera.width)} "
                             f"(H, W); got {segmenter.frame_size}: a resized or cropped frame is read in the wrong "
                             f"pixels")
        self.segmenter = segmenter

    def initialise(self, truth: FrameTruth) -> None:
        """The thesis's initialisation from one frame's truth (``InitConfig``, mode "truth").

        Needs the truth's position (x, y, z) and heading; α starts at its vehicle's or class's, or
        spread around the manifold for a class the model lacks (:func:`truth_alpha`).
        """
        if not isinstance(truth, FrameTruth):
            raise ValueError(f"Expected a FrameTruth (sequence.truth(i)); got {type(truth).__name__}")
        needed = (truth.x, truth.y, truth.z, truth.heading)
        if not all(math.isfinite(v) for v in needed):
            raise ValueError(f"Truth initialisation needs x, y, z and heading; got {needed}")
        alpha = truth_alpha(self.model, truth.vehicle, truth.vehicle_class, self.cfg.init.alpha)
        position = torch.tensor([truth.x, truth.y, truth.z], dtype=self.dtype, device=self.device)
        self.reset(truth_particles(position, truth.heading, alpha, self.cfg.filter.particles, self.cfg.init,
                                   self.generator))
        self._searching = self.cfg.redetect.after_truth
        self._track = None  # the thesis's small positive speed (init.speed_mps) stands

    def reset(self, particles: torch.Tensor) -> None:
        """Start from given particles: (N, 6) [x, y, z, h, v, α] describing the coming frame
        (equal weights; the next :meth:`step` weighs them without a prediction first). They are
        copied: the filter never writes into the caller's tensor."""
        check_shape("particles", particles, ("N", STATE_DIM))
        if particles.shape[0] == 0 or not bool(particles.isfinite().all()):
            raise ValueError(f"Expected at least one particle, all finite; got {particles.shape[0]}")
        self.particles = particles.to(self.device, self.dtype, copy=True)  # the caller's tensor is theirs
        self.log_weights = torch.full((self.particles.shape[0],), -math.log(self.particles.shape[0]),
                                      dtype=self.dtype, device=self.device)
        self._fresh = True
        self._start = self._frames
        self._searching = True  # re-detection follows this start (initialise: only with after_truth)
        self._track = list(self._recent) if self.cfg.init.speed_frames else None  # speeds measured (blind)
        self._missed = self._unexplained = 0

    @property
    def initialised(self) -> bool:
        return self.particles is not None

    # --- one frame --------------------------------------------------------------------------
    @torch.no_grad()
    def step(self, frame: np.ndarray | None = None, dt: float | None = None, mask: np.ndarray | None = None
             ) -> dict:
        """Track one frame: returns its estimate row (README, "Command line").

        Args:
            frame: (H, W) or (H, W, 3), the warm-up frames' size and dtype.
            dt: seconds since the previous frame, positive and finite; default 1 / fps.
            mask: (H, W) bool, the target's mask from your own segmentation, used instead of
                segmenting ``frame`` (which may then be None).
        """
        start = time.perf_counter()
        dt = self.dt if dt is None else dt
        # The inputs are checked before anything moves: a refused step leaves the filter as it was.
        if isinstance(dt, bool) or not (isinstance(dt, numbers.Real) and math.isfinite(dt) and dt > 0):
            raise ValueError("Expected dt, the seconds since the previous frame, to be positive and finite; "
                             f"got {dt!r}")
        if mask is not None:
            mask = self._check_mask(mask)
            if frame is not None and self.segmenter.ready:  # a blind start measures the blob's contrast in it
                self.segmenter.check_frame(frame)
        elif frame is None:
            raise ValueError("step needs a frame or a mask")
        else:
            self.segmenter.check_frame(frame)
        if self._frames:
            self._clock += dt
        if self.initialised and not self._fresh:
            self.particles = self._predict(dt)
        self._fresh = False
        near, box, side = self._predicted_region() if self.initialised else (None, None, math.inf)
        if mask is None:
            mask = self.segmenter(frame, near=near, exclude=box)
        self.last_mask = mask
        area = int(np.count_nonzero(mask))
        observed = 0 < area <= self.cfg.filter.max_foreground * mask.size
        clear = observed and clear_of_border(mask, self.cfg.init.border_px)
        point = (self._frames, self._clock, blob_column(mask)) if clear else None
        if observed:
            distance = self._frame_distance(mask, side)
        if observed and self._starts_blind(mask, box, clear):
            if self.initialised:  # a restart: the whole frame's distance, as at the first start
                distance = self._frame_distance(mask, math.inf)
            self._initialise_blind(mask, distance, frame)
        lost, weighed = True, False  # weighed: the weights took this frame's likelihoods or a redraw
        if self.initialised and observed and not self._missed:
            log_lik = self._log_likelihood(distance, self.particles)
            k = self._frames - self._start  # never searched at the start itself
            redrawn = False
            if self._searching and self.cfg.redetect.searches(k):
                log_lik, redrawn = self._redetect(mask, distance, frame, log_lik)
            elif self.cfg.redetect.view_searches(k):
                log_lik, redrawn = self._redetect(mask, distance, frame, log_lik, views_only=True)
            # Only particles of nonzero weight count: had one of weight 0 (resample_ess < 1) alone a likelihood,
            # every posterior weight would be 0 and log_softmax NaN.
            best = torch.where(self.log_weights > -math.inf, log_lik, -math.inf).max()
            if best >= LOST_LOG_LIKELIHOOD:
                self.log_weights = torch.log_softmax(self.log_weights + log_lik, dim=0)
                lost, weighed, self._unexplained = False, True, 0
            else:
                if redrawn:  # the weights stay, normalised again: the redrawn particles came in at 1/N
                    self.log_weights = torch.log_softmax(self.log_weights, dim=0)
                    weighed = True
                self._unexplained += 1
                if self._unexplained == _UNEXPLAINED_WARNING:
                    self._warn_unexplained(mask, float(best), side)
        row = {"frame": self._frames, "time_s": self._clock, "lost": int(lost), "mask_area_px": area}
        if self.initialised:
            row.update(self._estimate())
            if observed:
                row["overlap"] = self._overlap(mask, row)
            if not lost and self._optimiser is not None and self._frames % self.cfg.adapt.every == 0:
                self._adapt(distance, row)
            if self._track is not None:
                self._measure_speed(point, row)
            threshold = self.cfg.filter.resample_ess
            # Weights a frame left as they were carry nothing new: resampling them would only lose particles.
            row["resampled"] = int(weighed and (threshold >= 1 or row["ess"] < threshold * self.particles.shape[0]))
            if row["resampled"]:
                ancestors = resample(self.log_weights.exp(), self.cfg.filter.resample, self.generator)
                self.particles = self.particles[ancestors]
                self.log_weights = torch.full_like(self.log_weights, -math.log(self.particles.shape[0]))
        if point is None:
            self._recent.clear()
        else:
            self._recent.append(point)
        self._frames += 1
        row["step_ms"] = 1e3 * (time.perf_counter() - start)
        return row

    @torch.no_grad()
    def score(self, mask: np.ndarray, particles: torch.Tensor) -> torch.Tensor:
        """Eq. 5.2 of any particles against a target mask, leaving the filter as it is: how well
        each hypothesis (say the true position and heading with every α) explains the frame.

        Args:
            mask: (H, W) bool, the target's mask (e.g. ``last_mask`` after a :meth:`step`), not empty.
            particles: (N, 6) [x, y, z, h, v, α].
        Returns:
            (N,) log-likelihoods −mean((z − y)²)/2σ², the cells beyond an image edge on which the
            mask has a pixel left out of the sum (``observation.observed_cells``); −inf where not
            finite or where the window sees nothing of the image (behind the camera or wholly
            outside it); higher is better.
        """
        mask = self._check_mask(mask)
        if not mask.any():
            raise ValueError("Expected a non-empty mask to score particles against")
        check_shape("particles", particles, ("N", STATE_DIM))
        if particles.shape[0] == 0:
            return torch.empty(0, dtype=self.dtype, device=self.device)
        particles = particles.to(self.device, self.dtype)
        _, side = project_windows(self.camera, particles[:, X:Z + 1], self.model.template.window_m)
        side = side[side.isfinite()]
        return self._log_likelihood(self._frame_distance(mask, float(side.max()) if side.numel() else math.inf),
                                    particles)

    def _warn_unexplained(self, mask: np.ndarray, best: float, side: float) -> None:
        """Say why the last ``_UNEXPLAINED_WARNING`` frames were lost although they had a blob: ``best``
        the best particle's log-likelihood, ``side`` the largest predicted window in pixels."""
        sigma, floor = self.cfg.filter.sigma, LOST_LOG_LIKELIHOOD
        log.warning("frames %d-%d: no particle explains the blob (best log-likelihood %.0f; a frame is lost below "
                    "%.0f, a mean squared error above %.3g template units at filter.sigma=%g), so the track keeps its "
                    "prediction. %s; a smaller sigma makes that bound stricter (the default %g allows %.3g)",
                    self._frames - _UNEXPLAINED_WARNING + 1, self._frames, best, floor, -floor * 2 * sigma ** 2,
                    sigma, self._unexplained_because(mask, side), FilterConfig.sigma,
                    -floor * 2 * FilterConfig.sigma ** 2)

    def _unexplained_because(self, mask: np.ndarray, side: float) -> str:
        """The warning's reasons why no particle explains a blob (``mask``; ``side`` the largest
        predicted window, pixels)."""
        u0, v0, u1, v1 = mask_box(mask)
        return (f"The blob spans {u1 - u0 + 1} x {v1 - v0 + 1} px, the largest predicted window {side:.0f} px (the "
                f"model's {self.model.template.window_m:g} m): a vehicle longer than the window, or unlike every "
                f"vehicle the model was trained on, cannot be explained")

    def _check_mask(self, mask) -> np.ndarray:
        """A user's mask as an (H, W) bool array (a tensor is taken too) of the camera's image size
        (without a camera, of the earlier masks' size); ValueError otherwise: a mask of another size
        (say of downsampled frames) would be read in the wrong pixels."""
        if isinstance(mask, torch.Tensor):
            mask = mask.detach().cpu().numpy()
        if self.camera is not None:
            size = (self.camera.height, self.camera.width)
        else:
            size = self.last_mask.shape if self.last_mask is not None else getattr(mask, "shape", None)
        if not (isinstance(mask, np.ndarray) and mask.dtype == bool and mask.ndim == 2 and mask.shape == size):
            raise ValueError(f"Expected mask to be a bool array of the image's size {size} (H, W); got "
                             f"{getattr(mask, 'shape', type(mask).__name__)} {getattr(mask, 'dtype', '')}")
        return mask

    def _starts_blind(self, mask: np.ndarray, box: tuple[float, float, float, float] | None, clear: bool) -> bool:
        """Whether this frame's blob, ``mask`` (H, W) bool and not empty, ``clear`` of the image's edge or
        not (``clear_of_border``), starts the track blind (module docstring): before the start, when it
        is clear or the start has waited ``init.border_wait`` frames; after it, when for
        ``redetect.restart`` frames in a row the blob was clear and outside ``box`` (u0, v0, u1, v1),
        the predicted windows' box (None: no particle has a window). Counts the frames waited and
        missed."""
        if not self.initialised:
            if clear or self._cut_frames >= self.cfg.init.border_wait:
                return True
            if self._cut_frames == 0:
                log.info("frame %d: the blob touches the image's edge (init.border_px=%d); the blind start waits "
                         "for it to come clear, at most %d frames (init.border_wait)", self._frames,
                         self.cfg.init.border_px, self.cfg.init.border_wait)
            self._cut_frames += 1
            return False
        if not self.cfg.redetect.restart or self.camera is None:
            return False
        u0, v0, u1, v1 = mask_box(mask)
        reached = box is not None and box[0] <= u1 and u0 <= box[2] and box[1] <= v1 and v0 <= box[3]
        self._missed = 0 if reached or not clear else self._missed + 1
        if self._missed < self.cfg.redetect.restart:
            return False
        log.warning("frame %d: no particle's window has reached the blob for %d frames; the blind start runs again on "
                    "it (redetect.restart)", self._frames, self._missed)
        return True

    def _frame_distance(self, mask: np.ndarray, side: float) -> FrameDistance:
        """The mask's signed distance near the blob, its origin (``observation.frame_distance``) and
        the image edges that cut the blob (``observation.cut_edges``): distances beyond τ in the
        largest window (``side`` pixels) are clipped, so only that margin around the blob is
        transformed."""
        template = self.model.template
        distance, origin = frame_distance(mask, template.tau_px * side / template.size_px)  # capped at the image
        return FrameDistance(distance.to(self.device), origin, cut_edges(mask))

    def _predict(self, dt: float) -> torch.Tensor:
        """Eq. 5.1 and 5.3 for every particle, then (``filter.ground_contact``, camera height known)
        each centre put half its vehicle's height above the ground. Returns (N, 6)."""
        particles = predict(self.particles, dt, self.cfg.motion, self.generator)
        if self.cfg.filter.ground_contact and math.isfinite(self.camera_height_m):
            if self._half_heights is None:
                self._half_heights = half_heights(self.model)
            ground_y = float(camera_centre(self.camera)[1]) - self.camera_height_m
            particles[:, Y] = ground_y + interpolate_periodic(self._half_heights, particles[:, ALPHA])
        return particles

    def _predicted_region(self) -> tuple[tuple[float, float] | None, tuple[float, float, float, float] | None,
                                         float]:
        """The predicted target centre (u, v), the box (u0, v0, u1, v1) holding the particles' windows
        (their weighted spread: 3σ of the centres plus half the largest window), and the largest
        window side, in pixels."""
        uv, side = project_windows(self.camera, self.particles[:, X:Z + 1], self.model.template.window_m)
        w = self.log_weights.exp()
        finite = (uv.isfinite() & side.isfinite()).all(dim=1)
        if not bool(finite.all()):  # leave out the particles at or behind the camera
            if not finite.any():
                return None, None, math.inf
            w, uv, side = w[finite], uv[finite], side[finite]
        w = w / w.sum().clamp_min(1e-30)
        centre = (w[:, None] * uv).sum(0)
        spread = 3 * (w[:, None] * (uv - centre).square()).sum(0).sqrt() + side.max(0).values / 2
        box = torch.cat([centre - spread, centre + spread])  # the windows of the weighted particles (3σ)
        return tuple(centre.tolist()), tuple(box.tolist()), float(side.max())

    def _views(self, particles: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """View Θ of each particle: from its centre to the camera, in its body frame."""
        pose = VehiclePose(particles[:, X], particles[:, Y], particles[:, Z], particles[:, HEADING])
        return view_of_pose(pose, self.camera)

    def _log_likelihood(self, distance: FrameDistance, particles: torch.Tensor) -> torch.Tensor:
        """Eq. 5.2 per particle against the frame's (distance, origin, cut edges), summed over the cells
        of its window it observes (``observation.observed_cells``): beyond an edge that cuts the
        blob nothing is known, and the padding read there, the blob's edge carried on, made a
        vehicle leaving the image look as if it went on and lost it; those cells are marginalised
        out. −inf where it is not finite, observes no cell, or its window sees nothing of the image
        (``observation.sees_image``): behind the camera, or wholly outside the image, where it
        sampled only the padding of the edge's pixels (a blob at the edge, carried along, matched a
        flat car). Returns (N,).

        Particles are weighed in blocks (``_BLOCK_CPU``, ``_BLOCK_ACCELERATOR``): on the CPU each
        block's sampling grid and windows stay in its cache (measured: 8000 particles at once ran
        2.6x slower than 4000, not 2x); on an accelerator blocks are large, since there the time
        goes to launching kernels. Templates are formed only for windows with cells not observed.
        """
        theta, phi = self._views(particles)
        uv, side = project_windows(self.camera, particles[:, X:Z + 1], self.model.template.window_m)
        L, shape = self.appearance.size, (self.camera.height, self.camera.width)
        cut = any(distance.cut)
        if cut:  # the particles whose windows reach beyond an edge that cuts the blob
            columns, rows = observed_cells(uv, side, L, shape, distance.cut)
            partly = ~(columns.all(dim=1) & rows.all(dim=1))
        scale = L ** 2 * 2.0 * self.cfg.filter.sigma ** 2
        sse = []
        size = _BLOCK_CPU if particles.device.type == "cpu" else _BLOCK_ACCELERATOR
        for block in torch.arange(particles.shape[0], device=particles.device).split(size):
            z = observe_windows(distance.signed, uv[block], side[block], self.model.template, L, distance.origin)
            sse.append(self.appearance.squared_errors(z, particles[block, ALPHA], theta[block], phi[block]))
            if cut and partly[block].any():
                some = partly[block]
                j = block[some]
                observed = rows[j, :, None] & columns[j, None, :]  # (n, L, L)
                sse[-1][some] = self.appearance.squared_errors(z[some], particles[j, ALPHA], theta[j], phi[j],
                                                               observed).to(sse[-1])
        log_lik = -torch.cat(sse) / scale  # eq. 5.2: −mean((z − y)²) / 2σ²
        seen = log_lik.isfinite() & sees_image(uv, side, shape)
        return torch.where(seen, log_lik, -math.inf).to(self.dtype)

    def _initialise_blind(self, mask: np.ndarray, distance: FrameDistance,
                          frame: np.ndarray | None) -> None:
        """Particles from the first blob (``initialise.blind_hypotheses``); ``distance`` is the
        whole frame's; ``frame`` (None: a mask without its frame) gives the blob's contrast, measured
        only for ``init.ground_row`` null."""
        if not math.isfinite(self.camera_height_m):
            log.warning("blind start without the camera's height above the ground (init.camera_height_m, on track.py's "
                        "command line tracker.init.camera_height_m=METRES): the ranges come from the blob's size alone "
                        "and can be far off")
        wanted = self.cfg.init.ground_row is None and frame is not None and self.segmenter.ready
        contrast = self.segmenter.contrast(frame, mask) if wanted else math.nan
        blob = torch.from_numpy(mask).to(self.device)
        states, log_lik = blind_hypotheses(blob, distance.signed, self.camera, self.appearance, self.cfg.init,
                                           self.cfg.filter.sigma, self.camera_height_m, contrast, grid=self._grid,
                                           cut=distance.cut)
        classes = self.model.classify(states[:, ALPHA].to(self.dtype))
        self.reset(blind_particles(states, log_lik, self.cfg.filter.particles, self.cfg.init, self.camera,
                                   self.generator, classes))
        self._fresh = False  # weighed on this very frame
        best = states[log_lik.argmax()]
        name = self.model.class_names[self.model.classify(best[ALPHA:ALPHA + 1])]
        log.info("blind initialisation: best of %d hypotheses at x=%.1f z=%.1f m, α=%.2f (%s); ground row %+.2f",
                 states.shape[0], best[X], best[Z], best[ALPHA], name, self.cfg.init.contact_row(contrast))

    def _redetect(self, mask: np.ndarray, distance: FrameDistance, frame: np.ndarray | None,
                  log_lik: torch.Tensor, views_only: bool = False) -> tuple[torch.Tensor, bool]:
        """Re-detection (``RedetectConfig``): the worst-explaining particles redrawn around the blob's
        hypotheses that beat every particle by the margin, in place, at weight 1/N; returns the (N,)
        log-likelihoods with theirs and whether any was redrawn. ``views_only``: the hypotheses keep
        the estimate's identity (the grid's α nearest to the particles' circular mean and its two
        neighbours) and search the view."""
        rc = self.cfg.redetect
        wanted = (not rc.keep_range and self.cfg.init.ground_row is None and frame is not None
                  and self.segmenter.ready)  # the ground row places the hypotheses only without keep_range
        contrast = self.segmenter.contrast(frame, mask) if wanted else math.nan
        if not rc.keep_range:  # the hypotheses' windows, at the ground's range, can be larger than the particles'
            distance = self._frame_distance(mask, math.inf)  # for which the distance's margin was cut
        w = self.log_weights.exp()
        depths = self.camera.world_to_sensor(self.particles[:, X:Z + 1])[:, 2].to(w)  # (N,) along the optical axis
        ahead = w  # the weights of the range kept: the particles' ahead of the camera (behind it, no window)
        if rc.keep_range and not bool((depths > 0).all()):
            ahead = w * (depths > 0)
            if not float(ahead.sum()) > 0:  # no range to keep
                return log_lik, False
            ahead = ahead / ahead.sum()
        depth = float((ahead * depths).sum())
        alpha_index = None
        if views_only:
            steps = self._grid.alpha.shape[0]
            alpha = float(circular_mean(self.particles[:, ALPHA].to(torch.float64), w.to(torch.float64))[0])
            nearest = round(alpha * steps / (2 * math.pi))
            alpha_index = torch.tensor([nearest - 1, nearest, nearest + 1]) % steps
        states, hyp = blind_hypotheses(torch.from_numpy(mask).to(self.device), distance.signed, self.camera,
                                       self.appearance, self.cfg.init, self.cfg.filter.sigma, self.camera_height_m,
                                       contrast, distance.origin, depth if rc.keep_range else math.nan, self._grid,
                                       alpha_index, distance.cut)
        best = float(log_lik.max())
        better = hyp > best + rc.margin
        if not bool(better.any()):
            return log_lik, False
        n = self.particles.shape[0]
        m = max(1, round(rc.share * n))
        init = self.cfg.init
        if rc.keep_range:  # the particles' relative range spread (depth > 0 here), within init.range_std's bound
            spread = float((ahead * (depths - depth).square()).sum().sqrt()) / depth
            init = replace(init, range_std=min(spread, MAX_INIT_STD))
        new = blind_particles(states, torch.where(better, hyp, -math.inf), m, init, self.camera,
                              self.generator).to(self.dtype)
        if views_only:  # the identity stays the particles': the new ones take theirs, drawn by weight
            new[:, ALPHA] = self.particles[torch.multinomial(w, m, replacement=True, generator=self.generator), ALPHA]
        velocity = (w[:, None] * self.particles[:, SPEED, None] * torch.stack(
            [self.particles[:, HEADING].sin(), self.particles[:, HEADING].cos()], dim=1)).sum(0)  # (vx, vz)
        new[:, SPEED] = velocity[0] * new[:, HEADING].sin() + velocity[1] * new[:, HEADING].cos()
        worst = (self.log_weights + log_lik).topk(m, largest=False).indices
        self.particles[worst] = new
        self.log_weights[worst] = -math.log(n)
        log_lik = log_lik.clone()
        log_lik[worst] = self._log_likelihood(distance, new)
        log.debug("frame %d: re-detection redrew %d particles (best hypothesis %.1f, best particle %.1f)",
                  self._frames, m, float(hyp.max()), best)
        return log_lik, True

    def _measure_speed(self, point: tuple[int, float, float] | None, row: dict) -> None:
        """After a blind start (``init.speed_frames``): add this frame's (frame, s, blob column) ``point``
        (None: no blob clear of the image's edge) to the track, and once the track, with the frames in a
        row before the start it began with, spans ``speed_frames`` frames, set every particle's speed
        from the blob's motion across the line of sight at the estimate's depth
        (``initialise.speeds_from_track``). Until then the speeds follow only their random walk from
        about 0 and lag the vehicle (a vehicle at 10 m/s at 1000 m outran the windows)."""
        if point is not None:
            self._track.append(point)
        first = min(self._start, self._track[0][0]) if self._track else self._start
        if self._frames - first < self.cfg.init.speed_frames:
            return
        track, self._track = self._track, None
        if len(track) < 3:
            return
        depth = float(self.camera.world_to_sensor(torch.tensor([float(row[k]) for k in "xyz"], dtype=torch.float64))[2])
        if not depth > 0:  # an estimate at or behind the camera has no lateral scale: the speeds stay
            return
        _, times, columns = torch.tensor(track, dtype=torch.float64).unbind(1)
        lateral = (columns - self.camera.cx) * (depth / self.camera.fx)  # metres along the camera's x axis;
        # lens distortion is left out: it bends a column by far less than the blob moves in 10 frames
        axis = self.camera.R[0].to(self.device, self.dtype)  # the camera's x axis in the world frame
        self.particles[:, SPEED] = speeds_from_track(times, lateral, axis, self.particles[:, HEADING],
                                                     self.particles[:, SPEED], self.cfg.init.speed_std_mps)
        log.debug("frame %d: speeds set from the blob's motion across the line of sight over frames %d-%d, weighted "
                  "mean %.2f m/s", self._frames, track[0][0], track[-1][0],
                  float(self.log_weights.exp() @ self.particles[:, SPEED]))

    def _estimate(self) -> dict:
        """The estimate row of the current weighted particles (module docstring, step 4)."""
        model, p, C = self.model, self.particles, len(self.model.class_names)
        w = self.log_weights.exp().to(torch.float64)
        p64 = p.to(torch.float64)
        mean, cov = weighted_mean_cov(p64[:, [X, Y, Z, SPEED]], w)
        heading, heading_r = circular_mean(p64[:, HEADING], w)
        alpha, alpha_r = circular_mean(p64[:, ALPHA], w)
        posterior = class_posterior(model.classify(p[:, ALPHA]), w, C)
        scalars = torch.stack([heading, heading_r, alpha, alpha_r, effective_sample_size(w)])
        # One conversion to Python numbers: a float() per tensor cost a call each.
        numbers = torch.cat([mean, cov.diagonal().sqrt(), cov[_PAIRS], scalars, posterior, p64[w.argmax()]]).tolist()
        (x, y, z, speed), stds, covs = numbers[:4], numbers[4:8], numbers[8:14]
        heading, heading_r, alpha, alpha_r, ess = numbers[14:19]
        posterior, best = numbers[19:19 + C], numbers[19 + C:]
        theta, phi = view_of_pose(VehiclePose(x, y, z, heading), self.camera)
        nearest = model.nearest_vehicles(torch.tensor([alpha], dtype=self.dtype, device=self.device), 2)[0].tolist()
        return {"x": x, "y": y, "z": z, "heading": heading, "speed": speed, "alpha": alpha,
                **{f"std_{name}": std for name, std in zip(_LINEAR, stds)},
                **{f"cov_{_LINEAR[i]}_{_LINEAR[j]}": c for i, j, c in zip(*_PAIRS, covs)},
                "heading_concentration": heading_r, "alpha_concentration": alpha_r,
                "theta": float(theta), "phi": float(phi),
                "class": model.class_names[int(model.identity.labels[nearest[0]])],
                "nearest_1": model.vehicle_names[nearest[0]], "nearest_2": model.vehicle_names[nearest[1]],
                **{f"p_{name}": posterior[c] for c, name in enumerate(model.class_names)},
                **{f"best_{name}": best[i] for name, i in (("x", X), ("y", Y), ("z", Z), ("heading", HEADING),
                                                           ("speed", SPEED), ("alpha", ALPHA))},
                "ess": ess}

    def _estimate_particle(self, row: dict) -> torch.Tensor:
        """(1, 6) the estimate as a particle."""
        return torch.tensor([[row["x"], row["y"], row["z"], row["heading"], row["speed"], row["alpha"]]],
                            dtype=self.dtype, device=self.device)

    def _estimate_window(self, row: dict) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor,
                                                   torch.Tensor]:
        """The estimate's (α, θ, φ), each (1,), and its window: centre uv (1, 2), side (1, 2) pixels."""
        est = self._estimate_particle(row)
        theta, phi = (torch.tensor([row[k]], dtype=self.dtype, device=self.device) for k in ("theta", "phi"))
        uv, side = project_windows(self.camera, est[:, X:Z + 1], self.model.template.window_m)
        return est[:, ALPHA], theta, phi, uv, side

    def silhouette_at(self, row: dict, shape: tuple[int, int]) -> torch.Tensor:
        """The estimate's predicted silhouette placed in the frame: (H, W) bool.

        The shape is the method's, at the likelihood resolution (what the filter compared); the
        bilinear placement of its signed distance draws a smooth contour between its pixels.
        """
        alpha, theta, phi, uv, side = self._estimate_window(row)
        return place_silhouette(self.appearance(alpha, theta, phi)[0], uv[0], side[0], shape)

    def _overlap(self, mask: np.ndarray, row: dict) -> float:
        """Dice ξ (eq. 6.1) of the placed estimate and the segmented target mask: 2|F ∩ H| / (|F| + |H|),
        the intersection and the placed silhouette counted inside its window only; |F| is the row's
        ``mask_area_px``."""
        alpha, theta, phi, uv, side = self._estimate_window(row)
        if not bool(uv.isfinite().all() and side.isfinite().all()):
            return 0.0
        H, W = mask.shape
        (u0, v0), (u1, v1) = (uv[0] - side[0] / 2).floor().long().tolist(), (uv[0] + side[0] / 2).ceil().long().tolist()
        c0, r0, c1, r1 = min(max(u0, 0), W), min(max(v0, 0), H), min(max(u1 + 1, 0), W), min(max(v1 + 1, 0), H)
        placed = place_silhouette(self.appearance(alpha, theta, phi)[0], uv[0] - uv.new_tensor([c0, r0]), side[0],
                                  (r1 - r0, c1 - c0)).cpu().numpy()
        total = int(placed.sum()) + row["mask_area_px"]
        return 2.0 * int((placed & mask[r0:r1, c0:c1]).sum()) / total if total else 1.0

    def _adapt(self, distance: FrameDistance, row: dict) -> None:
        """A few Adam steps on the kernel widths towards the observation at the estimate. Steps that leave a
        log width non-finite or outside ``LOG_WIDTH_RANGE`` (a diverged Adam: a large ``adapt.lr`` times many
        ``adapt.steps``) are undone, with a warning, as ``fine_tune_widths`` refuses them: a NaN width made
        every later shape NaN and lost every later frame."""
        alpha, theta, phi, uv, side = self._estimate_window(row)
        z = observe_windows(distance.signed, uv, side, self.model.template, self.appearance.size, distance.origin)
        log_width = self.model.rbf.log_width
        before = log_width.detach().clone()
        with torch.enable_grad():
            for _ in range(self.cfg.adapt.steps):
                self._optimiser.zero_grad()
                loss = (self.appearance(alpha, theta, phi) - z).square().mean()
                loss.backward()
                self._optimiser.step()
        lo, hi = LOG_WIDTH_RANGE
        if not bool(((log_width >= lo) & (log_width <= hi)).all()):  # NaN fails both
            with torch.no_grad():
                log_width.copy_(before)
            self._optimiser = torch.optim.Adam([log_width], lr=self.cfg.adapt.lr)  # its moments diverged too
            self._adapt_undone += 1
            (log.warning if self._adapt_undone == 1 else log.debug)(
                "frame %s: kernel-width adaptation diverged (log widths left [%g, %g]) and was undone; a smaller "
                "adapt.lr or fewer adapt.steps keeps it (later ones are logged at debug level)", row["frame"], lo, hi)
        self._grid.forget()  # the widths changed the silhouettes,
        self._half_heights = None  # and so their heights (ground contact)

    # --- a whole sequence -------------------------------------------------------------------
    @torch.no_grad()
    def run(self, sequence: Sequence, frames: int | None = None, snapshots: int = 6, progress: bool = True,
            on_frame: Callable[[int, np.ndarray, dict], None] | None = None) -> TrackResult:
        """Track a sequence afresh: warm up the background, initialise (``cfg.init.mode``), step every
        frame. Each call starts a new track, as a new Tracker with the same seed would: what earlier
        steps or runs left (particles, frame count, clock) is dropped; kernel widths that
        ``adapt`` changed stay changed. (To start from your own particles, :meth:`reset` and
        :meth:`step`.)

        The background is learned from the sequence's target-free ``warmup_frames`` where it has
        them (the simulator), else from frames spread evenly over the whole sequence, with what
        moves taken out (``segmentation.static_background_frames``; docs/sequences.md, "The
        background of your own sequences"); so ``frames`` changes only how far the track goes, and
        the first rows are those of the whole run.

        Args:
            sequence: an opened sequence with a camera (``data.open_sequence``).
            frames: track the first ``frames`` frames (default all).
            snapshots: frames kept for figures, evenly spread over the frames from the first
                estimate on (and the first frame, when the track starts later).
            progress: show a tqdm bar.
            on_frame: called as ``on_frame(i, frame, row)`` after each frame is tracked, while the
                tracker is still at that frame (e.g. ``viz.OverlayVideo``); not timed.
        Returns:
            A :class:`TrackResult` whose rows carry the truth (``true_*``) where the sequence has it.
        """
        from tqdm import tqdm

        if not isinstance(sequence, Sequence):
            raise ValueError(f"Expected a Sequence (torch_atr.data.open_sequence(spec)); got {type(sequence).__name__}")
        if frames is not None and (isinstance(frames, bool) or not isinstance(frames, numbers.Integral) or frames < 1):
            raise ValueError(f"Expected frames to be a whole number >= 1, or None for all; got {frames!r}")
        if isinstance(snapshots, bool) or not isinstance(snapshots, numbers.Integral) or snapshots < 0:
            raise ValueError(f"Expected snapshots to be a whole number >= 0; got {snapshots!r}")
        if on_frame is not None and not callable(on_frame):
            raise ValueError(f"Expected on_frame to be a function f(i, frame, row), or None; got {on_frame!r}")
        n = len(sequence) if frames is None else min(int(frames), len(sequence))
        if n < 1:
            raise ValueError(f"{sequence.name}: nothing to track ({n} frames)")
        if self.camera is not None and sequence.camera is not None:
            mine, theirs = self.camera.to_dict(), sequence.camera.to_dict()
            differ = [key for key in mine if not np.allclose(mine[key], theirs[key], rtol=1e-9, atol=1e-12)]
            if differ:
                raise ValueError(f"{sequence.name}: its camera differs from the tracker's in {', '.join(differ)}; "
                                 f"build the Tracker with sequence.camera (or open the sequence without one)")
        self._begin()
        self._grid.forget()  # boxes kept at an earlier run's elevation (a new Tracker has none)
        self.dt = 1.0 / (sequence.fps if math.isfinite(sequence.fps) and sequence.fps > 0 else self.cfg.filter.fps)
        if self.cfg.init.camera_height_m is None:  # the sequence's (one's own may say None, or 0 or -5 m)
            self.camera_height_m = check_camera_height(
                f"{sequence.name}: camera_height_m (metres above the ground; NaN or None: unknown)",
                sequence.camera_height_m)
        count = self.cfg.segmentation.warmup_frames
        if hasattr(sequence, "warmup_frames"):
            self.warm_up(sequence.warmup_frames(count))
        else:  # no target-free frames: frames spread over the clip (not only those tracked), what moves taken out
            total = len(sequence)
            picks = sorted(set(np.linspace(0, total - 1, min(total, count)).round().astype(int).tolist()))
            log.info("%s: no target-free frames; the background is learned from %d frames spread over its %d, with "
                     "moving parts taken out (segmentation.static_background_frames)", sequence.name, len(picks),
                     total)
            self.warm_up(static_background_frames(sequence.frame(i) for i in picks))
        if self.cfg.init.mode == "truth":
            first = sequence.truth(0)
            if first is None:
                raise ValueError(f"{sequence.name}: init.mode=truth needs ground truth for frame 0; it has none "
                                 f"(use init.mode=blind)")
            self.initialise(first)
        keep, started = _evenly(0, n - 1, snapshots), False
        rows, shots, seconds = [], [], 0.0
        for i in tqdm(range(n), desc=f"tracking {sequence.name}", unit="frame", disable=not progress, leave=False):
            frame = sequence.frame(i)
            start = time.perf_counter()
            row = self.step(frame)
            seconds += time.perf_counter() - start
            if not started and "alpha" in row:  # the first estimate: the snapshots left go to the frames from here
                started, shots = True, shots[:min(1, snapshots - 1)]  # a frame before a late start: the scene
                keep = _evenly(i, n - 1, snapshots - len(shots))
            truth = sequence.truth(i)
            if truth is not None:
                row.update(truth_columns(truth))
                row.update(error_columns(row, self.model.class_names))
            rows.append(row)
            if i in keep:
                shots.append(self._snapshot(i, frame, row))
            if on_frame is not None:
                on_frame(i, frame, row)
        return TrackResult(rows, shots, seconds)

    def _snapshot(self, i: int, frame: np.ndarray, row: dict) -> dict:
        """One frame for the figures: the display image, the segmented mask, the placed estimate."""
        shape = self.last_mask.shape
        placed = self.silhouette_at(row, shape).cpu().numpy() if "alpha" in row else np.zeros(shape, dtype=bool)
        return {"frame": i, "image": self.segmenter.display(frame), "mask": self.last_mask, "silhouette": placed}


def _evenly(first: int, last: int, count: int) -> set[int]:
    """``count`` frames spread evenly over [first, last], both included where count >= 2."""
    return set(np.linspace(first, last, count).round().astype(int).tolist()) if count > 0 else set()


def column(rows: list[dict], name: str) -> np.ndarray:
    """One numeric column of estimate rows, (T,) float64 (NaN where a row lacks it)."""
    return np.array([float(row.get(name, math.nan)) for row in rows], dtype=np.float64)


def estimate_and_truth(rows: list[dict]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """The ``x``, ``z`` and ``theta`` columns of estimate rows and of their ``true_*`` columns, as
    :func:`~torch_atr.evaluation.frame_errors` takes them: (T,) arrays, NaN where a row lacks one."""
    return ({k: column(rows, k) for k in ("x", "z", "theta")},
            {k: column(rows, f"true_{k}") for k in ("x", "z", "theta")})


def row_errors(rows: list[dict]) -> dict[str, np.ndarray]:
    """:func:`~torch_atr.evaluation.frame_errors` of estimate rows against their truth."""
    return frame_errors(*estimate_and_truth(rows))


ERROR_COLUMNS = {"horizontal_error_m": "error_horizontal_m", "range_error_m": "error_range_m",
                 "aspect_error_rad": "error_aspect_rad",
                 "aspect_error_up_to_mirror_rad": "error_aspect_up_to_mirror_rad"}  # frame_errors' key -> column


def error_columns(row: dict, class_names=None) -> dict:
    """The per-frame errors of an estimate row that has its ``true_*`` columns, each only where the
    estimate and the truth both know it (an uncalibrated run has no position; SENSIAC's truth no
    x, z): ``error_horizontal_m``, ``error_range_m``, ``error_aspect_rad`` and
    ``error_aspect_up_to_mirror_rad`` (:func:`row_errors`); and with ``class_names``, ``recognised``:
    1 where the estimate's class is the true class, 0 where it is not or there is no estimate,
    absent where the true class is none of ``class_names`` (as metrics.json counts them)."""
    errors = {ERROR_COLUMNS[key]: float(error[0]) for key, error in row_errors([row]).items()}
    if class_names is not None and row.get("true_class") in class_names:
        errors["recognised"] = float(row.get("class") == row["true_class"])
    return {key: error for key, error in errors.items() if math.isfinite(error)}


def truth_columns(truth: FrameTruth) -> dict:
    """The ``true_*`` columns of an estimate row; θ is SENSIAC's aspect where only that is known
    (``FrameTruth.aspect`` equals θ)."""
    return {"true_x": truth.x, "true_y": truth.y, "true_z": truth.z, "true_heading": truth.heading,
            "true_theta": truth.theta if math.isfinite(truth.theta) else truth.aspect, "true_phi": truth.phi,
            "true_vehicle": truth.vehicle,
            "true_class": truth.vehicle_class}
