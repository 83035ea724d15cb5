"""The README's Python examples run as written, from the repository root, and give what their
comments say (shapes, dtypes, values)."""

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


def test_api_tour_segmentation(monkeypatch):
    ns = run_block(2, monkeypatch)
    mask = ns["mask"]
    assert isinstance(mask, np.ndarray) and mask.shape == (512, 640) and mask.dtype == bool


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_blocks_use_only_public_names(index):
    """Examples import from the package's public modules, never a private name."""
    imports = re.findall(r"^from (\S+) import (.+)$", BLOCKS[index], re.M)
    assert imports
    for module, names in imports:
        assert not any(part.startswith("_") for part in module.split(".")), module
        assert not any(name.strip().startswith("_") for name in names.split(",")), names
