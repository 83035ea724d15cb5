"""Model and tracking measures against loops and hand-computed cases."""

import copy
import math

import numpy as np
import pytest
import torch

from torch_atr.evaluation import alpha_grid_iou, per_class_mean, rbf_mapping_iou
from torch_atr.model.rbf import RBFViewMapping


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


def test_alpha_grid_iou_equals_a_loop_over_alpha_of_the_model_silhouette(model):
    from torch_atr.shape import iou

    theta = torch.tensor([0.3, 2.0, 4.0], dtype=torch.float64)
    phi = torch.tensor([0.1, 0.3, 0.0], dtype=torch.float64)
    masks = torch.stack([model.silhouette(model.alphas[k].expand(3), theta, phi) for k in (0, 30)])  # (2, 3, H, W)
    masks[1, 2] = False  # an empty view
    got = alpha_grid_iou(model, masks, theta, phi, grid=7)
    assert got.shape == (2, 7, 3)
    for a in range(7):
        alpha = torch.full((3,), 2 * math.pi * a / 7, dtype=torch.float64)
        recon = model.silhouette(alpha, theta, phi)
        for b in range(2):
            torch.testing.assert_close(got[b, a], iou(recon, masks[b]).to(got), atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="masks"):
        alpha_grid_iou(model, masks[0], theta, phi)


def test_masks_and_signed_distances_are_not_confused(model):
    """A float "mask" scored 1.0 everywhere, and fit_alpha on bool silhouettes found a wrong α
    with no complaint: each measure now names what it was given against what it takes."""
    from torch_atr.evaluation import fit_alpha, identity_distances, reconstruction_iou

    theta = torch.tensor([0.3, 2.0, 4.0])
    phi = torch.tensor([0.1, 0.3, 0.0])
    signed = model(model.alphas[5].expand(3), theta, phi)  # (3, S, S)
    K = len(model.alphas)
    cases = [(alpha_grid_iou, signed[None], "masks to be bool silhouettes; got dtype torch.float32"),
             (fit_alpha, signed > 0, "signed to be floating signed distances"),
             (identity_distances, (signed > 0)[None].expand(K, -1, -1, -1), "signed to be floating"),
             (identity_distances, signed[None].expand(K + 4, -1, -1, -1), rf"signed to have shape \({K}, "),
             (reconstruction_iou, signed[None].expand(K, -1, -1, -1), "templates to be bool silhouettes"),
             (fit_alpha, signed[:, :32, :32], "signed to have shape"),
             (fit_alpha, signed[:0], "at least one view")]
    for function, templates, message in cases:
        views = templates.shape[-3]
        with pytest.raises(ValueError, match=message):
            function(model, templates, theta[:views], phi[:views])


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_signed_distances_are_refused(model, bad):
    """One NaN (or infinite) pixel made every loss of fit_alpha NaN: it answered α = 0 with a NaN error
    and no complaint; identity_distances gave NaN rows and rbf_mapping_iou scored the pixel as outside."""
    from torch_atr.evaluation import fit_alpha, identity_distances

    theta = torch.tensor([0.3, 2.0, 4.0])
    phi = torch.tensor([0.1, 0.3, 0.0])
    with torch.no_grad():
        signed = model(model.alphas[5].expand(3), theta, phi)  # (3, S, S)
    signed[1, 7, 9] = bad
    with pytest.raises(ValueError, match=r"Expected signed to be finite signed distances; 1 value\(s\) are NaN"):
        fit_alpha(model, signed, theta, phi)
    K = len(model.alphas)
    with pytest.raises(ValueError, match="Expected signed to be finite signed distances"):
        identity_distances(model, signed[None].expand(K, -1, -1, -1), theta, phi)
    rbf = RBFViewMapping(theta, phi, init_width=0.5)
    with pytest.raises(ValueError, match="Expected signed to be finite signed distances"):
        rbf_mapping_iou(rbf, signed[None], theta, phi, signed[None] > 0, theta, phi, 1e-3)


def test_fit_alpha_below_zero_by_a_hair_wraps_to_zero_not_two_pi(model, monkeypatch):
    """Brent's search brackets the grid's best α by a step either side, so below 0 after α = 0: a refined α of
    -1e-20 came back as -1e-20 % 2π, which rounds to 2π itself, outside the promised [0, 2π)."""
    import scipy.optimize

    from torch_atr.evaluation import fit_alpha

    theta, phi = torch.tensor([0.3, 2.0]), torch.tensor([0.1, 0.3])
    signed = model(model.alphas[5].expand(2), theta, phi)
    monkeypatch.setattr(scipy.optimize, "minimize_scalar",
                        lambda *args, **kwargs: scipy.optimize.OptimizeResult(x=-1e-20, fun=-1.0))
    assert fit_alpha(model, signed, theta, phi) == (0.0, -1.0)


def test_alpha_grid_must_be_a_whole_number(model):
    """grid=10.5 gave alpha_grid_iou 11 columns at 2π·a/10.5 (uneven across the wrap), grid=True one column,
    and fit_alpha searched 361 α for grid=360.5: the docstrings promise (B, grid, V) at 2π·a/grid."""
    from torch_atr.evaluation import fit_alpha

    theta = torch.tensor([0.3, 2.0])
    phi = torch.tensor([0.1, 0.3])
    with torch.no_grad():
        signed = model(model.alphas[5].expand(2), theta, phi)  # (2, S, S)
    for grid in (10.5, True, "10", 0):
        with pytest.raises(ValueError, match=r"grid: expected an integer >= 1; got"):
            alpha_grid_iou(model, (signed > 0)[None], theta, phi, grid=grid)
    for grid in (360.5, True, 2):
        with pytest.raises(ValueError, match=r"grid: expected an integer >= 3; got"):
            fit_alpha(model, signed, theta, phi, grid=grid)
    assert alpha_grid_iou(model, (signed > 0)[None], theta, phi, grid=np.int64(4)).shape == (1, 4, 2)


def test_views_given_as_lists_keep_a_float64_models_precision_and_bools_are_refused(model):
    """Views given as lists were read as float32 before they were widened: a float64 model fitted α to
    θ off by ~1e-8 (4e-8 rad apart from the same views as float64 tensors). Bools were 0 and 1 radians."""
    from torch_atr.evaluation import fit_alpha, identity_distances

    wide = copy.deepcopy(model).double()
    theta, phi = [0.1, 1.3, 2.9], [0.05, 0.3, 0.6]
    exact = torch.tensor(theta, dtype=torch.float64), torch.tensor(phi, dtype=torch.float64)
    with torch.no_grad():
        signed = wide(wide.alphas[2].expand(3) + 0.1, *exact)  # (3, S, S)
    assert fit_alpha(wide, signed, theta, phi) == fit_alpha(wide, signed, *exact)
    masks = (signed > 0)[None].expand(len(wide.alphas), -1, -1, -1)
    torch.testing.assert_close(identity_distances(wide, signed[None].expand_as(masks), np.array(theta), phi),
                               identity_distances(wide, signed[None].expand_as(masks), *exact), rtol=0, atol=0)
    flags = np.array([True, False, True])
    with pytest.raises(ValueError, match="Expected theta to be numeric"):
        fit_alpha(wide, signed, flags, phi)
    with pytest.raises(ValueError, match="Expected phi to be numeric"):
        alpha_grid_iou(wide, masks[:1], theta, torch.tensor(flags), grid=4)
    rbf = RBFViewMapping(*exact, init_width=0.5)
    with pytest.raises(ValueError, match="Expected theta_out to be numeric"):
        rbf_mapping_iou(rbf, signed[None], *exact, masks[:1], flags, phi, 1e-3)


def test_identity_distances_against_a_loop_in_the_models_dtype(model):
    """identity_distances stored its errors in float32 whatever the model's dtype (a float64 model's
    were rounded to 7 digits); the reference is the mean squared error of each reconstruction, by hand."""
    from torch_atr.evaluation import identity_distances

    wide = copy.deepcopy(model).double()
    K = len(wide.alphas)
    theta = torch.tensor([0.1, 2.9], dtype=torch.float64)
    phi = torch.tensor([0.05, 0.6], dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    S = wide.template.size_px
    signed = torch.rand(K, 2, S, S, generator=g, dtype=torch.float64) * 2 - 1
    got = identity_distances(wide, signed, theta, phi)
    assert got.dtype == torch.float64 and got.shape == (K, K)
    with torch.no_grad():
        for k in (0, 7, K - 1):
            recon = wide(wide.alphas[k].expand(2), theta, phi).numpy()  # (2, S, S)
            for j in (0, 3, K - 1):
                assert got[k, j].item() == pytest.approx(((signed[j].numpy() - recon) ** 2).mean(), rel=1e-12)


def test_tracking_errors_by_hand():
    from torch_atr.evaluation import tracking_errors

    est = {"x": np.array([1.0, 2.0, np.nan, 0.0]), "z": np.array([100.0, 90.0, 95.0, 110.0]),
           "theta": np.array([0.1, 6.2, 3.0, 1.0])}
    truth = {"x": np.array([0.5, 2.5, 1.0, np.nan]), "z": np.array([100.0, 100.0, 100.0, 100.0]),
             "theta": np.array([6.2, 0.1, 3.5, np.nan])}
    got = tracking_errors(est, truth)
    assert got["horizontal_error_m"] == pytest.approx(0.5)  # frames 0, 1
    assert got["range_error_m"] == pytest.approx((0 + 10 + 5 + 10) / 4)
    wrap = 2 * math.pi - 6.1  # 0.1 and 6.2 are 0.183 apart across 0, not 6.1
    assert got["aspect_error_rad"] == pytest.approx((wrap + wrap + 0.5) / 3)
    assert got["aspect_error_up_to_mirror_rad"] == pytest.approx((wrap + wrap + 0.5) / 3)  # each mirror is farther
    mirrored = tracking_errors({"x": np.zeros(1), "z": np.zeros(1), "theta": np.array([2.0])},
                               {"x": np.zeros(1), "z": np.zeros(1), "theta": np.array([1.0])})
    assert mirrored["aspect_error_rad"] == pytest.approx(1.0)
    assert mirrored["aspect_error_up_to_mirror_rad"] == pytest.approx(math.pi - 3.0)  # 2.0 against π − 1.0
    none = tracking_errors({k: np.full(2, np.nan) for k in est}, {k: np.full(2, np.nan) for k in truth})
    assert none == {"horizontal_error_m": None, "range_error_m": None, "aspect_error_rad": None,
                    "aspect_error_up_to_mirror_rad": None}
    assert tracking_errors({k: list(v) for k, v in est.items()}, truth) == got  # lists are arrays
    with pytest.raises(ValueError, match=r"arrays of one shape \(T,\); got est\['x'\] \(1,\), est\['z'\] \(4,\)"):
        tracking_errors({**est, "x": est["x"][:1]}, truth)  # broadcast to 4 frames, it gave an error of 4 m
    with pytest.raises(ValueError, match=r"Expected truth\['theta'\], a \(T,\) array; truth has keys \['x', 'z'\]"):
        tracking_errors(est, {"x": truth["x"], "z": truth["z"]})


def test_the_aspect_error_up_to_the_mirror_counts_pi_minus_theta_right():
    """By hand: θ = 1.0 against its mirror π − 1.0 = 2.1416 (0 off), 2.0 (0.1416 off the mirror,
    1.0 off the truth), 1.2 (0.2 off the truth); across the wrap, θ = 3.0 against π − 3.0 = 0.1416,
    an estimate of 6.2 lies 0.2248 from it (6.2 − 2π = −0.0832); NaN stays NaN."""
    from torch_atr.evaluation import mirror_aspect_error

    truth = np.array([1.0, 1.0, 1.0, 3.0, np.nan])
    got = mirror_aspect_error(np.array([math.pi - 1.0, 2.0, 1.2, 6.2, 0.5]), truth)
    np.testing.assert_allclose(got[:4], [0.0, math.pi - 3.0, 0.2, 0.1416 - (6.2 - 2 * math.pi)], atol=1e-4)
    assert math.isnan(got[4])
    with pytest.raises(ValueError, match=r"of one shape \(T,\); got \(2,\) and \(3,\)"):
        mirror_aspect_error(np.zeros(2), np.zeros(3))


def test_recognition_best_matches_and_convergence(model):
    from torch_atr.evaluation import best_matches, frames_to_convergence, recognition_accuracy

    names = model.class_names
    k0 = 0
    own = names[model.vehicle_classes[k0]]
    other = next(n for n in names if n != own)
    alpha = np.array([model.alphas[k0].item()] * 3 + [np.nan])
    assert recognition_accuracy(model, alpha, [own, own, other, own]) == pytest.approx(2 / 4)
    assert recognition_accuracy(model, alpha, ["", "", "", ""]) is None
    assert best_matches(model, alpha)[0] == model.vehicle_names[k0]
    assert best_matches(model, np.full(3, np.nan)) == []
    # α either side of 0 (one estimate wrapped): their circular mean is 0, their plain mean π. The
    # two names nearest 0 by brute-force circular distance, nearest first.
    gap = np.abs((model.alphas.double().numpy() + math.pi) % (2 * math.pi) - math.pi)
    near = [model.vehicle_names[i] for i in np.argsort(gap, kind="stable")[:2]]
    assert best_matches(model, np.array([0.05, 2 * math.pi - 0.05, 0.05, 2 * math.pi - 0.05])) == near
    ok = np.array([0, 1, 1, 0] + [1] * 12, dtype=bool)
    assert frames_to_convergence(ok) == 4 and frames_to_convergence(ok[:8]) is None


def test_frames_to_convergence_refuses_what_is_not_a_bool_per_frame():
    """Errors passed for the flags (every non-zero one true) converged at frame 0; the flags themselves
    converge where ten in a row begin."""
    from torch_atr.evaluation import frames_to_convergence

    errors = np.array([0.5, 2.0, 0.1] + [0.2] * 12)
    with pytest.raises(ValueError, match=r"Expected ok to be a bool array of shape \(T,\); got shape \(15,\), "
                                         r"dtype float64"):
        frames_to_convergence(errors)
    with pytest.raises(ValueError, match=r"Expected ok .*; got shape \(1, 15\), dtype bool"):
        frames_to_convergence((errors < 1.0)[None])
    assert frames_to_convergence(errors < 1.0) == 2


def test_best_matches_refuses_alpha_that_is_not_one_per_frame(model):
    """A (T, 2) alpha was flattened into one sequence of 2T estimates."""
    from torch_atr.evaluation import best_matches

    with pytest.raises(ValueError, match=r"Expected alpha to have shape \(T,\); got \(3, 2\)"):
        best_matches(model, np.full((3, 2), 0.5))


def test_recognition_accuracy_refuses_alpha_that_is_not_one_per_frame(model):
    """A 0-d alpha raised a bare IndexError reading its length."""
    from torch_atr.evaluation import recognition_accuracy

    own = model.class_names[model.vehicle_classes[0]]
    with pytest.raises(ValueError, match=r"Expected alpha to have shape \(T,\); got \(\)"):
        recognition_accuracy(model, np.float64(model.alphas[0]), [own])
    with pytest.raises(ValueError, match=r"Expected alpha to have shape \(T,\); got \(2, 1\)"):
        recognition_accuracy(model, np.zeros((2, 1)), [own, own])
