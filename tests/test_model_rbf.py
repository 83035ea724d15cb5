"""RBF view mapping (eq. 4.12-4.13) against numpy least squares, brute-force kernels and gradcheck."""

import math

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from torch_atr.model.rbf import KERNEL_FLOOR, RBFViewMapping, rbf_features, ridge_hat
from torch_atr.pose import view_vectors


def _grid(n_theta: int, phis_deg, dtype=torch.float64):
    theta = torch.arange(n_theta, dtype=dtype) * (2 * math.pi / n_theta)
    phi = torch.tensor(phis_deg, dtype=dtype).deg2rad()
    T, P = torch.meshgrid(theta, phi, indexing="ij")
    return T.reshape(-1), P.reshape(-1)


def test_rbf_features_match_brute_force():
    g = torch.Generator().manual_seed(1)
    u = view_vectors(torch.rand(7, generator=g, dtype=torch.float64) * 6,
                     torch.rand(7, generator=g, dtype=torch.float64))
    centres = view_vectors(torch.rand(5, generator=g, dtype=torch.float64) * 6,
                           torch.rand(5, generator=g, dtype=torch.float64))
    widths = torch.rand(5, generator=g, dtype=torch.float64) + 0.2
    psi = rbf_features(u, centres, widths).numpy()
    un, cn, wn = u.numpy(), centres.numpy(), widths.numpy()
    for n in range(7):
        for l in range(5):
            r = math.sqrt(sum((un[n, i] - cn[l, i]) ** 2 for i in range(3)))
            k = math.exp(-r * r / (2 * wn[l] ** 2))
            assert psi[n, l] == pytest.approx(k if k >= KERNEL_FLOOR else 0.0, rel=1e-12, abs=1e-14)
        np.testing.assert_allclose(psi[n, 5:], [1.0, *un[n]], rtol=0, atol=0)


def test_kernel_tail_is_truncated_not_denormal():
    """Far centres give exact zeros (no denormals, which slow matmuls 5x), near ones the Gaussian."""
    u = view_vectors(torch.tensor([0.0]), torch.tensor([0.0]))
    centres = view_vectors(torch.linspace(0, math.pi, 50), torch.zeros(50))
    psi = rbf_features(u, centres, torch.full((50,), 0.1))[0, :50]
    r = (centres - u).norm(dim=1)
    want = torch.exp(-r ** 2 / 0.02)
    assert (psi[want < KERNEL_FLOOR] == 0).all() and (want < KERNEL_FLOOR).sum() > 30
    torch.testing.assert_close(psi[want >= KERNEL_FLOOR], want[want >= KERNEL_FLOOR])
    assert not ((psi > 0) & (psi < torch.finfo(torch.float32).tiny)).any()


def test_rbf_features_rejects_bad_widths():
    with pytest.raises(ValueError, match=r"widths to have shape \(4\)"):
        rbf_features(torch.zeros(2, 3), torch.zeros(4, 3), torch.ones(3))
    u = view_vectors(torch.tensor([0.3, 1.0]), torch.tensor([0.1, 0.2]))
    c = view_vectors(torch.zeros(2), torch.zeros(2))
    for widths in ([0.0, 0.5], [-0.2, 0.5]):  # NaN features; a negative width acted as its absolute value
        with pytest.raises(ValueError, match=r"Expected widths > 0; got min"):
            rbf_features(u, c, torch.tensor(widths))
    with pytest.raises(ValueError, match=r"Expected u to be unit vectors .* got norms from 2 to 2"):
        rbf_features(2 * u, c, torch.ones(2))  # the kernel's 2 − 2 u·c gave 1.0 where exp(−‖2u − c‖²/2) is 3.7e-6
    with pytest.raises(ValueError, match=r"Expected centres_u to be unit vectors"):
        rbf_features(u, 0.5 * c, torch.ones(2))


@pytest.mark.parametrize("ridge", [1e-4, 0.0])
def test_ridge_hat_of_float32_features_is_the_svd_filter_solution(ridge):
    """W = U diag(s / (s² + λ)) Vᵀ of Ψ's SVD, in float64, for the shipped model's float32 features at
    its training views: the Gram ΨΨᵀ squares Ψ's condition number (2.9e5), and solved in float32 W was
    0.8 % off at λ = 1e-4 and 177 % at λ = 0."""
    from torch_atr.model import GenerativeShapeModel
    from conftest import SHIPPED_CHECKPOINT

    rbf = GenerativeShapeModel.from_checkpoint(SHIPPED_CHECKPOINT).rbf
    with torch.no_grad():
        psi = rbf(rbf.centres_theta, rbf.centres_phi)  # (V, P) float32
    U, S, Vh = torch.linalg.svd(psi.double(), full_matrices=False)
    want = U @ torch.diag(S / (S ** 2 + ridge)) @ Vh
    got = ridge_hat(psi, ridge)
    assert got.dtype == torch.float32
    assert float((got.double() - want).norm() / want.norm()) < 1e-5


def test_default_width_is_mean_nearest_chord():
    theta, phi = _grid(12, [0, 20, 40])
    rbf = RBFViewMapping(theta, phi)
    pts = view_vectors(theta, phi).numpy()
    dist, _ = cKDTree(pts).query(pts, k=2)
    torch.testing.assert_close(rbf.widths, torch.full((36,), dist[:, 1].mean(), dtype=torch.float64))
    assert rbf.log_width.requires_grad and rbf.psi_dim == 40
    assert set(rbf.state_dict()) == {"centres_theta", "centres_phi", "log_width"}


def test_default_width_is_mean_nearest_chord_of_irregular_centres():
    """Brute-force double loop over random centres, whose nearest-neighbour chords all differ (on the
    grid above every centre's nearest chord is the 20° elevation step, so a max or a min passed too)."""
    g = torch.Generator().manual_seed(3)
    theta = torch.rand(9, generator=g, dtype=torch.float64) * 2 * math.pi
    phi = torch.rand(9, generator=g, dtype=torch.float64) * 1.2
    pts = view_vectors(theta, phi).tolist()
    nearest = [min(math.dist(p, q) for j, q in enumerate(pts) if j != i) for i, p in enumerate(pts)]
    assert max(nearest) - min(nearest) > 0.05
    width = sum(nearest) / len(nearest)
    torch.testing.assert_close(RBFViewMapping(theta, phi).widths, torch.full((9,), width, dtype=torch.float64))


def test_given_init_width_is_the_kernel_width():
    """init_width = s is every centre's width, and the features are the direct Gaussian kernel sum
    exp(−‖u − cₗ‖² / (2 s²)) at it (the tests above used s = 1, where s and s² agree)."""
    theta, phi = _grid(8, [0, 30])
    rbf = RBFViewMapping(theta, phi, init_width=0.3)
    torch.testing.assert_close(rbf.widths, torch.full((16,), 0.3, dtype=torch.float64))
    g = torch.Generator().manual_seed(2)
    q_theta = torch.rand(5, generator=g, dtype=torch.float64) * 6
    q_phi = torch.rand(5, generator=g, dtype=torch.float64)
    u, centres = view_vectors(q_theta, q_phi).numpy(), view_vectors(theta, phi).numpy()
    kernel = np.exp(-((u[:, None] - centres[None]) ** 2).sum(-1) / (2 * 0.3 ** 2))
    with torch.no_grad():
        psi = rbf(q_theta, q_phi).numpy()
    np.testing.assert_allclose(psi[:, :16], np.where(kernel >= KERNEL_FLOOR, kernel, 0.0), rtol=1e-9, atol=1e-12)


def test_init_width_validation():
    with pytest.raises(ValueError, match="init_width"):
        RBFViewMapping(torch.zeros(3), torch.zeros(3), init_width=-1.0)
    with pytest.raises(ValueError, match="pass init_width"):
        RBFViewMapping(torch.zeros(3), torch.zeros(3))
    with pytest.raises(ValueError, match="at least 2 centres"):
        RBFViewMapping(torch.zeros(1), torch.zeros(1))


def test_centres_of_two_float_dtypes_give_one_dtype():
    # float32 θ with float64 φ made a float32 centres_theta beside float64 centres_phi and log_width.
    theta, phi = _grid(6, [0.0, 20.0])
    for t, p, dtype in ((theta.float(), phi, torch.float64), (theta, phi.float(), torch.float64),
                        (theta.float(), phi.tolist(), torch.float32)):
        assert {v.dtype for v in RBFViewMapping(t, p).state_dict().values()} == {dtype}
    rbf = RBFViewMapping(theta.float(), phi)
    reference = RBFViewMapping(theta.float().double(), phi)
    torch.testing.assert_close(rbf(theta, phi), reference(theta, phi), rtol=0, atol=0)


def test_forward_takes_lists_and_arrays_and_names_bad_queries():
    """A list of views raised AttributeError ('list' object has no attribute 'to')."""
    theta, phi = _grid(6, [0.0, 20.0])
    rbf = RBFViewMapping(theta, phi)
    expected = rbf(theta[:3], phi[:3])
    torch.testing.assert_close(rbf(theta[:3].tolist(), phi[:3].numpy()), expected, rtol=0, atol=0)
    with pytest.raises(ValueError, match=r"Expected phi to have shape \(3\); got \(2,\)"):
        rbf(theta[:3].tolist(), phi[:2].tolist())
    with pytest.raises(ValueError, match=r"Expected theta to be numeric"):
        rbf("0.3", [0.1])


def _lstsq_reference(psi: np.ndarray, Y: np.ndarray, ridge: float) -> np.ndarray:
    """Per-vehicle ridge regression as ordinary least squares on [Ψ; √λ I] b = [y; 0]."""
    V, P = psi.shape
    A = np.vstack([psi, math.sqrt(ridge) * np.eye(P)])
    out = []
    for Yk in Y:  # (V, d)
        rhs = np.vstack([Yk, np.zeros((P, Yk.shape[1]))])
        out.append(np.linalg.lstsq(A, rhs, rcond=None)[0].T)  # (d, P)
    return np.stack(out)


@pytest.mark.parametrize("n_centres_theta", [12, 4])  # Nc = V (V < P) and Nc < V - 4 (V > P)
def test_fit_matches_numpy_lstsq(n_centres_theta):
    theta, phi = _grid(12, [0, 20, 40])
    ct, cp = _grid(n_centres_theta, [10, 30])
    rbf = RBFViewMapping(ct, cp)
    g = torch.Generator().manual_seed(2)
    Y = torch.rand(3, theta.shape[0], 10, generator=g, dtype=torch.float64) * 2 - 1
    ridge = 1e-2
    B = rbf.fit(theta, phi, Y, ridge)
    assert B.shape == (3, 10, rbf.psi_dim)
    ref = _lstsq_reference(rbf(theta, phi).detach().numpy(), Y.numpy(), ridge)
    np.testing.assert_allclose(B.detach().numpy(), ref, rtol=1e-7, atol=1e-9)


def test_fit_takes_templates_of_another_float_dtype():
    # float32 templates (as rendered) on float64 centres (as train.py's grid) raised a matmul dtype RuntimeError.
    theta, phi = _grid(12, [0, 20])
    g = torch.Generator().manual_seed(4)
    Y = torch.rand(2, theta.shape[0], 6, generator=g, dtype=torch.float64)
    rbf = RBFViewMapping(theta, phi)
    expected = rbf.fit(theta, phi, Y, 1e-3)
    torch.testing.assert_close(rbf.fit(theta, phi, Y.float(), 1e-3), expected, rtol=0, atol=1e-6)
    narrow = RBFViewMapping(theta.float(), phi.float()).fit(theta, phi, Y, 1e-3)
    assert narrow.dtype == torch.float32
    torch.testing.assert_close(narrow, expected.float(), rtol=1e-4, atol=1e-4)


def test_fit_interpolates_training_views_at_zero_ridge():
    theta, phi = _grid(12, [0, 20, 40])
    rbf = RBFViewMapping(theta, phi)
    g = torch.Generator().manual_seed(3)
    Y = torch.rand(2, 36, 8, generator=g, dtype=torch.float64)
    B = rbf.fit(theta, phi, Y, 0.0)
    recon = torch.einsum("kdp,vp->kvd", B, rbf(theta, phi))
    torch.testing.assert_close(recon, Y, atol=1e-8, rtol=0)


def test_psi_is_continuous_across_zero_azimuth():
    theta, phi = _grid(12, [0, 20, 40])
    rbf = RBFViewMapping(theta, phi)
    eps = 1e-7
    phis = torch.tensor([0.0, 0.2, 0.6], dtype=torch.float64)
    before = rbf(torch.full((3,), 2 * math.pi - eps, dtype=torch.float64), phis)
    after = rbf(torch.full((3,), eps, dtype=torch.float64), phis)
    torch.testing.assert_close(before, after, atol=1e-6, rtol=0)
    shifted = rbf(torch.full((3,), 0.4 + 2 * math.pi, dtype=torch.float64), phis)
    torch.testing.assert_close(shifted, rbf(torch.full((3,), 0.4, dtype=torch.float64), phis))


def test_gradcheck_features_and_closed_form_fit():
    g = torch.Generator().manual_seed(4)
    theta, phi = _grid(6, [0, 30])
    centres_u = view_vectors(*_grid(4, [15]))
    u = view_vectors(theta, phi).requires_grad_(True)
    log_w = torch.full((4,), math.log(0.7), dtype=torch.float64, requires_grad=True)
    Y = torch.rand(2, 12, 3, generator=g, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda uu, lw: rbf_features(uu, centres_u, lw.exp()), (u, log_w))
    fit = lambda lw: torch.einsum("kvd,vp->kdp", Y, ridge_hat(rbf_features(u.detach(), centres_u, lw.exp()), 1e-3))
    assert torch.autograd.gradcheck(fit, (log_w,))


def test_fit_gradient_reaches_widths():
    theta, phi = _grid(12, [0, 20])
    rbf = RBFViewMapping(theta, phi)
    g = torch.Generator().manual_seed(5)
    Y = torch.rand(2, 24, 5, generator=g, dtype=torch.float64)
    held_out = rbf(theta + 0.26, phi + 0.1)
    (torch.einsum("kdp,vp->kvd", rbf.fit(theta, phi, Y, 1e-4), held_out) ** 2).sum().backward()
    assert rbf.log_width.grad is not None and torch.isfinite(rbf.log_width.grad).all()
    assert rbf.log_width.grad.abs().max() > 0


def test_ridge_hat_rejects_negative_ridge():
    with pytest.raises(ValueError, match="ridge"):
        ridge_hat(torch.ones(3, 5), -1.0)
