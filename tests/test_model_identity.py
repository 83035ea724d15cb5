"""Identity manifold (eq. 4.8-4.11): ordering against brute force, spline against scipy."""

import itertools
import math

import numpy as np
import pytest
import torch
from scipy.interpolate import BSpline

from torch_atr.model.identity import IdentityManifold, dissimilarity, shortest_closed_path

TWO_PI = 2 * math.pi


def _tour_cost(D: np.ndarray, tour) -> float:
    return sum(D[tour[i], tour[(i + 1) % len(tour)]] for i in range(len(tour)))


def _brute_force_cost(D: np.ndarray) -> float:
    K = len(D)
    return min(_tour_cost(D, (0, *p)) for p in itertools.permutations(range(1, K)))


def _penalised(K: int, n_classes: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random templates -> D with the default penalty, and the labels."""
    g = torch.Generator().manual_seed(seed)
    Y = torch.rand(K, 3, 4, generator=g, dtype=torch.float64)
    labels = torch.randint(0, n_classes, (K,), generator=g)
    return dissimilarity(Y, labels).numpy(), labels.numpy()


def test_dissimilarity_matches_double_loop():
    g = torch.Generator().manual_seed(0)
    Y = torch.rand(5, 4, 6, generator=g, dtype=torch.float64)
    labels = torch.tensor([0, 1, 0, 2, 1])
    D = dissimilarity(Y, labels, a=2.5).numpy()
    Yn = Y.numpy()
    for u in range(5):
        for v in range(5):
            ref = sum(np.linalg.norm(Yn[u, m] - Yn[v, m]) for m in range(4)) + 2.5 * (labels[u] != labels[v]).item()
            assert D[u, v] == pytest.approx(ref, rel=1e-12, abs=1e-12)
    with pytest.raises(ValueError, match="penalty"):
        dissimilarity(Y, labels, a=-1.0)


def test_default_class_penalty_is_k_plus_one_times_max_d0():
    """The default a = (K + 1)·max D₀ of the docstring, D₀ from a double loop of per-view norms: the bound
    that keeps every class contiguous (a smaller a passed the random-template tour tests too)."""
    g = torch.Generator().manual_seed(4)
    Y = torch.rand(6, 3, 5, generator=g, dtype=torch.float64)
    labels = torch.tensor([0, 1, 1, 2, 0, 2])
    Yn = Y.numpy()
    D0 = np.array([[sum(np.linalg.norm(Yn[u, m] - Yn[v, m]) for m in range(3)) for v in range(6)] for u in range(6)])
    a = 7 * D0.max()
    want = D0 + a * (labels.numpy()[:, None] != labels.numpy()[None, :])
    np.testing.assert_allclose(dissimilarity(Y, labels).numpy(), want, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_held_karp_matches_brute_force_on_random_matrices(seed):
    rng = np.random.default_rng(seed)
    K = int(rng.integers(4, 9))
    D = rng.random((K, K))
    D = D + D.T  # symmetric, not metric
    order = shortest_closed_path(torch.tensor(D)).tolist()
    assert sorted(order) == list(range(K))
    assert _tour_cost(D, order) == pytest.approx(_brute_force_cost(D), rel=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_class_block_path_matches_brute_force_and_keeps_classes_contiguous(seed):
    K = 6 + seed % 4
    D, labels = _penalised(K, 3, seed)
    best = _brute_force_cost(D)
    for max_exact in (12, 0):  # Held-Karp over all vehicles, then the class-block decomposition
        order = shortest_closed_path(torch.tensor(D), torch.tensor(labels), max_exact=max_exact).tolist()
        assert _tour_cost(D, order) == pytest.approx(best, rel=1e-12)
        changes = sum(labels[order[i]] != labels[order[i - 1]] for i in range(K))
        n_classes = len(set(labels.tolist()))
        assert changes == (0 if n_classes == 1 else n_classes)


def test_class_block_path_equals_held_karp_on_twelve_vehicles():
    D, labels = _penalised(12, 4, 11)
    exact = shortest_closed_path(torch.tensor(D)).tolist()
    blocks = shortest_closed_path(torch.tensor(D), torch.tensor(labels), max_exact=0).tolist()
    assert _tour_cost(D, blocks) == pytest.approx(_tour_cost(D, exact), rel=1e-12)


def test_order_is_canonical():
    D, labels = _penalised(8, 2, 5)
    perm = np.random.default_rng(0).permutation(8)
    for max_exact in (12, 0):
        order = shortest_closed_path(torch.tensor(D), torch.tensor(labels), max_exact=max_exact).tolist()
        assert order[0] == 0 and order[1] < order[-1]
    # Relabelling the vehicles gives a cycle of the same length, read from the new vehicle 0.
    relabelled = shortest_closed_path(torch.tensor(D[np.ix_(perm, perm)])).tolist()
    assert relabelled[0] == 0 and relabelled[1] < relabelled[-1]
    assert _tour_cost(D, [perm[i] for i in relabelled]) == pytest.approx(_tour_cost(D, order), rel=1e-12)


def test_shortest_closed_path_errors():
    with pytest.raises(ValueError, match="symmetric"):
        shortest_closed_path(torch.tensor([[0.0, 1.0, 2.0], [3.0, 0.0, 1.0], [2.0, 1.0, 0.0]]))
    with pytest.raises(ValueError, match="pass labels"):
        shortest_closed_path(torch.zeros(4, 4), max_exact=2)
    with pytest.raises(ValueError, match="at most 9 classes"):
        shortest_closed_path(torch.zeros(10, 10), torch.arange(10), max_exact=2)


def _manifold(K=7, E=None, seed=0, orthonormal=True):
    g = torch.Generator().manual_seed(seed)
    E = K if E is None else E
    vectors = torch.randn(K, E, generator=g, dtype=torch.float64)
    if orthonormal:
        vectors = torch.linalg.qr(vectors)[0]
    order = torch.cat([torch.zeros(1, dtype=torch.long), torch.randperm(K - 1, generator=g) + 1])
    labels = torch.randint(0, 3, (K,), generator=g)
    return IdentityManifold.fit(vectors, labels, order), vectors, labels, order


def test_alphas_follow_cumulative_chord_length():
    m, vectors, _, order = _manifold(orthonormal=False)
    pts = vectors.numpy()[order.numpy()]
    chords = [np.linalg.norm(pts[(j + 1) % 7] - pts[j]) for j in range(7)]
    expected = TWO_PI * np.concatenate([[0.0], np.cumsum(chords)[:-1]]) / sum(chords)
    np.testing.assert_allclose(m.alphas[order].numpy(), expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("orthonormal", [True, False])
def test_spline_interpolates_identity_vectors(orthonormal):
    m, vectors, _, _ = _manifold(orthonormal=orthonormal, seed=1)
    torch.testing.assert_close(m(m.alphas), vectors, atol=1e-5, rtol=0)
    torch.testing.assert_close(m(m.alphas + TWO_PI), vectors, atol=1e-5, rtol=0)


def test_spline_matches_scipy_bspline():
    m, _, _, _ = _manifold(E=4, seed=2)
    spline = BSpline(m.knots.numpy(), m.coefficients.numpy(), 3, extrapolate="periodic")
    alpha = torch.linspace(-7.0, 13.0, 301, dtype=torch.float64)
    np.testing.assert_allclose(m(alpha).numpy(), spline(alpha.numpy()), rtol=1e-10, atol=1e-12)


def test_local_basis_matches_scipy_basis_elements():
    """i(α) = Σⱼ wⱼ cⱼ with 4 control points: the weights are scipy's B-spline basis values."""
    m, _, _, _ = _manifold(E=4, seed=2)
    alpha = torch.linspace(-7.0, 13.0, 301, dtype=torch.float64)
    first, weights = m.local_basis(alpha)
    assert first.dtype == torch.int64 and weights.shape == (301, 4)
    assert (weights >= -1e-15).all() and torch.allclose(weights.sum(1), torch.ones(301, dtype=torch.float64))
    n = m.coefficients.shape[0]
    assert (first >= 0).all() and (first + 3 < n).all()
    x = np.remainder(alpha.numpy(), TWO_PI)
    for i in range(0, 301, 15):
        for j in range(4):
            b = BSpline.basis_element(m.knots.numpy()[first[i] + j:first[i] + j + 5], extrapolate=False)
            assert weights[i, j].item() == pytest.approx(np.nan_to_num(b(x[i])), abs=1e-12)


def test_spline_is_c2_across_the_seam():
    m, _, _, _ = _manifold(seed=3)

    def derivatives(a: float) -> list[torch.Tensor]:
        alpha = torch.tensor([a], dtype=torch.float64, requires_grad=True)
        value = m(alpha)[0]
        first = torch.stack([torch.autograd.grad(v, alpha, create_graph=True)[0][0] for v in value])
        second = torch.stack([torch.autograd.grad(v, alpha, retain_graph=True)[0][0] for v in first])
        return [value.detach(), first.detach(), second]

    eps = 1e-6
    for before, after in zip(derivatives(TWO_PI - eps), derivatives(eps)):
        torch.testing.assert_close(before, after, atol=1e-3 * max(1.0, after.abs().max().item()), rtol=0)


def test_spline_batched_equals_loop_and_gradcheck():
    m, _, _, _ = _manifold(seed=4)
    g = torch.Generator().manual_seed(0)
    alpha = torch.rand(9, generator=g, dtype=torch.float64) * 20 - 5
    batched = m(alpha)
    for n in range(9):
        torch.testing.assert_close(batched[n], m(alpha[n:n + 1])[0], rtol=0, atol=1e-14)
    assert torch.autograd.gradcheck(m, (alpha.clone().requires_grad_(True),))


def _circular(a: float, b: float) -> float:
    d = (a - b) % TWO_PI
    return min(d, TWO_PI - d)


def test_classify_and_nearest_vehicles_match_brute_force():
    m, _, labels, _ = _manifold(K=8, seed=5)
    alpha = torch.linspace(-1.0, 8.0, 211, dtype=torch.float64)
    classes = m.classify(alpha).tolist()
    nearest = m.nearest_vehicles(alpha, k=3).tolist()
    alphas = m.alphas.tolist()
    for n, a in enumerate(alpha.tolist()):
        ranked = sorted(range(8), key=lambda k: (_circular(a, alphas[k]), k))
        assert classes[n] == labels[ranked[0]].item()
        assert nearest[n] == ranked[:3]
    torch.testing.assert_close(m.classify(m.alphas), labels)
    with pytest.raises(ValueError, match="k in"):
        m.nearest_vehicles(alpha, k=9)


@pytest.mark.parametrize("seed", range(3))
def test_class_arcs_cover_the_circle_once(seed):
    m, _, labels, _ = _manifold(K=8, seed=6 + seed)
    arcs = m.class_arcs()
    assert sum(end - start for _, start, end in arcs) == pytest.approx(TWO_PI)
    assert all(0 <= start < TWO_PI and start < end <= start + TWO_PI for _, start, end in arcs)
    alpha = torch.linspace(0, TWO_PI, 997, dtype=torch.float64)[:-1] + 1e-4
    classes = m.classify(alpha).tolist()
    for n, a in enumerate(alpha.tolist()):
        owners = [c for c, start, end in arcs if (a - start) % TWO_PI < end - start]
        assert owners == [classes[n]]
    set_labels = set(labels.tolist())
    assert {c for c, _, _ in arcs} == set_labels


@pytest.mark.parametrize("seed", range(3))
def test_classify_at_an_arc_start_is_that_arcs_class(seed):
    """Midway between two classes' vehicles the nearest αₖ is a tie, which argmin settled by vehicle
    index or rounding; the arc's start belongs to its arc (the half-open arcs of class_arcs), and the
    α just before it to the arc before."""
    m, _, labels, _ = _manifold(K=8, seed=6 + seed)
    arcs = m.class_arcs()
    alphas = m.alphas.tolist()

    def nearest_class(a: float) -> int:  # brute force, away from the tie
        return labels[min(range(8), key=lambda k: _circular(a, alphas[k]))].item()

    for (c, start, _), (c_before, _, _) in zip(arcs, arcs[-1:] + arcs[:-1]):
        assert (nearest_class(start + 1e-6), nearest_class(start - 1e-6)) == (c, c_before)
        ties = sorted(_circular(start, a) for a in alphas)[:2]
        assert ties[0] == pytest.approx(ties[1], abs=1e-12)  # a start is midway between two vehicles
        assert m.classify(torch.tensor([start, start - 1e-12], dtype=torch.float64)).tolist() == [c, c_before]
        for turns in (1, -2):  # α is wrapped mod 2π (which rounds the start itself)
            at = torch.tensor([start + 1e-9, start - 1e-9], dtype=torch.float64) + turns * TWO_PI
            assert m.classify(at).tolist() == [c, c_before]


def test_single_class_arc_is_whole_circle():
    vectors = torch.eye(4, dtype=torch.float64)
    m = IdentityManifold.fit(vectors, torch.zeros(4, dtype=torch.long), torch.arange(4))
    ((c, start, end),) = m.class_arcs()
    assert c == 0 and end - start == pytest.approx(TWO_PI)


def test_fit_errors_and_state_dict_round_trip():
    m, vectors, labels, order = _manifold(seed=9)
    with pytest.raises(ValueError, match="permutation"):
        IdentityManifold.fit(vectors, labels, torch.zeros(7, dtype=torch.long))
    with pytest.raises(ValueError, match="coincide"):
        IdentityManifold.fit(torch.zeros(3, 3), torch.zeros(3, dtype=torch.long), torch.arange(3))
    with pytest.raises(ValueError, match="alpha"):
        m(torch.zeros(2, 2))
    fresh = IdentityManifold(7).double()
    fresh.load_state_dict(m.state_dict())
    alpha = torch.linspace(0, 7, 13, dtype=torch.float64)
    torch.testing.assert_close(fresh(alpha), m(alpha), rtol=0, atol=0)
    assert fresh.class_arcs() == m.class_arcs()


def test_class_block_search_rejects_too_large_a_class():
    labels = torch.tensor([0] * 13 + [1] * 2)
    D = torch.ones(15, 15, dtype=torch.float64) - torch.eye(15, dtype=torch.float64)
    with pytest.raises(ValueError, match="13 vehicles.*at most 12 per class"):
        shortest_closed_path(D, labels)
