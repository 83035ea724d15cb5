"""The view mapping of the generative model: Gaussian RBF features on the view hemisphere.

Eq. 4.12-4.13: yᵏ(Θ) = Bᵏ Ψ(Θ) with Ψ(Θ) = [κ(‖u(Θ) − u(Υ₁)‖), …, κ(‖u(Θ) − u(Υ_Nc)‖), 1, u(Θ)].
Distances and the polynomial term use the unit view vector u(θ, φ) instead of the raw angles
(METHOD.md, "Distances on the view manifold"), so Ψ is continuous across θ = 0 / 2π.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from torch_atr._checks import as_float_tensor, check_shape
from torch_atr.pose import view_vectors

KERNEL_FLOOR = 1e-9  # κ below this is 0 (rbf_features)
_MAX_EXPONENT = -math.log(KERNEL_FLOOR)
_UNIT_TOLERANCE = 1e-4  # |‖u‖ − 1| allowed of a view vector (float32 rounding stays far below)


def rbf_features(u: torch.Tensor, centres_u: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
    """Ψ(Θ) of eq. 4.13 with a Gaussian kernel κ(r) = exp(−r² / (2 sₗ²)) per centre.

    Kernel values below ``KERNEL_FLOOR`` are set to 0: the tail underflows into denormal floats
    (≈ 4 % of the shipped model's entries for random views), which slowed the Ψ-first matmul of
    the reconstruction 5×; the truncation changes the shipped model's y by < 1e-8.

    u: (N, 3) unit view vectors; centres_u: (Nc, 3) unit centre view vectors u(Υₗ); widths: (Nc,)
    sₗ > 0. Returns (N, Nc + 4): [κ(‖u − u(Υ₁)‖), …, κ(‖u − u(Υ_Nc)‖), 1, u].
    """
    check_shape("u", u, ("N", 3))
    check_shape("centres_u", centres_u, ("Nc", 3))
    check_shape("widths", widths, (centres_u.shape[0],))
    if not bool((widths > 0).all()):  # 0 gave NaN features, a negative width acted as its absolute value
        raise ValueError(f"Expected widths > 0; got min {widths.min().item():.6g}")
    for name, x in (("u", u), ("centres_u", centres_u)):  # the kernel's 2 − 2 u·c holds for unit vectors only
        if x.numel() and not bool(((x.norm(dim=1) - 1).abs() <= _UNIT_TOLERANCE).all()):
            raise ValueError(f"Expected {name} to be unit vectors (view_vectors(theta, phi)); got norms from "
                             f"{x.norm(dim=1).min().item():.6g} to {x.norm(dim=1).max().item():.6g}")
    return _features(u, centres_u, widths)


def _features(u: torch.Tensor, centres_u: torch.Tensor, widths: torch.Tensor) -> torch.Tensor:
    """:func:`rbf_features` without its checks, for :class:`RBFViewMapping`, whose views are unit
    vectors and widths exp(log sₗ) > 0 by construction (a check a call was a GPU sync a call).
    Accurate to 3e-5 in float32 at the shipped widths (≥ 0.066): the exponent's u·c − 1 cancels
    to ~1e-7, scaled by 1/sₗ²."""
    # For unit vectors ‖u − c‖² = 2 − 2 u·c, so −r² / (2s²) = (u·c − 1) / s²: one addmm. The
    # exponent is clamped just below the floor before exp: exp of large negative numbers (underflow
    # to denormals) ran 80x slower than of the clamped ones on this CPU.
    inv = 1.0 / (widths * widths)  # (Nc,)
    exponent = torch.addmm(-inv, u, centres_u.T * inv).clamp(-_MAX_EXPONENT - 1.0, 0.0)  # (N, Nc)
    kernel = torch.exp(exponent).masked_fill(exponent < -_MAX_EXPONENT, 0.0)
    return torch.cat((kernel, torch.ones_like(u[:, :1]), u), dim=-1)


def mean_nearest_chord(centres_u: torch.Tensor) -> torch.Tensor:
    """Mean over centres of the chord distance to the nearest other centre.

    centres_u: (Nc, 3) with Nc >= 2. Returns a scalar tensor.
    """
    check_shape("centres_u", centres_u, ("Nc", 3))
    if centres_u.shape[0] < 2:
        raise ValueError(f"Expected at least 2 centres for a nearest-neighbour distance; got {centres_u.shape[0]}")
    dist = torch.cdist(centres_u, centres_u)
    dist.fill_diagonal_(float("inf"))
    return dist.min(dim=1).values.mean()


def ridge_hat(psi: torch.Tensor, ridge: float) -> torch.Tensor:
    """W = Ψ (ΨᵀΨ + λI)⁻¹ = (ΨΨᵀ + λI)⁻¹ Ψ, so that the ridge solution of eq. 4.13 is Bᵏ = Yᵏᵀ W.

    psi: (V, P) features of the training views; ridge: λ >= 0. Returns (V, P) in psi's dtype.
    Solves the smaller of the two Gram systems (the push-through identity makes them equal):
    with the centres at the training views P = V + 4 > V, and (ΨΨᵀ + λI) stays invertible as
    λ → 0, giving the exact (minimum-norm) interpolant. The Gram squares Ψ's condition number
    (2.2e6 for the shipped views at λ = 1e-4, 8e10 at 0), so it is solved in float64: in float32
    W was 0.8 % off at λ = 1e-4 and 177 % at 0, where the mappings' IoU at their own views fell
    from 1.00 to 0.52.
    """
    check_shape("psi", psi, ("V", "P"))
    if not ridge >= 0:
        raise ValueError(f"Expected ridge >= 0; got {ridge}")
    wide = psi.to(torch.float64)
    V, P = psi.shape
    if V <= P:
        gram = wide @ wide.T + ridge * torch.eye(V, dtype=wide.dtype, device=wide.device)  # (V, V)
        return torch.linalg.solve(gram, wide).to(psi.dtype)
    gram = wide.T @ wide + ridge * torch.eye(P, dtype=wide.dtype, device=wide.device)  # (P, P)
    return torch.linalg.solve(gram, wide.T).T.to(psi.dtype)


class RBFViewMapping(nn.Module):
    """Ψ(Θ) with Nc Gaussian centres Υₗ on the view hemisphere and learnable widths (eq. 4.12-4.13).

    Args:
        centres_theta, centres_phi: (Nc,) centre azimuths and elevations, radians (buffers, in their
            promoted float dtype, on centres_theta's device).
        init_width: initial kernel width sₗ (chord length, same for all centres); default the mean
            nearest-neighbour chord distance between the centres.

    The widths are ``exp(log_width)`` (a parameter of shape (Nc,)), positive by construction.
    """

    def __init__(self, centres_theta: torch.Tensor, centres_phi: torch.Tensor, init_width: float | None = None):
        super().__init__()
        centres_theta = as_float_tensor("centres_theta", centres_theta)
        centres_phi = as_float_tensor("centres_phi", centres_phi, like=centres_theta)
        # One dtype and device for both (float32 θ with float64 φ left buffers of two dtypes, which save refused).
        dtype = torch.promote_types(centres_theta.dtype, centres_phi.dtype)
        centres_theta, centres_phi = centres_theta.to(dtype), centres_phi.to(centres_theta.device, dtype)
        check_shape("centres_theta", centres_theta, ("Nc",))
        check_shape("centres_phi", centres_phi, (centres_theta.shape[0],))
        self.register_buffer("centres_theta", centres_theta.clone())
        self.register_buffer("centres_phi", centres_phi.clone())
        if init_width is None:
            width = mean_nearest_chord(self.centres_u)
            if not width > 0:
                raise ValueError("RBF centres coincide: cannot derive a default width; pass init_width")
        else:
            if not init_width > 0:
                raise ValueError(f"Expected init_width > 0; got {init_width}")
            width = torch.tensor(float(init_width), dtype=centres_theta.dtype, device=centres_theta.device)
        self.log_width = nn.Parameter(torch.log(width).expand(centres_theta.shape[0]).clone())

    @property
    def num_centres(self) -> int:
        return self.centres_theta.shape[0]

    @property
    def psi_dim(self) -> int:
        """P = Nc + 4, the length of Ψ(Θ)."""
        return self.num_centres + 4

    @property
    def widths(self) -> torch.Tensor:
        """(Nc,) kernel widths sₗ = exp(log_width)."""
        return self.log_width.exp()

    @property
    def centres_u(self) -> torch.Tensor:
        """(Nc, 3) view vectors u(Υₗ) of the centres."""
        return view_vectors(self.centres_theta, self.centres_phi)

    def forward(self, theta: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
        """Ψ(Θ) for theta, phi: (N,) radians (tensors, arrays or lists; taken in the centres' dtype and
        device). Returns (N, Nc + 4)."""
        like = self.centres_u
        theta, phi = (as_float_tensor(name, x, like=like).to(like) for name, x in (("theta", theta), ("phi", phi)))
        return _features(view_vectors(theta, phi), like, self.widths)

    def fit(self, theta: torch.Tensor, phi: torch.Tensor, Y: torch.Tensor, ridge: float) -> torch.Tensor:
        """Every Bᵏ of eq. 4.13 at once by regularised least squares.

        Minimises Σₖ ‖Yᵏᵀ − Bᵏ Ψᵀ‖² + λ‖Bᵏ‖² in closed form, B = Yᵀ Ψ (ΨᵀΨ + λI)⁻¹, with one
        factorisation shared by all K vehicles; differentiable with respect to the widths.

        theta, phi: (V,) training views, radians; Y: (K, V, d) flattened templates, any float dtype;
        ridge: λ >= 0. Returns B: (K, d, Nc + 4) in the centres' dtype and device.
        """
        check_shape("theta", theta, ("V",))
        check_shape("Y", Y, (None, theta.shape[0], None))
        W = ridge_hat(self(theta, phi), ridge)  # (V, P)
        return Y.transpose(1, 2).to(W) @ W  # (K, d, P), contiguous; float32 Y on float64 centres was a RuntimeError
