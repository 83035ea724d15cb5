"""Pinhole camera in the sensor frame of METHOD.md (x right, y up, z along the optical axis).

Pixels: u to the right, v down, (0, 0) the centre of the top-left pixel. Lens distortion is
OpenCV's (k1, k2, p1, p2, k3), applied in OpenCV's camera frame, which is the sensor frame
with y flipped; :meth:`Camera.from_opencv` and :meth:`Camera.opencv_pose` convert poses.
"""

from __future__ import annotations

import functools
import math
import numbers

import cv2
import numpy as np
import torch
from torch import nn

from torch_atr._checks import as_float_tensor, check_shape
from torch_atr.validate import MAX_IMAGE_SIDE, InputError, image_size, integer, real, rotation, vector

# Sensor frame (y up) <-> OpenCV camera frame (y down).
_FLIP_Y = np.diag([1.0, -1.0, 1.0])

# Bounds on a camera's numbers, generous around any real camera, so that an absurd value (a typed
# 1e300) fails where the camera is made, naming it, not as inf or NaN in a later projection.
FOCAL_RANGE_PX = (1e-3, 1e8)  # fx, fy: 1e8 px is a 100 m lens at 1 µm pixels; 1e-3 px a field of view over 179.7°
MAX_PRINCIPAL_PX = 1e8  # |cx|, |cy|: a principal point far outside any image, as a crop window shifts it
MAX_DISTORTION = 1e6  # |k1|, |k2|, |p1|, |p2|, |k3|: real lenses fit with terms of order 1, wide ones up to ~100s
MAX_TRANSLATION_M = 1e9  # |t| per axis: beyond the Moon


def _number(name: str, value) -> float:
    """A Python, NumPy or one-element torch real number as a float; ValueError naming it otherwise."""
    if isinstance(value, torch.Tensor) and value.numel() == 1 or isinstance(value, np.ndarray) and value.size == 1:
        value = value.item()
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"Expected {name} to be a number; got {value!r}")
    return float(value)


@functools.lru_cache(maxsize=64)  # a camera's every projection asks again (np.roots: about 35 us)
def _fold_r2(k1: float, k2: float, k3: float) -> float:
    """r² = x² + y² (normalised coordinates) where the radial distortion k1, k2, k3 folds back:
    the smallest s > 0 with d(r · (1 + k1 r² + k2 r⁴ + k3 r⁶)) / dr = 1 + 3 k1 s + 5 k2 s² + 7 k3 s³ = 0;
    inf where there is none. Beyond it points of wider angle land nearer the principal point, so
    OpenCV's model images points far outside the field of view inside the image."""
    s = np.roots([7 * k3, 5 * k2, 3 * k1, 1.0])  # leading zeros dropped: k3 = 0 is a quadratic
    s = s.real[(s.imag == 0) & (s.real > 0)]
    return float(s.min()) if s.size else math.inf


def _check_entries(name: str, value: torch.Tensor, bound: float, unit: str) -> None:
    """ValueError naming the first entry of ``value`` (a flat tensor) that is not finite or has a
    magnitude above ``bound``."""
    bad = ~(value.abs() <= bound)  # NaN compares False: bad
    if bool(bad.any()):
        i = int(bad.nonzero()[0, 0])
        raise ValueError(f"Expected {name} to be finite, each of magnitude at most {bound:g}{unit}; "
                         f"got {name}[{i}]={value[i].item()!r}")


def _image_size(width, height) -> tuple[int, int]:
    """(width, height) as whole pixels in [1, MAX_IMAGE_SIDE], or ValueError naming the bad one."""
    width, height = _number("width", width), _number("height", height)
    for name, value in (("width", width), ("height", height)):
        if not (1 <= value <= MAX_IMAGE_SIDE and value.is_integer()):
            raise ValueError(f"Expected a whole image size of 1 to {MAX_IMAGE_SIDE} px a side; got {name}={value!r}")
    return int(width), int(height)


class Camera(nn.Module):
    """A pinhole camera with intrinsics, distortion and a world -> sensor pose.

    Each number is bounded generously around real cameras (the module's constants), so that a
    typed 1e300 fails here, naming it, not as inf or NaN later: K, dist and t are finite in float32,
    and so are the rays of the image's pixels (:meth:`pixel_rays`: |u - cx| / fx <= 1.0007e11).

    Args:
        fx, fy: focal lengths in pixels, in [1e-3, 1e8] (``FOCAL_RANGE_PX``).
        cx, cy: principal point in pixels, each in [-1e8, 1e8] (``MAX_PRINCIPAL_PX``).
        width, height: image size in pixels, whole numbers in [1, 16384] (``validate.MAX_IMAGE_SIDE``: frames'
            limit too).
        dist: (5,) OpenCV distortion (k1, k2, p1, p2, k3), each in [-1e6, 1e6] (``MAX_DISTORTION``);
            zeros if None.
        R: (3, 3) rotation world -> sensor; identity if None (world = sensor frame).
        t: (3,) translation world -> sensor in metres: p_s = R p_w + t, each in [-1e9, 1e9]
            (``MAX_TRANSLATION_M``); zeros if None.
    Raises:
        ValueError naming the argument and its value when one is not a number, is NaN or infinite,
        or is outside its bounds.
    """

    def __init__(self, fx: float, fy: float, cx: float, cy: float, width: int, height: int,
                 dist=None, R=None, t=None, dtype: torch.dtype = torch.float64):
        super().__init__()
        fx, fy, cx, cy = (_number(name, v) for name, v in (("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)))
        lo, hi = FOCAL_RANGE_PX
        for name, value in (("fx", fx), ("fy", fy)):
            if not lo <= value <= hi:  # NaN compares False
                raise ValueError(f"Expected focal lengths in [{lo:g}, {hi:g}] px; got {name}={value!r}")
        for name, value in (("cx", cx), ("cy", cy)):
            if not abs(value) <= MAX_PRINCIPAL_PX:
                raise ValueError(f"Expected a principal point with coordinates in [-{MAX_PRINCIPAL_PX:g}, "
                                 f"{MAX_PRINCIPAL_PX:g}] px; got {name}={value!r}")
        self.width, self.height = _image_size(width, height)
        K = torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=dtype)
        dist = torch.zeros(5, dtype=dtype) if dist is None else torch.as_tensor(dist, dtype=dtype).flatten()
        R = torch.eye(3, dtype=dtype) if R is None else torch.as_tensor(R, dtype=dtype)
        t = torch.zeros(3, dtype=dtype) if t is None else torch.as_tensor(t, dtype=dtype).flatten()
        check_shape("dist", dist, (5,))
        check_shape("R", R, (3, 3))
        check_shape("t", t, (3,))
        _check_entries("dist", dist, MAX_DISTORTION, "")
        _check_entries("t", t, MAX_TRANSLATION_M, " m")
        rotation("R", R.tolist())  # orthonormal rows: a rotation, or a left-handed frame's (det ±1)
        self.register_buffer("K", K)
        self.register_buffer("dist", dist)
        self.register_buffer("R", R)
        self.register_buffer("t", t)

    def get_extra_state(self) -> dict:
        """The image size, which is no tensor, in ``state_dict`` with K, dist, R and t: loaded into a
        camera of another size, a state kept that camera's size and rendered into it."""
        return {"width": self.width, "height": self.height}

    def set_extra_state(self, state: dict) -> None:
        if not (isinstance(state, dict) and set(state) == {"width", "height"}):
            raise ValueError(f"Expected a camera's extra state {{'width': W, 'height': H}}; got {state!r}")
        self.width, self.height = _image_size(state["width"], state["height"])

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    def extra_repr(self) -> str:
        return (f"fx={self.fx:.1f}, fy={self.fy:.1f}, cx={self.cx:.1f}, cy={self.cy:.1f}, "
                f"size={self.width}x{self.height}")

    def world_to_sensor(self, points: torch.Tensor) -> torch.Tensor:
        """points: (..., 3) world metres -> (..., 3) sensor-frame metres."""
        points = as_float_tensor("points", points, like=self.K)
        if points.shape[-1:] != (3,):
            raise ValueError(f"Expected points to have shape (..., 3); got {tuple(points.shape)}")
        R, t = self.R.to(points), self.t.to(points)
        return points @ R.T + t  # p_s = R p_w + t

    def project(self, points: torch.Tensor, world: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
        """Project 3D points to pixels.

        Args:
            points: (..., 3) metres, in the world frame (or the sensor frame if ``world=False``).
        Returns:
            uv: (..., 2) pixels (u right, v down); depth: (..., ) metres along the optical axis.
            Points at or behind the camera (depth <= 0), and with lens distortion those beyond
            the radius where it folds back (r² >= :func:`_fold_r2`), get NaN ``uv``.
        """
        p = self.world_to_sensor(points) if world else as_float_tensor("points", points, like=self.K)
        if p.shape[-1:] != (3,):
            raise ValueError(f"Expected points to have shape (..., 3); got {tuple(p.shape)}")
        z = p[..., 2]
        # OpenCV normalised coordinates: y points down.
        xd, yd = x, y = p[..., 0] / z, -p[..., 1] / z
        seen = z > 0
        dist = self.dist.tolist()  # one read of the five numbers
        if any(dist):  # without distortion the terms below are 0 and 1: (x, y) as they are
            k1, k2, p1, p2, k3 = self.dist.to(p).unbind(0)
            r2 = x * x + y * y
            seen = seen & (r2 < _fold_r2(dist[0], dist[1], dist[4]))
            radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
            xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        K = self.K.to(p)
        u = K[0, 0] * xd + K[0, 2]
        v = K[1, 1] * yd + K[1, 2]
        uv = torch.stack([u, v], dim=-1)
        uv = torch.where(seen.unsqueeze(-1), uv, torch.full_like(uv, float("nan")))
        return uv, z

    def undistort(self, uv: torch.Tensor) -> torch.Tensor:
        """uv: (..., 2) image pixels -> (..., 2) the pixels where the same rays meet the image without
        lens distortion (OpenCV's iterative undistortion, to 1e-12), for :meth:`pixel_rays`;
        ``uv`` itself when the camera has no distortion. Same dtype and device as ``uv``."""
        uv = as_float_tensor("uv", uv, like=self.K)
        if uv.shape[-1:] != (2,):
            raise ValueError(f"Expected uv to have shape (..., 2); got {tuple(uv.shape)}")
        if not bool(self.dist.any()) or uv.numel() == 0:  # cv2 returns None for no points
            return uv
        K, dist = self.K.detach().cpu().double().numpy(), self.dist.detach().cpu().double().numpy()
        points = uv.detach().cpu().double().reshape(-1, 1, 2).numpy()
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
        if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
            out = cv2.undistortPointsIter(points, K, dist, None, K, criteria)
        else:  # OpenCV 5 takes the criteria in undistortPoints
            out = cv2.undistortPoints(points, K, dist, R=None, P=K, criteria=criteria)
        return torch.from_numpy(out.reshape(uv.shape)).to(uv)

    def pixel_rays(self, uv: torch.Tensor) -> torch.Tensor:
        """uv: (..., 2) undistorted pixels (:meth:`undistort`) -> (..., 3) sensor-frame ray directions with z = 1."""
        uv = as_float_tensor("uv", uv, like=self.K)
        if uv.shape[-1:] != (2,):
            raise ValueError(f"Expected uv to have shape (..., 2); got {tuple(uv.shape)}")
        K = self.K.to(uv)
        x = (uv[..., 0] - K[0, 2]) / K[0, 0]
        y = -(uv[..., 1] - K[1, 2]) / K[1, 1]
        return torch.stack([x, y, torch.ones_like(x)], dim=-1)

    @classmethod
    def from_opencv(cls, K, dist, rvec, tvec, width: int, height: int) -> "Camera":
        """Build from OpenCV calibration results (K (3, 3), dist, rvec (3,), tvec (3,)).

        ``dist`` holds OpenCV's coefficients in its order (k1, k2, p1, p2, k3, k4, ...); fewer than
        5 (none, or None as OpenCV takes it) are padded with zeros. This camera has k1, k2, p1, p2,
        k3 only, so more than 5 are taken only when every one beyond the 5th is zero; otherwise
        ValueError, since dropping them would move the projected pixels. So is a K other than
        [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]: this camera has no skew. Every number is then checked
        against the bounds of :class:`Camera` (tvec's as t's).
        """
        import cv2

        K, rvec, tvec = (np.asarray(v, dtype=np.float64) for v in (K, rvec, tvec))
        for name, value in (("rvec", rvec), ("tvec", tvec)):
            if value.size != 3:
                raise ValueError(f"Expected {name} to hold 3 numbers (shape (3,), (3, 1) or (1, 3)); "
                                 f"got shape {value.shape}")
            if not np.isfinite(value).all():  # a NaN rvec was reported as R[0][0]
                raise ValueError(f"Expected {name} to be finite; got {value.ravel().tolist()}")
        _check_entries("tvec", torch.from_numpy(tvec.ravel()), MAX_TRANSLATION_M, " m")  # t negates tvec[1]
        if K.shape != (3, 3):
            raise ValueError(f"Expected K to have shape (3, 3); got {K.shape}")
        if K[0, 1] != 0 or K[1, 0] != 0 or K[2].tolist() != [0.0, 0.0, 1.0]:
            raise ValueError(f"Expected K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (this camera has no skew); "
                             f"got {K.tolist()}")
        R_cv, _ = cv2.Rodrigues(rvec.reshape(3, 1))
        t_cv = tvec.reshape(3)
        dist = np.zeros(0) if dist is None else np.asarray(dist, dtype=np.float64).ravel()  # None: no distortion
        extra = {f"dist[{i}]": float(v) for i, v in enumerate(dist[5:], start=5) if v != 0}
        if extra:
            raise ValueError(f"Expected at most 5 distortion coefficients (k1, k2, p1, p2, k3: all this camera "
                             f"model has), or zeros beyond them; got {dist.size} coefficients with nonzero {extra}")
        d = np.zeros(5)
        d[: min(dist.size, 5)] = dist[:5]
        return cls(K[0, 0], K[1, 1], K[0, 2], K[1, 2], width, height, dist=d,
                   R=_FLIP_Y @ R_cv, t=_FLIP_Y @ t_cv)

    def opencv_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(rvec (3,), tvec (3,)) of this camera's pose in OpenCV's convention.

        OpenCV's world frame is right-handed. A camera whose world frame is right-handed too
        (det R = −1, as :meth:`from_opencv` builds) takes world points as they are; one whose
        world frame is sensor-like and so left-handed (det R = +1, e.g. R = identity) takes them
        with y negated, (x, −y, z). Either way ``cv2.projectPoints`` then agrees with :meth:`project`.
        """
        import cv2

        R = self.R.cpu().numpy()
        if np.linalg.det(R) > 0:
            R = R @ _FLIP_Y  # OpenCV's world points are (x, −y, z)
        R_cv = _FLIP_Y @ R
        t_cv = _FLIP_Y @ self.t.cpu().numpy()
        rvec, _ = cv2.Rodrigues(R_cv)
        return rvec.ravel(), t_cv

    def to_dict(self) -> dict:
        """A JSON-ready description (for ``camera.json``)."""
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
                "width": self.width, "height": self.height,
                "dist": self.dist.tolist(), "R": self.R.tolist(), "t": self.t.tolist()}

    @classmethod
    def from_dict(cls, d: dict, source: str = "camera") -> "Camera":
        """Inverse of :meth:`to_dict`, for data from a file: every key checked.

        fx, fy: finite numbers > 0; cx, cy: finite numbers; width, height: integers within
        :data:`~torch_atr.validate.MAX_IMAGE_SIDE`; dist: 5 finite numbers, R: a rotation
        (orthonormal rows; det ±1), t: 3 finite numbers, each optional or null; then every number
        within the bounds of :class:`Camera`. A missing, unknown or bad key raises
        :class:`~torch_atr.validate.InputError` naming ``source`` and the key.
        """
        if not isinstance(d, dict):
            raise InputError(f"{source}: expected an object of camera keys; got {type(d).__name__}")
        required = ("fx", "fy", "cx", "cy", "width", "height")
        missing = [k for k in required if k not in d]
        if missing:
            raise InputError(f"{source}: missing key(s) {', '.join(missing)}")
        unknown = sorted(set(d) - set(required) - {"dist", "R", "t"}, key=str)
        if unknown:
            raise InputError(f"{source}: unknown key(s) {', '.join(map(str, unknown))}")

        def key(name: str) -> str:
            return f"{source}, key {name!r}"

        fx, fy = (real(key(k), d[k], lo=0, lo_open=True) for k in ("fx", "fy"))
        cx, cy = (real(key(k), d[k]) for k in ("cx", "cy"))
        width = integer(key("width"), d["width"])
        height = integer(key("height"), d["height"])
        image_size(source, width, height)
        dist = None if d.get("dist") is None else vector(key("dist"), d["dist"], 5)
        R = None if d.get("R") is None else rotation(key("R"), d["R"])
        t = None if d.get("t") is None else vector(key("t"), d["t"], 3)
        try:
            return cls(fx, fy, cx, cy, width, height, dist=dist, R=R, t=t)
        except ValueError as exc:  # out of the camera's bounds: the message names the key and value
            raise InputError(f"{source}: {exc}") from None
