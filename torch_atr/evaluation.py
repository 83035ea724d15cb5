"""Measures of the generative model (chapter 6.1) used by ``train.py``, the tests and the README.

All functions take a fitted :class:`~torch_atr.model.GenerativeShapeModel` and use its
``reconstruct_grid`` (every α at every view), which contracts Ψ once per view.
"""

from __future__ import annotations

import math

import torch

from torch_atr._checks import check_shape
from torch_atr.shape import iou


def _views(model, templates: torch.Tensor, theta, phi, view_dim: int) -> tuple[torch.Tensor, torch.Tensor]:
    like = model.alphas
    theta, phi = torch.as_tensor(theta).to(like), torch.as_tensor(phi).to(like)
    check_shape("theta", theta, (templates.shape[view_dim],))
    check_shape("phi", phi, (templates.shape[view_dim],))
    return theta, phi


@torch.no_grad()
def reconstruction_iou(model, templates: torch.Tensor, theta, phi) -> torch.Tensor:
    """IoU of each vehicle's reconstruction at its own αₖ against its true silhouettes.

    templates: (K, V, H, W) bool silhouettes of the K training vehicles; theta, phi: (V,) radians.
    Returns (K, V) IoU.
    """
    check_shape("templates", templates, ("K", "V", None, None))
    theta, phi = _views(model, templates, theta, phi, 1)
    return torch.stack([iou(model.reconstruct_grid(model.alphas[k:k + 1], theta, phi)[0].cpu() > 0, templates[k])
                        for k in range(templates.shape[0])])


@torch.no_grad()
def identity_distances(model, signed: torch.Tensor, theta, phi) -> torch.Tensor:
    """Mean squared error between the reconstruction at αₖ and vehicle j's templates.

    signed: (K, V, H, W) signed-distance templates; theta, phi: (V,) radians.
    Returns (K, K): row k = reconstruction at αₖ, column j = vehicle j. A good model has its
    row minima on the diagonal.
    """
    check_shape("signed", signed, ("K", "V", None, None))
    theta, phi = _views(model, signed, theta, phi, 1)
    K = signed.shape[0]
    out = torch.empty(K, K)
    for k in range(K):
        recon = model.reconstruct_grid(model.alphas[k:k + 1], theta, phi).cpu()  # (1, V, H, W)
        out[k] = ((signed - recon) ** 2).mean(dim=(1, 2, 3))
    return out


@torch.no_grad()
def fit_alpha(model, signed: torch.Tensor, theta, phi, grid: int = 360) -> tuple[float, float]:
    """Search the identity manifold for the α that best explains one vehicle's known views.

    A grid over α ∈ [0, 2π) brackets the minimum of the mean squared signed-distance error;
    a bounded scalar search (scipy's Brent method) within one grid step either side refines it.
    signed: (V, H, W) signed-distance templates of the vehicle; theta, phi: (V,) radians.
    Returns (alpha in [0, 2π), its mean squared error).
    """
    from scipy.optimize import minimize_scalar

    check_shape("signed", signed, ("V", None, None))
    if grid < 3:
        raise ValueError(f"Expected grid >= 3; got {grid}")
    theta, phi = _views(model, signed, theta, phi, 0)
    target = signed.to(model.alphas)
    # In pixel-basis coordinates: ‖y − t‖² = ‖c − Uᵀt‖² + (‖t‖² − ‖Uᵀt‖²), the last term fixed.
    coords = model.project(target)  # (V, r)
    outside = (target.square().sum() - coords.square().sum()).clamp_min(0)
    count = target.numel()

    def loss_of(alpha: torch.Tensor) -> torch.Tensor:  # alpha (A,) -> (A,)
        c = model.reconstruct_grid(alpha, theta, phi, in_basis=True)  # (A, V, r)
        return ((c - coords).square().sum(dim=(1, 2)) + outside) / count

    step = 2 * math.pi / grid
    candidates = torch.arange(grid, dtype=target.dtype, device=target.device) * step
    losses = torch.cat([loss_of(chunk) for chunk in candidates.split(max(1, 8192 // len(theta)))])
    start = candidates[losses.argmin()].item()
    res = minimize_scalar(lambda a: loss_of(torch.tensor([a], dtype=target.dtype, device=target.device)).item(),
                          bounds=(start - step, start + step), method="bounded", options={"xatol": 1e-6})
    if res.fun <= losses.min().item():
        return float(res.x) % (2 * math.pi), float(res.fun)
    return start, losses.min().item()
