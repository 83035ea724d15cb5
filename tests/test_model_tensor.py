"""Tensor algebra (eq. 4.1-4.7) and the HOSVD core (eq. 4.14-4.18) against numpy references."""

import numpy as np
import pytest
import torch

from torch_atr.model.tensor import TensorCore, mode_basis, mode_product, unfold, principal_basis


def _thesis_tensor() -> torch.Tensor:
    """The 3 × 4 × 2 tensor of eq. 4.1 (frontal slices A₁, A₂)."""
    A1 = torch.tensor([[1, 4, 7, 10], [2, 5, 8, 11], [3, 6, 9, 12]], dtype=torch.float64)
    return torch.stack([A1, A1 + 12], dim=-1)


def test_unfold_matches_thesis_example():
    A = _thesis_tensor()
    assert A.shape == (3, 4, 2)
    A_1 = [[1, 4, 7, 10, 13, 16, 19, 22], [2, 5, 8, 11, 14, 17, 20, 23], [3, 6, 9, 12, 15, 18, 21, 24]]
    # eq. 4.3 with the thesis's typo fixed: the last row ends "23 24", not "23 23".
    A_2 = [[1, 2, 3, 13, 14, 15], [4, 5, 6, 16, 17, 18], [7, 8, 9, 19, 20, 21], [10, 11, 12, 22, 23, 24]]
    A_3 = [list(range(1, 13)), list(range(13, 25))]
    for mode, expected in enumerate([A_1, A_2, A_3]):
        torch.testing.assert_close(unfold(A, mode), torch.tensor(expected, dtype=torch.float64))


def test_unfold_rejects_bad_mode():
    with pytest.raises(ValueError, match="mode"):
        unfold(torch.zeros(2, 3), 2)


@pytest.mark.parametrize("mode", [0, 1, 2])
def test_mode_product_matches_brute_force_loop(mode):
    g = torch.Generator().manual_seed(mode)
    T = torch.randn(3, 4, 2, generator=g, dtype=torch.float64)
    Q = torch.randn(5, T.shape[mode], generator=g, dtype=torch.float64)
    out = mode_product(T, Q, mode)
    shape = list(T.shape)
    shape[mode] = 5
    ref = np.zeros(shape)
    Tn, Qn = T.numpy(), Q.numpy()
    for idx in np.ndindex(*shape):  # eq. 4.5: b[…, j, …] = Σᵢ a[…, i, …] q[j, i]
        for i in range(T.shape[mode]):
            src = list(idx)
            src[mode] = i
            ref[idx] += Tn[tuple(src)] * Qn[idx[mode], i]
    np.testing.assert_allclose(out.numpy(), ref, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(unfold(out, mode), Q @ unfold(T, mode))  # eq. 4.6


def test_mode_product_commutes_and_contracts_vectors():
    g = torch.Generator().manual_seed(7)
    T = torch.randn(3, 4, 2, generator=g, dtype=torch.float64)
    P, Q = torch.randn(6, 3, generator=g, dtype=torch.float64), torch.randn(5, 2, generator=g, dtype=torch.float64)
    torch.testing.assert_close(mode_product(mode_product(T, P, 0), Q, 2), mode_product(mode_product(T, Q, 2), P, 0))  # eq. 4.7
    v = torch.randn(4, generator=g, dtype=torch.float64)
    torch.testing.assert_close(mode_product(T, v, 1), torch.einsum("ijk,j->ik", T, v))
    with pytest.raises(ValueError, match=r"M to have shape \(\*, 2\)"):
        mode_product(T, P, 2)


def test_mode_basis_matches_numpy_svd():
    g = torch.Generator().manual_seed(8)
    T = torch.randn(6, 3, 4, generator=g, dtype=torch.float64)
    U, S = mode_basis(T, 0)
    ref_u, ref_s, _ = np.linalg.svd(T.numpy().reshape(6, -1), full_matrices=False)
    np.testing.assert_allclose(S.numpy(), ref_s, rtol=1e-10)
    np.testing.assert_allclose(np.abs(U.numpy().T @ ref_u), np.eye(6), atol=1e-8)  # same vectors up to sign
    assert (U.gather(0, U.abs().argmax(0, keepdim=True)) > 0).all()


def _random_mappings(K=5, d=12, P=7, seed=0):
    g = torch.Generator().manual_seed(seed)
    # A decaying spectrum so truncation errors are distinct.
    return torch.randn(K, d, P, generator=g, dtype=torch.float64) * torch.logspace(0, -2, d, dtype=torch.float64)[:, None]


def _stack(B: torch.Tensor) -> np.ndarray:
    """𝒞 = [B¹ … Bᴷ] as a numpy d × P × K array."""
    return np.moveaxis(B.numpy(), 0, -1)


@pytest.mark.parametrize("pixel_rank", [None, 12])
def test_full_rank_core_reconstructs_every_mapping(pixel_rank):
    B = _random_mappings()
    core = TensorCore.from_mappings(B, pixel_rank)
    A = core.core.numpy()
    if pixel_rank is not None:
        A = np.einsum("ir,rpk->ipk", core.pixel_basis.numpy(), A)
    ids = core.identity_vectors.numpy()
    np.testing.assert_allclose(ids @ ids.T, np.eye(5), atol=1e-10)
    for k in range(5):  # eq. 4.14: Bᵏ = 𝒜 ×₁ U₁ ×₃ iᵏ
        Bk = np.einsum("ipk,k->ip", A, ids[k])
        assert np.linalg.norm(Bk - B[k].numpy()) <= 1e-5 * np.linalg.norm(B[k].numpy())
    assert core.relative_error.item() < 1e-10


def test_identity_vectors_match_numpy_svd_of_mode3_unfolding():
    B = _random_mappings(seed=1)
    core = TensorCore.from_mappings(B, 4)
    C = _stack(B)
    ref_u, _, _ = np.linalg.svd(np.moveaxis(C, 2, 0).reshape(5, -1), full_matrices=False)
    np.testing.assert_allclose(np.abs(core.identity_vectors.numpy().T @ ref_u), np.eye(5), atol=1e-8)


def test_truncated_pixel_basis_spans_top_singular_vectors_and_reports_error():
    B = _random_mappings(seed=2)
    C = _stack(B)
    M = C.reshape(12, -1)  # mode-1 unfolding up to a column permutation
    ref_u, ref_s, _ = np.linalg.svd(M, full_matrices=False)
    errors = []
    for r in range(1, 13):
        core = TensorCore.from_mappings(B, r)
        U1 = core.pixel_basis.numpy()
        np.testing.assert_allclose(U1 @ U1.T, ref_u[:, :r] @ ref_u[:, :r].T, atol=1e-8)
        projected = np.einsum("ir,jr,jpk->ipk", U1, U1, C)
        expected = np.linalg.norm(C - projected) / np.linalg.norm(C)
        assert core.relative_error.item() == pytest.approx(expected, rel=1e-8, abs=1e-12)
        assert expected == pytest.approx(np.sqrt((ref_s[r:] ** 2).sum() / (ref_s ** 2).sum()), rel=1e-8, abs=1e-12)
        errors.append(expected)
    assert all(a > b for a, b in zip(errors, errors[1:-1])) and errors[-1] < 1e-12


def test_rank_is_capped_at_unfolding_rank():
    B = _random_mappings(K=2, d=20, P=3)
    core = TensorCore.from_mappings(B, 128)
    assert core.pixel_rank == 6 and core.core.shape == (6, 3, 2)


@pytest.mark.parametrize("pixel_rank", [None, 5])
def test_batched_reconstruct_equals_naive_eq_4_18_loop(pixel_rank):
    B = _random_mappings(seed=3)
    core = TensorCore.from_mappings(B, pixel_rank)
    g = torch.Generator().manual_seed(9)
    identity = torch.randn(6, 5, generator=g, dtype=torch.float64)
    psi = torch.randn(6, 7, generator=g, dtype=torch.float64)
    out = core.reconstruct(identity, psi).numpy()
    C, ids = _stack(B), core.identity_vectors.numpy()
    proj = np.eye(12) if pixel_rank is None else core.pixel_basis.numpy() @ core.pixel_basis.numpy().T
    for n in range(6):
        # 𝒜 = 𝒞 ×₃ U₃ᵀ, so 𝒜 ×₃ i = Σₖ (iᵏ · i) Bᵏ; then ×₂ Ψ.
        weights = ids @ identity[n].numpy()
        y = sum(weights[k] * C[:, :, k] @ psi[n].numpy() for k in range(5))
        np.testing.assert_allclose(out[n], proj @ y, rtol=1e-9, atol=1e-10)
    grid = core.reconstruct_grid(identity[:4], psi[:3]).numpy()  # every identity at every view
    assert grid.shape == (4, 3, 12)
    for a in range(4):
        for v in range(3):
            weights = ids @ identity[a].numpy()
            y = sum(weights[k] * C[:, :, k] @ psi[v].numpy() for k in range(5))
            np.testing.assert_allclose(grid[a, v], proj @ y, rtol=1e-9, atol=1e-10)


def test_reconstruct_grid_in_basis_gives_pixel_basis_coordinates():
    """in_basis=True returns c = U₁ᵀ y (r numbers, not d pixels) of the naive eq. 4.18 loop, Σₖ (iᵏ · i) Bᵏ Ψ."""
    B = _random_mappings(seed=5)
    core = TensorCore.from_mappings(B, 5)
    g = torch.Generator().manual_seed(11)
    identity = torch.randn(3, 5, generator=g, dtype=torch.float64)
    psi = torch.randn(2, 7, generator=g, dtype=torch.float64)
    coords = core.reconstruct_grid(identity, psi, in_basis=True).numpy()
    assert coords.shape == (3, 2, 5)
    C, ids, U1 = _stack(B), core.identity_vectors.numpy(), core.pixel_basis.numpy()
    for a in range(3):
        for v in range(2):
            weights = ids @ identity[a].numpy()
            y = sum(weights[k] * C[:, :, k] @ psi[v].numpy() for k in range(5))
            np.testing.assert_allclose(coords[a, v], U1.T @ y, rtol=1e-9, atol=1e-10)


def test_reconstruct_rejects_bad_shapes_and_keeps_dtype():
    core = TensorCore.from_mappings(_random_mappings().float(), 4)
    assert core.core.dtype == torch.float32
    with pytest.raises(ValueError, match="identity"):
        core.reconstruct(torch.zeros(3, 4), torch.zeros(3, 7))
    with pytest.raises(ValueError, match="psi"):
        core.reconstruct(torch.zeros(3, 5), torch.zeros(2, 7))
    assert core.reconstruct(torch.zeros(3, 5), torch.zeros(3, 7)).dtype == torch.float32


@pytest.mark.parametrize("pixel_rank", [None, 4])
def test_state_dict_rebuilds_from_sizes(pixel_rank):
    core = TensorCore.from_mappings(_random_mappings(), pixel_rank)
    fresh = TensorCore(12, 7, 5, pixel_rank).double()
    fresh.load_state_dict(core.state_dict())
    g = torch.Generator().manual_seed(10)
    identity, psi = torch.randn(3, 5, generator=g, dtype=torch.float64), torch.randn(3, 7, generator=g, dtype=torch.float64)
    torch.testing.assert_close(fresh.reconstruct(identity, psi), core.reconstruct(identity, psi), rtol=0, atol=0)
    assert ("pixel_basis" in core.state_dict()) == (pixel_rank is not None)


def test_principal_basis_spans_numpy_svd_subspace():
    rng = np.random.default_rng(3)
    Y = rng.standard_normal((60, 20)) @ np.diag(0.7 ** np.arange(20)) @ np.linalg.qr(rng.standard_normal((20, 20)))[0]
    U, error = principal_basis(torch.from_numpy(Y), 5)
    _, S, Vt = np.linalg.svd(Y)
    np.testing.assert_allclose(U.numpy().T @ U.numpy(), np.eye(5), atol=1e-10)
    np.testing.assert_allclose(U.numpy() @ U.numpy().T, Vt[:5].T @ Vt[:5], atol=1e-8)
    assert error.item() == pytest.approx(np.sqrt((S[5:] ** 2).sum() / (S ** 2).sum()), rel=1e-6)
    with pytest.raises(ValueError, match="rank"):
        principal_basis(torch.from_numpy(Y), 0)


def test_principal_basis_randomised_error_is_near_optimal():
    rng = np.random.default_rng(4)
    # A slowly decaying spectrum, like the templates', with r + oversample < min(M, d).
    Y = (rng.standard_normal((400, 300)) * (1.0 / (1 + np.arange(300)) ** 0.7)) @ np.linalg.qr(
        rng.standard_normal((300, 300)))[0]
    S = np.linalg.svd(Y, compute_uv=False)
    optimal = np.sqrt((S[20:] ** 2).sum() / (S ** 2).sum())
    U, error = principal_basis(torch.from_numpy(Y), 20)
    direct = np.linalg.norm(Y - Y @ U.numpy() @ U.numpy().T) / np.linalg.norm(Y)
    assert error.item() == pytest.approx(direct, rel=1e-8)
    assert optimal <= direct <= 1.01 * optimal
    U2, _ = principal_basis(torch.from_numpy(Y), 20)
    assert torch.equal(U, U2)  # seeded: deterministic


def test_principal_basis_ignores_and_keeps_the_global_rng():
    """The randomised sketch is seeded by ``seed`` alone: the same basis whatever the caller's global RNG
    state (two calls in a row share one state, as fork_rng restores it, so torch.equal above cannot tell),
    and that state is left as it was."""
    rng = np.random.default_rng(6)
    Y = torch.from_numpy((rng.standard_normal((200, 150)) / (1 + np.arange(150)) ** 0.5) @ np.linalg.qr(
        rng.standard_normal((150, 150)))[0])
    torch.manual_seed(1)
    U1, _ = principal_basis(Y, 10, oversample=4, power_iters=0)
    torch.manual_seed(2)
    state = torch.get_rng_state()
    U2, _ = principal_basis(Y, 10, oversample=4, power_iters=0)
    assert torch.equal(torch.get_rng_state(), state)
    torch.testing.assert_close(U1, U2, rtol=0, atol=0)
    U3, _ = principal_basis(Y, 10, oversample=4, power_iters=0, seed=1)
    assert not torch.equal(U1, U3)  # the seed, not the global state, picks the sketch


def test_principal_basis_error_of_float32_data_is_its_residual():
    """Rank 20 plus 1e-4 noise: the error, ‖Y‖² − ‖YU‖² in float32, read 0 for a true 2e-5."""
    rng = np.random.default_rng(5)
    Y = rng.standard_normal((2000, 20)) @ rng.standard_normal((20, 256)) + 1e-4 * rng.standard_normal((2000, 256))
    U, error = principal_basis(torch.from_numpy(Y).float(), 20)
    U64 = U.double().numpy()
    direct = np.linalg.norm(Y - Y @ U64 @ U64.T) / np.linalg.norm(Y)
    assert error.item() == pytest.approx(direct, rel=0.05) and direct > 1e-5


def test_project_gives_basis_coordinates_and_the_distance_identity():
    core = TensorCore.from_mappings(_random_mappings(seed=4), 5)
    g = torch.Generator().manual_seed(2)
    y, y2 = torch.randn(3, 12, generator=g, dtype=torch.float64), torch.randn(3, 5, generator=g, dtype=torch.float64)
    c = core.project(y)
    U = core.pixel_basis.numpy()
    np.testing.assert_allclose(c.numpy(), y.numpy() @ U, rtol=1e-12)
    direct = ((y2.numpy() @ U.T - y.numpy()) ** 2).sum(1)  # ‖U c' − y‖²
    via = ((y2 - c) ** 2).sum(1) + (y ** 2).sum(1) - (c ** 2).sum(1)
    np.testing.assert_allclose(via.numpy(), direct, rtol=1e-10)
    with pytest.raises(ValueError, match="12"):
        core.project(torch.zeros(3, 11, dtype=torch.float64))


def test_given_pixel_basis_core_and_error_against_numpy():
    B = _random_mappings(seed=6)
    g = torch.Generator().manual_seed(3)
    U1 = torch.linalg.qr(torch.randn(12, 4, generator=g, dtype=torch.float64)).Q  # any orthonormal basis
    core = TensorCore.from_mappings(B, pixel_basis=U1)
    C, U, U3 = _stack(B), U1.numpy(), core.identity_vectors.numpy()
    np.testing.assert_allclose(core.core.numpy(), np.einsum("ir,ipk,kj->rpj", U, C, U3), atol=1e-12)
    residual = C - np.einsum("ir,jr,jpk->ipk", U, U, C)
    assert core.relative_error.item() == pytest.approx(np.linalg.norm(residual) / np.linalg.norm(C), rel=1e-10)
    with pytest.raises(ValueError, match="not both"):
        TensorCore.from_mappings(B, 4, pixel_basis=U1)
    # Columns of norm 2: project's coordinates and fit_alpha's split of ‖y − t‖² would be wrong without a word.
    with pytest.raises(ValueError, match=r"pixel_basis to have orthonormal columns; \|UᵀU − I\| reaches 3"):
        TensorCore.from_mappings(B, pixel_basis=2 * U1)
