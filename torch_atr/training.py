"""What ``train.py`` needs beyond the model: its config, the view grids and the rendered data.

The training set of chapter 6.1: every training vehicle rendered at a grid of views on the
hemisphere (azimuth step 12°, elevation step 10° over [0°, 40°] by default: 150 views) and
encoded by the clipped signed distance (METHOD.md "Templates").
"""

from __future__ import annotations

import fnmatch
import logging
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import torch
from tqdm import tqdm

from torch_atr._checks import check_shape
from torch_atr.cli import error_text
from torch_atr.config import ConfigError, ModelConfig, TemplateConfig, check_seed
from torch_atr.render import render_templates
from torch_atr.shape import signed_distance
from torch_atr.validate import read_json_object, show

log = logging.getLogger(__name__)

MAX_VIEWS = 10_000  # training views (and RBF centres): the RBF solve is V x V, the templates K x V x H x W
REPORT_FORMAT = "torch_atr.train_report"  # the "format" of train.py's report.json
_RUN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")


def _dividing_steps(step: float) -> tuple[float, float]:
    """The steps in (0, 180] nearest ``step`` below and above it that divide 360 (degrees): whole
    degrees, or for a step under 1° multiples of its leading decimal place (0.7 -> 0.6 or 0.8)."""
    unit = min(1.0, 10.0 ** math.floor(math.log10(step)))
    units = round(360.0 / unit)  # 360° in units
    steps = [k * unit for k in range(1, units // 2 + 1) if units % k == 0]
    return max(s for s in steps if s < step), min(s for s in steps if s > step)


@dataclass(frozen=True)
class ViewGridConfig:
    """The training views: azimuths 0, s_θ, … < 360°, elevations 0, s_φ, … ≤ φ_max (degrees).

    s_θ must divide 360°, so the azimuths are evenly spaced across the wrap too.
    """

    azimuth_step_deg: float = 12.0
    elevation_step_deg: float = 10.0
    elevation_max_deg: float = 40.0

    def __post_init__(self) -> None:
        if not 0 < self.azimuth_step_deg <= 180:
            raise ConfigError(f"views.azimuth_step_deg must be in (0, 180]; got {self.azimuth_step_deg}")
        if not 0 < self.elevation_step_deg <= 90:
            raise ConfigError(f"views.elevation_step_deg must be in (0, 90]; got {self.elevation_step_deg}")
        if not 0 <= self.elevation_max_deg < 90:
            raise ConfigError(f"views.elevation_max_deg must be in [0, 90); got {self.elevation_max_deg}")
        if not math.isfinite(360.0 / self.azimuth_step_deg * (self.elevation_max_deg / self.elevation_step_deg + 1)):
            raise ConfigError(f"views: azimuth_step_deg={self.azimuth_step_deg:g} and elevation_step_deg="
                              f"{self.elevation_step_deg:g} give more views than a float counts; expected at most "
                              f"{MAX_VIEWS}")  # a step of 1e-313° (the counts below would be infinite)
        n_theta, n_phi = self.counts
        if n_theta * n_phi > MAX_VIEWS:
            raise ConfigError(f"views: azimuth_step_deg={self.azimuth_step_deg:g} and elevation_step_deg="
                              f"{self.elevation_step_deg:g} give {n_theta} x {n_phi} = {n_theta * n_phi} views; "
                              f"expected at most {MAX_VIEWS}")
        top = (n_phi - 1) * self.elevation_step_deg  # the grid's highest elevation
        if top + self.elevation_step_deg / 2 > 90:  # the held-out and validation views lie half a step above it
            raise ConfigError(f"views: elevation_step_deg={self.elevation_step_deg:g} and elevation_max_deg="
                              f"{self.elevation_max_deg:g} put the held-out views half a step above the top elevation "
                              f"{top:g}°, at {top + self.elevation_step_deg / 2:g}°, beyond the zenith; expected at "
                              f"most 90°: lower either")
        per_turn = 360.0 / self.azimuth_step_deg  # azimuths in 360°
        if abs(per_turn - n_theta) > 1e-9 * per_turn:
            below, above = _dividing_steps(self.azimuth_step_deg)
            wrap = 360.0 - (n_theta - 1) * self.azimuth_step_deg
            raise ConfigError(f"views.azimuth_step_deg={self.azimuth_step_deg:.12g} must divide 360 (e.g. {below:g} or "
                              f"{above:g}): 360/{self.azimuth_step_deg:g} = {per_turn:.4g} azimuths would leave a step "
                              f"of {wrap:.3g}° where they wrap")

    @property
    def counts(self) -> tuple[int, int]:
        """(azimuths, elevations) of the grid."""
        return (round(360.0 / self.azimuth_step_deg),
                math.floor(self.elevation_max_deg / self.elevation_step_deg + 1e-9) + 1)

    def grid(self, d_theta_deg: float = 0.0, d_phi_deg: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
        """The grid, optionally offset: returns theta, phi (V,) float64 radians, θ varying fastest.

        Offsets shift every view (the held-out views of issue 3 use half a step: +6°, +5°);
        θ wraps to [0, 2π).
        """
        n_theta, n_phi = self.counts
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


def shipped_model() -> ModelConfig:
    """The model section ``train.py`` defaults to: the shipped model's, which tunes the kernel widths
    for 50 Adam steps on the half-step validation views (held-out IoU +0.01; configs/default.yaml)."""
    return ModelConfig(width_steps=50)


@dataclass(frozen=True)
class TrainConfig:
    """``train.py``'s config. The defaults are the shipped model's, those of ``configs/default.yaml``,
    so a config file that leaves a key out gets the shipped value."""

    name: str = "default"  # run name: TensorBoard logs go to <log_dir>/<name>
    checkpoint: str | None = None  # null: <log_dir>/<name>/model.pt
    log_dir: str = "runs"
    tensorboard: bool = True
    seed: int = 0
    catalog: str = "train"  # "train": the shipped training split; else a catalog folder or its catalog.yaml
    evaluate_test_split: bool = True  # fit α for each held-out test vehicle and report its class
    template: TemplateConfig = field(default_factory=TemplateConfig)
    views: ViewGridConfig = field(default_factory=ViewGridConfig)
    model: ModelConfig = field(default_factory=shipped_model)

    def __post_init__(self) -> None:
        check_seed("seed", self.seed)
        # The run folder is <log_dir>/<name>: a plain folder name keeps it inside log_dir.
        if not _RUN_NAME.fullmatch(self.name):
            raise ConfigError(f"name must be a plain folder name (letters, digits and '._-', not starting with "
                              f"'.', at most 100 characters; no '/'); got {show(self.name)}")
        for key, value in (("checkpoint", self.checkpoint), ("log_dir", self.log_dir)):
            if value is not None and (not value.strip() or "\0" in value):
                raise ConfigError(f"{key} must be a path; got {show(value)}")
        if not self.catalog.strip():  # Path('') is '.': the current folder's catalog.yaml was read
            raise ConfigError(f"catalog must be 'train' or a catalog folder (or its catalog.yaml); "
                              f"got {show(self.catalog)}")
        for key in ("checkpoint", "log_dir", "catalog"):  # ~ as a shell would, for paths from config files
            if getattr(self, key) not in (None, "train"):
                object.__setattr__(self, key, os.path.expanduser(getattr(self, key)))

    @property
    def run_dir(self) -> Path:
        """<log_dir>/<name>: the run's TensorBoard logs, figures and report."""
        return Path(self.log_dir) / self.name

    @property
    def checkpoint_path(self) -> Path:
        """``checkpoint``, or <log_dir>/<name>/model.pt when it is null."""
        return Path(self.checkpoint) if self.checkpoint is not None else self.run_dir / "model.pt"


def check_checkpoint_path(checkpoint: Path, run_dir: Path, run_files: tuple[str, ...]) -> None:
    """Raise ConfigError naming the key ``checkpoint`` and its path when the run would write over its
    own checkpoint there: ``checkpoint`` is the run folder ``run_dir``, a folder above it, or one of
    the files the run writes into it (``run_files``: names or glob patterns, ``events.out.tfevents.*``)."""
    path, folder = checkpoint.resolve(), run_dir.resolve()
    default = f"(or leave checkpoint unset: {run_dir / 'model.pt'})"
    if path == folder or path in folder.parents:
        where = "the run folder" if path == folder else "a folder above the run folder"
        raise ConfigError(f"checkpoint={checkpoint} is {where} {run_dir}; the checkpoint must be a file of its own "
                          f"{default}")
    if path.parent == folder and any(fnmatch.fnmatchcase(path.name, pattern) for pattern in run_files):
        raise ConfigError(f"checkpoint={checkpoint} is the run's own {path.name} in {run_dir}, which the run writes "
                          f"over; give the checkpoint another path {default}")


def is_train_report(path: Path) -> bool:
    """True when ``path`` is a report.json written by train.py (a JSON object whose format is ours)."""
    try:
        return read_json_object(path, "").get("format") == REPORT_FORMAT
    except (OSError, ValueError):
        return False


def non_finite_keys(data, prefix: str = "") -> list[str]:
    """Dotted keys (``train_iou.tank``, ``test_split[2].mse``) of the NaN or infinite floats in nested
    dicts and lists of plain data, in order."""
    if isinstance(data, float):
        return [] if math.isfinite(data) else [prefix or "value"]
    if isinstance(data, dict):
        items = ((f"{prefix}.{k}" if prefix else str(k), v) for k, v in data.items())
    elif isinstance(data, (list, tuple)):
        items = ((f"{prefix}[{i}]", v) for i, v in enumerate(data))
    else:
        return []
    return [key for name, value in items for key in non_finite_keys(value, name)]


def render_set(vehicles: Sequence, theta: torch.Tensor, phi: torch.Tensor, cfg: TemplateConfig,
               desc: str = "rendering") -> tuple[torch.Tensor, torch.Tensor]:
    """Render and encode every vehicle at every view.

    vehicles: K vehicles; theta, phi: (V,) radians.
    Returns (masks (K, V, H, W) bool, signed (K, V, H, W) float32 in [−1, 1]).
    """
    masks = torch.stack([render_templates(v, theta, phi, cfg) for v in tqdm(vehicles, desc=desc, unit="vehicle")])
    signed = signed_distance(masks.reshape(-1, cfg.size_px, cfg.size_px), cfg.tau_px).reshape(masks.shape)
    return masks, signed


def check_templates(vehicles: Sequence, masks: torch.Tensor, cfg: TemplateConfig) -> None:
    """Raise ValueError naming the first vehicle whose templates are unusable: empty in a view (a
    model far too small, e.g. a file in metres given scale 0.001) or reaching the window's edge (too big
    for ``template.window_m``, so its silhouettes are cut).

    vehicles: K vehicles; masks: (K, V, S, S) bool, their templates (:func:`render_set`).
    """
    check_shape("masks", masks, (len(vehicles), "V", cfg.size_px, cfg.size_px))
    edge = masks[..., 0, :].any(-1) | masks[..., -1, :].any(-1) | masks[..., 0].any(-1) | masks[..., -1].any(-1)
    empty = ~masks.flatten(2).any(-1)
    for vehicle, empty_k, edge_k in zip(vehicles, empty, edge):
        size = " × ".join(f"{e:.3g}" for e in vehicle.mesh.extents)
        if empty_k.any():
            raise ValueError(f"vehicle {vehicle.name!r} ({size} m) covers no template pixel in {int(empty_k.sum())} "
                             f"of {len(empty_k)} views ({cfg.window_m:g} m window, {cfg.size_px} px): too small; check "
                             f"its length or scale")
        if edge_k.any():
            raise ValueError(f"vehicle {vehicle.name!r} ({size} m) reaches the edge of the {cfg.window_m:g} m template "
                             f"window in {int(edge_k.sum())} of {len(edge_k)} views: too big; check its length or "
                             f"scale, or widen template.window_m")


def trained_catalog(extra) -> str:
    """The catalog a checkpoint's model was trained on, from the checkpoint's ``extra``
    (:func:`~torch_atr.model.generative.load_checkpoint`): "train" (the shipped split) or the
    folder (or manifest) ``train.py catalog=PATH`` recorded; "train" when the checkpoint does not say."""
    config = extra.get("config") if isinstance(extra, dict) else None
    catalog = config.get("catalog") if isinstance(config, dict) else None
    return catalog if isinstance(catalog, str) else "train"


def training_templates(model, catalog: str = "train") -> torch.Tensor:
    """The training templates of a model re-rendered from its catalog (Method IV of the tracker).

    Renders the model's vehicles (by name, from ``catalog``: "train", a catalog folder or its manifest; see
    :func:`trained_catalog`) at its RBF centres (the training views of every model ``train.py``
    fits) with its template geometry. Returns (K, V, S, S) float32 signed distances in [−1, 1].
    Raises ValueError naming the vehicles the catalog lacks; warns of vehicles whose templates
    differ from the model's reconstruction (:data:`CATALOG_AGREEMENT`): files edited since training.
    """
    from torch_atr.evaluation import reconstruction_iou
    from torch_atr.vehicles import load_catalog, load_catalog_folder

    try:
        vehicles = load_catalog("train") if catalog == "train" else load_catalog_folder(catalog)
    except FileNotFoundError as exc:
        raise FileNotFoundError(f"Method IV re-renders the training vehicles from the catalog the checkpoint names: "
                                f"{error_text(exc)}") from None
    catalog_vehicles = {v.name: v for v in vehicles}
    missing = [name for name in model.vehicle_names if name not in catalog_vehicles]
    if missing:
        raise ValueError(f"Method IV re-renders the training vehicles, but catalog {catalog!r} lacks {missing}")
    theta, phi = model.rbf.centres_theta.detach().cpu(), model.rbf.centres_phi.detach().cpu()
    masks, signed = render_set([catalog_vehicles[name] for name in model.vehicle_names], theta, phi, model.template,
                               "Method IV templates")
    agreement = reconstruction_iou(model, masks, theta, phi).mean(1).tolist()
    changed = [f"{name} ({a:.2f})" for name, a in zip(model.vehicle_names, agreement) if a < CATALOG_AGREEMENT]
    if changed:
        log.warning("Method IV: has catalog %s changed since training? Its %s differ from what the model learned "
                    "(mean IoU of the model's reconstruction against the re-rendered templates below %.2f); Method IV "
                    "compares these templates, not the model's", catalog, ", ".join(changed), CATALOG_AGREEMENT)
    return signed


CATALOG_AGREEMENT = 0.8  # training_templates: a vehicle re-rendered below this mean IoU with its reconstruction
# has changed since training (the shipped model's lowest is 0.97, the T-55's; a Camry made 1.8 times as long gives
# 0.29 in tests/test_train.py)
