"""The README's Python examples run as written, from the repository root, and give what their
comments say (shapes, dtypes, values)."""

import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
BLOCKS = re.findall(r"^```python\n(.*?)^```", (REPO / "README.md").read_text(encoding="utf-8"), re.S | re.M)


def run_block(index: int, monkeypatch) -> dict:
    """Execute README Python block ``index`` (0-based) as a script from the repository root; its globals."""
    monkeypatch.chdir(REPO)
    namespace = {"__name__": "__readme__"}
    exec(compile(BLOCKS[index], f"README.md python block {index + 1}", "exec"), namespace)
    return namespace


def test_readme_has_the_blocks_these_tests_check():
    assert len(BLOCKS) == 3
    assert "Tracker(" in BLOCKS[0] and "render_templates" in BLOCKS[1] and "ForegroundSegmenter" in BLOCKS[2]


def test_api_tour_tracking(monkeypatch):
    ns = run_block(0, monkeypatch)
    result, row, live = ns["result"], ns["row"], ns["live"]
    x, cls = result.column("x"), result.column("class")
    assert x.shape == (60,) and np.isfinite(x).all()  # "(60,) metres"
    assert cls.shape == (60,) and cls.dtype.kind == "U" and (cls == "suv").mean() > 0.5  # "(60,) str: 'suv', ..."
    assert result.frames_per_second > 0
    metrics = result.metrics(ns["model"])  # metrics.json's measures, from the rows by hand here
    assert metrics["horizontal_error_m"] == pytest.approx(
        np.nanmean(np.abs(result.column("x") - result.column("true_x"))), rel=1e-12)
    assert metrics["recognition_accuracy"] == pytest.approx(np.mean(cls == "suv"))
    assert {"class", "x", "lost"} <= row.keys()
    scores = live.score(live.last_mask, live.particles)
    assert scores.shape == (live.particles.shape[0],)  # "(N,) eq. 5.2 of any (N, 6) hypotheses"


def test_api_tour_model(monkeypatch):
    ns = run_block(1, monkeypatch)
    masks, sd, y, mask = ns["masks"], ns["sd"], ns["y"], ns["mask"]
    assert len(ns["vehicles"]) == 36  # "36 URDF vehicles (6 per class)"
    assert masks.shape == (2, 64, 64) and masks.dtype == torch.bool and masks.any()
    assert sd.shape == (2, 64, 64) and float(sd.min()) >= -1 and float(sd.max()) <= 1
    assert ((sd > 0) == masks).all()  # "positive inside"
    assert y.shape == (2, 64, 64)
    assert isinstance(mask, torch.Tensor) and mask.shape == (512, 640) and mask.dtype == torch.bool and mask.any()
    # the lines whose value the README only names in a comment
    model, alpha, catalog = ns["model"], ns["alpha"], {v.name: v.cls for v in ns["vehicles"]}
    assert len(ns["load_catalog"]("test")) == 8  # "test": 8 held-out
    assert ns["t72"].joints["turret_yaw"] == 0.5  # articulated turret
    own = ns["own"]
    assert own.cls == "pickup" and own.mesh.extents.argmax() == 0 and 4 < own.mesh.extents[0] < 7  # forward: x
    classes = [model.class_names[int(c)] for c in model.classify(alpha)]
    assert classes == [catalog[name] for name in model.vehicle_names[:2]]  # the training vehicles' own classes
    assert model.nearest_vehicles(alpha, k=2)[:, 0].tolist() == [0, 1]  # each is its own nearest
    theta, phi = ns["view_of_pose"](ns["pose"], ns["camera"])  # the camera 3 m above, 1000 m away, side-on
    assert abs(float(phi) - math.atan2(3.0, 1000.0)) < 1e-9 and abs(abs(math.sin(float(theta))) - 1) < 1e-9


def test_api_tour_segmentation(monkeypatch):
    ns = run_block(2, monkeypatch)
    mask = ns["mask"]
    assert isinstance(mask, np.ndarray) and mask.shape == (512, 640) and mask.dtype == bool


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_blocks_use_only_public_names(index):
    """Examples import from the package's public modules, never a private name."""
    text = re.sub(r"\(([^)]*)\)", lambda m: m.group(1).replace("\n", " "), BLOCKS[index])  # (a,\n b) on one line
    imports = re.findall(r"^from (\S+) import (.+)$", text, re.M)
    modules = [m for line in re.findall(r"^import (.+)$", text, re.M) for m in line.split(",")]
    assert imports
    for module, names in imports:
        assert not any(part.startswith("_") for part in module.split(".")), module
        assert not any(name.strip().startswith("_") for name in names.split(",")), names
    for module in modules:  # import pkg._private
        assert not any(part.startswith("_") for part in module.split(" as ")[0].strip().split(".")), module
