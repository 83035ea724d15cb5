"""Pose geometry (torch_atr.pose): view vectors, body -> world, the view of a pose, against closed forms."""

import math

import numpy as np
import pytest
import torch

from torch_atr.camera import Camera
from torch_atr.pose import VehiclePose, body_to_world, camera_centre, view_of_pose, view_vectors

TWO_PI = 2 * math.pi


def test_view_vectors_axes_and_unit_norm():
    theta = torch.tensor([0.0, math.pi / 2, math.pi, 0.3], dtype=torch.float64)
    phi = torch.tensor([0.0, 0.0, 0.0, math.pi / 2], dtype=torch.float64)
    u = view_vectors(theta, phi)
    expected = torch.tensor([[1.0, 0, 0], [0, 1.0, 0], [-1.0, 0, 0], [0, 0, 1.0]], dtype=torch.float64)
    torch.testing.assert_close(u, expected, atol=1e-12, rtol=0)
    g = torch.Generator().manual_seed(0)
    u = view_vectors(torch.rand(50, generator=g) * 7, torch.rand(50, generator=g) * 1.5)
    torch.testing.assert_close(u.norm(dim=1), torch.ones(50))


def test_view_vectors_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="phi"):
        view_vectors(torch.zeros(3), torch.zeros(4))
    with pytest.raises(ValueError, match="theta"):
        view_vectors(torch.zeros(3, 1), torch.zeros(3))


def test_body_to_world_axes_and_handedness():
    gen = torch.Generator().manual_seed(1)
    h = torch.rand(6, generator=gen, dtype=torch.float64) * TWO_PI
    pos = torch.randn(6, 3, generator=gen, dtype=torch.float64) * 10
    R, t = body_to_world(VehiclePose(pos[:, 0], pos[:, 1], pos[:, 2], h))
    assert R.shape == (6, 3, 3) and t.shape == (6, 3)
    torch.testing.assert_close(t, pos)
    zero = torch.zeros_like(h)
    torch.testing.assert_close(R[:, :, 0], torch.stack([h.sin(), zero, h.cos()], -1))  # X: direction of travel
    torch.testing.assert_close(R[:, :, 1], torch.stack([-h.cos(), zero, h.sin()], -1))  # Y: the driver's left
    torch.testing.assert_close(R[:, :, 2], torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64).expand(6, 3))
    torch.testing.assert_close(R.transpose(1, 2) @ R, torch.eye(3, dtype=torch.float64).expand(6, 3, 3))
    # The world frame (x right, y up, z forward) is left-handed: an unmirrored vehicle has det −1 there,
    # and +1 once carried into OpenCV's right-handed camera frame (y down).
    torch.testing.assert_close(torch.linalg.det(R), -torch.ones(6, dtype=torch.float64))
    flip = torch.diag(torch.tensor([1.0, -1.0, 1.0], dtype=torch.float64))
    torch.testing.assert_close(torch.linalg.det(flip @ R), torch.ones(6, dtype=torch.float64))
    for n in range(6):
        R_n, t_n = body_to_world(VehiclePose(float(pos[n, 0]), float(pos[n, 1]), float(pos[n, 2]), float(h[n])))
        torch.testing.assert_close(R_n, R[n])
        torch.testing.assert_close(t_n, t[n])


def test_body_to_world_pitch_and_roll():
    R, _ = body_to_world(VehiclePose(0.0, 0.0, 0.0, 0.0, pitch=0.2))
    torch.testing.assert_close(R[:, 0], torch.tensor([0.0, -math.sin(0.2), math.cos(0.2)], dtype=torch.float64))
    R, _ = body_to_world(VehiclePose(0.0, 0.0, 0.0, 0.0, roll=0.3))
    torch.testing.assert_close(R[:, 1], torch.tensor([-math.cos(0.3), math.sin(0.3), 0.0], dtype=torch.float64))


def test_view_of_pose_closed_forms():
    cam = Camera(800.0, 800.0, 320.0, 240.0, 640, 480)
    cases = [  # (x, y, z, heading) -> (theta, phi)
        ((0.0, 0.0, 50.0, 0.0), (math.pi, 0.0)),  # driving away: the camera sees the rear
        ((0.0, 0.0, 50.0, math.pi), (0.0, 0.0)),  # driving towards the camera: the front
        ((0.0, 0.0, 50.0, math.pi / 2), (3 * math.pi / 2, 0.0)),  # driving right: its right side
        ((0.0, 0.0, 50.0, -math.pi / 2), (math.pi / 2, 0.0)),  # driving left: its left side
        ((50.0, 0.0, 0.0, 0.0), (math.pi / 2, 0.0)),  # to the camera's right, driving away from it along +z
        ((0.0, -50.0, 50.0, 0.0), (math.pi, math.pi / 4)),  # camera 50 m above, 50 m behind
    ]
    for (x, y, z, h), (want_t, want_p) in cases:
        theta, phi = view_of_pose(VehiclePose(x, y, z, h), cam)
        assert theta.shape == () and 0 <= theta.item() < TWO_PI
        assert math.isclose(theta.item(), want_t, abs_tol=1e-9) or math.isclose(abs(theta.item() - want_t), TWO_PI,
                                                                                  abs_tol=1e-9), (x, y, z, h)
        assert phi.item() == pytest.approx(want_p, abs=1e-9)


def test_view_of_pose_batched_general_formula_and_camera_centre():
    """Camera at the origin: θ = h − bearing(camera from vehicle), φ = atan2(−y, ‖(x, z)‖); a moved camera
    gives the views of the vehicle positions relative to its centre."""
    gen = torch.Generator().manual_seed(2)
    n = 32
    pos = torch.randn(n, 3, generator=gen, dtype=torch.float64) * torch.tensor([30.0, 5.0, 30.0])
    h = (torch.rand(n, generator=gen, dtype=torch.float64) - 0.5) * 4 * math.pi
    theta, phi = view_of_pose(VehiclePose(pos[:, 0], pos[:, 1], pos[:, 2], h), Camera(500, 500, 320, 240, 640, 480))
    assert theta.shape == (n,) and phi.shape == (n,) and theta.dtype == torch.float64
    want_t = torch.remainder(h - torch.atan2(-pos[:, 0], -pos[:, 2]), TWO_PI)
    diff = torch.remainder(theta - want_t + math.pi, TWO_PI) - math.pi
    assert diff.abs().max() < 1e-9 and (theta >= 0).all() and (theta < TWO_PI).all()
    torch.testing.assert_close(phi, torch.atan2(-pos[:, 1], pos[:, [0, 2]].norm(dim=-1)))
    for k in range(n):
        t_k, p_k = view_of_pose(VehiclePose(*pos[k].tolist(), float(h[k])), Camera(500, 500, 320, 240, 640, 480))
        assert t_k.item() == pytest.approx(theta[k].item(), abs=1e-12) and p_k.item() == pytest.approx(phi[k].item())
    a = 0.3  # camera at c, pitched down: rows are its right, up and forward axes in the world
    R = torch.tensor([[1.0, 0.0, 0.0], [0.0, math.cos(a), math.sin(a)], [0.0, -math.sin(a), math.cos(a)]],
                     dtype=torch.float64)
    c = torch.tensor([3.0, 7.0, -2.0], dtype=torch.float64)
    moved = Camera(500, 500, 320, 240, 640, 480, R=R, t=-(R @ c))
    t_m, p_m = view_of_pose(VehiclePose(pos[:, 0] + c[0], pos[:, 1] + c[1], pos[:, 2] + c[2], h), moved)
    torch.testing.assert_close(t_m, theta)
    torch.testing.assert_close(p_m, phi)


def test_camera_centre_is_minus_r_transpose_t():
    a = 0.3
    R = torch.tensor([[1.0, 0.0, 0.0], [0.0, math.cos(a), math.sin(a)], [0.0, -math.sin(a), math.cos(a)]],
                     dtype=torch.float64)
    c = torch.tensor([3.0, 7.0, -2.0], dtype=torch.float64)
    cam = Camera(500, 500, 320, 240, 640, 480, R=R, t=-(R @ c))
    torch.testing.assert_close(camera_centre(cam), c)
    _, depth = cam.project(c + 1e-9)
    assert abs(depth.item()) < 1e-6


def test_bad_poses_raise():
    cam = Camera(500.0, 500.0, 320.0, 240.0, 640, 480)
    with pytest.raises(ValueError, match="pose fields of one shape"):
        view_of_pose(VehiclePose(torch.zeros(2), torch.zeros(3), 10.0, 0.0), cam)
    floor = Camera.from_opencv(cam.K.numpy(), np.zeros(5), np.zeros(3), np.array([0.0, 0.0, 5.0]), 640, 480)
    with pytest.raises(ValueError, match=r"sensor-like .* got det R = -1\.000"):
        view_of_pose(VehiclePose(0.0, 0.0, 10.0, 0.0), floor)
    with pytest.raises(ValueError, match=r"\(\) or \(N,\); got \(2, 2\)"):
        body_to_world(VehiclePose(torch.zeros(2, 2), 0.0, 0.0, 0.0))


def test_view_of_pose_flat_closed_form_equals_the_rotation_path():
    """The flat-ground shortcut gives what Rᵀ (c − t) with body_to_world's R gives (pitch = roll = 0
    given as tensors takes the general path)."""
    gen = torch.Generator().manual_seed(7)
    pos = torch.randn(40, 3, generator=gen, dtype=torch.float64) * 50
    h = torch.rand(40, generator=gen, dtype=torch.float64) * 7
    a = 0.2
    R = torch.tensor([[1.0, 0.0, 0.0], [0.0, math.cos(a), math.sin(a)], [0.0, -math.sin(a), math.cos(a)]],
                     dtype=torch.float64)
    cam = Camera(500, 500, 320, 240, 640, 480, R=R, t=torch.tensor([1.0, -2.0, 3.0], dtype=torch.float64))
    flat = view_of_pose(VehiclePose(pos[:, 0], pos[:, 1], pos[:, 2], h), cam)
    zero = torch.zeros(40, dtype=torch.float64)
    general = view_of_pose(VehiclePose(pos[:, 0], pos[:, 1], pos[:, 2], h, roll=zero, pitch=zero), cam)
    torch.testing.assert_close(flat[0], general[0])
    torch.testing.assert_close(flat[1], general[1])


def test_view_of_pose_takes_numpy_roll_and_pitch_like_its_other_fields():
    """Roll and pitch given as NumPy arrays (as x, y, z and heading may be) give the views that the
    same angles as tensors give; an array raised 'The truth value of an array ... is ambiguous'."""
    cam = Camera(500, 500, 320, 240, 640, 480)
    x, h = np.array([1.0, -4.0, 9.0]), np.array([0.1, 2.2, 4.0])
    for roll, pitch in ((np.zeros(3), np.zeros(3)), (np.array([0.1, 0.0, -0.2]), np.array([0.0, 0.3, 0.1]))):
        got = view_of_pose(VehiclePose(x, -3.0, 40.0, h, roll=roll, pitch=pitch), cam)
        want = view_of_pose(VehiclePose(torch.from_numpy(x), -3.0, 40.0, torch.from_numpy(h),
                                        roll=torch.from_numpy(roll), pitch=torch.from_numpy(pitch)), cam)
        torch.testing.assert_close(got, want)
    assert view_of_pose(VehiclePose(1.0, -3.0, 40.0, 0.5, roll=np.float64(0.0)), cam)[0].shape == ()
