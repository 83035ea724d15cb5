"""train.py end to end: a reduced run by default, the full default config under -m slow."""

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import train
from torch_atr.config import ConfigError
from torch_atr.io import OutputExistsError
from torch_atr.model import GenerativeShapeModel
from torch_atr.render import render_templates
from torch_atr.shape import iou
from torch_atr.vehicles import load_catalog

REPO = Path(__file__).resolve().parents[1]


TINY = ("template.size_px=16", "template.tau_px=2", "views.azimuth_step_deg=60", "views.elevation_step_deg=40",
        "model.pixel_rank=8", "model.width_steps=0", "evaluate_test_split=false", "tensorboard=false")


def _run(tmp_path, *overrides, flags=()):
    ckpt = tmp_path / "model.pt"
    report = train.main(["--config", str(REPO / "configs/default.yaml"), *flags, f"checkpoint={ckpt}",
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

    # Re-runs: outputs are replaced only with --overwrite, and a file that is not ours never.
    report_path = tmp_path / "runs/test/report.json"
    assert json.loads(report_path.read_text())["format"] == "torch_atr.train_report" == report["format"]
    before = ckpt.read_bytes(), report_path.read_text()
    with pytest.raises(OutputExistsError, match=r"runs/test already holds a run \(report.json\); pass --overwrite"):
        _run(tmp_path, *TINY)
    report_path.unlink()  # a run folder without its report: an unfinished run, never replaced
    with pytest.raises(OutputExistsError, match="runs/test is not empty and holds no report.json of ours"):
        _run(tmp_path, *TINY, flags=["--overwrite"])
    report_path.write_text(before[1])
    with pytest.raises(OutputExistsError, match=rf"{ckpt} exists; pass --overwrite"):
        _run(tmp_path, *TINY, "name=other")
    notes = tmp_path / "my_notes.txt"
    notes.write_text("precious")
    with pytest.raises(OutputExistsError, match=rf"{notes} exists and is not a checkpoint; refusing .*even with "):
        _run(tmp_path, *TINY, f"checkpoint={notes}", "name=other", flags=["--overwrite"])
    assert notes.read_text() == "precious" and (ckpt.read_bytes(), report_path.read_text()) == before
    _, second = _run(tmp_path, *TINY, flags=["--overwrite"])
    assert json.loads(report_path.read_text())["views"] == second["views"] == 6 * 2
    assert GenerativeShapeModel.from_checkpoint(ckpt).core.pixel_rank == 8


def test_user_errors_print_one_line_and_exit_2(tmp_path):
    result = subprocess.run([sys.executable, str(REPO / "train.py"), "model.ridg=1", f"log_dir={tmp_path}"],
                            capture_output=True, text=True, cwd=tmp_path)
    assert result.returncode == 2
    assert result.stderr.startswith("train.py: error: override model.ridg=1: unknown config key(s) model.ridg;")
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert "configs/default.yaml" not in result.stderr


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


def test_non_finite_measures_are_named():
    from torch_atr.training import non_finite_keys

    report = {"views": 150, "train_iou": {"tank": 0.9, "car": math.nan}, "test_split": [{"mse": 0.1},
                                                                                        {"mse": math.inf}],
              "note": "nan", "ok": True}
    assert non_finite_keys(report) == ["train_iou.car", "test_split[1].mse"]
    assert non_finite_keys({"a": [1.0, 2]}) == []
