"""Foreground segmentation by background subtraction (thesis 3.1).

A per-pixel mixture of Gaussians (OpenCV's MOG2, Zivkovic's refinement of Stauffer & Grimson,
eq. 3.1-3.2) is learned on target-free frames; then each frame is compared with it. The raw
foreground is cleaned by a morphological opening (removes specks) then closing (fills holes),
and the target blob is kept: the largest connected component, or the one nearest a predicted
pixel.

By default, as the thesis does with a fixed camera, the background model is frozen after the
warm-up (``learning_rate = 0``). On real footage that fails: a global brightness change (clouds,
camera gain) turns the whole scene into foreground (METHOD.md, pitfalls). Two options, which the
tracker turns on and feeds with its prediction:

- ``learning_rate > 0``: the background keeps learning every ``learning_interval`` frames,
  except where the target is: inside the ``exclude`` box (the tracker's predicted target region)
  and on the detected foreground, the frame is replaced by the background image before the
  update, so a slow or stopped target is not absorbed (selective update);
- ``compensate_gain``: before the comparison, the frame's global gain and offset against the
  background image, frame ≈ a·background + b, are fitted by least squares on a fixed grid of
  pixels outside ``exclude`` (the worst-fitting 20 % dropped and the fit repeated) and undone.

Thin parts (``thin_threshold`` > 0, off by default). Blur takes a gun barrel a pixel or two wide
below MOG2's threshold at range, and a tank without its gun has an APC's silhouette. A lower
threshold finds it, but also a blur halo all round the vehicle, which makes a small far vehicle
look bigger. So the frame is compared a second time at ``thin_threshold``, and only parts that
reach at least 3 px straight out (2 px diagonally) beyond a one-pixel ring round the target blob,
connected to it through pixels above that threshold, join the blob (:func:`extend_thin_parts`;
such a part joins with the halo it touches).
The second comparison learns nothing, but with ``learning_rate`` −1 it counts as a frame in
OpenCV's automatic rate.

16-bit IR (and float) frames are mapped to uint8 by one fixed linear map chosen on the warm-up
frames, so the map does not change from frame to frame and MOG2's statistics stay valid: the
robust range [lo, hi] between two percentiles of the warm-up pixels is widened by ``headroom``
times its width on each side (room for targets warmer or colder than any background) and mapped
to [0, 255]; values outside are clipped. uint8 grey frames are used as they are; colour frames
(H, W, 3, RGB, as the sequences give them) are converted to grey first. A pixel that is NaN or
infinite in a float frame has no data: it takes the background's value, so it is never
foreground (and is left out of the gain fit); in a warm-up frame, the same pixel's value in the
nearest warm-up frame before it that has one, else the nearest after it (MOG2 would learn a
made-up value there as a second mode, and the pixel, blended into the background image, would
then be foreground wherever it has no data).
"""

from __future__ import annotations

import logging
import math
import numbers
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable, Iterable

import cv2
import numpy as np
from scipy.stats import median_abs_deviation

from torch_atr._checks import describe_array, to_grey
from torch_atr.config import ConfigError
from torch_atr.validate import show

logger = logging.getLogger(__name__)

FRAME_DTYPES = (np.uint8, np.uint16, np.float32, np.float64)  # what frames may hold


MAX_WARMUP_FRAMES = 1000  # warm-up frames are held in memory: about 1 MB each at 640 x 512 (measured)
MAX_KERNEL_PX = 64  # cleaning kernels: 64 px closes gaps wider than any vehicle's; 3001 took 43 s a frame


@dataclass(frozen=True)
class SegmentationConfig:
    """Background subtraction and mask cleaning settings.

    The defaults were chosen on the IR simulator with four TRAINING vehicles (M1A2, Boxer, Hilux,
    Civic; ``benchmarks/bench_segmentation.py``): var_threshold 36 with no opening and a 3 px
    closing gave mean IoU 0.93 at 1000 m and 0.75 at 3500 m, against 0.89 and 0.68 for
    var_threshold 16 with 3 px opening and 5 px closing. Noisier real footage may want an opening.
    """

    history: int = 200  # MOG2 history: frames that make up the background statistics
    var_threshold: float = 36.0  # MOG2 squared Mahalanobis distance above which a pixel is foreground
    detect_shadows: bool = False  # MOG2 shadow labelling (shadows count as background)
    learning_rate: float = 0.0  # after warm-up; 0 freezes the background (thesis 3.1), -1 = OpenCV's automatic
    learning_interval: int = 1  # learn on every k-th frame (when learning_rate != 0)
    compensate_gain: bool = False  # fit and undo frame ≈ a·background + b before comparing
    warmup_frames: int = 50  # at most this many frames are taken from warm_up's iterable
    open_px: int = 1  # diameter of the elliptic opening kernel; 0 or 1 = no opening
    close_px: int = 3  # diameter of the elliptic closing kernel; 0 or 1 = no closing
    min_area_px: int = 4  # connected components smaller than this are never the target
    low_percentile: float = 1.0  # IR normalisation: lo = this percentile of the warm-up pixels
    high_percentile: float = 99.0  # IR normalisation: hi = this percentile of the warm-up pixels
    headroom: float = 0.5  # IR normalisation: [lo, hi] widened by this fraction of hi - lo on each side
    thin_threshold: float = 0.0  # MOG2 threshold finding thin parts (gun barrels) beyond the blob; 0: off

    def __post_init__(self) -> None:
        checks = {
            "history": self.history >= 1,
            "var_threshold": self.var_threshold > 0,
            "learning_rate": self.learning_rate == -1 or 0 <= self.learning_rate <= 1,
            "learning_interval": self.learning_interval >= 1,
            "warmup_frames": 1 <= self.warmup_frames <= MAX_WARMUP_FRAMES,
            "open_px": 0 <= self.open_px <= MAX_KERNEL_PX,
            "close_px": 0 <= self.close_px <= MAX_KERNEL_PX,
            "min_area_px": self.min_area_px >= 0,
            "low_percentile": 0 <= self.low_percentile < self.high_percentile,
            "high_percentile": self.high_percentile <= 100,
            "headroom": self.headroom >= 0,
            "thin_threshold": self.thin_threshold == 0 or 0 < self.thin_threshold < self.var_threshold,
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            values = ", ".join(f"{k}={show(getattr(self, k))}" for k in bad)
            raise ConfigError(f"segmentation: bad value(s) {values} (history, learning_interval >= 1; "
                              f"warmup_frames in [1, {MAX_WARMUP_FRAMES}]; var_threshold > 0; learning_rate in [0, 1] "
                              f"or -1; open_px, close_px in [0, {MAX_KERNEL_PX}]; min_area_px, headroom >= 0; "
                              "0 <= low < high <= 100 percentiles; thin_threshold 0 or in (0, var_threshold))")


def normalise_ir(frame: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Map a grey frame linearly to uint8: ``lo`` -> 0, ``hi`` -> 255, clipped outside.

    Args:
        frame: (H, W) any real dtype (e.g. uint16 IR counts).
        lo, hi: the input values that map to 0 and 255, ``lo < hi``.
    Returns:
        (H, W) uint8, round((frame - lo) · 255 / (hi - lo)) clipped to [0, 255].
    """
    if not isinstance(frame, np.ndarray) or frame.ndim != 2:
        raise ValueError(f"Expected frame to have shape (H, W); got {getattr(frame, 'shape', type(frame).__name__)}")
    return _affine_uint8(frame, *_ir_scale(lo, hi))


def _ir_scale(lo: float, hi: float) -> tuple[float, float]:
    """(k, c) of the map x -> k·x + c taking ``lo`` to 0 and ``hi`` to 255."""
    if not hi > lo:
        raise ValueError(f"Expected lo < hi; got lo={lo}, hi={hi}")
    k = 255.0 / (hi - lo)
    return k, -k * lo


def _affine_uint8(grey: np.ndarray, k: float, c: float) -> np.ndarray:
    """round(k·grey + c) saturated to uint8 in one pass (OpenCV's addWeighted with a zero second term)."""
    return cv2.addWeighted(grey, k, grey, 0.0, c, dtype=cv2.CV_8U)


def _check_mask(mask) -> np.ndarray:
    if not isinstance(mask, np.ndarray) or mask.ndim != 2:
        raise ValueError(f"Expected mask to have shape (H, W); got {getattr(mask, 'shape', type(mask).__name__)}")
    return mask.astype(bool)


def _check_count(name: str, value) -> None:
    """ValueError unless ``value`` is a whole number >= 0 (a pixel count or kernel size)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 0:
        raise ValueError(f"Expected {name} to be a whole number >= 0; got {value!r}")


def clean_mask(mask: np.ndarray, open_px: int, close_px: int) -> np.ndarray:
    """Morphological opening then closing with elliptic kernels.

    Args:
        mask: (H, W) bool (or 0/non-zero) foreground.
        open_px, close_px: kernel diameters in pixels; 0 or 1 skips that step.
    Returns:
        (H, W) bool. Pixels outside the image count as neither foreground nor background
        (OpenCV's default border), so the frame edge neither erodes nor grows the mask. An even
        diameter's kernel has no centre: the erosion uses it and the dilation its point reflection,
        as scipy.ndimage does (``morphologyEx`` uses one kernel for both, which shifts the mask a pixel).
    """
    _check_count("open_px", open_px)
    _check_count("close_px", close_px)
    m = _check_mask(mask)
    out = np.zeros_like(m)
    box = _foreground_box(m, 2 * (open_px // 2 + close_px // 2) + 1)
    if box is None:
        return out
    # Only the foreground's box is filtered, grown by more than the opening and the closing reach:
    # beyond that margin the result is background, and inside it the same as the whole frame's.
    region = m[box].view(np.uint8)
    for opening, size in ((True, open_px), (False, close_px)):
        if size > 1:  # erosion by the kernel, dilation by its point reflection
            kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
            reflected, a, b = np.ascontiguousarray(kernel[::-1, ::-1]), (size // 2,) * 2, (size - 1 - size // 2,) * 2
            if opening:
                region = cv2.dilate(cv2.erode(region, kernel, anchor=a), reflected, anchor=b)
            else:
                region = cv2.erode(cv2.dilate(region, reflected, anchor=b), kernel, anchor=a)
    out[box] = region.view(bool)
    return out


def _foreground_box(mask: np.ndarray, margin: int = 0) -> tuple[slice, slice] | None:
    """The (rows, cols) slices of the box holding a (H, W) bool mask's foreground, grown by ``margin``
    pixels and clipped to the image; None when there is none."""
    rows = np.flatnonzero(mask.any(1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(mask.any(0))
    H, W = mask.shape
    return (slice(max(int(rows[0]) - margin, 0), min(int(rows[-1]) + margin + 1, H)),
            slice(max(int(cols[0]) - margin, 0), min(int(cols[-1]) + margin + 1, W)))


def _check_near(near) -> tuple[float, float] | None:
    """A predicted pixel ``near`` (u, v), any two real numbers (a tensor too), as finite floats;
    None for None. ValueError naming it otherwise."""
    if near is None:
        return None
    try:
        u, v = (float(c) for c in near)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"Expected near to be a pixel (u, v); got {near!r}") from exc
    if not (math.isfinite(u) and math.isfinite(v)):
        raise ValueError(f"Expected near to be finite; got {near!r}")
    return u, v


def select_blob(mask: np.ndarray, near: tuple[float, float] | None = None, min_area: int = 0) -> np.ndarray:
    """Keep one 8-connected component of a mask: the target blob.

    Args:
        mask: (H, W) bool foreground.
        near: (u, v) pixel (u right, v down); if given, keep the component with the pixel nearest
            to it (distance 0 if it lies on the component), else the largest component (the
            first label on a tie).
        min_area: components with fewer pixels are ignored.
    Returns:
        (H, W) bool, all False when no component qualifies.
    """
    _check_count("min_area", min_area)
    m = _check_mask(mask)
    near = _check_near(near)
    out = np.zeros_like(m)
    box = _foreground_box(m)  # components are found inside the foreground's box only
    if box is None:
        return out
    y0, x0 = box[0].start, box[1].start
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m[box].view(np.uint8), connectivity=8)
    areas = stats[:, cv2.CC_STAT_AREA]
    valid = areas >= max(min_area, 1)
    valid[0] = False  # label 0 is the background
    if not valid.any():
        return out
    if near is None:
        keep = int(np.argmax(np.where(valid, areas, -1)))
    else:  # the foreground pixel of a valid component nearest to (u, v)
        u, v = near
        xy = cv2.findNonZero(m[box].view(np.uint8)).reshape(-1, 2)  # the foreground's (x, y) in the box
        cols, rows = xy[:, 0], xy[:, 1]
        own = labels[rows, cols]
        ok = valid[own]
        d2 = (cols[ok] + x0 - u) ** 2 + (rows[ok] + y0 - v) ** 2
        keep = own[ok][np.argmin(d2)]
    out[box] = labels == keep
    return out


Box = tuple[float, float, float, float]  # (u0, v0, u1, v1) pixels, inclusive corners

_GAIN_STRIDE = 7  # the gain fit samples every 7th pixel in each direction
_GAIN_TRIM = 0.2  # ... and refits without the worst-fitting fifth
_FOREGROUND_MARGIN_PX = 7  # the detected foreground is grown by this before a selective update
_THIN_RING_PX = 1  # thin parts: the ring round the blob that a blur halo fills ...
_THIN_REACH_PX = 2.0  # ... and how far beyond it a part must reach (3 x 3 chamfer: 3 px straight, 2 diagonally)
_THIN_SEARCH_PX = (16, 32)  # ... and the margins (rows, columns) round the blob searched first for them
_TILE_PX = (32, 64)  # MOG2 runs on tiles of this many rows and columns (_TiledMOG2) ...
_REGION_MARGIN_PX = 16  # ... and compares those within this of the last blob first (ForegroundSegmenter)

Region = Callable[[int, int, int, int], np.ndarray]  # (r0, r1, c0, c1) -> (H, W) bool, exact in [r0:r1, c0:c1]


def _box_corners(box: Box | None) -> tuple[float, float, float, float] | None:
    """A predicted box's (u0, v0, u1, v1) as floats; None for None or a box with a non-finite
    corner (no prediction). ValueError for anything else that is not four numbers."""
    if box is None:
        return None
    try:
        corners = tuple(float(c) for c in box)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"Expected a box (u0, v0, u1, v1); got {box!r}") from exc
    if len(corners) != 4:
        raise ValueError(f"Expected a box (u0, v0, u1, v1); got {box!r}")
    return corners if all(map(math.isfinite, corners)) else None


def _box_mask(shape: tuple[int, int], box: Box | None) -> np.ndarray:
    """(H, W) bool: True inside the box (clipped to the image); all False for None or an empty box."""
    out = np.zeros(shape, dtype=bool)
    corners = _box_corners(box)
    if corners is None:
        return out
    u0, v0, u1, v1 = corners
    H, W = shape
    c0, c1 = int(np.clip(np.floor(u0), 0, W)), int(np.clip(np.ceil(u1) + 1, 0, W))
    r0, r1 = int(np.clip(np.floor(v0), 0, H)), int(np.clip(np.ceil(v1) + 1, 0, H))
    out[r0:r1, c0:c1] = True
    return out


def _components_holding(blob: np.ndarray, low_in: Region, rect: tuple[int, int, int, int], ring_px: int
                        ) -> tuple[np.ndarray, np.ndarray, tuple[slice, slice]]:
    """The 8-connected components of ``low | blob`` that hold pixels of ``blob`` (whose bounding
    rectangle (x, y, w, h) is ``rect``), and the box that holds them grown by ``ring_px``.

    They are labelled in the blob's rectangle grown by ``_THIN_SEARCH_PX`` (16 rows, 32 columns: a
    gun reaches far sideways, rarely up or down, and every tile costs the segmenter a comparison),
    and in the whole frame only when one of them, grown by the ring, would leave that region
    inside the image: the result is the whole frame's either way, at a fraction of the cost (a
    whole 640 x 512 frame of noise at the lower threshold is most of this function's time).
    ``low_in(r0, r1, c0, c1)`` gives ``low`` exact in rows r0:r1 and columns c0:c1, so a segmenter
    compares only the pixels looked at.

    Returns:
        labels: the labels inside the box; touching: (T,) the labels holding the blob; box: the
        (rows, cols) slices of the box in the frame.
    """
    H, W = blob.shape
    x, y, w, h = rect
    rows, cols = _THIN_SEARCH_PX
    for r0, r1, c0, c1 in ((max(y - rows, 0), min(y + h + rows, H), max(x - cols, 0), min(x + w + cols, W)),
                           (0, H, 0, W)):
        both = low_in(r0, r1, c0, c1)[r0:r1, c0:c1] | blob[r0:r1, c0:c1]
        _, labels, stats, _ = cv2.connectedComponentsWithStats(both.view(np.uint8), connectivity=8)
        touching = np.unique(labels[blob[r0:r1, c0:c1]])
        corner = stats[touching, :2]  # (left, top) of each, then (right, bottom) past its end, in the region
        (left, top), (right, bottom) = corner.min(0) - ring_px, (corner + stats[touching, 2:4]).max(0) + ring_px
        # Off the region's edges (or on the image's), no part of them lies outside the region.
        if (left > 0 or c0 == 0) and (top > 0 or r0 == 0) and (right < c1 - c0 or c1 == W) and (
                bottom < r1 - r0 or r1 == H):
            break
    top, left = max(top, 0), max(left, 0)
    bottom, right = min(bottom, r1 - r0), min(right, c1 - c0)  # the ring clipped at the image's edges
    return labels[top:bottom, left:right], touching, np.s_[r0 + top:r0 + bottom, c0 + left:c0 + right]


def extend_thin_parts(blob: np.ndarray, low: np.ndarray, ring_px: int = _THIN_RING_PX,
                      reach_px: float = _THIN_REACH_PX) -> np.ndarray:
    """The blob with the thin parts a lower threshold found (module docstring, "Thin parts").

    The ring is the blob dilated by an elliptic ``ring_px`` radius. A connected part of ``low``
    outside the ring joins when some pixel of it lies at least ``reach_px`` beyond the ring and it
    is 8-connected to the blob through ``low``. Distances are OpenCV's 3 × 3 chamfer approximation
    of the Euclidean one (steps 0.955 straight, 1.3693 diagonal), so with the default 2.0 a part
    must reach 3 px straight out or 2 diagonally; the ``low`` pixels of the ring
    next to it join too, joining it to the blob. A halo at most ``reach_px`` thick beyond the
    ring, and anything not connected to the blob, stay out, unless a part that reaches further
    touches the halo: the part joins whole, the halo with it (a 12 px barrel through a 2 px halo
    round a 20 x 20 blob brought 178 px, not 12). On the simulator it does not matter: a rule that
    lets through only the part's far pixels and the halo within 3 px of them (22 px in that case)
    gave the same mean mask IoU over the 8 test vehicles, 0.931/0.865/0.758/0.742 at 1000, 2000,
    3000 and 3500 m against 0.931/0.865/0.757/0.742 (``python benchmarks/bench_segmentation.py
    --ranges 1000 2000 3000 3500 --seg thin_threshold=9``, 2026-11-28), so it was not kept.

    Args:
        blob: (H, W) bool, the target blob; low: (H, W) bool, the foreground at the lower threshold.
    Returns:
        (H, W) bool, a superset of ``blob``.
    """
    blob, low = _check_mask(blob), _check_mask(low)
    if low.shape != blob.shape:
        raise ValueError(f"Expected low of the blob's shape {blob.shape}; got {low.shape}")
    return _extend_thin_parts(blob, lambda r0, r1, c0, c1: low, ring_px, reach_px)


def _extend_thin_parts(blob: np.ndarray, low_in: Region, ring_px: int, reach_px: float) -> np.ndarray:
    """:func:`extend_thin_parts` of an (H, W) bool ``blob`` (extended in place and returned), with
    the lower threshold's foreground given box by box: ``low_in(r0, r1, c0, c1)`` is (H, W) bool,
    exact in rows r0:r1 and columns c0:c1 (:func:`_components_holding`)."""
    points = cv2.findNonZero(blob.view(np.uint8))
    if points is None:
        return blob
    labels, touching, box = _components_holding(blob, low_in, cv2.boundingRect(points), ring_px)
    out, blob, low = blob, blob[box], low_in(box[0].start, box[0].stop, box[1].start, box[1].stop)[box]
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ring_px + 1,) * 2)
    ring = cv2.dilate(blob.view(np.uint8), disk).astype(bool)
    beyond = np.isin(labels, touching) & ~ring  # reachable from the blob, outside the ring
    if not beyond.any():
        return out
    reach = cv2.distanceTransform((~ring).view(np.uint8), cv2.DIST_L2, 3)  # from the ring
    n, parts = cv2.connectedComponents(beyond.view(np.uint8), connectivity=8)
    far = np.zeros(n)
    np.maximum.at(far, parts[beyond], reach[beyond])
    keep = far >= reach_px
    keep[0] = False  # label 0: not beyond the ring
    thin = keep[parts]
    if not thin.any():
        return out
    bridge = thin
    for _ in range(ring_px):  # through the ring, one pixel at a time
        bridge = bridge | (ring & low & cv2.dilate(bridge.view(np.uint8), np.ones((3, 3), np.uint8)).astype(bool))
    out[box] |= bridge
    return out


class _TiledMOG2:
    """OpenCV's MOG2 on tiles of ``_TILE_PX`` (rows, columns), one model each.

    MOG2 models every pixel on its own, so the tiles give the whole frame's model and masks
    exactly (tests/test_segmentation.py compares them with one model), while a comparison can be
    limited to the pixels it is needed in (``ForegroundSegmenter``, "Region compared"). A
    whole-frame call spreads the tiles over as many threads as OpenCV uses
    (``cv2.getNumThreads()``), as OpenCV splits one model's rows; the threads end with the object,
    and a forked process makes its own. A call on some tiles runs them on the calling thread: in
    the tracker's step, waking a second thread cost more than the tiles (2.2 ms against 0.7 for a
    tank's 3 bands of whole rows at 1000 m).
    """

    def __init__(self, shape: tuple[int, int], history: int, var_threshold: float, detect_shadows: bool):
        (H, W), (th, tw) = shape, _TILE_PX
        self.shape = (H, W)
        self.columns = len(range(0, W, tw))  # tiles in a row of tiles
        self.tiles = [(r, min(r + th, H), c, min(c + tw, W)) for r in range(0, H, th) for c in range(0, W, tw)]
        self.models = [cv2.createBackgroundSubtractorMOG2(history=history, varThreshold=var_threshold,
                                                          detectShadows=detect_shadows) for _ in self.tiles]
        self.var_threshold = var_threshold
        self.threads = max(1, min(cv2.getNumThreads(), len(self.tiles)))
        self._pool, self._pid = None, None  # made on first use, and again in a forked child (its threads stay behind)

    def apply(self, image: np.ndarray, rate: float, threshold: float | None = None,
              tiles: list[int] | None = None, out: np.ndarray | None = None) -> np.ndarray:
        """MOG2's ``apply(image, learningRate=rate)`` at ``threshold`` (the models' own if None) on
        the given tiles (every tile if None), into ``out``.

        Args:
            image: (H, W) uint8; out: (H, W) uint8 or None (zeros).
        Returns:
            out: (H, W) uint8, MOG2's mask (255 foreground, 127 shadow, 0 background) on the tiles
            applied, untouched elsewhere.
        """
        out = np.zeros(image.shape, np.uint8) if out is None else out
        tiles = range(len(self.tiles)) if tiles is None else tiles

        def run(group: np.ndarray) -> None:
            for t in group:
                (r0, r1, c0, c1), model = self.tiles[t], self.models[t]
                if threshold is not None:
                    model.setVarThreshold(threshold)
                out[r0:r1, c0:c1] = model.apply(image[r0:r1, c0:c1], learningRate=rate)
                if threshold is not None:
                    model.setVarThreshold(self.var_threshold)

        whole = len(tiles) == len(self.tiles)
        first, *rest = np.array_split(np.asarray(tiles, dtype=int), self.threads if whole else 1)
        if rest and self._pid != os.getpid():
            self._pool, self._pid = ThreadPoolExecutor(self.threads - 1), os.getpid()
        pending = [self._pool.submit(run, group) for group in rest]
        run(first)
        for job in pending:
            job.result()
        return out

    def regions_of(self, image: np.ndarray, rate: float, threshold: float | None = None) -> Region:
        """The foreground of ``image`` compared tile by tile as boxes are asked for, each tile once:
        ``fg_in(r0, r1, c0, c1)`` is (H, W) bool, MOG2's foreground (not shadow) in rows r0:r1 and
        columns c0:c1 and in every tile compared before, False elsewhere. Arguments as :meth:`apply`."""
        out, done = np.zeros(image.shape, np.uint8), np.zeros(len(self.tiles), dtype=bool)
        th, tw = _TILE_PX

        def fg_in(r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
            meeting = [i * self.columns + j for i in range(r0 // th, -(-r1 // th))
                       for j in range(c0 // tw, -(-c1 // tw))]
            todo = [t for t in meeting if not done[t]]
            if todo:
                self.apply(image, rate, threshold, todo, out)
                done[todo] = True
            return out == 255

        return fg_in

    def background_image(self) -> np.ndarray:
        """(H, W) uint8, MOG2's background image."""
        out = np.empty(self.shape, np.uint8)
        for (r0, r1, c0, c1), model in zip(self.tiles, self.models):
            out[r0:r1, c0:c1] = model.getBackgroundImage()
        return out


_MOVING_SIGMAS = 3.0  # static_background_frames: a pixel this many robust σ from its median moves
_MEDIAN_ROWS = 64  # ... computed over blocks of this many rows, to bound the memory


def _grey_frames(frames: Iterable[np.ndarray], what: str, limit: int | None = None) -> list[np.ndarray]:
    """Up to ``limit`` warm-up frames as (H, W) greys of their dtype, checked to share frame 0's
    size and dtype; at least one."""
    greys = []
    for i, frame in enumerate(frames):
        if i == limit:
            break
        grey = to_grey(f"warm-up frame {i}", frame, FRAME_DTYPES, "RGB")
        if greys and (grey.shape, grey.dtype) != (greys[0].shape, greys[0].dtype):
            raise ValueError(f"warm-up frame {i}: shape {frame.shape}, dtype {frame.dtype} differs from "
                             f"frame 0's size {greys[0].shape}, dtype {greys[0].dtype}")
        greys.append(grey)
    if not greys:
        raise ValueError(f"{what} needs at least one frame; got none")
    return greys


def _from_nearest(stack: np.ndarray, skip: np.ndarray) -> np.ndarray:
    """Each value of ``stack`` (K, ...) where ``skip`` (K, ...) bool is set replaced by the same
    pixel's value in the nearest frame before it where it is not, else the nearest after it; kept
    where it is set in every frame. Returns (K, ...) of ``stack``'s dtype."""
    k = np.arange(stack.shape[0]).reshape(-1, *[1] * (stack.ndim - 1))
    before = np.maximum.accumulate(np.where(skip, -1, k), axis=0)  # the last kept frame up to each
    after = np.minimum.accumulate(np.where(skip, k.size, k)[::-1], axis=0)[::-1]  # the first kept from each
    source = np.where(before >= 0, before, np.where(after < k.size, after, k))
    return np.take_along_axis(stack, source, axis=0)


def static_background_frames(frames: Iterable[np.ndarray]) -> list[np.ndarray]:
    """Warm-up frames with what moves taken out, for a sequence without target-free frames.

    MOG2 learns whatever the warm-up frames show. Taken from the start of a clip whose vehicle is
    there from the first frame, they teach it the vehicle as background, and the road it uncovers
    later becomes a ghost blob that the tracker then follows. Here a pixel of a frame that lies
    more than 3 robust σ from the pixel's median over the frames (σ: scipy's normal-scaled median
    absolute deviation) is taken from the nearest frame before it where it does not (else the nearest
    after it): a target that covers a
    pixel in fewer than half the frames is replaced by what it hides, with the background's own
    noise (the median itself in its place would shrink the variance MOG2 learns there). Spread
    the frames over the sequence so a moving target covers each pixel in few of them. A pixel
    that is NaN in some frame is left as it is in every frame; an infinite one counts as moving.

    Args:
        frames: K frames (an iterable, read once: each is kept only as grey), (H, W) or (H, W, 3)
            RGB, all the same size and dtype (uint8, uint16, float32 or float64).
    Returns:
        K grey (H, W) frames of that dtype, for :meth:`ForegroundSegmenter.warm_up`.
    """
    stack = np.stack(_grey_frames(frames, "static_background_frames"))  # (K, H, W)
    work = np.float64 if stack.dtype == np.float64 else np.float32
    out = np.empty_like(stack)
    for r in range(0, stack.shape[1], _MEDIAN_ROWS):
        block = stack[:, r:r + _MEDIAN_ROWS].astype(work)
        sigma = median_abs_deviation(block, axis=0, scale="normal")
        moving = np.abs(block - np.median(block, axis=0)) > _MOVING_SIGMAS * sigma
        out[:, r:r + _MEDIAN_ROWS] = _from_nearest(stack[:, r:r + _MEDIAN_ROWS], moving)  # half the frames are still
    return list(out)


def fit_gain(frame: np.ndarray, background: np.ndarray, valid: np.ndarray) -> tuple[float, float]:
    """Least-squares gain and offset with frame ≈ a·background + b over the valid pixels.

    The worst-fitting 20 % of the valid pixels are dropped and the fit repeated, so a target or a
    second vehicle does not bias it. Pixels NaN or infinite in either image have no data and are
    left out. Returns (1, 0) when the background has no contrast there.

    Args:
        frame, background: (H, W) any real dtype; valid: (H, W) bool.
    """
    if not (isinstance(frame, np.ndarray) and frame.ndim == 2):
        raise ValueError(f"Expected frame to have shape (H, W); got {describe_array(frame)}")
    if not (isinstance(background, np.ndarray) and background.shape == frame.shape):
        raise ValueError(f"Expected background to have the frame's shape {frame.shape}; got "
                         f"{describe_array(background)}")
    if not (isinstance(valid, np.ndarray) and valid.dtype == bool and valid.shape == frame.shape):
        raise ValueError(f"Expected valid to be a bool array of the frame's shape {frame.shape}; got "
                         f"{describe_array(valid)}")
    x = background[valid].astype(np.float64)
    y = frame[valid].astype(np.float64)
    finite = np.isfinite(x) & np.isfinite(y)
    if not finite.all():
        x, y = x[finite], y[finite]
    a, b = 1.0, 0.0
    for _ in range(2):
        if x.size < 3 or x.std() < 1e-6:
            return 1.0, 0.0
        mx, my = x.mean(), y.mean()
        a = float(((x - mx) * (y - my)).mean() / ((x - mx) ** 2).mean())  # least squares, closed form
        b = float(my - a * mx)
        residual = np.abs(y - (a * x + b))
        keep = residual <= np.partition(residual, int((1 - _GAIN_TRIM) * (residual.size - 1)))[
            int((1 - _GAIN_TRIM) * (residual.size - 1))]
        x, y = x[keep], y[keep]
    if not (np.isfinite(a) and np.isfinite(b) and a > 1e-3):
        return 1.0, 0.0
    return a, b


def _clean_reach(cfg: SegmentationConfig) -> int:
    """How many pixels away :func:`clean_mask` looks: opening then closing, each an erosion and a
    dilation by half its kernel."""
    return 2 * (cfg.open_px // 2 + cfg.close_px // 2)


def _region_first(last: tuple[int, int, int, int] | None, box: Box | None, near: tuple[float, float] | None,
                  shape: tuple[int, int]) -> tuple[int, int, int, int] | None:
    """The box (r0, r1, c0, c1) to compare first: the box of the ``last`` blob's (r0, r1, c0, c1)
    and ``near``, or with no last blob the predicted box, grown by ``_REGION_MARGIN_PX`` and
    clipped to the image; None without a finite prediction, or when it is the whole image or does
    not hold ``near``."""
    corners = _box_corners(box)
    if near is None or not np.isfinite(near).all():
        return None
    u, v = near
    if last is not None:
        rows, cols = (min(last[0], v), max(last[1], v + 1)), (min(last[2], u), max(last[3], u + 1))
    elif corners is not None:
        rows, cols = (corners[1], corners[3] + 1), (corners[0], corners[2] + 1)
    else:
        return None
    (r0, r1), (c0, c1) = ((int(np.clip(np.floor(lo) - _REGION_MARGIN_PX, 0, n)),
                           int(np.clip(np.ceil(hi) + _REGION_MARGIN_PX, 0, n)))
                          for (lo, hi), n in zip((rows, cols), shape))
    if (r0, r1, c0, c1) == (0, shape[0], 0, shape[1]) or not (r0 <= v < r1 and c0 <= u < c1):
        return None
    return r0, r1, c0, c1


def _chosen_within(cleaned: np.ndarray, blob: np.ndarray, region: tuple[int, int, int, int],
                   near: tuple[float, float], reach: int) -> bool:
    """Whether the blob chosen from the box r0:r1, c0:c1 alone is the one the whole frame gives.

    The cleaned mask equals the whole frame's more than ``reach`` pixels inside the box (or up to
    the image's edge). So it does when the cleaned mask has no foreground within ``2·reach + 2``
    pixels of an edge inside the image (an empty ring there parts whatever lies beyond from the
    rest, with the same components, sizes and all) and the chosen blob is nearer ``near`` than
    any pixel within ``reach`` of such an edge, or beyond it.

    Args:
        cleaned: (H, W) bool, the cleaned mask of the box (False elsewhere); blob: (H, W) bool,
            the blob :func:`select_blob` chose from it; region: (r0, r1, c0, c1); near: (u, v) pixel.
    """
    r0, r1, c0, c1 = region
    (H, W), (u, v), band = cleaned.shape, near, 2 * reach + 2
    strips = [(r0 > 0, np.s_[r0:min(r0 + band, r1), c0:c1]), (r1 < H, np.s_[max(r1 - band, r0):r1, c0:c1]),
              (c0 > 0, np.s_[r0:r1, c0:min(c0 + band, c1)]), (c1 < W, np.s_[r0:r1, max(c1 - band, c0):c1])]
    box = _foreground_box(blob)
    if box is None or any(inner and cleaned[strip].any() for inner, strip in strips):
        return False
    ys, xs = np.nonzero(blob[box])
    gap = min(v - (r0 + reach) if r0 > 0 else np.inf, r1 - 1 - reach - v if r1 < H else np.inf,
              u - (c0 + reach) if c0 > 0 else np.inf, c1 - 1 - reach - u if c1 < W else np.inf)
    return bool(np.sqrt(((xs + box[1].start - u) ** 2 + (ys + box[0].start - v) ** 2).min()) < gap)


class ForegroundSegmenter:
    """MOG2 background subtraction with a cleaned target mask (module docstring).

    Usage: ``seg = ForegroundSegmenter(cfg); seg.warm_up(target_free_frames); mask = seg(frame)``.
    Frames must keep the warm-up frames' size and dtype. An empty or all-foreground mask (e.g.
    after a sudden global change) is returned like any other and logged at debug level.

    Region compared. MOG2 runs on tiles of ``_TILE_PX`` pixels, one model each (``_TiledMOG2``,
    the same per-pixel models). Given a prediction ``near``, a frame is compared first in the tiles
    that meet the box of the last frame's blob and of ``near`` (with no last blob, the ``exclude``
    box) grown by ``_REGION_MARGIN_PX``, and in every tile only when the blob chosen there might
    not be the whole frame's choice (foreground near those tiles' inner edges, or a pixel beyond
    them could be nearer ``near``), on frames that learn, and with OpenCV's automatic rate; the
    thin parts' comparison covers the tiles round the blob. The masks are the whole frame's
    (tests/test_segmentation.py). The models differ only where a tile was not compared: a
    comparison that learns nothing still leaves a mode of weight zero where a pixel fits none,
    and such modes never make a pixel background.
    """

    def __init__(self, cfg: SegmentationConfig | None = None):
        self.cfg = cfg or SegmentationConfig()
        self.levels: tuple[float, float] | None = None  # (lo, hi) of the IR map; None for uint8 frames
        self.gain: tuple[float, float] = (1.0, 0.0)  # the last (a, b) of frame ≈ a·background + b
        self._mog: _TiledMOG2 | None = None
        self._kind: tuple[tuple[int, int], np.dtype] | None = None
        self._background: np.ndarray | None = None  # MOG2's background image, refreshed when it learns
        self._frames = 0
        self._last_box: tuple[int, int, int, int] | None = None  # the last frame's blob's box (r0, r1, c0, c1)

    def check_frame(self, frame) -> None:
        """Raise ValueError unless ``frame`` can be segmented: warmed up, and a numpy (H, W) or
        (H, W, 3) array of the warm-up frames' size and dtype. (A tracker checks before it moves.)"""
        if self._kind is None:
            raise RuntimeError("ForegroundSegmenter: call warm_up(frames) before segmenting frames")
        if not (isinstance(frame, np.ndarray) and frame.shape[:2] == self._kind[0] and frame.dtype == self._kind[1]
                and (frame.ndim == 2 or frame.ndim == 3 and frame.shape[2] == 3)):
            raise ValueError(f"Expected a frame of size {self._kind[0]} and dtype {self._kind[1]} like the "
                             f"warm-up frames; got {describe_array(frame)}")

    def _grey(self, frame) -> tuple[np.ndarray, np.ndarray | None]:
        """(H, W) or (H, W, 3) frame -> (H, W) grey of its dtype, checked against the warm-up frames,
        with its non-finite pixels (float frames) set to 0, and the (H, W) bool mask of those
        pixels (None: none)."""
        self.check_frame(frame)
        grey = to_grey("frame", frame, FRAME_DTYPES, "RGB")
        if grey.dtype.kind != "f" or np.isfinite(grey).all():
            return grey, None
        missing = ~np.isfinite(grey)
        return np.where(missing, 0, grey).astype(grey.dtype), missing

    def _to_uint8_scale(self, a: float = 1.0, b: float = 0.0) -> tuple[float, float]:
        """(k, c) with uint8 value = k·grey + c: the IR levels' map, then the gain (x − b) / a undone."""
        k, c = (1.0, 0.0) if self.levels is None else _ir_scale(*self.levels)
        return k / a, (c - b) / a

    def display(self, frame: np.ndarray) -> np.ndarray:
        """The frame as the segmenter compares it: (H, W) uint8 grey (IR mapped by the warm-up
        levels, before gain compensation)."""
        if self._kind is None:
            raise RuntimeError("ForegroundSegmenter: call warm_up(frames) first")
        return _affine_uint8(self._grey(frame)[0], *self._to_uint8_scale())

    @property
    def frame_size(self) -> tuple[int, int] | None:
        """(H, W) of the warm-up frames, which every frame must have; None before :meth:`warm_up`."""
        return None if self._kind is None else self._kind[0]

    @property
    def ready(self) -> bool:
        """True once :meth:`warm_up` has learned a background."""
        return self._mog is not None

    def contrast(self, frame: np.ndarray, mask: np.ndarray) -> float:
        """The target's median contrast: |frame − background| over the mask's pixels, in grey levels
        of the uint8 scale the segmenter compares (IR mapped, the last gain undone).

        Args:
            frame: (H, W) or (H, W, 3) like the warm-up frames; mask: (H, W) bool, non-empty.
        """
        if not self.ready:
            raise RuntimeError("ForegroundSegmenter: call warm_up(frames) before measuring contrast")
        mask = _check_mask(mask)
        if mask.shape != self._kind[0] or not mask.any():
            raise ValueError(f"Expected a non-empty mask of the frames' size {self._kind[0]}; got shape {mask.shape}, "
                             f"{int(mask.sum())} pixels")
        grey, missing = self._grey(frame)
        image = _affine_uint8(grey, *self._to_uint8_scale(*self.gain))
        if missing is not None:
            mask = mask & ~missing
            if not mask.any():
                raise ValueError("The mask's pixels are all NaN or infinite in the frame: no contrast to measure")
        return float(np.median(np.abs(image[mask].astype(np.float64) - self._background[mask])))

    def warm_up(self, frames: Iterable[np.ndarray]) -> None:
        """Learn the background from target-free frames (a fresh model each call).

        Args:
            frames: iterable of (H, W) or (H, W, 3) frames, all the same size and dtype; at most
                ``cfg.warmup_frames`` are read from it.
        """
        cfg = self.cfg
        greys = _grey_frames(frames, "warm_up", cfg.warmup_frames)
        self._kind = (greys[0].shape, greys[0].dtype)
        if greys[0].dtype == np.uint8:
            self.levels = None
        else:
            stack = np.stack(greys)  # (K, H, W)
            missing = ~np.isfinite(stack) if stack.dtype.kind == "f" else np.zeros((), dtype=bool)
            any_missing = bool(missing.any())
            # The finite pixels (a float frame's in float64), partitioned in place by the percentiles (the
            # stack itself when all are: it is not read again): the stack in float64, its finite pixels and
            # percentile's copy took 50 4K frames to 10 GB.
            finite = stack[~missing] if any_missing else stack
            if finite.size == 0:
                raise ValueError("warm_up: the frames hold no finite pixel (all NaN or infinite)")
            finite = finite.astype(np.float64, copy=False) if finite.dtype.kind == "f" else finite
            lo, hi = np.percentile(finite, [cfg.low_percentile, cfg.high_percentile], overwrite_input=True)
            span = float(hi - lo) or 1.0  # a flat background still gets a valid map
            self.levels = (float(lo) - cfg.headroom * span, float(lo) + (1 + cfg.headroom) * span)
            logger.debug("IR normalisation: [%.1f, %.1f] -> [0, 255]", *self.levels)
            if any_missing:  # no data: MOG2 learns the pixel's value in the nearest frame with it
                gaps = missing.any(axis=0)  # (H, W): only these pixels are filled (the whole stack's
                stack[:, gaps] = _from_nearest(stack[:, gaps], missing[:, gaps])  # indices took 11 copies)
                greys = list(stack)
        self._mog = _TiledMOG2(greys[0].shape, cfg.history, cfg.var_threshold, cfg.detect_shadows)
        for grey in greys:
            self._mog.apply(self.display(grey), -1)
        self._background = self._mog.background_image()
        self.gain, self._frames, self._last_box = (1.0, 0.0), 0, None
        H, W = self._kind[0]
        self._samples = np.ix_(np.arange(0, H, _GAIN_STRIDE), np.arange(0, W, _GAIN_STRIDE))  # the gain fit's grid

    def __call__(self, frame: np.ndarray, near: tuple[float, float] | None = None,
                 exclude: Box | None = None) -> np.ndarray:
        """The cleaned target mask of one frame.

        Args:
            frame: (H, W) or (H, W, 3) of the warm-up frames' size and dtype.
            near: optional predicted target pixel (u, v); keep the blob nearest to it (and compare
                the pixels near it and the last blob first: class docstring, "Region compared").
            exclude: optional predicted target box (u0, v0, u1, v1) in pixels: left out of the
                gain fit and of the background update.
        Returns:
            (H, W) bool.
        """
        if self._mog is None:
            raise RuntimeError("ForegroundSegmenter: call warm_up(frames) before segmenting frames")
        cfg = self.cfg
        grey, missing = self._grey(frame)
        near = _check_near(near)  # before the region compared first reads it
        k, c = self._to_uint8_scale()
        if cfg.compensate_gain:  # on a fixed grid of pixels outside the target box
            keep = ~_box_mask(grey.shape, exclude)[self._samples]
            if missing is not None:
                keep &= ~missing[self._samples]
            self.gain = fit_gain(grey[self._samples] * k + c, self._background[self._samples], keep)
            k, c = self._to_uint8_scale(*self.gain)
        image = _affine_uint8(grey, k, c)
        if missing is not None:  # no data: the background, never foreground
            image[missing] = self._background[missing]
        # A positive rate learns only in the selective update below; −1 is OpenCV's automatic
        # rate on every whole frame.
        learn = cfg.learning_rate > 0 and self._frames % cfg.learning_interval == 0
        (H, W), rate = image.shape, min(cfg.learning_rate, 0.0)
        whole = (0, H, 0, W)
        fg_in = self._mog.regions_of(image, rate)
        # Region compared (class docstring): near the prediction first, unless every tile must see
        # the frame (learning needs the whole foreground; OpenCV's automatic rate counts frames).
        region = None if learn or rate < 0 else _region_first(self._last_box, exclude, near, image.shape)
        if region is not None:
            raw = fg_in(*region)
            cleaned = clean_mask(raw, cfg.open_px, cfg.close_px)
            mask = select_blob(cleaned, near, cfg.min_area_px)
        if region is None or not _chosen_within(cleaned, mask, region, near, _clean_reach(cfg)):
            raw = fg_in(*whole)
            mask = select_blob(clean_mask(raw, cfg.open_px, cfg.close_px), near, cfg.min_area_px)
        self._frames += 1
        if cfg.thin_threshold > 0 and mask.any():  # the same comparison at the lower threshold; nothing learned
            low_in = self._mog.regions_of(image, 0.0, cfg.thin_threshold)
            if rate < 0:  # every tile counts the frame in OpenCV's automatic rate
                low_in(*whole)
            mask = _extend_thin_parts(mask, low_in, _THIN_RING_PX, _THIN_REACH_PX)
        if learn:  # selective update: the background image stands in where the target may be
            grown = cv2.dilate(raw.astype(np.uint8), cv2.getStructuringElement(
                cv2.MORPH_ELLIPSE, (2 * _FOREGROUND_MARGIN_PX + 1,) * 2)).astype(bool)
            image = np.where(_box_mask(grey.shape, exclude) | grown, self._background, image)
            self._mog.apply(image, cfg.learning_rate)
            self._background = self._mog.background_image()
        box = _foreground_box(mask)
        self._last_box = None if box is None else (box[0].start, box[0].stop, box[1].start, box[1].stop)
        fraction = np.count_nonzero(mask) / mask.size
        if fraction == 0:
            logger.debug("empty foreground mask")
        elif fraction > 0.5:
            logger.debug("foreground covers %.0f %% of the frame (a global change?)", 100 * fraction)
        return mask

