"""Ground contact: a vehicle rests on the known ground plane, so its centre's height follows from
its identity.

The state's y is the centre of the vehicle's 3D bounding box, which sits half the vehicle's height
H(α)/2 above the ground. With the ground plane known (the camera's height above it), fixing
y = y_ground + H(α)/2 ties the range to the row where the blob meets the ground: a vehicle that
drifts in range with a free y can keep its silhouette in place by sinking or rising, one whose
y is fixed by the ground cannot. H(α)/2 is read off the model itself, once per tracker: the
depth below the window centre of the lowest point of the reconstructed side view (θ = π/2,
φ = 0, where the bounding box's full height shows), to a fraction of a template pixel by
interpolating the signed distance's zero crossing.
"""

from __future__ import annotations

import math

import torch

from torch_atr._checks import check_shape


def bottom_edge_px(signed: torch.Tensor) -> torch.Tensor:
    """The lowest point of each silhouette, in template pixels from the top edge (rows grow down).

    Args:
        signed: (B, S, S) signed distances, positive inside.
    Returns:
        (B,) the largest row coordinate where a column's distance crosses zero going down
        (linear between pixel centres r + 0.5); NaN for an empty silhouette.
    """
    check_shape("signed", signed, ("B", "S", "S"))
    upper, lower = signed[:, :-1, :], signed[:, 1:, :]
    crossing = (upper > 0) & (lower <= 0)  # (B, S-1, S): inside at row r, outside at r + 1
    rows = torch.arange(signed.shape[1] - 1, dtype=signed.dtype, device=signed.device)[None, :, None]
    edge = rows + 0.5 + upper / (upper - lower).where(crossing, torch.ones_like(upper))
    edge = edge.where(crossing, torch.full_like(edge, -math.inf)).amax(dim=(1, 2))
    bottom_row_inside = signed[:, -1, :] > 0  # a silhouette touching the bottom edge: the edge itself
    edge = torch.where(bottom_row_inside.any(dim=1), torch.full_like(edge, float(signed.shape[1])), edge)
    return torch.where(edge.isfinite(), edge, torch.full_like(edge, math.nan))


def half_heights(model, grid: int = 256) -> torch.Tensor:
    """H(α)/2 in metres at α = 2π k / grid, k = 0 … grid − 1: (grid,), the model's dtype and device."""
    alpha = torch.arange(grid, dtype=model.alphas.dtype, device=model.alphas.device) * (2 * math.pi / grid)
    with torch.no_grad():
        side = model(alpha, torch.full_like(alpha, math.pi / 2), torch.zeros_like(alpha))
    template = model.template
    return (bottom_edge_px(side) - template.size_px / 2) * (template.window_m / template.size_px)


def interpolate_periodic(table: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Linear interpolation of a table sampled at α = 2π k / G (periodic): table (G,), alpha (N,)
    radians. Returns (N,); NaN where alpha is not finite."""
    check_shape("table", table, ("G",))
    check_shape("alpha", alpha, ("N",))
    g = table.shape[0]
    position = torch.remainder(alpha, 2 * math.pi) * (g / (2 * math.pi))
    low = position.floor().long().clamp(0, g - 1)  # NaN (from a non-finite alpha) casts to −2⁶³
    frac = (position - low).to(table.dtype)
    return table[low] * (1 - frac) + table[(low + 1) % g] * frac
