"""The particle state and its dynamics: the white-noise motion model (eq. 5.1) and the random
walk on the identity manifold (eq. 5.3).

A particle is one row of an (N, 6) tensor ``[x, y, z, h, v, α]`` (columns :data:`X` … :data:`ALPHA`):
the vehicle's centre (x, y, z) in the camera's world frame (metres; :mod:`torch_atr.pose`), its
heading h (radians from +z towards +x), its speed v (m/s) and its identity α ∈ [0, 2π).

Noise convention: the variances are per second of sequence time, so a frame step of Δt seconds
draws w ~ N(0, σ² Δt) (a Wiener process; the filter behaves the same at any frame rate). At 30 Hz
the thesis's σ²_x = 0.1 m²/s gives σ_x = 5.8 cm per frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from torch_atr._checks import check_shape
from torch_atr.config import ConfigError
from torch_atr.pose import wrap_angle

X, Y, Z, HEADING, SPEED, ALPHA = range(6)
STATE_DIM = 6


@dataclass(frozen=True)
class MotionConfig:
    """Process noise of eq. 5.1 and 5.3: variances per second (module docstring).

    Defaults: the thesis's σ²_v = 1, σ²_x = σ²_z = 0.1 and σ²_y = 1 (chapter 6.2). Its σ²_α of
    0.8–1.2 (units unstated) we do not take: as rad²/s it moves α by 0.18 rad (one training vehicle)
    per frame, so the identity trades freely against range and view, and near side-on views the
    heading then drifts with nothing to hold it (T-72 at 1000 m, truth start: aspect error 0.61 rad
    at σ²_α = 1, 0.26 at 0.05). The thesis gives no heading noise; σ²_h = 0.1 rad²/s lets the
    heading follow a vehicle turning at 0.1 rad/s (a 100 m circle at 5 m/s).
    """

    sigma2_x: float = 0.1  # m² / s
    sigma2_y: float = 1.0  # m² / s
    sigma2_z: float = 0.1  # m² / s
    sigma2_heading: float = 0.1  # rad² / s
    sigma2_speed: float = 1.0  # (m/s)² / s
    sigma2_alpha: float = 0.05  # rad² / s (the thesis: ~1; see the class docstring)
    sigma2_elevation: float = 0.01  # rad² / s, of the view elevation φ (uncalibrated sequences only)

    def __post_init__(self) -> None:
        for key in ("sigma2_x", "sigma2_y", "sigma2_z", "sigma2_heading", "sigma2_speed", "sigma2_alpha",
                    "sigma2_elevation"):
            value = getattr(self, key)
            if not (math.isfinite(value) and 0 <= value <= 1e4):
                raise ConfigError(f"motion.{key} must be a variance in [0, 1e4]; got {value!r}")

    def std_per_step(self, dt: float) -> torch.Tensor:
        """(6,) float64 standard deviations per frame step of ``dt`` seconds, in state-column order."""
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"Expected a positive finite time step dt; got {dt!r}")
        var = (self.sigma2_x, self.sigma2_y, self.sigma2_z, self.sigma2_heading, self.sigma2_speed, self.sigma2_alpha)
        return torch.tensor(var, dtype=torch.float64).mul(dt).sqrt()


def predict(particles: torch.Tensor, dt: float, cfg: MotionConfig, generator: torch.Generator | None = None
            ) -> torch.Tensor:
    """Draw X_t ~ p(X_t | X_{t−1}) (eq. 5.1) and α_t ~ p(α_t | α_{t−1}) (eq. 5.3) for every particle.

        h_t = h + w_h,  v_t = v + w_v,  x_t = x + v sin(h) Δt + w_x,  y_t = y + w_y,
        z_t = z + v cos(h) Δt + w_z,  α_t = α + w_α

    with the previous h and v in the drift and the angles wrapped to [0, 2π). The speed is
    signed: a negative one drives backwards, the vehicle still facing h.

    Args:
        particles: (N, 6) [x, y, z, h, v, α]; any float dtype and device.
        dt: the frame step, seconds.
        cfg: the noise variances per second.
        generator: the source of randomness (on ``particles``' device); same seed, same draws.
    Returns:
        (N, 6) new particles.
    """
    check_shape("particles", particles, ("N", STATE_DIM))
    if not particles.is_floating_point():
        raise ValueError(f"Expected floating particles; got {particles.dtype}")
    std = cfg.std_per_step(dt).to(particles)
    noise = torch.randn(particles.shape, generator=generator, dtype=particles.dtype, device=particles.device)
    h, v = particles[:, HEADING], particles[:, SPEED]
    drift = torch.zeros_like(particles)
    drift[:, X] = v * torch.sin(h) * dt  # eq. 5.1
    drift[:, Z] = v * torch.cos(h) * dt
    out = particles + drift + noise * std
    out[:, HEADING] = wrap_angle(out[:, HEADING])
    out[:, ALPHA] = wrap_angle(out[:, ALPHA])  # eq. 5.3
    return out
