"""Calibration against known cameras: IR focal length from targets, checkerboards rendered with a
known K, R, t (cv2.warpPerspective of a board texture, supersampled, blurred, noisy)."""

import json
import math

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
import torch

from torch_atr.calibration import (_canonical_order, _focal_uncertainty, calibrate_checkerboard, camera_from_focal,
                                   draw_cubes, find_checkerboard, floor_pose, focal_from_target, levelled_camera)
from torch_atr.camera import Camera
from torch_atr.data.checkerboard import calibration_poses, render_checkerboard
from torch_atr.data.sequence import load_camera_json

# ---------------------------------------------------------------- IR: focal length from targets

F_IR, W_IR, H_IR = 2100.0, 640, 512
PP = ((W_IR - 1) / 2, (H_IR - 1) / 2)


def _ir_targets(rng: np.random.Generator, n: int, far: float = 3500.0) -> torch.Tensor:
    """(n, 3) sensor-frame target centres at 1000 m to ``far``, inside the field of view."""
    z = rng.uniform(1000, far, n)
    x = z * rng.uniform(-0.13, 0.13, n)  # |u - cx| < 0.13 f = 273 px
    y = z * rng.uniform(-0.1, 0.1, n)
    return torch.tensor(np.stack([x, y, z], -1))


def test_focal_from_position_recovers_f():
    rng = np.random.default_rng(0)
    cam = camera_from_focal(F_IR, W_IR, H_IR)
    p = _ir_targets(rng, 40)
    uv, _ = cam.project(p, world=False)
    rng_m = p.norm(dim=-1)  # slant range
    assert abs(focal_from_target(uv[0], rng_m[0], position_xy=p[0, :2], principal_point=PP) / F_IR - 1) < 1e-9
    noisy = uv + torch.tensor(rng.normal(0, 0.3, uv.shape))
    f = focal_from_target(noisy, rng_m, position_xy=p[:, :2], principal_point=PP)
    assert abs(f / F_IR - 1) < 0.005


def test_focal_from_size_recovers_f():
    """A target of known length across the image plane (aspect 90°) and its pixel extent."""
    rng = np.random.default_rng(1)
    cam = camera_from_focal(F_IR, W_IR, H_IR)
    p = _ir_targets(rng, 30, far=2000.0)  # the thesis picks a near, side-on frame
    length = torch.tensor(rng.uniform(4.0, 7.0, 30))
    half = torch.stack([length / 2, torch.zeros(30), torch.zeros(30)], -1)
    (uv0, _), (uv1, _), (uv, _) = (cam.project(q, world=False) for q in (p - half, p + half, p))
    extent = (uv1[:, 0] - uv0[:, 0]).numpy()
    one = focal_from_target(uv[0].numpy(), float(p[0].norm()), size_m=float(length[0]),
                            extent_px=float(extent[0]), principal_point=PP)
    assert abs(one / F_IR - 1) < 1e-9
    noisy = extent + rng.normal(0, 0.1, 30)  # extents of 4 to 15 px
    f = focal_from_target(uv, p.norm(dim=-1), size_m=length, extent_px=noisy, principal_point=PP)
    assert abs(f / F_IR - 1) < 0.005


def test_camera_from_focal_projects_like_the_pinhole():
    cam = camera_from_focal(800.0, 320, 240)
    uv, _ = cam.project(torch.tensor([[1.0, 2.0, 10.0]], dtype=torch.float64))
    torch.testing.assert_close(uv, torch.tensor([[159.5 + 80.0, 119.5 - 160.0]], dtype=torch.float64))
    cam = camera_from_focal(800.0, 320, 240, principal_point=(150.0, 110.0))
    assert (cam.cx, cam.cy, cam.fx, cam.fy) == (150.0, 110.0, 800.0, 800.0)


def test_focal_from_target_errors():
    uv = np.array([[400.0, 300.0], [200.0, 100.0]])
    with pytest.raises(ValueError, match="exactly one"):
        focal_from_target(uv, [1000.0, 1000.0], principal_point=PP)
    with pytest.raises(ValueError, match="exactly one"):
        focal_from_target(uv, [1000.0, 1000.0], principal_point=PP, position_xy=np.ones((2, 2)), size_m=4.0)
    with pytest.raises(ValueError, match=r"range_m\[1\]"):
        focal_from_target(uv, [1000.0, 5.0], principal_point=PP, position_xy=[[10.0, 2.0], [10.0, 2.0]])
    with pytest.raises(ValueError, match=r"range_m\[0\]"):
        focal_from_target(uv, [-1.0, 5.0], principal_point=PP, position_xy=np.ones((2, 2)))
    with pytest.raises(ValueError, match=r"position_xy.*\(3, 2\)"):
        focal_from_target(uv, 1000.0, principal_point=PP, position_xy=np.ones((3, 2)))
    with pytest.raises(ValueError, match=r"pixel_uv.*\(2, 3\)"):
        focal_from_target(np.ones((2, 3)), 1000.0, principal_point=PP, position_xy=np.ones((2, 2)))
    with pytest.raises(ValueError, match="optical axis"):
        focal_from_target(uv, 1000.0, principal_point=PP, position_xy=np.zeros((2, 2)))
    with pytest.raises(ValueError, match="both size_m and extent_px"):
        focal_from_target(uv, 1000.0, principal_point=PP, size_m=4.0)
    with pytest.raises(ValueError, match=r"extent_px\[1\]"):
        focal_from_target(uv, 1000.0, principal_point=PP, size_m=4.0, extent_px=[3.0, 0.0])
    for pp in [(float("nan"), 255.5), (319.5, float("inf"))]:
        with pytest.raises(ValueError, match="principal_point to be finite"):
            focal_from_target(uv, 1000.0, principal_point=pp, position_xy=[[10.0, 2.0], [10.0, 2.0]])
        with pytest.raises(ValueError, match="principal_point to be finite"):
            focal_from_target(uv, 1000.0, principal_point=pp, size_m=4.0, extent_px=[3.0, 5.0])


# ---------------------------------------------------------------- visible: checkerboards

W, H = 640, 480
K = np.array([[610.0, 0.0, 317.0], [0.0, 615.0, 244.0], [0.0, 0.0, 1.0]])
PATTERN, SQUARE = (9, 6), 0.04
COLS, ROWS = PATTERN
# Board frame: inner corner (c, r) at (c, r, 0) * SQUARE; the square diagonal from corner 0 is dark;
# cameras are on the +Z side. That is the floor frame calibration.py documents.
CORNERS = np.array([[c * SQUARE, r * SQUARE, 0.0] for r in range(ROWS) for c in range(COLS)])
CENTRE = np.array([(COLS - 1) * SQUARE / 2, (ROWS - 1) * SQUARE / 2, 0.0])
# (azimuth°, elevation°, distance m, roll°) of the calibration views
VIEWS = [(0, 55, 0.85, 10), (60, 45, 0.9, 100), (120, 60, 0.8, 200), (180, 50, 0.95, 290),
         (240, 40, 0.9, 45), (300, 65, 0.8, 160), (30, 75, 0.85, 250)]


def _pose(az: float, el: float, dist: float, roll: float, aim=np.zeros(3)):
    """OpenCV world -> camera (R (3, 3), t (3,)) of a camera looking at the board centre."""
    a, e = np.deg2rad(az), np.deg2rad(el)
    centre = CENTRE + dist * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    z = CENTRE + aim - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])  # rows: camera x right, y down, z forward
    c, s = np.cos(np.deg2rad(roll)), np.sin(np.deg2rad(roll))
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ R
    return R, -R @ centre


def _render(R: np.ndarray, t: np.ndarray, rng: np.random.Generator, ss: int = 3) -> np.ndarray:
    """(H, W) uint8 image of the board, rendered at ss x resolution and area-averaged down."""
    ppm, margin = 2000.0, SQUARE  # texture pixels per metre; white margin around the squares
    x0 = -SQUARE - margin
    size = int(round(((COLS + 1) * SQUARE + 2 * margin) * ppm)), int(round(((ROWS + 1) * SQUARE + 2 * margin) * ppm))
    X = (np.arange(size[0]) + 0.5) / ppm + x0
    Y = (np.arange(size[1]) + 0.5) / ppm + x0
    i, j = np.floor(X / SQUARE)[None, :] + 1, np.floor(Y / SQUARE)[:, None] + 1  # square indices
    dark = (i >= 0) & (i <= COLS) & (j >= 0) & (j <= ROWS) & ((i + j) % 2 == 0)
    texture = np.where(dark, 25, 230).astype(np.uint8)
    tex_to_board = np.array([[1 / ppm, 0, 0.5 / ppm + x0], [0, 1 / ppm, 0.5 / ppm + x0], [0, 0, 1]])
    Ks = K * [[ss], [ss], [1]]
    Ks[:2, 2] += (ss - 1) / 2  # pixel centres of the fine grid
    homography = Ks @ np.column_stack([R[:, 0], R[:, 1], t]) @ tex_to_board
    fine = cv2.warpPerspective(texture, homography, (W * ss, H * ss), flags=cv2.INTER_LINEAR, borderValue=128)
    img = cv2.GaussianBlur(cv2.resize(fine, (W, H), interpolation=cv2.INTER_AREA), (0, 0), 0.7)
    return np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8)


def _truth_pixels(R, t, points=CORNERS):
    uv, _ = cv2.projectPoints(points, cv2.Rodrigues(R)[0], t, K, None)
    return uv.reshape(-1, 2)


@pytest.fixture(scope="module")
def views():
    rng = np.random.default_rng(0)
    out = []
    for view in VIEWS:
        R, t = _pose(*view, aim=rng.uniform(-0.04, 0.04, 3))
        px = _truth_pixels(R, t)
        assert ((px > 20) & (px < [W - 20, H - 20])).all(), f"test setup: view {view} leaves the image"
        out.append((_render(R, t, rng), R, t))
    return out


def test_find_checkerboard_corners_in_floor_frame_order(views):
    for image, R, t in views:
        corners = find_checkerboard(image, PATTERN)
        assert corners.shape == (COLS * ROWS, 2)
        assert np.abs(corners - _truth_pixels(R, t)).max() < 0.25
    colour = np.repeat(views[0][0][..., None], 3, axis=2)
    np.testing.assert_allclose(find_checkerboard(colour, PATTERN), find_checkerboard(views[0][0], PATTERN))
    assert find_checkerboard(np.full((H, W), 128, np.uint8), PATTERN) is None


@pytest.mark.parametrize("shape", [(10, 10), (0, 0), (1, 1), (14, 2000), (2000, 14), (10, 10, 3)])
def test_find_checkerboard_in_an_image_too_small_for_the_detector_finds_none(shape):
    """A 10 x 10 image raised OpenCV's adaptiveThreshold assertion instead of finding no board."""
    assert find_checkerboard(np.zeros(shape, np.uint8), PATTERN) is None
    assert find_checkerboard(np.zeros((15, 2000), np.uint8), (3, 3)) is None  # the smallest side it runs on
    with pytest.raises(ValueError, match=r"at least 3 x 3 inner corners \(the fewest OpenCV finds\); got \(2, 5\)"):
        find_checkerboard(np.zeros((H, W), np.uint8), (2, 5))
    for fraction in [(9.5, 6), (9, 6.0001), ("9", 6)]:  # (9.5, 6) was taken for (9, 6)
        with pytest.raises(ValueError, match=r"^Expected pattern to be \(columns, rows\) of inner corners, two int"):
            find_checkerboard(np.zeros((H, W), np.uint8), fraction)
    assert find_checkerboard(np.zeros((H, W), np.uint8), (np.int64(9), 6.0)) is None  # whole numbers of any type


@pytest.mark.parametrize("order", ["same", "half turn", "rows reversed", "columns reversed"])
def test_corner_order_is_canonical_whatever_the_detector_returns(views, order):
    """The detector may start at any board corner; the floor-frame order must not depend on it."""
    image, R, t = views[1]
    truth = _truth_pixels(R, t).reshape(ROWS, COLS, 2).astype(np.float32)
    shuffled = {"same": truth, "half turn": truth[::-1, ::-1], "rows reversed": truth[::-1],
                "columns reversed": truth[:, ::-1]}[order]
    np.testing.assert_array_equal(_canonical_order(image, shuffled), truth)


def test_calibrate_checkerboard_recovers_intrinsics(views):
    camera, rms = calibrate_checkerboard([v[0] for v in views], PATTERN, SQUARE)
    assert rms < 0.2
    got = np.array([camera.fx, camera.fy, camera.cx, camera.cy])
    want = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
    assert np.abs(got / want - 1).max() < 0.01, got
    assert (camera.width, camera.height) == (W, H)


def test_calibrate_checkerboard_is_reproducible_to_the_last_bit(views):
    """OpenCV's solver on two threads gave cameras differing in the 12th digit from run to run."""
    cv2.setNumThreads(2)
    runs = [calibrate_checkerboard([v[0] for v in views], PATTERN, SQUARE) for _ in range(4)]
    assert all(c.to_dict() == runs[0][0].to_dict() and rms == runs[0][1] for c, rms in runs)
    assert cv2.getNumThreads() == 2  # the caller's setting is back


def test_calibrate_checkerboard_names_the_image_without_a_board(views):
    images = [v[0] for v in views[:4]]
    images[2] = np.full((H, W), 200, np.uint8)
    with pytest.raises(ValueError, match="image 2"):
        calibrate_checkerboard(images, PATTERN, SQUARE)
    with pytest.raises(ValueError, match="image 1"):
        calibrate_checkerboard([images[0], images[0][:100], images[0]], PATTERN, SQUARE)
    with pytest.raises(ValueError, match="at least 3"):
        calibrate_checkerboard(images[:2], PATTERN, SQUARE)
    with pytest.raises(ValueError, match="uint8"):
        calibrate_checkerboard([images[0].astype(np.uint16)] * 3, PATTERN, SQUARE)


@pytest.mark.parametrize("flag", ["CALIB_RATIONAL_MODEL", "CALIB_THIN_PRISM_MODEL", "CALIB_TILTED_MODEL"])
def test_calibrate_checkerboard_refuses_extra_distortion_terms(views, flag):
    """K fitted with distortion terms that Camera (k1, k2, p1, p2, k3) cannot keep would be wrong."""
    with pytest.raises(ValueError, match=flag):
        calibrate_checkerboard([v[0] for v in views], PATTERN, SQUARE, flags=cv2.CALIB_FIX_K3 | getattr(cv2, flag))


@pytest.mark.parametrize("flag", ["CALIB_USE_INTRINSIC_GUESS", "CALIB_FIX_FOCAL_LENGTH"])
def test_calibrate_checkerboard_refuses_flags_that_need_a_given_camera_matrix(views, flag):
    """No camera matrix is passed to cv2.calibrateCamera: USE_INTRINSIC_GUESS failed inside OpenCV ('the camera
    matrix is not 3x3'), and FIX_FOCAL_LENGTH held OpenCV's own first estimate, returned as the camera."""
    with pytest.raises(ValueError, match=rf"^Expected flags without {flag}: calibrate_checkerboard fits the camera "
                                         r"from the images alone, with no camera matrix to start from or to hold"):
        calibrate_checkerboard([v[0] for v in views], PATTERN, SQUARE, flags=cv2.CALIB_FIX_K3 | getattr(cv2, flag))


def test_calibrate_checkerboard_refuses_boards_in_one_orientation():
    """Shifted boards on one floor gave fx = 122,585 for 820, the same board thrice 12,687, at rms < 0.13 px."""
    rng = np.random.default_rng(3)
    R, t = _pose(20, 50, 0.9, 0)
    shifted = [_render(R, t + R @ [dx, dy, dz], rng) for dx, dy, dz in
               [(0.0, 0.0, 0.0), (-0.08, 0.0, 0.0), (0.04, -0.06, 0.0)]]  # one plane
    parallel = [_render(R, t + R @ [0.0, 0.0, dz], rng) for dz in (0.0, 0.1, 0.25)]  # moved along the normal
    for images in (shifted, parallel, [shifted[0]] * 3):
        with pytest.raises(ValueError, match="different orientations: the 3 boards' normals are at most 0.[0-4]"):
            calibrate_checkerboard(images, PATTERN, SQUARE)
    # the reviewer's scene: a camera pitched down 25° over boards on the floor (torch_atr's own renderer)
    pitch = np.deg2rad(25)
    floor_cam = Camera(820.0, 800.0, 330.0, 235.0, 640, 480, R=[[1.0, 0.0, 0.0], [0.0, np.cos(pitch), np.sin(pitch)],
                                                                [0.0, -np.sin(pitch), np.cos(pitch)]])
    generator = torch.Generator().manual_seed(2)
    on_floor = [render_checkerboard(floor_cam, PATTERN, 0.25, [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]],
                                    [-1.0 + 0.3 * k, -3.0, 5.0 + 0.5 * k], generator=generator) for k in range(3)]
    with pytest.raises(ValueError, match="Tilt the board between views.*floor_pose"):
        calibrate_checkerboard(on_floor, PATTERN, 0.25)


def test_a_long_focal_length_camera_with_tilted_boards_is_calibrated():
    """A 12,000 px telephoto (the simulator's class of camera) over boards tilted ±25° about x and y:
    through a nominal max(W, H) camera they looked 2.9° apart and were refused; its own fit sees
    them as they are."""
    f = 12000.0
    camera = Camera(f, f, 320.0, 240.0, 640, 480)
    generator = torch.Generator().manual_seed(0)
    square = 0.25
    images = []
    for axis, angle in (("x", 25), ("x", -25), ("y", 25), ("y", -25)):
        R = Rotation.from_euler(axis, angle, degrees=True).as_matrix()
        t = np.array([0.0, 0.0, 80.0]) - R @ [5 * square, 3.5 * square, 0.0]  # the board's centre on the axis
        images.append(render_checkerboard(camera, PATTERN, square, R, t, generator=generator))
    fitted, rms = calibrate_checkerboard(images, PATTERN, square)
    assert rms < 0.3 and abs(fitted.fx / f - 1) < 0.05 and abs(fitted.fy / f - 1) < 0.05


def _turned_pose(rotvec, shift, distance: float = 0.75):
    """OpenCV world -> camera (R, t) of a board facing the camera (board X along the image's x, Y up the
    image, Z towards the camera) turned by ``rotvec`` (radians, camera axes), its centre at (shift, distance)."""
    R = Rotation.from_rotvec(rotvec).as_matrix() @ np.diag([1.0, -1.0, -1.0])
    return R, np.array([shift[0], shift[1], distance]) - R @ CENTRE


@pytest.mark.parametrize("turn", [(0.52, 0.0, 0.0), (0.37, 0.37, 0.0)])
def test_boards_in_two_orientations_one_facing_the_camera_are_refused(turn):
    """Two boards facing the camera (one turned in its plane, shifted) and a third tilted 30°: their normals are
    30° apart, but two orientations one of which faces the camera leave the focal length undetermined (Sturm and
    Maybank, 1999), and OpenCV fitted fx = 111 (about x) and 850 px (about a diagonal) for 610 at rms 0.03 px: they
    were returned as the camera. A fourth board tilted about y determines it."""
    rng = np.random.default_rng(1)
    images = [_render(*_turned_pose(rotvec, shift), rng)
              for rotvec, shift in [((0, 0, 0), (0, 0)), ((0, 0, 0.4), (0.05, 0.03)), (turn, (0, 0))]]
    with pytest.raises(ValueError, match=r"orientations determine the focal length: the 3 views fit fx = .* but only "
                                         r"to ±[\d.e+]+ % \(one standard deviation; at most 10 %\)"):
        calibrate_checkerboard(images, PATTERN, SQUARE)
    camera, _ = calibrate_checkerboard(images + [_render(*_turned_pose((0, -0.52, 0), (0, 0)), rng)], PATTERN, SQUARE)
    assert (camera.fx, camera.fy) == pytest.approx((K[0, 0], K[1, 1]), rel=0.01)


@pytest.mark.parametrize("flags", [cv2.CALIB_FIX_K3, cv2.CALIB_FIX_K3 | cv2.CALIB_FIX_PRINCIPAL_POINT,
                                   cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST, cv2.CALIB_FIX_ASPECT_RATIO],
                         ids=["fix_k3", "fix_k3_principal_point", "fix_k3_zero_tangent", "fix_aspect_ratio"])
def test_focal_uncertainty_is_opencvs_standard_deviation_on_good_views(views, flags):
    """Reference: cv2.calibrateCameraExtended's stdDeviationsIntrinsics (on views that determine the camera; on
    degenerate ones its pseudo-inverse drops the undetermined direction and reported 0.01 px for fx = 111 px)."""
    corners = [find_checkerboard(image, PATTERN) for image, _, _ in views]
    obj = CORNERS.astype(np.float32)
    _, K_fit, dist, rvecs, tvecs, std, _, _ = cv2.calibrateCameraExtended([obj] * len(corners), corners, (W, H), None,
                                                                          None, flags=flags)
    expected = max(std[0, 0] / K_fit[0, 0], std[1, 0] / K_fit[1, 1])
    assert _focal_uncertainty(obj, corners, K_fit, dist, rvecs, tvecs, flags) == pytest.approx(expected, rel=1e-3)


DIST = np.array([-0.28, 0.09, 0.0012, -0.0008, 0.0])  # a wide-angle lens's barrel distortion (k1, k2, p1, p2, k3)


@pytest.fixture(scope="module")
def distorted_views():
    """The calibration views through K with DIST: each fine (3 x 3) pixel takes the board's texture where
    cv2.undistortPoints sends it (the pinhole pixel of its ray), area-averaged, blurred, noisy as ``_render``'s."""
    ss = 3
    Ks = K * [[ss], [ss], [1]]
    Ks[:2, 2] += (ss - 1) / 2
    u, v = np.meshgrid(np.arange(W * ss, dtype=np.float64), np.arange(H * ss, dtype=np.float64))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    points = np.stack([u, v], -1).reshape(-1, 1, 2)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4 (4.10 has no criteria in undistortPoints)
        pinhole = cv2.undistortPointsIter(points, Ks, DIST, None, Ks, criteria)
    else:  # OpenCV 5 folded it into undistortPoints
        pinhole = cv2.undistortPoints(points, Ks, DIST, R=None, P=Ks, criteria=criteria)
    pad = W * ss  # the pinhole image reaches beyond the distorted one's edges
    map_u, map_v = (pinhole.reshape(H * ss, W * ss, 2)[..., k].astype(np.float32) + pad for k in (0, 1))
    ppm, x0 = 2000.0, -2 * SQUARE  # texture pixels per metre; the white margin's corner
    size = int(round((COLS + 3) * SQUARE * ppm)), int(round((ROWS + 3) * SQUARE * ppm))
    i = np.floor(((np.arange(size[0]) + 0.5) / ppm + x0) / SQUARE)[None, :] + 1
    j = np.floor(((np.arange(size[1]) + 0.5) / ppm + x0) / SQUARE)[:, None] + 1
    texture = np.where((i >= 0) & (i <= COLS) & (j >= 0) & (j <= ROWS) & ((i + j) % 2 == 0), 25, 230).astype(np.uint8)
    tex_to_board = np.array([[1 / ppm, 0, 0.5 / ppm + x0], [0, 1 / ppm, 0.5 / ppm + x0], [0, 0, 1]])
    Kp = Ks + [[0, 0, pad], [0, 0, pad], [0, 0, 0]]
    rng = np.random.default_rng(0)
    out = []
    for view in VIEWS:
        R, t = _pose(*view, aim=rng.uniform(-0.04, 0.04, 3))
        sharp = cv2.warpPerspective(texture, Kp @ np.column_stack([R[:, 0], R[:, 1], t]) @ tex_to_board,
                                    (W * ss + 2 * pad, H * ss + 2 * pad), flags=cv2.INTER_LINEAR, borderValue=128)
        fine = cv2.remap(sharp, map_u, map_v, cv2.INTER_LINEAR, borderValue=128)
        img = cv2.GaussianBlur(cv2.resize(fine, (W, H), interpolation=cv2.INTER_AREA), (0, 0), 0.7)
        corners, _ = cv2.projectPoints(CORNERS, cv2.Rodrigues(R)[0], t, K, DIST)
        out.append((np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8), corners.reshape(-1, 2)))
    return out


def test_a_distorting_lens_is_recovered_as_opencv_recovers_it_from_exact_corners(distorted_views):
    """Corners where cv2.projectPoints puts them through the distorted lens; the calibration against the true
    camera and against cv2.calibrateCamera given those exact corners."""
    for image, truth in distorted_views:
        assert np.abs(find_checkerboard(image, PATTERN) - truth).max() < 0.15
    camera, rms = calibrate_checkerboard([image for image, _ in distorted_views], PATTERN, SQUARE)
    exact = [truth.astype(np.float32) for _, truth in distorted_views]
    _, K_ref, dist_ref, _, _ = cv2.calibrateCamera([CORNERS.astype(np.float32)] * len(exact), exact, (W, H), None,
                                                   None, flags=cv2.CALIB_FIX_K3)
    assert rms < 0.1
    for reference, dist in ((K, DIST), (K_ref, dist_ref.ravel())):
        assert (camera.fx, camera.fy) == pytest.approx((reference[0, 0], reference[1, 1]), rel=2e-3)
        assert (camera.cx, camera.cy) == pytest.approx((reference[0, 2], reference[1, 2]), abs=1.0)
        assert camera.dist[0].item() == pytest.approx(dist[0], abs=0.01)
    # The fitted lens takes the corner pixels to the rays the true lens does, within a pixel at the focal length.
    pixels = np.concatenate([truth for _, truth in distorted_views])
    rays = camera.pixel_rays(camera.undistort(torch.tensor(pixels))).numpy()[:, :2] * [1.0, -1.0]  # OpenCV's y down
    np.testing.assert_allclose(rays, cv2.undistortPoints(pixels.reshape(-1, 1, 2), K, DIST).reshape(-1, 2),
                               atol=1.0 / K[0, 0])


def test_calibration_poses_hold_an_unmirrored_board_whose_corners_are_found_where_they_project():
    """The poses had det R = +1 in the sensor-like world: a mirrored board, whose corners were found
    170-220 px from where the pose put corners 0, 1, ... (the detector labels a real board)."""
    camera = Camera(800.0, 800.0, 319.5, 239.5, 640, 480)  # world = sensor frame
    generator = torch.Generator().manual_seed(0)
    flip_y = np.diag([1.0, -1.0, 1.0])  # sensor frame (y up) -> OpenCV's camera frame (y down)
    for R, t in calibration_poses(camera, PATTERN, SQUARE, count=4):
        assert torch.linalg.det(R).item() == pytest.approx(-1.0)  # right-handed board, left-handed world
        found = find_checkerboard(render_checkerboard(camera, PATTERN, SQUARE, R, t, generator=generator), PATTERN)
        assert found is not None
        p_cv = (CORNERS @ R.numpy().T + t.numpy()) @ flip_y
        expected, _ = cv2.projectPoints(p_cv, np.zeros(3), np.zeros(3), camera.K.numpy(), None)
        assert np.abs(found - expected.reshape(-1, 2)).max() < 0.5


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra @ Rb.T) - 1) / 2, -1, 1))))


@pytest.mark.parametrize("view", [(20, 50, 0.9, 0), (200, 35, 1.0, 180), (110, 70, 0.8, 75)])
def test_floor_pose_matches_truth(view):
    rng = np.random.default_rng(1)
    R, t = _pose(*view)
    image = _render(R, t, rng)
    intrinsics = Camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], W, H)
    got = floor_pose(intrinsics, image, PATTERN, SQUARE)
    # truth in the sensor frame (y up): flip OpenCV's y row
    R_true, t_true = np.diag([1.0, -1.0, 1.0]) @ R, np.diag([1.0, -1.0, 1.0]) @ t
    assert _angle_deg(got.R.numpy(), R_true) < 0.5
    assert np.linalg.norm(got.t.numpy() - t_true) / np.linalg.norm(t_true) < 0.01
    # the camera sits above the floor (+Z) in the floor frame
    assert (-got.R.numpy().T @ got.t.numpy())[2] > 0


def test_floor_pose_through_a_distorting_lens_is_opencvs_pose_of_the_exact_corners(distorted_views):
    """A camera with barrel distortion (DIST) against cv2.solvePnP of the exact corners (cv2.projectPoints through
    K and DIST) given the true lens: the pose from undistorted corners, not from the distorted pixels as if pinhole."""
    camera = Camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], W, H, dist=DIST)
    flip_y = np.diag([1.0, -1.0, 1.0])  # OpenCV's camera frame (y down) -> sensor frame (y up)
    for image, truth in distorted_views[:3]:
        got = floor_pose(camera, image, PATTERN, SQUARE)
        ok, rvec, tvec = cv2.solvePnP(CORNERS, truth, K, DIST)
        assert ok
        R_ref, t_ref = flip_y @ cv2.Rodrigues(rvec)[0], flip_y @ tvec.ravel()
        assert _angle_deg(got.R.numpy(), R_ref) < 0.3
        assert np.linalg.norm(got.t.numpy() - t_ref) / np.linalg.norm(t_ref) < 0.005


def test_floor_pose_errors():
    intrinsics = Camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], W, H)
    with pytest.raises(ValueError, match="no 9x6 checkerboard"):
        floor_pose(intrinsics, np.zeros((H, W), np.uint8), PATTERN, SQUARE)
    with pytest.raises(ValueError, match="480 x 640"):
        floor_pose(intrinsics, np.zeros((100, 100), np.uint8), PATTERN, SQUARE)
    for square in (0.0, math.inf, math.nan):  # an infinite square passed, to fail in cv2's solver with cv2.error
        with pytest.raises(ValueError, match=f"square_m; got {square}"):
            floor_pose(intrinsics, np.zeros((H, W), np.uint8), PATTERN, square)
        with pytest.raises(ValueError, match=f"square_m; got {square}"):
            calibrate_checkerboard([], PATTERN, square)


def test_draw_cubes_paints_the_projected_corners():
    rng = np.random.default_rng(2)
    R, t = _pose(40, 45, 0.9, 20)
    image = _render(R, t, rng)
    camera = Camera.from_opencv(K, np.zeros(5), cv2.Rodrigues(R)[0], t, W, H)
    size, positions = 0.05, np.array([[0.0, 0.0, 0.0], [0.2, 0.12, 0.0]])
    red = (0, 0, 255)
    out = draw_cubes(image, camera, size, positions, color=red)
    assert out.shape == (H, W, 3) and image.ndim == 2  # input untouched, output BGR
    unit = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64)
    for p in positions:
        for u, v in np.rint(_truth_pixels(R, t, p + size * unit)).astype(int):
            assert tuple(out[v, u]) == red, (u, v)
    painted = (out != np.repeat(image[..., None], 3, axis=2)).any(-1)
    corners = np.rint(_truth_pixels(R, t, np.concatenate([p + size * unit for p in positions])))
    (u0, v0), (u1, v1) = corners.min(0).astype(int), corners.max(0).astype(int)
    assert painted.sum() > 100 and not painted[:v0].any() and not painted[v1 + 1:].any()
    assert not painted[:, :u0].any() and not painted[:, u1 + 1:].any()
    # a cube behind the camera is left out without error
    behind = -R.T @ t + 2 * (-R.T @ t - CENTRE)
    np.testing.assert_array_equal(draw_cubes(out, camera, size, behind[None]), out)
    with pytest.raises(ValueError, match=r"positions.*\(C, 3\)"):
        draw_cubes(image, camera, size, np.zeros((2, 2)))


def test_a_sign_mix_up_or_no_frame_is_named_not_returned():
    """A target right of the principal point with x < 0 fitted f = -10000 (returned as is)."""
    right = np.array([[PP[0] + 20.0, PP[1]]])
    with pytest.raises(ValueError, match="not positive: .*u grows right with x, v grows down while y grows up"):
        focal_from_target(right, 1000.0, principal_point=PP, position_xy=[[-2.0, 0.0]])
    assert focal_from_target(right, 1000.0, principal_point=PP, position_xy=[[2.0, 0.0]]) == pytest.approx(1e4, 1e-3)
    with pytest.raises(ValueError, match="pixel_uv to hold at least one frame"):
        focal_from_target(np.zeros((0, 2)), np.zeros(0), principal_point=PP, position_xy=np.zeros((0, 2)))


@pytest.mark.parametrize("yaw_deg", [0.0, 40.0, -130.0])
def test_levelled_camera_of_a_hand_worked_floor_pose(yaw_deg, tmp_path):
    """A camera 2 m above the floor at (0.3, -1, 2), tilted 30° down along the floor direction turned yaw_deg from +Y
    towards +X, built as OpenCV's pose: levelled, it is the simulator's tilt matrix (scene_camera's) at height 2 m,
    sees floor points where the posed camera does, and round-trips through a camera.json bit for bit."""
    tilt, yaw = math.radians(30.0), math.radians(yaw_deg)
    forward = np.array([math.sin(yaw), math.cos(yaw), 0.0])  # floor frame: X, Y on the floor, Z up
    right = np.array([math.cos(yaw), -math.sin(yaw), 0.0])
    axis = math.cos(tilt) * forward - math.sin(tilt) * np.array([0.0, 0.0, 1.0])
    R_cv = np.stack([right, np.cross(axis, right), axis])  # rows: OpenCV camera x (right), y (down), z (optical axis)
    assert np.cross(axis, right)[2] < 0  # y points down
    centre = np.array([0.3, -1.0, 2.0])
    dist = np.array([-0.1, 0.02, 0.0, 0.0, 0.0])
    posed = Camera.from_opencv(K, dist, cv2.Rodrigues(R_cv)[0], -R_cv @ centre, W, H)
    levelled, height = levelled_camera(posed)
    assert height == pytest.approx(2.0, abs=1e-12)
    c, s = math.cos(tilt), math.sin(tilt)
    np.testing.assert_allclose(levelled.R.numpy(), [[1, 0, 0], [0, c, s], [0, -s, c]], atol=1e-12)
    np.testing.assert_allclose(levelled.t.numpy(), 0.0, atol=1e-12)
    # A floor point 6 m ahead and 1.5 m right: world (1.5, -2, 6) in the levelled frame.
    floor_point = centre + 6.0 * forward + 1.5 * right - 2.0 * np.array([0.0, 0.0, 1.0])
    uv_posed, _ = posed.project(torch.tensor(floor_point))
    uv_levelled, _ = levelled.project(torch.tensor([1.5, -2.0, 6.0], dtype=torch.float64))
    expected, _ = cv2.projectPoints(floor_point[None], cv2.Rodrigues(R_cv)[0], -R_cv @ centre, K, dist)
    np.testing.assert_allclose(uv_posed.numpy(), expected.reshape(2), atol=1e-9)
    np.testing.assert_allclose(uv_levelled.numpy(), expected.reshape(2), atol=1e-9)
    path = tmp_path / "camera.json"
    path.write_text(json.dumps(levelled.to_dict()), encoding="utf-8")
    assert load_camera_json(path).to_dict() == levelled.to_dict()


def test_focal_uncertainty_of_many_views_is_opencvs_without_the_whole_jacobian():
    """200 views of the board: the Jacobian over every pose is 21 600 x 1209, and building and decomposing it
    peaked at 850 MB (and 10 s); each view's pose is eliminated first, so the peak stays a few MB. Reference:
    cv2.calibrateCameraExtended's stdDeviationsIntrinsics on exact projections with 0.1 px of noise."""
    import tracemalloc

    rng = np.random.default_rng(3)
    obj = CORNERS.astype(np.float32)
    corners = []
    for _ in range(200):
        R, t = _pose(rng.uniform(-40, 40), rng.uniform(45, 80), rng.uniform(0.6, 0.9), rng.uniform(-30, 30))
        uv, _ = cv2.projectPoints(CORNERS, cv2.Rodrigues(R)[0], t, K, None)
        corners.append((uv + rng.normal(0, 0.1, uv.shape)).astype(np.float32))
    flags = cv2.CALIB_FIX_K3
    _, K_fit, dist, rvecs, tvecs, std, _, _ = cv2.calibrateCameraExtended([obj] * len(corners), corners, (W, H), None,
                                                                          None, flags=flags)
    tracemalloc.start()
    try:
        uncertainty = _focal_uncertainty(obj, corners, K_fit, dist, rvecs, tvecs, flags)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert uncertainty == pytest.approx(max(std[0, 0] / K_fit[0, 0], std[1, 0] / K_fit[1, 1]), rel=1e-3)
    assert peak < 20e6
