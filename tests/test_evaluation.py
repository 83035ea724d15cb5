import math
from pathlib import Path

import numpy as np
import pytest
import torch

from torch_atr.evaluation import alpha_grid_iou, per_class_mean, rbf_mapping_iou
from torch_atr.model import GenerativeShapeModel
from torch_atr.model.rbf import RBFViewMapping


@pytest.fixture(scope="module")
def model():
    return GenerativeShapeModel.from_checkpoint(Path(__file__).resolve().parents[1] / "checkpoints" / "default.pt")


def test_per_class_mean_against_a_loop():
    values = torch.tensor([0.1, 0.5, 0.9, 0.3, 0.7])
    classes = [2, 0, 2, 0, 2]
    got = per_class_mean(values, classes, ["a", "b", "c"])
    assert set(got) == {"a", "c", "all"}  # no vehicle of class "b"
    assert got["a"] == pytest.approx((0.5 + 0.3) / 2) and got["c"] == pytest.approx((0.1 + 0.9 + 0.7) / 3)
    assert got["all"] == pytest.approx(values.mean().item())
    with pytest.raises(ValueError, match="values"):
        per_class_mean(values[:4], classes, ["a", "b", "c"])


def test_rbf_mapping_iou_equals_explicit_mappings_applied_at_new_views():
    g = torch.Generator().manual_seed(0)
    theta = torch.arange(12, dtype=torch.float64) * (2 * math.pi / 12)
    phi = torch.full((12,), 0.2, dtype=torch.float64)
    signed = torch.randn(3, 12, 5, 5, generator=g, dtype=torch.float64)
    theta_out, phi_out = theta[:4] + 0.2, phi[:4] + 0.1
    masks_out = torch.rand(3, 4, 5, 5, generator=g) > 0.5
    rbf = RBFViewMapping(theta, phi).double()
    B = rbf.fit(theta, phi, signed.reshape(3, 12, 25), 1e-3)  # (K, d, P), the closed form of eq. 4.13
    pred = torch.einsum("kdp,up->kud", B, rbf(theta_out, phi_out)).reshape(3, 4, 5, 5)
    expected = ((pred > 0) & masks_out).sum((2, 3)) / ((pred > 0) | masks_out).sum((2, 3)).clamp_min(1)
    got = rbf_mapping_iou(rbf, signed, theta, phi, masks_out, theta_out, phi_out, 1e-3)
    torch.testing.assert_close(got, expected.float(), check_dtype=False)


from torch_atr.evaluation import alpha_grid_iou, per_class_mean, rbf_mapping_iou
from torch_atr.model import GenerativeShapeModel
