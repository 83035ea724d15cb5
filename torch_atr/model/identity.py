"""The identity manifold: a closed cubic B-spline through the ordered identity vectors (eq. 4.8-4.11).

The vehicles are ordered by the class-constrained shortest closed path on the dissimilarity
D(u, v) = Σₘ ‖yₘᵘ − yₘᵛ‖ + a·[Lᵤ ≠ Lᵥ]; a periodic cubic B-spline interpolates the identity
vectors iᵏ in that order, parameterised by α ∈ [0, 2π) at cumulative chord length, so α advances
uniformly in identity space and αₖ marks vehicle k.
"""

from __future__ import annotations

import itertools
import math
import numbers

import numpy as np
import torch
from scipy.interpolate import make_interp_spline
from torch import nn

from torch_atr._checks import check_shape

DEGREE = 3  # cubic B-spline
MAX_EXACT = 12  # largest vehicle set (or class) solved by Held-Karp dynamic programming
MAX_CLASSES = 9  # the class-block search tries (C - 1)! cyclic class orders
TWO_PI = 2.0 * math.pi


def dissimilarity(Y: torch.Tensor, labels: torch.Tensor, a: float | None = None) -> torch.Tensor:
    """Class-penalised multi-view dissimilarity of eq. 4.8-4.9.

    Y: (K, V, d) flattened signed-distance templates; labels: (K,) class indices; a: the class
    penalty. Returns D: (K, K), D(u, v) = Σₘ ‖yₘᵘ − yₘᵛ‖ + a·[Lᵤ ≠ Lᵥ].

    The default a = (K + 1)·max D₀ (D₀ without the penalty) keeps every class contiguous on the
    shortest closed path: a tour with C classes has at least C class changes, one that splits a
    class at least C + 1, and the penalty-free part of any tour lies in [0, K·max D₀] < a.
    """
    check_shape("Y", Y, ("K", "V", "d"))
    check_shape("labels", labels, (Y.shape[0],))
    per_view = Y.transpose(0, 1)  # (V, K, d)
    D0 = torch.cdist(per_view, per_view, compute_mode="donot_use_mm_for_euclid_dist").sum(0)  # (K, K)
    if a is None:
        a = (Y.shape[0] + 1) * D0.max().item()
    elif not a >= 0:
        raise ValueError(f"Expected a class penalty a >= 0; got {a}")
    different = (labels.unsqueeze(0) != labels.unsqueeze(1)).to(D0.dtype)
    return D0 + a * different


def _held_karp(D: np.ndarray, starts: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Shortest Hamiltonian paths over all of ``D``'s n nodes from each start (Held-Karp DP).

    D: (n, n); starts: S start nodes. Returns cost (2ⁿ, S, n), cost[mask, s, j] the shortest path
    from starts[s] through exactly the nodes of ``mask`` ending at j (inf if none), and the
    predecessor of j on that path (−1 at the start).
    """
    n = D.shape[0]
    bits = 1 << np.arange(n)
    cost = np.full((1 << n, len(starts), n), np.inf)
    parent = np.full((1 << n, len(starts), n), -1, dtype=np.int8)
    for s, start in enumerate(starts):
        cost[1 << start, s, start] = 0.0
    for mask in range(1, 1 << n):
        ends = np.flatnonzero(mask & bits)
        if len(ends) < 2:
            continue
        # cost[mask, s, j] = min_i cost[mask \ {j}, s, i] + D[i, j]
        candidates = cost[mask ^ bits[ends]] + D[:, ends].T[:, None, :]  # (E, S, n)
        cost[mask][:, ends] = candidates.min(-1).T
        parent[mask][:, ends] = candidates.argmin(-1).T
    return cost, parent


def _backtrack(parent: np.ndarray, s: int, end: int) -> list[int]:
    """The node sequence of the full-mask path from start index ``s`` ending at ``end``."""
    mask = parent.shape[0] - 1
    path = [end]
    while (prev := int(parent[mask, s, path[-1]])) >= 0:
        mask ^= 1 << path[-1]
        path.append(prev)
    return path[::-1]


def _min_plus(F: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(F ⊗ G)[a, c] = min_b F[a, b] + G[b, c] and its argmin b. F: (A, B), G: (B, C)."""
    total = F[:, :, None] + G[None, :, :]  # (A, B, C)
    return total.min(1), total.argmin(1)


def _class_block_tour(D: np.ndarray, labels: np.ndarray) -> list[int]:
    """Shortest closed tour that keeps each class contiguous (exact among such tours).

    Held-Karp gives the shortest Hamiltonian path between every (entry, exit) pair inside each
    class; an exact search over cyclic class orders (the first class fixed, (C − 1)! orders) then
    chains the blocks with a min-plus DP over the chosen endpoints.
    """
    classes = sorted(set(labels.tolist()), key=lambda c: (c != labels[0], c))  # vehicle 0's class first
    if len(classes) > MAX_CLASSES:
        raise ValueError(f"Exact class-block search supports at most {MAX_CLASSES} classes; got {len(classes)}")
    members, inner, parents = {}, {}, {}
    for c in classes:
        m = np.flatnonzero(labels == c)
        if len(m) > MAX_EXACT:
            raise ValueError(f"Class {c} has {len(m)} vehicles; exact ordering supports at most {MAX_EXACT} per class")
        cost, parents[c] = _held_karp(D[np.ix_(m, m)], list(range(len(m))))
        inner[c] = cost[-1]  # (n_c, n_c): entry -> exit through all of class c
        members[c] = m

    def chain(cyclic: tuple) -> tuple[np.ndarray, list]:
        """Tour costs (first entry, last exit) for one cyclic class order, and per-step argmins."""
        F = inner[cyclic[0]]  # (entries of the first class, exits of the current class)
        steps = []
        for prev, c in zip(cyclic, cyclic[1:]):
            G, arg_exit = _min_plus(F, D[np.ix_(members[prev], members[c])])  # -> entries of c
            F, arg_entry = _min_plus(G, inner[c])  # -> exits of c
            steps.append((arg_exit, arg_entry))
        return F + D[np.ix_(members[cyclic[-1]], members[cyclic[0]])].T, steps  # close the loop

    best = None
    for rest in itertools.permutations(classes[1:]):
        total, steps = chain((classes[0], *rest))
        if best is None or total.min() < best[0].min():
            best = total, steps, (classes[0], *rest)
    total, steps, cyclic = best
    first, exit_ = np.unravel_index(total.argmin(), total.shape)
    endpoints = []  # (entry, exit) per block, from the last block back
    for arg_exit, arg_entry in reversed(steps):
        entry = arg_entry[first, exit_]
        endpoints.append((entry, exit_))
        exit_ = arg_exit[first, entry]
    endpoints.append((first, exit_))
    tour = []
    for c, (entry, exit_) in zip(cyclic, reversed(endpoints)):
        tour += [int(members[c][i]) for i in _backtrack(parents[c], int(entry), int(exit_))]
    return tour


def shortest_closed_path(D: torch.Tensor, labels: torch.Tensor | None = None,
                         max_exact: int = MAX_EXACT) -> torch.Tensor:
    """The class-constrained shortest closed path of eq. 4.10-4.11.

    D: (K, K) symmetric dissimilarity with the class penalty (:func:`dissimilarity`);
    labels: (K,) class indices, needed when K > ``max_exact``. Returns order: (K,) int64, the
    vehicles along the closed path, starting at vehicle 0 and oriented so that
    order[1] < order[−1].

    K <= ``max_exact``: Held-Karp over all vehicles, exact. Otherwise the class-block
    decomposition, exact whenever the optimal tour keeps each class contiguous, which the
    default penalty of :func:`dissimilarity` guarantees.
    """
    check_shape("D", D, ("K", "K"))
    K = D.shape[0]
    Dn = D.detach().cpu().double().numpy()
    if not np.isfinite(Dn).all() or not np.allclose(Dn, Dn.T, rtol=1e-9, atol=0.0):
        raise ValueError("Expected D to be a finite symmetric matrix")
    if K <= 2:
        tour = list(range(K))
    elif K <= max_exact:
        cost, parent = _held_karp(Dn, [0])
        end = int(np.argmin(cost[-1, 0] + Dn[:, 0]))
        tour = _backtrack(parent, 0, end)
    else:
        if labels is None:
            raise ValueError(f"K = {K} > max_exact = {max_exact}: pass labels for the class-block ordering")
        check_shape("labels", labels, (K,))
        tour = _class_block_tour(Dn, labels.detach().cpu().numpy())
    start = tour.index(0)
    tour = tour[start:] + tour[:start]
    if K > 2 and tour[1] > tour[-1]:
        tour = tour[:1] + tour[:0:-1]
    return torch.tensor(tour, dtype=torch.long, device=D.device)


def _local_basis(x: torch.Tensor, knots: torch.Tensor, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The degree-3 B-spline basis at x inside its base interval (Cox-de Boor recursion).

    x: (N,); knots: (n + 4,) for n coefficients. Returns first: (N,) int64, the first of the 4
    coefficients that carry x, and weights: (N, 4) their basis values; differentiable in x.
    """
    span = (torch.searchsorted(knots, x.detach(), right=True) - 1).clamp(DEGREE, n - 1)  # t[ℓ] <= x < t[ℓ+1]
    near = knots[span.unsqueeze(-1) + torch.arange(1 - DEGREE, DEGREE + 1, device=knots.device)]  # t[ℓ−2 … ℓ+3]
    unit = torch.eye(DEGREE + 1, dtype=knots.dtype, device=knots.device)
    d = [unit[j].expand(x.shape[0], -1) for j in range(DEGREE + 1)]  # de Boor on the 4 unit vectors
    for r in range(1, DEGREE + 1):
        for j in range(DEGREE, r - 1, -1):
            left = near[:, j - 1]  # t[ℓ + j − 3]
            right = near[:, j - r + DEGREE]  # t[ℓ + j + 1 − r]
            w = ((x - left) / (right - left)).unsqueeze(-1)
            d[j] = (1.0 - w) * d[j - 1] + w * d[j]
    return span - DEGREE, d[DEGREE]


class IdentityManifold(nn.Module):
    """The 1-D closed identity manifold i(α), α ∈ [0, 2π) (eq. 4.16, Fig. 4.6).

    Built by :meth:`fit`; the constructor allocates zero buffers of the right sizes (for loading
    a ``state_dict``).

    Args:
        num_vehicles: K >= 2.
        identity_dim: E, the length of an identity vector (K for the HOSVD's U₃); default K.

    Buffers:
        knots: (K + 7,) the periodic knot vector (data sites at the αₖ, extended by 3 each side).
        coefficients: (K + 3, E) B-spline control points.
        alphas: (K,) αₖ of each vehicle, in the original vehicle order.
        order: (K,) int64, the vehicles along the closed path (order[0] = 0 sits at α = 0).
        labels: (K,) int64 class index per vehicle.
    """

    def __init__(self, num_vehicles: int, identity_dim: int | None = None):
        super().__init__()
        if num_vehicles < 2:
            raise ValueError(f"Expected at least 2 vehicles for a closed identity manifold; got {num_vehicles}")
        E = num_vehicles if identity_dim is None else identity_dim
        self.register_buffer("knots", torch.zeros(num_vehicles + 1 + 2 * DEGREE))
        self.register_buffer("coefficients", torch.zeros(num_vehicles + DEGREE, E))
        self.register_buffer("alphas", torch.zeros(num_vehicles))
        self.register_buffer("order", torch.arange(num_vehicles))
        self.register_buffer("labels", torch.zeros(num_vehicles, dtype=torch.long))

    @property
    def num_vehicles(self) -> int:
        return self.alphas.shape[0]

    @classmethod
    def fit(cls, identity_vectors: torch.Tensor, labels: torch.Tensor, order: torch.Tensor) -> IdentityManifold:
        """Interpolate the ordered identity vectors with a closed periodic cubic B-spline.

        identity_vectors: (K, E) the iᵏ; labels: (K,) class indices; order: (K,) a permutation
        of 0..K−1 (from :func:`shortest_closed_path`). The spline parameter is cumulative chord
        length scaled to [0, 2π): α of ``order[0]`` is 0 and α advances uniformly in identity space.
        """
        check_shape("identity_vectors", identity_vectors, ("K", "E"))
        K, E = identity_vectors.shape
        check_shape("labels", labels, (K,))
        check_shape("order", order, (K,))
        if labels.is_floating_point():
            raise ValueError(f"Expected integer class labels; got dtype {labels.dtype}")
        if sorted(order.tolist()) != list(range(K)):
            raise ValueError(f"Expected order to be a permutation of 0..{K - 1}; got {order.tolist()}")
        module = cls(K, E).to(identity_vectors)
        points = identity_vectors.detach().cpu().double().numpy()[order.cpu().numpy()]  # (K, E) along the path
        closed = np.concatenate([points, points[:1]])  # (K + 1, E), back to the start
        chords = np.linalg.norm(np.diff(closed, axis=0), axis=1)  # (K,)
        if not (chords > 0).all():
            raise ValueError("Consecutive identity vectors along the order coincide: the chord-length parameter "
                             "is undefined")
        sites = TWO_PI * np.concatenate([[0.0], np.cumsum(chords)]) / chords.sum()  # (K + 1,), sites[K] = 2π
        spline = make_interp_spline(sites, closed, k=DEGREE, bc_type="periodic")
        module.knots.copy_(torch.from_numpy(spline.t))
        module.coefficients.copy_(torch.from_numpy(spline.c))
        module.alphas[order] = torch.from_numpy(sites[:K]).to(module.alphas)
        module.order.copy_(order)
        module.labels.copy_(labels)
        return module

    def forward(self, alpha: torch.Tensor) -> torch.Tensor:
        """i(α) for alpha: (N,) radians (wrapped mod 2π). Returns (N, E); differentiable in α."""
        first, weights = self.local_basis(alpha)
        rows = first.unsqueeze(-1) + torch.arange(DEGREE + 1, device=first.device)  # (N, 4)
        return torch.einsum("nj,nje->ne", weights, self.coefficients[rows])

    def local_basis(self, alpha: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The cubic spline's local form: i(α) = Σⱼ weights[:, j] · coefficients[first + j], j < 4.

        Only 4 control points carry each α, so anything linear in i(α) (eq. 4.18) can be
        contracted with 4 control points instead of K identity dimensions.

        alpha: (N,) radians (wrapped mod 2π; taken in the knots' dtype and device). Returns first:
        (N,) int64 in [0, K) and weights: (N, 4), the B-spline basis values (non-negative, summing to 1).
        """
        check_shape("alpha", alpha, ("N",))
        return _local_basis(torch.remainder(alpha.to(self.knots), TWO_PI), self.knots, self.coefficients.shape[0])

    def circular_distances(self, alpha: torch.Tensor) -> torch.Tensor:
        """|α − αₖ| on the circle for alpha: (N,) (in the model's dtype and device). Returns (N, K) in [0, π]."""
        check_shape("alpha", alpha, ("N",))
        diff = torch.remainder(alpha.to(self.alphas).unsqueeze(-1) - self.alphas + math.pi, TWO_PI) - math.pi
        return diff.abs()

    def nearest_vehicles(self, alpha: torch.Tensor, k: int = 2) -> torch.Tensor:
        """The k vehicles with αₖ nearest to alpha: (N,) on the circle. Returns (N, k) int64, nearest first."""
        if isinstance(k, bool) or not isinstance(k, numbers.Integral) or not 1 <= k <= self.num_vehicles:
            raise ValueError(f"Expected a whole k in [1, {self.num_vehicles}]; got {k!r}")
        k = int(k)  # numpy's integers too
        return self.circular_distances(alpha).argsort(dim=-1, stable=True)[:, :k]

    def classify(self, alpha: torch.Tensor) -> torch.Tensor:
        """Class index of the arc of :meth:`class_arcs` that holds alpha: (N,) radians (wrapped mod 2π),
        i.e. of the nearest αₖ. An α midway between two classes' vehicles, an arc's start, is the
        arc's class, as :meth:`class_arcs` has it (the nearest αₖ is a tie there). Returns (N,) int64.
        Tensor work only, on the model's device: it runs every frame."""
        check_shape("alpha", alpha, ("N",))
        starts, labels, count = self._arc_starts()
        at = torch.remainder(alpha.to(starts.device, torch.float64), TWO_PI)
        index = torch.searchsorted(starts, at, right=True) - 1  # −1 before the first start: the last arc's
        return labels[torch.remainder(index, count.clamp_min(1))]  # one class: no start, every α its own

    def _arc_starts(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The classes' arcs as tensors: starts (K,) float64 in [0, 2π), sorted, +inf after the last
        real one; labels (K,), the class of the arc from each start; count (), the real starts.

        Vehicle order[j] owns the arc up to the midpoint to the next vehicle along the path; an arc
        starts where the class changes along the path."""
        sites = self.alphas[self.order].double()  # along the path
        upper = (sites + torch.cat([sites[1:], sites.new_tensor([TWO_PI])])) / 2  # order[j] owns up to here
        labels = self.labels[self.order]
        change = labels != labels.roll(1)  # order[j] starts an arc at upper[j - 1]
        starts = torch.where(change, torch.remainder(upper.roll(1), TWO_PI), torch.inf)
        starts, by_start = starts.sort()
        return starts, labels[by_start], change.sum()

    def class_arcs(self) -> list[tuple[int, float, float]]:
        """The arcs owned by each class, sorted by start (:meth:`_arc_starts`).

        Each vehicle owns the arc between the midpoints to its two neighbours along the path;
        consecutive vehicles of one class merge. Returns (class, start, end) with start in
        [0, 2π) and start < end <= start + 2π: the arc holds α with (α − start) mod 2π < end − start.
        """
        starts, labels, count = self._arc_starts()
        count = int(count)
        if count == 0:  # one class: the whole circle, from the midpoint past the last vehicle
            sites = self.alphas[self.order].double()
            start = float(torch.remainder((sites[-1] + TWO_PI) / 2, TWO_PI))
            return [(int(labels[0]), start, start + TWO_PI)]
        starts, labels = starts[:count].tolist(), labels[:count].tolist()
        ends = starts[1:] + [starts[0] + TWO_PI]
        return list(zip(labels, starts, ends))
