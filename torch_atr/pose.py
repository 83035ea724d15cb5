"""Pose geometry shared by the renderer, the model and the tracker (METHOD.md, "Frames and angles").

Frames:

- **World frame** of a :class:`~torch_atr.camera.Camera`: sensor-like, x right, y up, z forward,
  metres (the camera maps it to its sensor frame by ``p_s = R p_w + t``). For the simulator and
  the tracker it is the sensor-centred, ground-levelled frame of thesis Fig. 5.4: origin at the
  camera centre, y vertical, z the camera's horizontal forward direction; with R = I it is the
  sensor frame. It is LEFT-handed, so the body -> world matrix of a real (unmirrored) vehicle
  has determinant −1; composed with the y-flip into OpenCV's camera frame it is a proper rotation.
- **Body frame** of a vehicle: +X forward, +Y left, +Z up; the origin of a :class:`VehiclePose`.

Heading h is the direction of travel measured from +z towards +x: the vehicle moves along
(sin h, 0, cos h). The view Θ = (θ, φ) is the direction from the vehicle to the camera in the
body frame, as the unit vector u(θ, φ) = (cos φ cos θ, cos φ sin θ, sin φ): θ = 0 sees the
front, π/2 the left side, π the rear.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import torch
from pytorch_kinematics.transforms import euler_angles_to_matrix

from torch_atr._checks import as_float_tensor, check_shape
from torch_atr.camera import Camera

TWO_PI = 2.0 * math.pi

# Body axes -> world axes at heading 0: X (forward) -> +z, Y (left) -> -x, Z (up) -> +y.
_BODY_TO_WORLD_H0 = ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0))


def wrap_angle(a: torch.Tensor) -> torch.Tensor:
    """Angles (any shape) wrapped to [0, 2π); never 2π itself, which float remainder can return."""
    a = torch.remainder(a, TWO_PI)
    return torch.where(a >= TWO_PI, torch.zeros_like(a), a)


def view_vectors(theta: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
    """Unit view vectors u(θ, φ) = (cos φ cos θ, cos φ sin θ, sin φ) in the vehicle body frame.

    theta: (N,) azimuth from the vehicle's front, radians; phi: (N,) elevation, radians.
    Returns (N, 3).
    """
    check_shape("theta", theta, ("N",))
    check_shape("phi", phi, (theta.shape[0],))
    cos_phi = torch.cos(phi)
    return torch.stack((cos_phi * torch.cos(theta), cos_phi * torch.sin(theta), torch.sin(phi)), dim=-1)


@dataclass(frozen=True)
class VehiclePose:
    """Pose of a vehicle's body frame in the camera's world frame (x right, y up, z forward).

    Each field is a float or a tensor; tensors of shape (N,) describe N poses at once.
    ``x, y, z``: position of the body-frame origin, metres. ``heading``: radians from +z towards
    +x (the vehicle moves along (sin h, 0, cos h)). ``roll``, ``pitch``: radians, right-hand
    rotations about the body's +X then +Y axes (positive pitch lowers the nose, positive roll
    lowers the right side); 0 on flat ground.
    """

    x: float | torch.Tensor
    y: float | torch.Tensor
    z: float | torch.Tensor
    heading: float | torch.Tensor
    roll: float | torch.Tensor = 0.0
    pitch: float | torch.Tensor = 0.0

    def stacked(self) -> torch.Tensor:
        """(..., 6) tensor [x, y, z, heading, roll, pitch], ... = () or (N,); dtype and device of
        the first floating tensor field, else float64 on the CPU."""
        names = ("x", "y", "z", "heading", "roll", "pitch")
        values = [getattr(self, n) for n in names]
        ref = next((v for v in values if isinstance(v, torch.Tensor) and v.is_floating_point()),
                   torch.zeros((), dtype=torch.float64))
        fields = [as_float_tensor(f"pose.{n}", v, like=ref).to(ref) for n, v in zip(names, values)]
        try:
            fields = torch.broadcast_tensors(*fields)
        except RuntimeError as exc:
            shapes = ", ".join(f"{n}={tuple(f.shape)}" for n, f in zip(names, fields))
            raise ValueError(f"Expected pose fields of one shape () or (N,); got {shapes}") from exc
        if fields[0].dim() > 1:
            raise ValueError(f"Expected pose fields of shape () or (N,); got {tuple(fields[0].shape)}")
        return torch.stack(fields, dim=-1)


def body_to_world(pose: VehiclePose) -> tuple[torch.Tensor, torch.Tensor]:
    """Rigid map of body coordinates to world coordinates: p_w = R p_b + t.

    R = R_y(h) · A · R_Y(pitch) · R_X(roll), where A maps the body axes to the world axes at
    heading 0 (X -> +z, Y -> −x, Z -> +y) and R_y(h) turns +z towards +x about the world's up
    axis. det R = −1 because the world frame (x right, y up, z forward) is left-handed.

    Args:
        pose: fields of shape () or (N,).
    Returns:
        R: (..., 3, 3); t: (..., 3) = (x, y, z); ... is () or (N,).
    """
    p = pose.stacked()
    zero = torch.zeros_like(p[..., 3])
    yaw = euler_angles_to_matrix(torch.stack([zero, p[..., 3], zero], dim=-1), "XYZ")  # R_y(h)
    tilt = euler_angles_to_matrix(torch.stack([p[..., 5], p[..., 4], zero], dim=-1), "YXZ")  # R_Y R_X
    A = torch.tensor(_BODY_TO_WORLD_H0, dtype=p.dtype, device=p.device)
    return yaw @ A @ tilt, p[..., :3]


def check_sensor_like(camera: Camera) -> None:
    """Raise ValueError unless the camera's world frame is sensor-like (left-handed: det R = +1)."""
    (a, b, c), (d, e, f), (g, h, i) = camera.R.tolist()  # a 3 x 3 determinant in Python: no tensor ops per call
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    if det < 0:
        raise ValueError(f"Expected a camera whose world frame is sensor-like (x right, y up, z forward; "
                         f"det R = +1); got det R = {det:.3f}, a right-handed world such as from_opencv's")


def camera_centre(camera: Camera) -> torch.Tensor:
    """The camera centre −Rᵀ t in its world frame: (3,), the camera's dtype and device."""
    return -(camera.R.T @ camera.t)


def _is_zero(value: float | torch.Tensor) -> bool:
    """True for a number 0 (not a tensor or an array of angles: those take the general path)."""
    return isinstance(value, numbers.Real) and value == 0


def view_of_pose(pose: VehiclePose, camera: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """The view Θ = (θ, φ) under which ``camera`` sees a vehicle at ``pose`` (METHOD.md).

    Θ is the direction from the pose's position (x, y, z) to the camera centre, in the body
    frame: θ = atan2(d_Y, d_X) wrapped to [0, 2π) (0 sees the front, π/2 the left side, π the
    rear), φ = atan2(d_Z, ‖(d_X, d_Y)‖) in [−π/2, π/2] (positive: camera above; not clamped).
    For a distant camera any point of the vehicle gives the same view; the tracker uses the
    centre of the vehicle's bounding box.

    Args:
        pose: fields of shape () or (N,) (e.g. positions (N, 3) and headings (N,) of particles).
        camera: its world frame must be sensor-like.
    Returns:
        theta, phi: (...,) radians, shape and dtype of the pose fields.

    Example: particles with positions ``pos`` (N, 3) and headings ``h`` (N,):
    ``view_of_pose(VehiclePose(pos[:, 0], pos[:, 1], pos[:, 2], h), camera)``.
    """
    check_sensor_like(camera)
    if _is_zero(pose.roll) and _is_zero(pose.pitch):  # flat ground: Rᵀ (c − t) in closed form
        p = pose.stacked()
        w = camera_centre(camera).to(p) - p[..., :3]
        sin_h, cos_h = torch.sin(p[..., 3]), torch.cos(p[..., 3])
        d = torch.stack([w[..., 0] * sin_h + w[..., 2] * cos_h,  # forward (sin h, 0, cos h)
                         w[..., 2] * sin_h - w[..., 0] * cos_h,  # left (−cos h, 0, sin h)
                         w[..., 1]], dim=-1)  # up
    else:
        R, t = body_to_world(pose)
        d = ((camera_centre(camera).to(t) - t).unsqueeze(-1) * R).sum(dim=-2)  # Rᵀ (c − t): (..., 3) in the body frame
    theta = wrap_angle(torch.atan2(d[..., 1], d[..., 0]))
    phi = torch.atan2(d[..., 2], torch.hypot(d[..., 0], d[..., 1]))
    return theta, phi
