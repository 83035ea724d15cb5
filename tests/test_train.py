"""train.py end to end: a reduced run by default, the full default config under -m slow."""

import json
import math
from pathlib import Path

import pytest
import torch

import train
from torch_atr.config import ConfigError
from torch_atr.model import GenerativeShapeModel
from torch_atr.render import render_templates
from torch_atr.shape import iou
from torch_atr.vehicles import load_catalog

REPO = Path(__file__).resolve().parents[1]


def _run(tmp_path, *overrides):
    ckpt = tmp_path / "model.pt"
    report = train.main(["--config", str(REPO / "configs/default.yaml"), f"checkpoint={ckpt}",
                         f"log_dir={tmp_path / 'runs'}", "name=test", *overrides])
    return ckpt, report


def test_reduced_training_writes_a_loadable_checkpoint_and_logs(tmp_path):
    ckpt, report = _run(tmp_path, "template.size_px=32", "views.azimuth_step_deg=30", "views.elevation_step_deg=20",
                        "model.pixel_rank=48", "model.width_steps=3", "evaluate_test_split=false")
    raw = torch.load(ckpt, weights_only=True)
    assert raw["extra"]["config"]["template"]["size_px"] == 32
    model = GenerativeShapeModel.from_checkpoint(ckpt)
    assert len(model.vehicle_names) == 36 and model.core.pixel_rank == 48
    assert report["identity_self_match"]["all"]
    assert report["train_iou"]["all"] > 0.9
    assert json.loads((tmp_path / "runs/test/report.json").read_text())["views"] == 12 * 3
    assert list((tmp_path / "runs/test").glob("events.out.tfevents.*"))
    # Independent reference: the renderer, at views between the training ones.
    vehicles = {v.name: v for v in load_catalog("train")}
    theta = torch.tensor([math.radians(15.0), math.radians(200.0)])
    phi = torch.tensor([math.radians(10.0), math.radians(30.0)])
    for k in (0, 20):
        truth = render_templates(vehicles[model.vehicle_names[k]], theta, phi, model.template)
        recon = model.silhouette(model.alphas[k].expand(2), theta, phi)
        assert iou(recon, truth).mean() > 0.7  # 32 px, 30° steps: coarse but still the right shape


def test_bad_config_key_and_type_are_named(tmp_path):
    with pytest.raises(ConfigError, match="model.ridg"):
        _run(tmp_path, "model.ridg=1")
    with pytest.raises(ConfigError, match="template.size_px"):
        _run(tmp_path, "template.size_px=big")


@pytest.mark.slow
def test_default_training_meets_the_quality_bars(tmp_path):
    _, report = _run(tmp_path)
    assert report["train_iou"]["all"] >= 0.95 and min(report["train_iou"].values()) >= 0.9
    assert report["held_out_iou"]["all"] >= 0.85
    assert report["identity_self_match"]["all"]
