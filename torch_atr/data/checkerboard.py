"""Rendered checkerboard images through a :class:`~torch_atr.camera.Camera`: the calibration target
of thesis 3.3 (Fig. 3.5, 3.6) for a simulated camera, whose true intrinsics and pose are known.

Board frame: the floor frame of :mod:`torch_atr.calibration`: inner corner k of a (columns, rows)
pattern at (k % columns, k // columns, 0) · square_m, so the corners are ``_board_points``'s and
the square diagonally inside the origin corner is dark; X along the rows, Y along the columns,
Z = X × Y. The board's squares span one square beyond the outer inner corners, and a white margin
one more square; around it lies a uniform background. A board pose maps board points into the
camera's world frame, p_w = R p_b + t (R orthogonal; det −1 when the world frame is sensor-like,
since the board frame is right-handed).

Each pixel is the mean of ``SUPERSAMPLE``² sub-samples, so edges are anti-aliased and
:func:`~torch_atr.calibration.find_checkerboard` finds the corners to a small fraction of a pixel.
The camera's lens distortion is not rendered (every camera here has none).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from torch_atr._checks import check_pattern, check_shape
from torch_atr.camera import Camera

SUPERSAMPLE = 4  # sub-samples per pixel side
DARK, LIGHT, BACKGROUND = 30.0, 220.0, 120.0  # grey levels of the dark squares, the light ones and the margin, around


def render_checkerboard(camera: Camera, pattern: tuple[int, int], square_m: float, R, t, *,
                        noise: float = 1.0, generator: torch.Generator | None = None) -> np.ndarray:
    """One image of a checkerboard at a pose (module docstring).

    Args:
        camera: a distortion-free camera (intrinsics and world -> sensor pose).
        pattern: (columns, rows) of inner corners, at least 3 x 3 (the fewest OpenCV finds).
        square_m: side of a square, metres.
        R: (3, 3) board -> world rotation; t: (3,) the board's origin in the world frame, metres.
        noise: σ of white noise added, grey levels (drawn from ``generator``).
        generator: for the noise; None: torch's global generator.
    Returns:
        (height, width) uint8 grey image.
    """
    cols, rows = check_pattern(pattern)
    if not (0 < square_m < math.inf and 0 <= noise < math.inf):
        raise ValueError(f"Expected a positive square_m and noise >= 0; got {square_m}, {noise}")
    if bool(camera.dist.abs().sum() > 0):
        raise ValueError("Expected a camera without lens distortion")
    R, t = torch.as_tensor(R, dtype=torch.float64), torch.as_tensor(t, dtype=torch.float64)
    check_shape("R", R, (3, 3))
    check_shape("t", t, (3,))
    if not torch.allclose(R @ R.T, torch.eye(3, dtype=torch.float64), atol=1e-9):
        raise ValueError("Expected R to be orthogonal (R Rᵀ = I)")
    S, (W, H) = SUPERSAMPLE, (camera.width, camera.height)
    offsets = (torch.arange(S, dtype=torch.float64) + 0.5) / S - 0.5
    u = (torch.arange(W, dtype=torch.float64)[:, None] + offsets).flatten()  # (W·S,) sub-sample columns
    v = (torch.arange(H, dtype=torch.float64)[:, None] + offsets).flatten()
    uv = torch.stack(torch.meshgrid(u, v, indexing="xy"), dim=-1)  # (H·S, W·S, 2)
    cam_R, cam_t = camera.R.to(torch.float64), camera.t.to(torch.float64)
    centre = -(cam_R.T @ cam_t)  # the camera centre, world frame
    rays = camera.pixel_rays(uv.to(camera.K)).to(torch.float64) @ cam_R  # (H·S, W·S, 3) world: Rᵀ d
    # In board coordinates the camera is q = Rᵀ (c − t) and a ray e = Rᵀ d; the board is Z = 0.
    q, e = R.T @ (centre - t), rays @ R
    s = -q[2] / e[..., 2]
    hit = (s > 0) & s.isfinite()
    a, b = (torch.where(hit, q[i] + s * e[..., i], torch.full_like(s, math.nan)) / square_m for i in (0, 1))
    i, j = a.floor(), b.floor()
    on_squares = (i >= -1) & (i <= cols - 1) & (j >= -1) & (j <= rows - 1)
    on_board = (i >= -2) & (i <= cols) & (j >= -2) & (j <= rows)
    dark = on_squares & ((i + j).remainder(2) == 0)
    grey = torch.where(dark, DARK, torch.where(on_board, LIGHT, BACKGROUND))
    grey = grey.reshape(H, S, W, S).mean(dim=(1, 3))
    grey = grey + noise * torch.randn(H, W, generator=generator, dtype=torch.float64)
    return grey.round().clamp(0, 255).to(torch.uint8).numpy()


def _rotation(axis: tuple[float, float, float], angle: float) -> torch.Tensor:
    """(3, 3) right-hand rotation by ``angle`` radians about the unit ``axis`` (Rodrigues)."""
    k = torch.tensor(axis, dtype=torch.float64)
    K = torch.tensor([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]], dtype=torch.float64)
    return torch.eye(3, dtype=torch.float64) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def calibration_poses(camera: Camera, pattern: tuple[int, int], square_m: float, count: int = 8,
                      tilt_deg: float = 30.0) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Board poses for intrinsic calibration: a board held before the camera at ``count`` poses.

    The board faces the camera at a distance where it spans about half the image width, turned
    by ``tilt_deg`` about the axis at 360° · k / count in the image plane (tilts about different
    axes fix the focal length and the principal point), and shifted off the optical axis towards
    a different quarter of the image each time.

    Returns:
        ``count`` pairs (R (3, 3), t (3,)) of board -> world poses in ``camera``'s world frame.
    """
    cols, rows = (int(p) for p in pattern)
    if not 3 <= count <= 100:
        raise ValueError(f"Expected count in [3, 100]; got {count}")
    size = torch.tensor([(cols - 1) * square_m, (rows - 1) * square_m, 0.0], dtype=torch.float64)
    distance = 2.0 * camera.fx * float(size[0]) / camera.width  # the board spans half the width
    half_w, half_h = camera.width / 4 / camera.fx * distance, camera.height / 4 / camera.fy * distance
    # board X right, Y up, Z towards the camera: det −1, a right-handed board in the left-handed sensor frame
    flip = torch.diag(torch.tensor([1.0, 1.0, -1.0], dtype=torch.float64))
    cam_R, cam_t = camera.R.to(torch.float64), camera.t.to(torch.float64)
    poses = []
    for k in range(count):
        angle = 2 * math.pi * k / count
        axis = (math.cos(angle), math.sin(angle), 0.0)
        R_s = _rotation(axis, math.radians(tilt_deg)) @ flip  # board -> sensor
        centre_s = torch.tensor([0.6 * half_w * math.cos(angle + math.pi / 4),
                                 0.6 * half_h * math.sin(angle + math.pi / 4), distance], dtype=torch.float64)
        t_s = centre_s - R_s @ (size / 2)  # the board's centre at centre_s
        poses.append((cam_R.T @ R_s, cam_R.T @ (t_s - cam_t)))  # sensor -> world: p_w = Rᵀ (p_s − t)
    return poses
