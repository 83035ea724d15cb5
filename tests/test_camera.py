"""torch_atr.camera.Camera against OpenCV and its own inverses."""

import math

import cv2
import numpy as np
import pytest
import torch

from torch_atr.camera import Camera
from torch_atr.validate import InputError

K_CV = np.array([[820.0, 0.0, 322.5], [0.0, 790.0, 251.25], [0.0, 0.0, 1.0]])
DIST_CV = np.array([-0.21, 0.08, 0.0012, -0.0007, -0.015])
RVEC = np.array([0.05, -0.3, 0.12])
TVEC = np.array([0.4, -1.1, 2.5])


def _camera() -> Camera:
    return Camera.from_opencv(K_CV, DIST_CV, RVEC, TVEC, width=640, height=512)


def _points_in_front(n: int, seed: int) -> np.ndarray:
    """(n, 3) world points 5-40 m in front of the OpenCV camera (RVEC, TVEC), within ~25° of the axis."""
    rng = np.random.default_rng(seed)
    depth = rng.uniform(5, 40, n)
    xy = rng.uniform(-0.45, 0.45, (n, 2)) * depth[:, None]
    p_cam = np.column_stack([xy, depth])
    R_cv, _ = cv2.Rodrigues(RVEC)
    return (p_cam - TVEC) @ R_cv  # R_cvᵀ (p_cam − t)


@pytest.mark.parametrize("dist", [DIST_CV, np.zeros(5)])  # without distortion project skips its terms
def test_project_matches_cv2_project_points(dist):
    cam = Camera.from_opencv(K_CV, dist, RVEC, TVEC, width=640, height=512)
    pts = _points_in_front(200, seed=0)
    rvec, tvec = cam.opencv_pose()
    ref, _ = cv2.projectPoints(pts, rvec, tvec, cam.K.numpy(), cam.dist.numpy())
    uv, depth = cam.project(torch.from_numpy(pts))
    np.testing.assert_allclose(uv.numpy(), ref.reshape(-1, 2), atol=1e-6)
    R_cv, _ = cv2.Rodrigues(RVEC)
    np.testing.assert_allclose(depth.numpy(), pts @ R_cv.T[:, 2] + TVEC[2], atol=1e-9)


def test_opencv_pose_of_a_sensor_like_world_takes_y_negated_points():
    """World = sensor-like (y up, left-handed, det R = +1): OpenCV sees the world points as (x, −y, z)."""
    a = 0.2  # pitched down by a, turned by 0.1 rad, centred 4 m up
    R = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(a), math.sin(a)], [0.0, -math.sin(a), math.cos(a)]])
    R = R @ np.array([[math.cos(0.1), 0.0, -math.sin(0.1)], [0.0, 1.0, 0.0], [math.sin(0.1), 0.0, math.cos(0.1)]])
    for rot in (np.eye(3), R):
        cam = Camera(700.0, 710.0, 300.0, 260.0, 640, 512, dist=DIST_CV, R=rot, t=-rot @ np.array([0.0, 4.0, 0.0]))
        pts = np.random.default_rng(3).uniform([-8, -2, 15], [8, 3, 40], (100, 3))
        rvec, tvec = cam.opencv_pose()
        ref, _ = cv2.projectPoints(pts * [1.0, -1.0, 1.0], rvec, tvec, cam.K.numpy(), cam.dist.numpy())
        np.testing.assert_allclose(cam.project(torch.from_numpy(pts))[0].numpy(), ref.reshape(-1, 2), atol=1e-6)


def test_project_without_opencv_helpers():
    """A point on the optical axis lands on (cx, cy); +y in the sensor frame is up (smaller v)."""
    cam = Camera(500.0, 400.0, 320.0, 240.0, 640, 480)
    uv, _ = cam.project(torch.tensor([[0.0, 0.0, 10.0], [1.0, 2.0, 10.0]]))
    np.testing.assert_allclose(uv.numpy(), [[320.0, 240.0], [370.0, 160.0]], atol=1e-4)


def test_from_opencv_round_trip():
    cam = _camera()
    rvec, tvec = cam.opencv_pose()
    np.testing.assert_allclose(rvec, RVEC, atol=1e-12)
    np.testing.assert_allclose(tvec, TVEC, atol=1e-12)
    np.testing.assert_allclose(cam.K.numpy(), K_CV)
    np.testing.assert_allclose(cam.dist.numpy(), DIST_CV)
    again = Camera.from_opencv(cam.K.numpy(), cam.dist.numpy(), rvec, tvec, cam.width, cam.height)
    for name in ("K", "dist", "R", "t"):
        torch.testing.assert_close(getattr(again, name), getattr(cam, name), rtol=0, atol=1e-12)
    # OpenCV's world frame is right-handed and the sensor frame (y up) left-handed.
    assert torch.linalg.det(cam.R).item() == pytest.approx(-1.0)


def test_pixel_rays_invert_project_without_distortion():
    cam = Camera(600.0, 610.0, 300.5, 200.25, 640, 480)
    pts = torch.from_numpy(_points_in_front(50, seed=1))  # identity pose: sensor = world
    uv, depth = cam.project(pts)
    rays = cam.pixel_rays(uv)
    torch.testing.assert_close(rays * depth.unsqueeze(-1), pts, rtol=0, atol=1e-9)
    grid = torch.tensor([[0.0, 0.0], [639.0, 479.0], [17.5, 301.0]], dtype=torch.float64)
    uv_again, _ = cam.project(cam.pixel_rays(grid) * 7.0)
    torch.testing.assert_close(uv_again, grid, rtol=0, atol=1e-9)


def test_undistort_matches_cv2_for_any_batch_shape_and_takes_no_points():
    """No points (a frame without detections) raised AttributeError: cv2 returns None for them."""
    cam = _camera()
    uv = torch.tensor([[0.0, 0.0], [639.0, 511.0], [17.5, 301.0], [322.5, 251.25]], dtype=torch.float64)
    for batch in (uv, uv.reshape(2, 2, 2), uv[0]):
        out = cam.undistort(batch)
        assert out.shape == batch.shape
        x = (out[..., 0] - K_CV[0, 2]) / K_CV[0, 0]  # OpenCV's normalised coordinates, y down
        y = (out[..., 1] - K_CV[1, 2]) / K_CV[1, 1]
        rays = torch.stack([x, y, torch.ones_like(x)], -1).reshape(-1, 3).numpy()
        again, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K_CV, DIST_CV)  # distorts them back
        np.testing.assert_allclose(again.reshape(batch.shape), batch.numpy(), atol=1e-9)
    for empty in (torch.zeros(0, 2), torch.zeros(3, 0, 2, dtype=torch.float64)):
        out = cam.undistort(empty)
        assert out.shape == empty.shape and out.dtype == empty.dtype


def test_points_behind_the_camera_are_nan():
    cam = _camera()
    p_sensor = torch.tensor([[0.0, 0.0, -1.0], [1.0, 1.0, 0.0], [0.2, 0.1, 3.0]], dtype=torch.float64)
    uv, depth = cam.project(p_sensor, world=False)
    assert torch.isnan(uv[:2]).all() and torch.isfinite(uv[2]).all()
    assert depth.tolist() == [-1.0, 0.0, 3.0]


def test_points_beyond_the_distortion_fold_are_nan_not_imaged_inside():
    """OpenCV's radial polynomial folds back: with this barrel lens a point 63° off the axis, far
    outside the field of view, lands inside the image, on a pixel whose ray (cv2.undistortPoints)
    points 9° off the axis. Its uv is NaN, as behind the camera; points inside the fold keep cv2's."""
    dist = np.array([-0.35, 0.15, 0.0, 0.0, -0.03])  # d(r · radial)/dr = 0 at r² = 2.297 (56°)
    cam = Camera(500.0, 500.0, 319.5, 239.5, 640, 480, dist=dist)
    p = np.array([[20.0, 0.0, 10.0], [3.0, -2.0, 10.0], [1.4, 0.5, 1.0], [1.6, 0.0, 1.0]])  # r² 4, 0.13, 2.21, 2.56
    ref, _ = cv2.projectPoints(p * [1.0, -1.0, 1.0], np.zeros(3), np.zeros(3), cam.K.numpy(), dist)
    ref = ref.reshape(-1, 2)
    assert 0 < ref[0, 0] < 640 and 0 < ref[0, 1] < 480  # OpenCV images the first point inside the frame ...
    ray = cv2.undistortPoints(ref[:1].reshape(1, 1, 2), cam.K.numpy(), dist).ravel()
    assert abs(ray[0] - 0.16) < 0.01  # ... on a pixel that sees another direction (x/z = 0.16, not 2)
    uv, depth = cam.project(torch.from_numpy(p), world=False)
    assert torch.isnan(uv[[0, 3]]).all() and depth[0] == 10.0
    np.testing.assert_allclose(uv[1:3].numpy(), ref[1:3], atol=1e-9)
    # Their pixels' rays are theirs (undistortion converges slowly near the fold: 1.6e-7 there).
    np.testing.assert_allclose(cam.pixel_rays(cam.undistort(uv[1:3])).numpy(), p[1:3] / p[1:3, 2:], atol=1e-6)


def test_the_fold_of_a_lens_with_two_turning_points_is_the_first():
    """k1 = −0.5, k2 = 0.05: r (1 + k1 r² + k2 r⁴) rises, falls from r² = 0.764 and rises again from
    r² = 5.236. Brute force: the first r of a dense grid where the radial map stops rising. The fold
    is there, not at the second turn: a point at r² = 2, between them, is NaN like one beyond both,
    and points inside the fold keep cv2's pixels."""
    from torch_atr.camera import _fold_r2

    k1, k2 = -0.5, 0.05
    r = np.linspace(0.0, 3.0, 300_001)  # steps of 1e-5
    radial = r * (1 + k1 * r ** 2 + k2 * r ** 4)
    first = r[np.argmax(np.diff(radial) <= 0)]
    assert _fold_r2(k1, k2, 0.0) == pytest.approx(first ** 2, abs=1e-4)
    dist = np.array([k1, k2, 0.0, 0.0, 0.0])
    cam = Camera(500.0, 500.0, 319.5, 239.5, 640, 480, dist=dist)
    x = np.sqrt([0.5, 0.75, 2.0, 9.0])  # r² inside, just inside, between the turns, beyond both
    p = np.column_stack([x, np.zeros(4), np.ones(4)])
    uv, _ = cam.project(torch.from_numpy(p), world=False)
    assert torch.isfinite(uv[:2]).all() and torch.isnan(uv[2:]).all()
    ref, _ = cv2.projectPoints(p[:2] * [1.0, -1.0, 1.0], np.zeros(3), np.zeros(3), cam.K.numpy(), dist)
    np.testing.assert_allclose(uv[:2].numpy(), ref.reshape(-1, 2), atol=1e-9)


def test_points_on_the_camera_plane_are_nan_without_distortion_too():
    """Depth 0 is not in front of the camera: without distortion (project skips its terms) a point
    at z = 0 gave x / 0 = ±inf, an infinite pixel where z >= 0 counted as seen; it is NaN, like one
    behind the camera, as the docstring promises (depth <= 0)."""
    cam = Camera(600.0, 610.0, 300.5, 200.25, 640, 480)
    p_sensor = torch.tensor([[1.0, 1.0, 0.0], [-2.0, 0.5, 0.0], [1.0, 0.0, -0.0], [0.2, 0.1, 3.0]],
                            dtype=torch.float64)
    uv, depth = cam.project(p_sensor, world=False)
    assert torch.isnan(uv[:3]).all() and torch.isfinite(uv[3]).all()
    assert depth.tolist() == [0.0, 0.0, 0.0, 3.0]


def test_project_batch_shapes_and_bad_shape():
    cam = _camera()
    pts = torch.from_numpy(_points_in_front(12, seed=2)).reshape(3, 4, 3)
    uv, depth = cam.project(pts)
    assert uv.shape == (3, 4, 2) and depth.shape == (3, 4)
    torch.testing.assert_close(uv[1], cam.project(pts[1])[0])
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\); got \(4, 2\)"):
        cam.project(torch.zeros(4, 2))


def test_dict_round_trip_and_errors():
    cam = _camera()
    again = Camera.from_dict(cam.to_dict())
    for name in ("K", "dist", "R", "t"):
        torch.testing.assert_close(getattr(again, name), getattr(cam, name), rtol=0, atol=0)
    assert (again.width, again.height) == (640, 512)
    d = cam.to_dict()
    del d["fy"], d["height"]
    with pytest.raises(ValueError, match=r"calib\.json: missing key\(s\) fy, height"):
        Camera.from_dict(d, source="calib.json")
    with pytest.raises(ValueError, match=r"unknown key\(s\) focal"):
        Camera.from_dict({**cam.to_dict(), "focal": 1.0})
    with pytest.raises(ValueError, match="focal lengths"):
        Camera(-1.0, 500.0, 320.0, 240.0, 640, 480)
    with pytest.raises(ValueError, match="principal point"):
        Camera(500.0, 500.0, math.nan, 240.0, 640, 480)


@pytest.mark.parametrize("key, value, message", [
    ("fx", -1.0, "key 'fx': expected a finite number > 0; got -1.0"),
    ("fx", math.inf, "key 'fx': expected a finite number > 0; got inf"),
    ("cx", math.nan, "key 'cx': expected a finite number; got nan"),
    ("cy", True, "key 'cy': expected a finite number; got True"),
    ("fy", "500", "key 'fy': expected a finite number > 0; got '500'"),
    ("width", 640.5, "key 'width': expected an integer; got 640.5"),
    ("width", math.inf, "key 'width': expected an integer; got inf"),
    ("height", 10 ** 9, r"height: expected an integer in \[1, 16384\]; got 1000000000"),
    ("dist", [0.1, 0, 0, 0], r"key 'dist': expected a list of 5 numbers"),
    ("t", [0, 0, math.inf], r"key 't'\[2\]: expected a finite number; got inf"),
    ("R", [[1, 0, 0], [0, 1, 0], [0, 0, 2]], r"key 'R': expected a rotation .*differs from I by 3"),
    ("R", [[1, 0, 0], [0, 1, 0]], r"key 'R': expected a 3 x 3 matrix"),
])
def test_from_dict_refuses_what_a_camera_file_must_not_hold(key, value, message):
    d = {**_camera().to_dict(), key: value}
    with pytest.raises(InputError, match=f"^calib.json, {message}" if message.startswith("key") else message):
        Camera.from_dict(d, source="calib.json")


def test_rotated_camera_sees_rotated_world():
    """A camera turned 30° from +z towards +x has the world point at that bearing on its optical axis."""
    a = math.radians(30.0)
    # Sensor axes expressed in the world: forward = (sin a, 0, cos a), right = (cos a, 0, -sin a), up = +y.
    R = torch.tensor([[math.cos(a), 0.0, -math.sin(a)], [0.0, 1.0, 0.0], [math.sin(a), 0.0, math.cos(a)]],
                     dtype=torch.float64)
    cam = Camera(500.0, 500.0, 320.0, 240.0, 640, 480, R=R)
    uv, depth = cam.project(torch.tensor([20 * math.sin(a), 0.0, 20 * math.cos(a)], dtype=torch.float64))
    torch.testing.assert_close(uv, torch.tensor([320.0, 240.0], dtype=torch.float64))
    assert depth.item() == pytest.approx(20.0)


@pytest.mark.parametrize("args, kwargs, message", [
    ((500.0, 500.0, 320.0, 240.0, 640.7, 480), {}, "whole image size"),  # was silently 640
    ((500.0, 500.0, 320.0, 240.0, 640, 480), {"R": torch.zeros(3, 3)}, "R: expected a rotation"),
    ((500.0, 500.0, 320.0, 240.0, 640, 480), {"dist": [math.nan] * 5}, "dist to be finite"),
    ((500.0, 500.0, 320.0, 240.0, 640, 480), {"t": [0.0, math.inf, 0.0]}, "t to be finite"),
    (("500", 500.0, 320.0, 240.0, 640, 480), {}, "fx to be a number; got '500'"),
])
def test_the_constructor_checks_what_from_dict_checks(args, kwargs, message):
    """A zero R or NaN distortion was accepted and projected every point to NaN."""
    with pytest.raises(ValueError, match=message):
        Camera(*args, **kwargs)
    cam = Camera(np.float64(500.0), torch.tensor(500.0), 320, 240.0, np.int64(640), 480.0)  # any real scalars
    assert (cam.fx, cam.width, cam.height) == (500.0, 640, 480)


@pytest.mark.parametrize("K, rvec, tvec, message", [
    (K_CV[:2], RVEC, TVEC, r"K to have shape \(3, 3\); got \(2, 3\)"),  # was taken: fx, fy, cx, cy are in it
    (K_CV.ravel(), RVEC, TVEC, r"K to have shape \(3, 3\); got \(9,\)"),  # was IndexError
    (K_CV + [[0, 40.0, 0], [0, 0, 0], [0, 0, 0]], RVEC, TVEC, r"no skew\); got \[\[820\.0, 40\.0"),  # was dropped
    (K_CV * 2, RVEC, TVEC, r"\[0, 0, 1\]\] \(this camera has no skew\); got .*\[0\.0, 0\.0, 2\.0\]\]"),
    (K_CV, cv2.Rodrigues(RVEC)[0], TVEC, r"rvec to hold 3 numbers .*got shape \(3, 3\)"),  # a rotation matrix
    (K_CV, RVEC, TVEC[:2], r"tvec to hold 3 numbers .*got shape \(2,\)"),
    (K_CV, [np.nan, 0.1, 0.2], TVEC, r"rvec to be finite; got \[nan, 0.1, 0.2\]"),  # was named R[0][0]
    (K_CV, RVEC, [0.0, np.inf, 1.0], r"tvec to be finite; got \[0.0, inf, 1.0\]"),
])
def test_from_opencv_names_a_matrix_it_cannot_take(K, rvec, tvec, message):
    """A (2, 3) K was read as fx, fy, cx, cy and a skew dropped, silently; a flat K or a rotation
    matrix for rvec raised numpy's IndexError or reshape error, naming neither."""
    with pytest.raises(ValueError, match=message):
        Camera.from_opencv(K, DIST_CV, rvec, tvec, 640, 512)
    cam = Camera.from_opencv(K_CV, DIST_CV, RVEC.reshape(3, 1), TVEC.reshape(1, 3), 640, 512)  # OpenCV's shapes
    torch.testing.assert_close(cam.R, _camera().R, rtol=0, atol=0)


def test_from_opencv_refuses_distortion_terms_it_cannot_keep():
    """8 rational or 12 thin-prism coefficients were cut to 5 silently: 215 px off cv2.projectPoints."""
    pts = _points_in_front(50, seed=4)
    for count in (8, 12, 14):
        extra = np.zeros(count - 5)
        extra[0] = 0.05
        with pytest.raises(ValueError, match=rf"k3.*got {count} coefficients with nonzero {{'dist\[5\]': 0.05}}"):
            Camera.from_opencv(K_CV, np.concatenate([DIST_CV, extra]), RVEC, TVEC, 640, 512)
        # zeros beyond k3 are the 5-term model: kept, and projecting as OpenCV does with all of them
        dist = np.concatenate([DIST_CV, np.zeros(count - 5)])
        cam = Camera.from_opencv(K_CV, dist, RVEC, TVEC, 640, 512)
        ref, _ = cv2.projectPoints(pts, RVEC, TVEC, K_CV, dist)
        np.testing.assert_allclose(cam.project(torch.from_numpy(pts))[0].numpy(), ref.reshape(-1, 2), atol=1e-6)
    for dist in (DIST_CV[:4], DIST_CV[:5], np.zeros(0), None):  # 4 or 5 coefficients, or none: padded with zeros
        cam = Camera.from_opencv(K_CV, dist, RVEC, TVEC, 640, 512)  # None was a NaN k1: "dist to be finite"
        ref, _ = cv2.projectPoints(pts, RVEC, TVEC, K_CV, dist if dist is not None and dist.size else None)
        np.testing.assert_allclose(cam.project(torch.from_numpy(pts))[0].numpy(), ref.reshape(-1, 2), atol=1e-6)


@pytest.mark.parametrize("change, message", [
    ({"fx": 1e300}, r"focal lengths in \[0\.001, 1e\+08\] px; got fx=1e\+300"),
    ({"fy": 1e-300}, r"focal lengths in \[0\.001, 1e\+08\] px; got fy=1e-300"),
    ({"fx": math.nan}, r"got fx=nan"),
    ({"cx": -1e30}, r"principal point with coordinates in \[-1e\+08, 1e\+08\] px; got cx=-1e\+30"),
    ({"cy": math.inf}, r"got cy=inf"),
    ({"width": 1e30}, r"whole image size of 1 to 16384 px a side; got width=1e\+30"),
    ({"height": 16385}, r"whole image size of 1 to 16384 px a side; got height=16385\.0"),
    ({"width": 0}, r"got width=0\.0"),
    ({"dist": [0.1, 0.0, 0.0, 0.0, 1e300]},
     r"dist to be finite, each of magnitude at most 1e\+06; got dist\[4\]=1e\+300"),
    ({"dist": [0.1, -2e6, 0.0, 0.0, 0.0]}, r"got dist\[1\]=-2000000\.0"),
    ({"t": [0.0, 0.0, 1e10]}, r"t to be finite, each of magnitude at most 1e\+09 m; got t\[2\]=10000000000\.0"),
])
def test_the_constructor_refuses_absurd_magnitudes(change, message):
    """Distortion of 1e300, a width of 1e30 px or a focal length of 1e300 were taken and projected
    to inf or NaN; each is refused naming the argument and its value."""
    args = {"fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0, "width": 640, "height": 480}
    with pytest.raises(ValueError, match=message):
        Camera(**{**args, **change})
    bounds = {"fx": 1e8, "fy": 1e-3, "cx": -1e8, "cy": 1e8, "width": 16384, "height": 1,
              "dist": [1e6, -1e6, 1e6, -1e6, 1e6], "t": [1e9, -1e9, 1e9]}
    cam = Camera(**{**args, **{k: bounds[k] for k in change}})  # the bounds themselves are taken
    assert cam.to_dict()[next(iter(change))] == bounds[next(iter(change))]


def test_files_and_opencv_results_with_absurd_magnitudes_are_refused_naming_them():
    d = {**_camera().to_dict(), "dist": [0.0, 0.0, 0.0, 0.0, 1e300]}
    with pytest.raises(InputError, match=r"^calib\.json: Expected dist to be finite.*got dist\[4\]=1e\+300$"):
        Camera.from_dict(d, source="calib.json")
    with pytest.raises(InputError, match=r"^calib\.json: Expected focal lengths .*got fy=1e\+300$"):
        Camera.from_dict({**_camera().to_dict(), "fy": 1e300}, source="calib.json")
    with pytest.raises(ValueError, match=r"got fx=1e\+300"):
        Camera.from_opencv(K_CV * [[1e300 / 820, 1, 1], [1, 1, 1], [1, 1, 1]], DIST_CV, RVEC, TVEC, 640, 512)
    with pytest.raises(ValueError, match=r"got dist\[2\]=1e\+300"):
        Camera.from_opencv(K_CV, [0.0, 0.0, 1e300], RVEC, TVEC, 640, 512)
    with pytest.raises(ValueError, match=r"Expected tvec to be finite, each of magnitude at most 1e\+09 m; "
                                         r"got tvec\[1\]=1e\+300"):
        Camera.from_opencv(K_CV, DIST_CV, RVEC, [0.0, 1e300, 1.0], 640, 512)
    with pytest.raises(ValueError, match=r"got width=1e\+30"):
        Camera.from_opencv(K_CV, DIST_CV, RVEC, TVEC, 1e30, 512)


def test_the_image_size_travels_in_the_state_dict():
    """Only K, dist, R and t were buffers: a 640 x 512 camera's state loaded into a 10 x 10 one kept
    10 x 10, and render_mask rasterised into that."""
    big, small = Camera(1000.0, 1000.0, 320.0, 256.0, 640, 512), Camera(5.0, 5.0, 5.0, 5.0, 10, 10)
    small.load_state_dict(big.state_dict())
    assert (small.width, small.height, small.fx) == (640, 512, 1000.0)
    state = big.state_dict()
    state["_extra_state"] = {"width": 0, "height": 512}
    with pytest.raises(ValueError, match="whole image size of 1 to 16384 px a side; got width=0"):
        small.load_state_dict(state)
