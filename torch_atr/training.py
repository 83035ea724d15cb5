"""What ``train.py`` needs beyond the model: its config, the view grids and the rendered data.

The training set of chapter 6.1: every training vehicle rendered at a grid of views on the
hemisphere (azimuth step 12°, elevation step 10° over [0°, 40°] by default: 150 views) and
encoded by the clipped signed distance (METHOD.md "Templates").
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Sequence

import torch
from tqdm import tqdm

from torch_atr.config import ConfigError, ModelConfig, TemplateConfig
from torch_atr.render import render_templates
from torch_atr.shape import signed_distance

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ViewGridConfig:
    """The training views: azimuths 0, s_θ, … < 360°, elevations 0, s_φ, … ≤ φ_max (degrees)."""

    azimuth_step_deg: float = 12.0
    elevation_step_deg: float = 10.0
    elevation_max_deg: float = 40.0

    def __post_init__(self) -> None:
        if not 0 < self.azimuth_step_deg <= 180:
            raise ConfigError(f"views.azimuth_step_deg must be in (0, 180]; got {self.azimuth_step_deg}")
        if not self.elevation_step_deg > 0:
            raise ConfigError(f"views.elevation_step_deg must be positive; got {self.elevation_step_deg}")
        if not 0 <= self.elevation_max_deg < 90:
            raise ConfigError(f"views.elevation_max_deg must be in [0, 90); got {self.elevation_max_deg}")

    def grid(self, d_theta_deg: float = 0.0, d_phi_deg: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
        """The grid, optionally offset: returns theta, phi (V,) float64 radians, θ varying fastest.

        Offsets shift every view (the held-out views of issue 3 use half a step: +6°, +5°);
        θ wraps to [0, 2π).
        """
        n_theta = round(360.0 / self.azimuth_step_deg)
        n_phi = math.floor(self.elevation_max_deg / self.elevation_step_deg + 1e-9) + 1
        th = (torch.arange(n_theta, dtype=torch.float64) * self.azimuth_step_deg + d_theta_deg) % 360.0
        ph = torch.arange(n_phi, dtype=torch.float64) * self.elevation_step_deg + d_phi_deg
        phi, theta = torch.meshgrid(ph, th, indexing="ij")
        return torch.deg2rad(theta.reshape(-1)), torch.deg2rad(phi.reshape(-1))

    def validation(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Views for tuning the kernel widths: half-step offsets along ONE axis at a time.

        (θ + s_θ/2, φ) and (θ, φ + s_φ/2) for the grid's (θ, φ), so the diagonal offsets
        (θ + s_θ/2, φ + s_φ/2) used to report held-out IoU stay unseen by the tuning.
        Returns theta, phi (2V,) radians.
        """
        t1, p1 = self.grid(d_theta_deg=self.azimuth_step_deg / 2)
        t2, p2 = self.grid(d_phi_deg=self.elevation_step_deg / 2)
        return torch.cat([t1, t2]), torch.cat([p1, p2])

    def held_out(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The intermediate views of the quality bar: (θ + s_θ/2, φ + s_φ/2). Returns (V,) each."""
        return self.grid(self.azimuth_step_deg / 2, self.elevation_step_deg / 2)


@dataclass(frozen=True)
class TrainConfig:
    """``train.py``'s config: ``configs/default.yaml`` holds the shipped model's values."""

    name: str = "default"  # run name: TensorBoard logs go to <log_dir>/<name>
    checkpoint: str = "runs/default/model.pt"
    log_dir: str = "runs"
    tensorboard: bool = True
    seed: int = 0
    catalog: str = "train"  # "train": the shipped training split; else a folder with a catalog.yaml manifest
    evaluate_test_split: bool = True  # fit α for each held-out test vehicle and report its class
    template: TemplateConfig = field(default_factory=TemplateConfig)
    views: ViewGridConfig = field(default_factory=ViewGridConfig)
    model: ModelConfig = field(default_factory=ModelConfig)


def render_set(vehicles: Sequence, theta: torch.Tensor, phi: torch.Tensor, cfg: TemplateConfig,
               desc: str = "rendering") -> tuple[torch.Tensor, torch.Tensor]:
    """Render and encode every vehicle at every view.

    vehicles: K vehicles; theta, phi: (V,) radians.
    Returns (masks (K, V, H, W) bool, signed (K, V, H, W) float32 in [−1, 1]).
    """
    masks = torch.stack([render_templates(v, theta, phi, cfg) for v in tqdm(vehicles, desc=desc, unit="vehicle")])
    signed = signed_distance(masks.reshape(-1, cfg.size_px, cfg.size_px), cfg.tau_px).reshape(masks.shape)
    return masks, signed
