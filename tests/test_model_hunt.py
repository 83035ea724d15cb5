"""The whole fitted model against a from-scratch numpy/scipy composition of chapter 4, and fit_alpha against
brute force over α.

The reference shares no code with torch_atr.model: Ψ by a loop over centres (eq. 4.12-4.13), each Bᵏ
by numpy least squares on the ridge-augmented system, the pixel basis from numpy's SVD of the
templates, the vehicle order by brute force over permutations (eq. 4.10-4.11) and the identity spline
from scipy. With U₃ orthogonal (eq. 4.14), 𝒜 ×₃ i(α) ×₂ Ψ = Σₖ cₖ(α) Bᵏ Ψ, where cₖ is scipy's periodic
cubic spline through the unit vector of vehicle k at the sites: the identity vectors, their signs and
the HOSVD drop out.
"""

import itertools
import math

import numpy as np
import pytest
import torch
from scipy.interpolate import make_interp_spline

from torch_atr.config import ModelConfig, TemplateConfig
from torch_atr.evaluation import fit_alpha
from torch_atr.model import GenerativeShapeModel

K, S = 5, 8
TEMPLATE = TemplateConfig(size_px=S, window_m=4.0, tau_px=2.0)
CLASSES = [0, 1, 0, 1, 1]
RIDGE = 1e-3


def _views() -> tuple[np.ndarray, np.ndarray]:
    theta = np.repeat(np.arange(6) * (2 * np.pi / 6), 2)
    phi = np.tile(np.deg2rad([5.0, 35.0]), 6)
    return theta, phi


@pytest.fixture(scope="module")
def case():
    theta, phi = _views()
    rng = np.random.default_rng(7)
    # Smooth in the view, distinct per vehicle: a few random harmonics of θ and φ per pixel.
    a = rng.normal(size=(K, 3, S * S))
    basis = np.stack([np.ones_like(theta), np.cos(theta) * np.cos(phi), np.sin(theta) * np.cos(phi)])  # (3, V)
    Y = np.tanh(np.einsum("kcd,cv->kvd", a, basis))  # (K, V, d)
    templates = torch.tensor(Y.reshape(K, -1, S, S))
    models = {rank: GenerativeShapeModel.fit(templates, torch.tensor(theta), torch.tensor(phi),
                                             [f"v{k}" for k in range(K)], CLASSES, ["car", "tank"], TEMPLATE,
                                             ModelConfig(pixel_rank=rank, ridge=RIDGE))
              for rank in (None, 20)}
    return theta, phi, Y, models


def _u(theta, phi) -> np.ndarray:
    return np.stack([np.cos(phi) * np.cos(theta), np.cos(phi) * np.sin(theta), np.sin(phi)], axis=-1)


def _psi(theta, phi, ct, cp, widths) -> np.ndarray:
    """Ψ of eq. 4.13 by a loop: [κ(‖u − u(Υₗ)‖) …, 1, u], κ(r) = exp(−r² / (2 sₗ²))."""
    u, c = _u(theta, phi), _u(ct, cp)
    out = np.empty((len(u), len(c) + 4))
    for n in range(len(u)):
        for ell in range(len(c)):
            out[n, ell] = math.exp(-np.sum((u[n] - c[ell]) ** 2) / (2 * widths[ell] ** 2))
        out[n, len(c):] = [1.0, *u[n]]
    return out


def _tour_cost(D, tour) -> float:
    return sum(D[tour[i], tour[(i + 1) % len(tour)]] for i in range(len(tour)))


def _reference(theta, phi, Y, rank):
    """(B (K, d, P), projection (d, d), the order by brute force, the mean nearest chord) from numpy alone."""
    c = _u(theta, phi)
    chord = np.linalg.norm(c[:, None] - c[None], axis=-1)
    np.fill_diagonal(chord, np.inf)
    width = chord.min(1).mean()
    psi = _psi(theta, phi, theta, phi, np.full(len(theta), width))
    V, P = psi.shape
    A = np.vstack([psi, math.sqrt(RIDGE) * np.eye(P)])  # ridge as least squares: [Ψ; √λ I] b = [y; 0]
    B = np.stack([np.linalg.lstsq(A, np.vstack([Yk, np.zeros((P, Yk.shape[1]))]), rcond=None)[0].T for Yk in Y])
    if rank is None:
        projection = np.eye(Y.shape[-1])
    else:
        _, _, vt = np.linalg.svd(Y.reshape(-1, Y.shape[-1]), full_matrices=False)
        projection = vt[:rank].T @ vt[:rank]
    D = sum(np.linalg.norm(Y[:, None, m] - Y[None, :, m], axis=-1) for m in range(V))  # eq. 4.8-4.9
    D = D + (K + 1) * D.max() * (np.array(CLASSES)[:, None] != np.array(CLASSES)[None])
    best = min(((0, *p) for p in itertools.permutations(range(1, K))), key=lambda t: _tour_cost(D, t))
    return B, projection, D, best, width


def _cardinal(order, alpha) -> np.ndarray:
    """cₖ(α) (N, K): scipy's periodic cubic spline through the unit vectors e_order[j] at sites 2πj/K (the
    rows of an orthogonal U₃ are all √2 apart, so the chord-length sites are even)."""
    points = np.eye(K)[list(order)]
    sites = np.arange(K + 1) * (2 * np.pi / K)
    spline = make_interp_spline(sites, np.vstack([points, points[:1]]), k=3, bc_type="periodic")
    return spline(np.mod(alpha, 2 * np.pi))


@pytest.mark.parametrize("rank", [None, 20])
def test_fitted_model_equals_the_numpy_scipy_composition(case, rank):
    theta, phi, Y, models = case
    model = models[rank]
    B, projection, D, best, width = _reference(theta, phi, Y, rank)
    np.testing.assert_allclose(model.rbf.widths.detach().numpy(), width, rtol=1e-12)
    order = model.identity.order.tolist()
    assert _tour_cost(D, order) == pytest.approx(_tour_cost(D, best), rel=1e-12)
    np.testing.assert_allclose(model.alphas.numpy()[order], np.arange(K) * (2 * np.pi / K), rtol=0, atol=1e-12)

    rng = np.random.default_rng(3)
    alpha = np.concatenate([rng.uniform(-7, 14, 6), [0.0, 2 * np.pi, -1e-12, 2 * np.pi - 1e-12],
                            model.alphas.numpy()])
    th = rng.uniform(-1, 7, len(alpha))
    ph = rng.uniform(0, np.pi / 2, len(alpha))
    psi = _psi(th, ph, theta, phi, np.full(len(theta), width))
    expected = np.einsum("nk,kdp,np->nd", _cardinal(order, alpha), B, psi) @ projection  # projection symmetric
    with torch.no_grad():
        got = model(torch.tensor(alpha), torch.tensor(th), torch.tensor(ph)).reshape(len(alpha), -1).numpy()
        grid = model.reconstruct_grid(torch.tensor(alpha[:5]), torch.tensor(th[:4]), torch.tensor(ph[:4]))
        coords = model.reconstruct_grid(torch.tensor(alpha[:5]), torch.tensor(th[:4]), torch.tensor(ph[:4]),
                                        in_basis=True)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    grid_expected = np.einsum("ak,kdp,vp->avd", _cardinal(order, alpha[:5]), B, psi[:4]) @ projection
    np.testing.assert_allclose(grid.reshape(5, 4, -1).numpy(), grid_expected, rtol=0, atol=1e-9)
    basis = np.eye(S * S) if rank is None else model.core.pixel_basis.numpy()
    np.testing.assert_allclose(coords.numpy() @ basis.T, grid_expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(basis.T @ basis, np.eye(basis.shape[1]), rtol=0, atol=1e-12)


def test_fit_alpha_finds_the_brute_force_minimum(case):
    """fit_alpha (a 360-point grid, then Brent) against the mean squared error at 36000 α, for targets at
    a vehicle (α₀ = 0, on the seam), between vehicles, and with noise."""
    theta, phi, _, models = case
    model = models[20]
    rng = np.random.default_rng(5)
    th, ph = torch.tensor(theta), torch.tensor(phi)
    dense = np.arange(36000) * (2 * np.pi / 36000)
    for alpha_true, noise in ((0.0, 0.0), (2.0, 0.0), (4.4, 0.3), (6.2, 0.1)):
        with torch.no_grad():
            target = model(torch.full((len(theta),), alpha_true, dtype=torch.float64), th, ph)
            target = target + noise * torch.tensor(rng.normal(size=target.shape))
            mse = torch.cat([((model.reconstruct_grid(torch.tensor(chunk), th, ph) - target) ** 2).mean(dim=(1, 2, 3))
                             for chunk in np.split(dense, 36)]).numpy()  # (36000,)
        best = dense[mse.argmin()]
        got, got_mse = fit_alpha(model, target, theta, phi)
        assert 0 <= got < 2 * np.pi
        assert abs(math.remainder(got - best, 2 * np.pi)) < 2 * np.pi / 36000
        assert got_mse <= mse.min() + 1e-12
        with torch.no_grad():
            at = model(torch.full((len(theta),), got, dtype=torch.float64), th, ph)
        assert got_mse == pytest.approx(((at - target) ** 2).mean().item(), rel=1e-9)
