"""The predicted shape yⱼ of each particle: Methods I–IV of chapter 6 (METHOD.md "Methods").

All four share the filter and its noises; only the appearance differs:

    I    α and Θ continuous: y(α, Θ) = 𝒜 ×₃ i(α) ×₂ Ψ(Θ) (eq. 4.18)
    II   Θ continuous, α snapped to the nearest training vehicle's αₖ
    III  α continuous, Θ snapped to the nearest training view
    IV   the nearest training vehicle's rendered template at the nearest training view

The training views are the RBF centres (``train.py`` puts one at each training view).

Speed. The identity manifold is a cubic B-spline, so i(α) = Σⱼ bⱼ(α) c_{s+j} mixes only 4 of its
K + 3 control points (:meth:`~torch_atr.model.IdentityManifold.local_basis`). Contracting the
core with the control points once, 𝒜' = 𝒜 ×₃ Cᵀ, a particle's pixel-basis coordinates are
Σⱼ bⱼ 𝒜'_{s+j} Ψ(Θ): 4·r·P multiply-adds instead of K·r·P (9× fewer for K = 36). Particles are
grouped by their spline span s (at most K groups, never a loop over particles): one
(nₛ × P) @ (P × 4r) matmul per group. The coordinates are expanded on the pixel basis pooled to
the likelihood resolution L (exact: pooling is linear).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from torch_atr._checks import check_shape
from torch_atr.model import GenerativeShapeModel
from torch_atr.pose import view_vectors
from torch_atr.tracking.observation import silhouette_boxes

METHODS = ("I", "II", "III", "IV")
SPLINE_POINTS = 4  # control points carrying each α (cubic spline)


def pool_images(images: torch.Tensor, size: int) -> torch.Tensor:
    """Average-pool square images (..., S, S) to (..., L, L), L = ``size`` dividing S."""
    if not isinstance(images, torch.Tensor) or images.dim() < 2:
        got = tuple(images.shape) if isinstance(images, torch.Tensor) else type(images).__name__
        raise ValueError(f"Expected images to be a tensor of shape (..., S, S); got {got}")
    S = images.shape[-1]
    if images.shape[-2] != S or size < 1 or S % size:
        raise ValueError(f"Expected square images whose size {tuple(images.shape[-2:])} is a multiple of {size}")
    flat = images.reshape(-1, 1, S, S)
    return F.avg_pool2d(flat, S // size).reshape(*images.shape[:-2], size, size)


class ShapeAppearance(nn.Module):
    """Predicted signed-distance templates y (N, L, L) of particles, for one of Methods I–IV.

    Args:
        model: the generative model (kept as a submodule; its buffers move with ``.to()``).
        method: "I", "II", "III" or "IV".
        size: L, the likelihood resolution (divides the template size S).
        templates: (K, V, S, S) signed-distance templates of the K training vehicles at the V
            training views (the RBF centres), needed by Method IV only
            (:func:`~torch_atr.training.render_set` renders them).

    Buffers: ``windows`` (K, P, 4r), for each spline span s the control-point core
    [𝒜'_s … 𝒜'_{s+3}] arranged for one matmul; ``basis`` (L², r) the pixel basis B pooled to L;
    ``gram`` (r, r) BᵀB; ``templates`` (K, V, L²) pooled and ``template_boxes`` (K, V, 4) their
    silhouettes' boxes at full size (Method IV), or None.
    """

    def __init__(self, model: GenerativeShapeModel, method: str = "I", size: int = 32,
                 templates: torch.Tensor | None = None):
        super().__init__()
        if method not in METHODS:
            raise ValueError(f"Unknown method {method!r}; expected one of {', '.join(METHODS)}")
        if model.core.pixel_basis is None:
            raise ValueError("The tracker needs a model with a pixel basis (model.pixel_rank set)")
        S, K, V = model.template.size_px, model.core.num_vehicles, model.rbf.num_centres
        self.model, self.method, self.size = model, method, int(size)
        with torch.no_grad():
            A, C = model.core.core, model.identity.coefficients.to(model.core.core)  # (r, P, K), (K + 3, K)
            control = torch.einsum("rpk,ck->cpr", A, C)  # 𝒜' = 𝒜 ×₃ Cᵀ: (K + 3, P, r)
            spans = torch.arange(K, device=A.device)[:, None] + torch.arange(SPLINE_POINTS, device=A.device)
            windows = control[spans].permute(0, 2, 1, 3).reshape(K, A.shape[1], -1)  # (K, P, 4r)
            r = model.core.pixel_rank
            basis = pool_images(model.core.pixel_basis.T.reshape(r, S, S), self.size).reshape(r, -1).T
        self.register_buffer("windows", windows.contiguous())
        self.register_buffer("basis", basis.contiguous())  # (L², r)
        self.register_buffer("gram", (basis.T @ basis).contiguous())  # (r, r) BᵀB, for ‖y‖² = cᵀ G c
        if method == "IV":
            if templates is None:
                raise ValueError("Method IV needs the training templates (K, V, S, S): pass "
                                 "templates=torch_atr.training.training_templates(model)")
            if tuple(templates.shape) != (K, V, S, S):
                raise ValueError(f"Expected templates of shape {(K, V, S, S)} (vehicles, RBF-centre views, pixels); "
                                 f"got {tuple(templates.shape)}")
            pooled = pool_images(templates.to(A), self.size).reshape(K, V, -1)
            self.register_buffer("templates", pooled)
            self.register_buffer("template_boxes", silhouette_boxes(templates.to(A.device).flatten(0, 1) > 0
                                                                    ).view(K, V, 4))
        else:
            self.register_buffer("templates", None)
            self.register_buffer("template_boxes", None)

    def _queries(self, alpha: torch.Tensor, theta: torch.Tensor, phi: torch.Tensor
                 ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """alpha, theta, phi checked to be (N,) each and converted to the model's dtype and device."""
        check_shape("alpha", alpha, ("N",))
        for name, q in (("theta", theta), ("phi", phi)):
            check_shape(name, q, (alpha.shape[0],))
        return tuple(q.to(self.windows) for q in (alpha, theta, phi))

    def snap(self, alpha: torch.Tensor, theta: torch.Tensor, phi: torch.Tensor
             ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None, torch.Tensor | None]:
        """The method's (α, θ, φ) for (N,) queries, and the snapped vehicle and view indices (N,)
        (None where the method keeps that variable continuous). A non-finite α, or Θ with a
        non-finite angle, is kept as it is (its index is arbitrary), so that its shape is NaN."""
        model = self.model
        vehicle = view = None
        if self.method in ("II", "IV"):
            vehicle = model.identity.nearest_vehicles(alpha, 1)[:, 0]
            alpha = model.alphas[vehicle].to(alpha).where(alpha.isfinite(), alpha)
        if self.method in ("III", "IV"):
            centres = model.rbf.centres_u.to(theta)  # (V, 3)
            view = torch.cdist(view_vectors(theta, phi), centres).argmin(dim=1)
            finite = theta.isfinite() & phi.isfinite()
            theta, phi = (model.rbf.centres_theta[view].to(theta).where(finite, theta),
                          model.rbf.centres_phi[view].to(theta).where(finite, phi))
        return alpha, theta, phi, vehicle, view

    def grid_boxes(self, alpha: torch.Tensor, theta: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
        """The boxes of this method's full-size silhouettes (y > 0, S × S template pixels) for every α
        at every view: the shapes it compares, snapped as :meth:`snap` snaps them (Method IV: the
        templates' own). The blind start lays these boxes on the blob.

        alpha: (A,); theta, phi: (B,) radians. Returns (A·B, 4) [c0, r0, c1, r1], α-major, float32
        (NaN for an empty silhouette).
        """
        check_shape("alpha", alpha, ("A",))
        check_shape("theta", theta, ("B",))
        check_shape("phi", phi, tuple(theta.shape))
        A, B = alpha.shape[0], theta.shape[0]
        alpha, _, _, vehicle, _ = self.snap(alpha.to(self.windows), *self.windows.new_zeros(2, A))
        _, theta, phi, _, view = self.snap(self.windows.new_zeros(B), theta.to(self.windows), phi.to(self.windows))
        if self.method == "IV":
            return self.template_boxes[vehicle][:, view].reshape(-1, 4)
        S = self.model.template.size_px
        with torch.no_grad():
            shapes = self.model.reconstruct_grid(alpha, theta, phi)  # (A, B, S, S)
        return silhouette_boxes(shapes.reshape(-1, S, S) > 0)

    def coords(self, alpha: torch.Tensor, theta: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
        """Pixel-basis coordinates c = 𝒜 ×₃ i(α) ×₂ Ψ(Θ), grouped by spline span.

        alpha, theta, phi: (N,) each (radians). Returns (N, r) in the model's dtype.
        """
        alpha, theta, phi = self._queries(alpha, theta, phi)
        psi = self.model.rbf(theta, phi)  # (N, P)
        first, weights = self.model.identity.local_basis(alpha)
        N, r = alpha.shape[0], self.basis.shape[1]
        if N == 0:  # no span groups, and torch.cat needs one
            return psi.new_empty(0, r)
        order = torch.argsort(first)  # particles grouped by span: one contiguous slice per group
        spans, counts = torch.unique_consecutive(first[order], return_counts=True)
        groups = psi[order].split(counts.tolist())
        local = torch.cat([group @ self.windows[s] for s, group in zip(spans.tolist(), groups)])  # ≤ K groups
        out = torch.empty(N, r, dtype=psi.dtype, device=psi.device)
        out[order] = (weights[order].unsqueeze(-1) * local.view(N, SPLINE_POINTS, r)).sum(1)  # Σⱼ bⱼ 𝒜'_{s+j} Ψ
        return out

    def squared_errors(self, z: torch.Tensor, alpha: torch.Tensor, theta: torch.Tensor, phi: torch.Tensor,
                       observed: torch.Tensor | None = None) -> torch.Tensor:
        """Σ (zⱼ − yⱼ)² over the L × L pixels of each particle, without forming yⱼ (Methods I–III).

        With y = B c on the pooled basis, ‖z − y‖² = ‖z‖² − 2 (Bᵀz)·c + cᵀ (BᵀB) c: one read of z
        for Bᵀz instead of forming y (N × L²) and three passes over z − y. Method IV compares the
        templates directly.

        z: (N, L, L) observed signed distances; alpha, theta, phi: (N,). observed: optional
        (N, L, L) bool, the pixels observed (``observation.observed_cells``): the sum runs over
        them only, the others marginalised out of eq. 5.2's Gaussian (yⱼ is formed); NaN where a
        particle observes none. Returns (N,).
        """
        alpha, theta, phi = self._queries(alpha, theta, phi)
        check_shape("z", z, (alpha.shape[0], self.size, self.size))
        if observed is not None:
            check_shape("observed", observed, tuple(z.shape))
            errors = (z - self(alpha, theta, phi).to(z)).square().masked_fill(~observed, 0.0).sum(dim=(1, 2))
            return torch.where(observed.any(dim=(1, 2)), errors, torch.nan)
        if self.method == "IV":  # the templates themselves; NaN for a non-finite query, as forward gives
            alpha, theta, phi, vehicle, view = self.snap(alpha, theta, phi)
            y = self.templates[vehicle, view].view_as(z).to(z)
            finite = alpha.isfinite() & theta.isfinite() & phi.isfinite()
            return (z - y).square().sum(dim=(1, 2)).masked_fill(~finite, torch.nan)
        c = self.coords(*self.snap(alpha, theta, phi)[:3])  # (N, r)
        flat = z.flatten(1).to(c)  # (N, L²); reshape(N, -1) is ambiguous for N = 0
        expanded = flat.square().sum(1) - 2 * ((flat @ self.basis) * c).sum(1) + ((c @ self.gram) * c).sum(1)
        return expanded.clamp_min(0)  # the expansion cancels to ~1e-3 below 0 for a near-perfect fit in float32

    def forward(self, alpha: torch.Tensor, theta: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
        """Predicted templates y for alpha, theta, phi: (N,) radians (any float dtype). Returns
        (N, L, L) in the model's dtype."""
        alpha, theta, phi, vehicle, view = self.snap(*self._queries(alpha, theta, phi))
        if self.method == "IV":
            finite = alpha.isfinite() & theta.isfinite() & phi.isfinite()
            y = self.templates[vehicle, view].masked_fill_(~finite[:, None], torch.nan)  # (N, L²), a fresh gather
        else:
            y = self.coords(alpha, theta, phi) @ self.basis.T  # (N, L²)
        return y.view(-1, self.size, self.size)
