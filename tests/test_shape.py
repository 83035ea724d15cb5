"""torch_atr.shape against scipy's exact EDT and brute-force set counts."""

import numpy as np
import pytest
import torch
from scipy import ndimage

from torch_atr.shape import clip_distance, dice, iou, signed_distance, signed_distance_px, silhouette


def _blobs(rng: np.random.Generator, n: int, h: int, w: int) -> np.ndarray:
    """(n, h, w) bool: random smoothed-noise blobs, several touching the border."""
    noise = rng.normal(size=(n, h, w))
    smooth = np.stack([ndimage.gaussian_filter(x, sigma=3, mode="wrap") for x in noise])
    return smooth > 0.05


def _reference_sdt(mask: np.ndarray, tau: float) -> np.ndarray:
    """scipy: distance_transform_edt gives each non-zero pixel its distance to the nearest zero."""
    d = ndimage.distance_transform_edt(mask) - ndimage.distance_transform_edt(~mask)
    return np.clip(d, -tau, tau) / tau


@pytest.mark.parametrize("tau", [3.0, 6.0, 100.0])
def test_signed_distance_matches_scipy(tau):
    masks = _blobs(np.random.default_rng(0), 8, 40, 56)
    masks[0] = False
    masks[0, :, :5] = True  # a band along the left border
    masks[1] = True
    masks[1, 17, 30] = False  # a single hole
    assert masks[2:].any(axis=(1, 2)).all() and not masks[2:].all(axis=(1, 2)).any()
    assert (masks[:, 0, :].any() and masks[:, :, -1].any()), "blobs should touch the border"
    got = signed_distance(torch.from_numpy(masks), tau)
    assert got.dtype == torch.float32 and got.shape == masks.shape and got.device.type == "cpu"
    ref = np.stack([_reference_sdt(m, tau) for m in masks])
    np.testing.assert_allclose(got.numpy(), ref, atol=1e-4, rtol=0)


def test_signed_distance_values_and_single_mask():
    mask = np.zeros((9, 9), dtype=bool)
    mask[2:7, 2:7] = True  # 5 x 5 square
    got = signed_distance(mask, tau_px=100.0).numpy() * 100.0
    assert got[4, 4] == pytest.approx(3.0, abs=1e-5)  # centre: 3 px to the nearest outside pixel
    assert got[2, 2] == pytest.approx(1.0, abs=1e-5)
    assert got[1, 4] == pytest.approx(-1.0, abs=1e-5)
    assert got[0, 0] == pytest.approx(-2 * np.sqrt(2), abs=1e-4)
    assert (np.abs(got) >= 1 - 1e-6).all()


def test_signed_distance_px_is_unclipped_and_finite():
    masks = _blobs(np.random.default_rng(2), 4, 30, 50)
    got = signed_distance_px(torch.from_numpy(masks))
    ref = np.stack([ndimage.distance_transform_edt(m) - ndimage.distance_transform_edt(~m) for m in masks])
    assert np.abs(ref).max() > 6  # beyond any template clip
    np.testing.assert_allclose(got.numpy(), ref, atol=1e-4, rtol=0)
    none = signed_distance_px(torch.zeros(2, 30, 50, dtype=torch.bool))
    assert (none == -80).all()  # −(H + W): finite, beyond any in-image distance
    assert (signed_distance_px(np.ones((30, 50), dtype=bool)) == 80).all()


def test_clip_distance_per_batch_tau_against_numpy():
    d = torch.linspace(-20, 20, 41).expand(3, 2, 41).contiguous()
    tau = torch.tensor([1.0, 4.0, 9.5]).reshape(3, 1, 1)
    got = clip_distance(d, tau)
    want = np.clip(d.numpy(), -tau.numpy(), tau.numpy()) / tau.numpy()
    np.testing.assert_allclose(got.numpy(), want, rtol=1e-7)
    assert clip_distance(d.double(), 2.0).dtype == torch.float64
    with pytest.raises(ValueError, match="tau_px > 0"):
        clip_distance(d, torch.tensor([1.0, 0.0, 2.0]).reshape(3, 1, 1))
    with pytest.raises(ValueError, match="floating tensor"):
        clip_distance(torch.zeros(2, 2, dtype=torch.long), 1.0)


def test_signed_distance_empty_and_full_masks():
    masks = torch.zeros(2, 3, 16, 12, dtype=torch.bool)
    masks[1] = True
    got = signed_distance(masks, 6.0)
    assert got.shape == (2, 3, 16, 12)
    assert (got[0] == -1).all() and (got[1] == 1).all()


def test_silhouette_round_trip_is_exact():
    masks = _blobs(np.random.default_rng(1), 6, 32, 32)
    for tau in (1.0, 2.5, 6.0):
        y = signed_distance(masks, tau)
        assert torch.equal(silhouette(y), torch.from_numpy(masks))


def test_silhouette_is_strictly_positive_distance():
    """The module docstring: a reconstruction's silhouette is y > 0, so y = 0 (a zero crossing, or an
    all-zero reconstruction) is outside, and the smallest positive normal float inside."""
    assert not silhouette(torch.zeros(2, 2)).any()
    tiny = torch.finfo(torch.float32).tiny
    y = torch.tensor([[0.0, -0.0, tiny], [-tiny, 0.5, -0.5]])
    assert silhouette(y).tolist() == [[False, False, True], [False, True, False]]


def test_iou_and_dice_match_brute_force_counts():
    rng = np.random.default_rng(2)
    a = rng.random((2, 5, 7, 9)) < 0.4
    b = rng.random((2, 5, 7, 9)) < 0.6
    a[0, 0], b[0, 0] = False, False  # both empty: defined as 1
    a[0, 1], b[0, 1] = True, False  # one empty: 0
    got_iou, got_dice = iou(a, b), dice(torch.from_numpy(a), torch.from_numpy(b))
    assert got_iou.shape == (2, 5) and got_dice.shape == (2, 5)
    for idx in np.ndindex(2, 5):
        fa = {p for p in np.ndindex(7, 9) if a[idx][p]}
        fb = {p for p in np.ndindex(7, 9) if b[idx][p]}
        union, inter = len(fa | fb), len(fa & fb)
        want_iou = 1.0 if union == 0 else inter / union
        want_dice = 1.0 if not fa and not fb else 2 * inter / (len(fa) + len(fb))
        assert got_iou[idx].item() == pytest.approx(want_iou, abs=1e-6)
        assert got_dice[idx].item() == pytest.approx(want_dice, abs=1e-6)
    assert got_iou[0, 0] == 1 and got_iou[0, 1] == 0 and got_dice[0, 1] == 0


@pytest.mark.parametrize("bad, text", [
    (np.zeros(5, dtype=bool), r"\(5,\)"),
    (np.zeros((4, 0), dtype=bool), r"\(4, 0\)"),
    (np.zeros((4, 4), dtype=np.uint8), "bool"),
])
def test_signed_distance_bad_masks_raise(bad, text):
    with pytest.raises(ValueError, match=text):
        signed_distance(bad, 6.0)


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="tau_px"):
        signed_distance(np.zeros((4, 4), dtype=bool), 0.0)
    with pytest.raises(ValueError, match=r"\(3, 4\) and \(4, 4\)"):
        iou(torch.zeros(3, 4, dtype=torch.bool), torch.zeros(4, 4, dtype=torch.bool))
    with pytest.raises(ValueError, match=r"\(4,\)"):
        dice(torch.zeros(4, dtype=torch.bool), torch.zeros(4, dtype=torch.bool))
    with pytest.raises(ValueError, match="H, W"):
        silhouette(torch.zeros(4))


@pytest.mark.parametrize("tau", [float("inf"), float("nan"), 0.0, -1.0, torch.tensor(2.0), True])
def test_signed_distance_needs_a_finite_positive_number(tau):
    """tau_px = inf clipped every distance to 0 (an empty silhouette); a tensor failed in a bool test."""
    with pytest.raises(ValueError, match="tau_px to be a finite number > 0"):
        signed_distance(np.ones((4, 4), bool), tau)
