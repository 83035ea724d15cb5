"""Camera calibration: IR cameras from target metadata (thesis 3.2), visible cameras from a
checkerboard (thesis 3.3).

IR (SENSIAC): the database has no calibration, but each frame gives the target's slant range and
its centre pixel. With the pinhole model (eq. 3.3-3.4), ``u - cx = f x / z`` and
``v - cy = -f y / z`` in the sensor frame of METHOD.md (x right, y up, z forward), so a frame
whose target position across the line of sight is known, or whose target has a known size
across it (the thesis uses the frame where the aspect is 90°: the vehicle is seen side-on and
spans its length), pins down ``f``. :func:`focal_from_target` solves that by least squares over
any number of frames and :func:`camera_from_focal` turns ``f`` into a :class:`Camera`.

Visible: OpenCV's checkerboard detector and calibration replace the MATLAB toolbox of the
thesis. :func:`calibrate_checkerboard` gives the intrinsics and distortion from several views of
a board, :func:`floor_pose` the extrinsics from one board lying on the floor, and
:func:`draw_cubes` draws wireframe cubes standing on the floor to check the result (Fig. 3.7).

**Floor frame** (the world frame of :func:`floor_pose` and :func:`draw_cubes`): origin at the
board's first inner corner, the one whose diagonal inner square is dark; X along the board's
rows (first corner -> second corner), Y along its columns, Z = X × Y up out of the floor, towards
the camera; metres. The dark square fixes the origin only for a pattern with one odd and one even
inner-corner count (e.g. 9 × 6); a pattern with both even or both odd is symmetric under a
half turn and its origin may be either end.
"""

from __future__ import annotations

import logging
import math
from typing import Sequence

import cv2
import numpy as np
import torch

from torch_atr._checks import as_float_tensor, check_finite, check_pattern, check_shape, to_grey
from torch_atr.camera import Camera

logger = logging.getLogger(__name__)

# The 12 edges of a cube whose corners are numbered by bits (x, y, z) = (i & 1, i >> 1 & 1, i >> 2 & 1).
_CUBE_CORNERS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64)
_CUBE_EDGES = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]
_FLOAT64 = torch.zeros((), dtype=torch.float64)  # arrays and lists are read in double precision
_MAX_ITERATIONS = 100  # fixed-point steps of the size method
_EDGE_SAMPLES = 9  # points per drawn edge, so edges bend with the lens distortion
# cv2.calibrateCamera flags that fit distortion terms beyond Camera's (k1, k2, p1, p2, k3)
_EXTRA_TERM_FLAGS = {"CALIB_RATIONAL_MODEL": cv2.CALIB_RATIONAL_MODEL,
                     "CALIB_THIN_PRISM_MODEL": cv2.CALIB_THIN_PRISM_MODEL,
                     "CALIB_TILTED_MODEL": cv2.CALIB_TILTED_MODEL}
# cv2.calibrateCamera flags that start from, or hold, a camera matrix given to it; calibrate_checkerboard gives none.
# USE_INTRINSIC_GUESS failed inside OpenCV ('the camera matrix is not 3x3'); FIX_FOCAL_LENGTH held OpenCV's own first
# estimate (fx 607, fy 613 px on views that fit 610 free), which the focal-length checks then passed unexamined.
_GUESS_FLAGS = {"CALIB_USE_INTRINSIC_GUESS": cv2.CALIB_USE_INTRINSIC_GUESS,
                "CALIB_FIX_FOCAL_LENGTH": cv2.CALIB_FIX_FOCAL_LENGTH}
# Zhang's method needs boards in different orientations: parallel boards (one floor, the same board
# again, boards all facing the camera) gave fx 54,000-123,000 for 820 at rms 0.05-0.13 px. Their
# normals measured (see _orientation_spread_deg) 0.003-0.18 degrees apart; 6 boards tilted 1, 2,
# 3, 5 degrees either way measured 1.7, 3.3, 4.7, 8.1 and were 18, 33, 13, 3 % off in fx.
_MIN_ORIENTATION_SPREAD_DEG = 5.0
# Boards in other degenerate orientations (two boards facing the camera and one tilted 30° about the image's x
# axis; two orientations, one of them facing the camera) pass the spread test and gave fx 111 and 850 for 610 at
# rms 0.03 px: their fitted focal lengths had a standard deviation (_focal_uncertainty) of 1600 % and 27 %; the
# tests' good views 0.04-0.2 %, a 12,000 px telephoto over boards tilted ±25° 2.9 %.
_MAX_FOCAL_UNCERTAINTY = 0.1
_MIN_DETECTOR_SIDE = 15  # cv2.findChessboardCorners' adaptive threshold asserts on an image side under 15 px


def _per_frame(name: str, x, n: int | None = None, cols: int | None = None) -> torch.Tensor:
    """A finite float64 tensor of shape (N,) or (N, cols). A single frame may omit N; with ``n``
    given it is repeated to N = n, and any other N must equal n."""
    t = as_float_tensor(name, x, like=_FLOAT64).to(torch.float64)
    if t.dim() == (0 if cols is None else 1):
        t = t.unsqueeze(0)
        if n is not None:
            t = t.expand(n, *t.shape[1:])
    check_shape(name, t, ("N",) if cols is None else ("N", cols))
    if t.shape[0] == 0:
        raise ValueError(f"Expected {name} to hold at least one frame; got shape {tuple(t.shape)}")
    if n is not None and t.shape[0] != n:
        raise ValueError(f"Expected {name} to have {n} rows like pixel_uv; got shape {tuple(t.shape)}")
    return check_finite(name, t)


def _first_bad(name: str, values: torch.Tensor, bad: torch.Tensor, what: str) -> None:
    """Raise ``ValueError`` naming the first frame where ``bad`` (N,) holds."""
    if bad.any():
        i = int(torch.nonzero(bad)[0])
        raise ValueError(f"Expected {what}; got {name}[{i}] = {values[i].tolist()}")


def focal_from_target(pixel_uv, range_m, *, principal_point: tuple[float, float],
                      position_xy=None, size_m=None, extent_px=None) -> float:
    """Focal length in pixels from target observations of known range (thesis 3.2).

    Give either ``position_xy``, or ``size_m`` with ``extent_px``. Over several frames the
    result is the least-squares fit; for one frame it is the thesis's one-frame solution.

    Args:
        pixel_uv: (N, 2) or (2,) pixels of the target centre (u right, v down), undistorted.
        range_m: (N,) or scalar slant range, metres: the distance camera -> target centre.
        principal_point: (2,) (cx, cy) pixels, e.g. the image centre ((W - 1) / 2, (H - 1) / 2).
        position_xy: (N, 2) or (2,) sensor-frame x (right) and y (up) of the target centre,
            metres. Depth z = sqrt(r² - x² - y²); residuals of u - cx = f x / z and
            v - cy = -f y / z (eq. 3.4) are linear in f, so f = Σ a·b / Σ a·a with
            a = (x / z, -y / z), b = (u - cx, v - cy).
        size_m: (N,) or scalar size of the target parallel to the image plane, metres (e.g. its
            length at aspect 90°; with a narrow field of view, across the line of sight).
        extent_px: (N,) or scalar pixel extent of that size: e = f s / z, with
            z = r / sqrt(1 + ρ² / f²) and ρ the centre's pixel distance from the principal
            point. With a = s / z, f is the fixed point of f <- Σ a·e / Σ a·a, the linear least
            squares of e = f a with z taken from the previous f (started from z = r). Without
            noise that is the exact f; with noise it approximates the minimiser of the pixel
            residuals Σ (e - f s / z)², whose normal equation weights each frame's term by a
            further f² / (f² + ρ²) (near 1 for targets close to the optical axis).
    Returns:
        f in pixels.
    Raises:
        ValueError: on bad shapes or values (naming the argument and frame), on both or neither
            kind of knowledge, or when f is not observable (every target on the optical axis).
    """
    uv = _per_frame("pixel_uv", pixel_uv, cols=2)
    n = uv.shape[0]
    r = _per_frame("range_m", range_m, n)
    _first_bad("range_m", r, r <= 0, "positive ranges")
    pp = as_float_tensor("principal_point", principal_point, like=_FLOAT64).to(torch.float64)
    check_shape("principal_point", pp, (2,))
    if not torch.isfinite(pp).all():
        raise ValueError(f"Expected principal_point to be finite; got {pp.tolist()}")
    b = uv - pp  # (N, 2) pixel offsets from (cx, cy)
    by_position = position_xy is not None
    if by_position == (size_m is not None or extent_px is not None):
        raise ValueError("Give either position_xy, or size_m with extent_px (exactly one of the two)")
    if by_position:
        xy = _per_frame("position_xy", position_xy, n, cols=2)
        z2 = r * r - (xy * xy).sum(-1)
        _first_bad("range_m", r, z2 <= 0, "ranges longer than the lateral offsets position_xy")
        a = torch.stack([xy[:, 0], -xy[:, 1]], dim=-1) / z2.sqrt().unsqueeze(-1)  # (N, 2) = (x/z, -y/z)
        aa = (a * a).sum()
        if aa <= 0:
            raise ValueError("focal length not observable: every target lies on the optical axis (x = y = 0)")
        f = float((a * b).sum() / aa)
        if not f > 0:
            raise ValueError(f"the least-squares focal length is {f:.6g}, not positive: the pixels lie on the other "
                             f"side of the principal point from position_xy (u grows right with x, v grows down "
                             f"while y grows up)")
        return f
    if size_m is None or extent_px is None:
        raise ValueError("The size method needs both size_m and extent_px")
    s = _per_frame("size_m", size_m, n)
    e = _per_frame("extent_px", extent_px, n)
    _first_bad("size_m", s, s <= 0, "positive sizes")
    _first_bad("extent_px", e, e <= 0, "positive extents")
    # e = f s / z is linear in f once z is known; z = r / sqrt(1 + ρ²/f²) depends on f only through
    # the off-axis term, so fixed-point steps of the linear least squares converge (from z = r).
    rho2 = (b * b).sum(-1)
    f = torch.zeros((), dtype=torch.float64)
    for _ in range(_MAX_ITERATIONS):
        a = s / r if f == 0 else s / r * torch.sqrt(1 + rho2 / f**2)  # (N,) = s / z
        f, previous = (a * e).sum() / (a * a).sum(), f
        if abs(f - previous) <= 1e-12 * f:
            return float(f)
    raise ValueError(f"focal length did not converge in {_MAX_ITERATIONS} steps (last f = {float(f)})")


def camera_from_focal(f: float, width: int, height: int,
                      principal_point: tuple[float, float] | None = None) -> Camera:
    """A distortion-free camera with fx = fy = f, posed at the world origin (world = sensor frame).

    The principal point defaults to the image centre ((width - 1) / 2, (height - 1) / 2), pixel
    (0, 0) being the centre of the top-left pixel.
    """
    cx, cy = ((width - 1) / 2, (height - 1) / 2) if principal_point is None else principal_point
    return Camera(float(f), float(f), float(cx), float(cy), width, height)


def _board_points(pattern: tuple[int, int], square_m: float) -> np.ndarray:
    """(P, 3) float32 board corners in the floor frame, row by row: corner k at (k % cols, k // cols, 0) · square."""
    if not 0 < square_m < math.inf:
        raise ValueError(f"Expected a positive finite square_m; got {square_m}")
    cols, rows = pattern
    c, r = np.meshgrid(np.arange(cols), np.arange(rows))
    return (np.stack([c.ravel(), r.ravel(), np.zeros(cols * rows)], -1) * square_m).astype(np.float32)


def _canonical_order(grey: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Reorder a (rows, cols, 2) corner grid into the floor-frame order of the module docstring."""
    # Z = X × Y points towards the camera iff X -> Y turns counter-clockwise on screen; with v
    # pointing down that is a negative cross product of the image vectors.
    x_dir, y_dir = grid[0, 1] - grid[0, 0], grid[1, 0] - grid[0, 0]
    if x_dir[0] * y_dir[1] - x_dir[1] * y_dir[0] > 0:
        grid = grid[::-1]
    rows, cols = grid.shape[:2]
    if (rows + cols) % 2:  # the two end squares differ in colour: put the dark one at the origin
        c, r = np.meshgrid(np.arange(cols), np.arange(rows))
        H, _ = cv2.findHomography(np.stack([c.ravel(), r.ravel()], -1).astype(np.float32), grid.reshape(-1, 2))
        centres = cv2.perspectiveTransform(np.array([[[0.5, 0.5], [cols - 1.5, rows - 1.5]]], np.float32), H)[0]
        first, last = (float(cv2.getRectSubPix(grey, (3, 3), tuple(map(float, p))).mean()) for p in centres)
        if first > last:
            grid = grid[::-1, ::-1]
    return np.ascontiguousarray(grid)


def find_checkerboard(image: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    """The inner corners of a checkerboard, refined to sub-pixel, or None if none is found.

    An image with a side under 15 pixels, too small for OpenCV's detector to run, has none.

    Args:
        image: (H, W) grey or (H, W, 3) BGR uint8.
        pattern: (columns, rows) of inner corners, e.g. (9, 6).
    Returns:
        (P, 2) float32 pixels, P = columns · rows, row by row in the floor-frame order of the
        module docstring (corner k sits at board position (k % columns, k // columns)).
    """
    cols, rows = check_pattern(pattern)
    grey = to_grey("image", image, (np.uint8,))
    if min(grey.shape) < _MIN_DETECTOR_SIDE:
        return None
    found, corners = cv2.findChessboardCorners(
        grey, (cols, rows), flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    grid = corners.reshape(rows, cols, 2)
    spacing = min(np.linalg.norm(np.diff(grid, axis=0), axis=-1).min(),
                  np.linalg.norm(np.diff(grid, axis=1), axis=-1).min())
    half = int(np.clip(0.4 * spacing, 2, 11))  # the search window must not reach the next corner
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    corners = cv2.cornerSubPix(grey, corners, (half, half), (-1, -1), criteria)
    return _canonical_order(grey, corners.reshape(rows, cols, 2)).reshape(-1, 2)


def _orientation_spread_deg(board_xy: np.ndarray, img_points: list[np.ndarray], K: np.ndarray) -> float:
    """The largest angle between two boards' normals, in degrees, seen through the camera ``K``.

    Each board's vanishing line l = H⁻ᵀ (0, 0, 1) (H: board plane -> image homography) gives its
    normal n ∝ Kᵀ l. Parallel boards share the vanishing line, so their angle is zero whatever K
    is: through the K fitted from them, which is then arbitrary, as through the true one. Other
    angles scale with the true focal length over K's (a nominal K of focal length max(W, H) made
    boards tilted 50° apart look 2.9° apart to a 12,000 px camera), so K is the fitted one.

    Args:
        board_xy: (P, 2) board corners in the board plane; img_points: V arrays (P, 2) of pixels;
        K: (3, 3) intrinsics.
    """
    normals = []
    for corners in img_points:
        H, _ = cv2.findHomography(board_xy, corners)
        n = K.T @ np.linalg.solve(H.T, [0.0, 0.0, 1.0])  # Kᵀ H⁻ᵀ e₃
        normals.append(n / np.linalg.norm(n))
    cos = np.abs(np.stack(normals) @ np.stack(normals).T)  # (V, V); a vanishing line's sign is arbitrary
    return float(np.degrees(np.arccos(np.clip(cos.min(), 0.0, 1.0))))


def _focal_uncertainty(obj: np.ndarray, img_points: list[np.ndarray], K: np.ndarray, dist: np.ndarray,
                       rvecs, tvecs, flags: int) -> float:
    """The larger relative standard deviation of the fitted fx and fy, σ(f) / f, from the fit's Jacobian.

    The reprojection residuals r of all corners, with the Jacobian J of the projections over the
    parameters the flags leave free (fx and fy, or fy with fx = fy · fx / fy fixed, cx and cy, k1, k2,
    p1, p2, k3, and each view's rvec and tvec), give the Gauss-Newton covariance σ² (JᵀJ)⁻¹ with
    σ² = |r|² / (residuals − parameters). Views that leave the focal length undetermined (the
    degenerate configurations of Sturm and Maybank, 1999) make JᵀJ (nearly) singular along the
    directions the data cannot fix, whatever the rms.

    Each view's pose is eliminated first: with Fᵥ its rows' columns of the shared parameters and Qᵥ an
    orthonormal basis of its 6 pose columns, the shared parameters' block of (JᵀJ)⁻¹ is (Σᵥ Gᵥᵀ Gᵥ)⁻¹ for
    Gᵥ = Fᵥ − Qᵥ Qᵥᵀ Fᵥ (the Schur complement), so the SVD is of the stacked Gᵥ, at most 9 columns, not of
    J's 9 + 6 V (200 views of 54 corners peaked at 850 MB and took 10 s).

    Args:
        obj: (P, 3) board corners; img_points: V arrays (P, 2) of pixels; K: (3, 3); dist: OpenCV's
        coefficients; rvecs, tvecs: V poses from ``cv2.calibrateCamera``; flags: its flags.
    """
    fx, fy = K[0, 0], K[1, 1]
    aspect = flags & cv2.CALIB_FIX_ASPECT_RATIO  # one focal parameter, fy, with fx = fy · fx / fy
    focal = np.array([fy] if aspect else [fx, fy])
    fixed_tangent = cv2.CALIB_ZERO_TANGENT_DIST | getattr(cv2, "CALIB_FIX_TANGENT_DIST", 0)
    # projectPoints' Jacobian columns: rvec 0-2, tvec 3-5, fx 6, fy 7, cx 8, cy 9, k1 10, k2 11, p1 12, p2 13, k3 14
    free = [column for column, fixed in ((8, cv2.CALIB_FIX_PRINCIPAL_POINT), (9, cv2.CALIB_FIX_PRINCIPAL_POINT),
                                         (10, cv2.CALIB_FIX_K1), (11, cv2.CALIB_FIX_K2), (12, fixed_tangent),
                                         (13, fixed_tangent), (14, cv2.CALIB_FIX_K3)) if not flags & fixed]
    blocks, residuals = [], []
    for corners, rvec, tvec in zip(img_points, rvecs, tvecs):
        projected, jac = cv2.projectPoints(obj, rvec, tvec, K, dist)  # jac: (2P, 15)
        residuals.append(projected.reshape(-1) - corners.reshape(-1))
        focal_columns = jac[:, 6:7] * (fx / fy) + jac[:, 7:8] if aspect else jac[:, 6:8]
        shared = np.hstack([focal_columns, jac[:, free]])  # (2P, shared parameters)
        pose, _ = np.linalg.qr(jac[:, :6])  # (2P, 6)
        blocks.append(shared - pose @ (pose.T @ shared))
    J, r = np.vstack(blocks), np.concatenate(residuals)
    scale = np.linalg.norm(J, axis=0)
    scale[scale == 0] = 1.0
    _, s, vt = np.linalg.svd(J / scale, full_matrices=False)
    with np.errstate(divide="ignore", invalid="ignore"):  # diag of (JᵀJ)⁻¹ for the focal lengths
        variance = ((vt[:, :len(focal)] / s[:, None]) ** 2).sum(axis=0) / scale[:len(focal)] ** 2
    sigma2 = float(r @ r) / max(J.shape[0] - J.shape[1] - 6 * len(img_points), 1)
    relative = np.sqrt(sigma2 * variance) / focal
    return float(np.nan_to_num(relative, nan=np.inf).max())


def calibrate_checkerboard(images: Sequence[np.ndarray], pattern: tuple[int, int], square_m: float,
                           flags: int = cv2.CALIB_FIX_K3) -> tuple[Camera, float]:
    """Intrinsics and distortion from views of a checkerboard (thesis 3.3, Fig. 3.5).

    Args:
        images: at least 3 uint8 images, (H, W) grey or (H, W, 3) BGR, all the same size.
        pattern: (columns, rows) of inner corners.
        square_m: side of a board square, metres.
        flags: ``cv2.calibrateCamera`` flags; the default fits k1, k2, p1, p2 and keeps k3 = 0,
            as the MATLAB toolbox the thesis used does. Flags that add distortion terms
            (``CALIB_RATIONAL_MODEL``, ``CALIB_THIN_PRISM_MODEL``, ``CALIB_TILTED_MODEL``) are
            refused: :class:`Camera` holds only k1, k2, p1, p2, k3, and K fitted with the extra
            terms would not match the distortion kept. So are ``CALIB_USE_INTRINSIC_GUESS`` and
            ``CALIB_FIX_FOCAL_LENGTH``: no camera matrix is given to start from or to hold.

    The boards must lie in different orientations (tilt the board between views, by tens of
    degrees about different axes): boards all in one plane or in parallel planes, such as several
    boards on the floor, leave the focal length undetermined, and OpenCV then returns a camera tens
    of times off at a small rms. So do boards in only two orientations when one of them faces the
    camera, or when they are turned about an axis along the image's rows or columns (two boards
    facing the camera and a third tilted 30° about the x axis gave fx 111 px for 610 at rms 0.03 px).
    Such views are refused; for a fixed camera over a floor, calibrate the intrinsics from a
    hand-held board and pose the camera with :func:`floor_pose`.
    Returns:
        (camera, rms): the camera posed at the world origin (world = sensor frame), and the RMS
        reprojection error in pixels; the same to the last bit for the same images (OpenCV's
        solver runs on one thread).
    Raises:
        ValueError: fewer than 3 images, an image of another size, an image without the
            board (naming its index), a flag that adds distortion terms or needs a camera matrix
            given (naming it), boards whose normals are all within 5° of each other
            (:func:`_orientation_spread_deg`), or
            views that fit the focal length only to more than ±10 % (one standard deviation,
            :func:`_focal_uncertainty`).
    """
    extra = [name for name, bit in _EXTRA_TERM_FLAGS.items() if flags & bit]
    if extra:
        raise ValueError(f"Expected flags without {' or '.join(extra)}: Camera keeps only the distortion "
                         f"(k1, k2, p1, p2, k3); got flags={flags}")
    guess = [name for name, bit in _GUESS_FLAGS.items() if flags & bit]
    if guess:
        raise ValueError(f"Expected flags without {' or '.join(guess)}: calibrate_checkerboard fits the camera from "
                         f"the images alone, with no camera matrix to start from or to hold; got flags={flags}")
    pattern = check_pattern(pattern)
    obj = _board_points(pattern, square_m)
    if len(images) < 3:
        raise ValueError(f"Expected at least 3 checkerboard images; got {len(images)}")
    size = None
    img_points = []
    for i, image in enumerate(images):
        grey = to_grey(f"images[{i}]", image, (np.uint8,))
        if size is None:
            size = grey.shape
        elif grey.shape != size:
            raise ValueError(f"image {i}: size {grey.shape} differs from image 0's {size}")
        corners = find_checkerboard(grey, pattern)
        if corners is None:
            raise ValueError(f"image {i}: no {pattern[0]}x{pattern[1]} checkerboard found")
        img_points.append(corners)
    height, width = size
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # on more threads its sums are not reproducible: the same images gave
    try:  # cameras differing in the 12th digit, which a tracker's run then amplified
        rms, K, dist, rvecs, tvecs = cv2.calibrateCamera([obj] * len(img_points), img_points, (width, height),
                                                         None, None, flags=flags)
    finally:
        cv2.setNumThreads(threads)
    spread = _orientation_spread_deg(obj[:, :2], img_points, K)
    if spread < _MIN_ORIENTATION_SPREAD_DEG:
        raise ValueError(f"Expected boards in different orientations: the {len(img_points)} boards' normals are at "
                         f"most {spread:.2f}° apart (need {_MIN_ORIENTATION_SPREAD_DEG:g}°), so the focal length is "
                         f"not determined. Tilt the board between views; for a fixed camera over a floor, calibrate "
                         f"with a hand-held board and pose the camera with floor_pose")
    uncertainty = _focal_uncertainty(obj, img_points, K, dist, rvecs, tvecs, flags)
    if not uncertainty <= _MAX_FOCAL_UNCERTAINTY:
        raise ValueError(f"Expected boards whose orientations determine the focal length: the {len(img_points)} views "
                         f"fit fx = {K[0, 0]:.1f}, fy = {K[1, 1]:.1f} px at rms {rms:.3f} px, but only to ±"
                         f"{100 * uncertainty:.3g} % (one standard deviation; at most {100 * _MAX_FOCAL_UNCERTAINTY:g} "
                         f"%). Boards in two orientations, one of them facing the camera, or turned about one axis "
                         f"along the image's rows or columns, leave it undetermined: tilt the board by tens of degrees "
                         f"about different axes")
    logger.info("checkerboard calibration from %d images: rms %.3f px", len(img_points), rms)
    camera = Camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], width, height, dist=dist.ravel()[:5])
    return camera, float(rms)


def floor_pose(camera: Camera, image: np.ndarray, pattern: tuple[int, int], square_m: float) -> Camera:
    """The camera's pose w.r.t. the floor, from one image of a checkerboard lying on it (Fig. 3.6).

    Args:
        camera: the calibrated intrinsics and distortion (its pose is ignored).
        image: (H, W) grey or (H, W, 3) BGR uint8, the camera's size.
        pattern: (columns, rows) of inner corners; square_m: side of a square, metres.
    Returns:
        A copy of ``camera`` whose R, t map the floor frame of the module docstring to the
        sensor frame.
    """
    pattern = check_pattern(pattern)
    obj = _board_points(pattern, square_m)
    grey = to_grey("image", image, (np.uint8,))
    if grey.shape != (camera.height, camera.width):
        raise ValueError(f"Expected the floor image to be {camera.height} x {camera.width} like the camera; "
                         f"got {grey.shape[0]} x {grey.shape[1]}")
    corners = find_checkerboard(grey, pattern)
    if corners is None:
        raise ValueError(f"floor image: no {pattern[0]}x{pattern[1]} checkerboard found")
    K, dist = camera.K.cpu().numpy(), camera.dist.cpu().numpy()
    ok, rvec, tvec = cv2.solvePnP(obj, corners, K, dist)
    if not ok:
        raise ValueError("floor image: solvePnP found no pose for the checkerboard")
    return Camera.from_opencv(K, dist, rvec, tvec, camera.width, camera.height)


def levelled_camera(camera: Camera) -> tuple[Camera, float]:
    """The tracker's camera from a floor-posed one: its world frame made sensor-like and ground-levelled.

    :func:`floor_pose` gives a camera whose world frame is the (right-handed, Z up) floor frame;
    the tracker and the simulator want the world frame of :mod:`torch_atr.pose`: origin at the
    camera centre c, y up (the floor's Z), z the optical axis a projected on the floor, x = z × y
    (right). A world point p maps to the floor point c + M p, M = [x | y | z] (columns, floor
    coordinates), so the camera becomes R' = R M, t' = R c + t = 0 (det R' = +1), and the camera
    stands c_Z above the floor.

    Args:
        camera: world frame = floor frame (e.g. from :func:`floor_pose`); its optical axis must
            not be vertical.
    Returns:
        (camera with R' and t' = 0, height of the camera centre above the floor in metres).
    """
    R, t = camera.R.to(torch.float64), camera.t.to(torch.float64)
    if float(torch.linalg.det(R)) > 0:
        raise ValueError("Expected a camera posed in the right-handed floor frame (det R = -1, as floor_pose "
                         "returns); got det R = +1, a world frame that is already sensor-like")
    centre = -(R.T @ t)  # camera centre in the floor frame
    up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    axis = R.T @ torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)  # the optical axis, floor frame
    forward = axis - (axis @ up) * up
    if float(forward.norm()) < 1e-6:
        raise ValueError("Expected a camera whose optical axis is not vertical; the forward direction is undefined")
    forward = forward / forward.norm()
    right = torch.linalg.cross(forward, up)  # forward × up points right in a right-handed, Z-up frame
    M = torch.stack([right, up, forward], dim=1)  # (3, 3) world -> floor axes
    levelled = Camera(camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height,
                      dist=camera.dist, R=R @ M, dtype=camera.K.dtype)
    return levelled, float(centre[2])


def draw_cubes(image: np.ndarray, camera: Camera, cube_size: float, positions,
               color: tuple[int, int, int] = (255, 255, 255), thickness: int = 1) -> np.ndarray:
    """Wireframe cubes standing on the floor, projected with ``camera`` (Fig. 3.7).

    Args:
        image: (H, W) grey or (H, W, 3) BGR uint8; not modified.
        camera: a posed camera (e.g. from :func:`floor_pose`).
        cube_size: edge length, metres.
        positions: (C, 3) world metres of each cube's corner with the smallest x, y, z; a cube
            spans ``cube_size`` from there along +X, +Y and +Z.
        color: BGR; thickness: line width in pixels.
    Returns:
        (H, W, 3) uint8 BGR copy of the image with the cubes drawn. Edges with a point behind the
        camera are left out.
    """
    out = to_grey("image", image, (np.uint8,))
    out = cv2.cvtColor(out, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    if not cube_size > 0:
        raise ValueError(f"Expected a positive cube_size; got {cube_size}")
    pos = as_float_tensor("positions", positions, like=camera.K)
    check_shape("positions", pos, ("C", 3))
    corners = pos[:, None] + cube_size * torch.as_tensor(_CUBE_CORNERS).to(pos)  # (C, 8, 3)
    a, b = (torch.tensor(i, device=pos.device) for i in zip(*_CUBE_EDGES))
    s = torch.linspace(0, 1, _EDGE_SAMPLES).to(pos)[:, None]  # (S, 1)
    edges = corners[:, a, None] * (1 - s) + corners[:, b, None] * s  # (C, 12, S, 3)
    uv, _ = camera.project(edges)  # (C, 12, S, 2)
    for line in uv.reshape(-1, _EDGE_SAMPLES, 2).cpu().numpy():
        if np.isfinite(line).all():
            cv2.polylines(out, [np.round(line).astype(np.int32)], False, color, thickness)
    return out
