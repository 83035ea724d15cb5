"""Shape encoding of silhouettes (METHOD.md, "Templates"): clipped signed distance and overlaps.

The encoding of a binary silhouette is its signed Euclidean distance transform in pixels,
positive inside, clipped to [−τ, τ] and divided by τ; a reconstruction's silhouette is y > 0.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch


def _as_masks(name: str, mask) -> torch.Tensor:
    """A bool tensor of shape (..., H, W) with H, W >= 1, from a bool tensor or array."""
    if not isinstance(mask, torch.Tensor):
        mask = torch.from_numpy(np.array(mask, copy=True))
    if mask.dtype != torch.bool:
        raise ValueError(f"Expected {name} to be a bool mask of shape (..., H, W); got dtype {mask.dtype}")
    if mask.dim() < 2 or mask.shape[-1] == 0 or mask.shape[-2] == 0:
        raise ValueError(f"Expected {name} to have shape (..., H, W) with H, W >= 1; got {tuple(mask.shape)}")
    return mask


def signed_distance(mask, tau_px: float) -> torch.Tensor:
    """Clipped signed Euclidean distance transform, in units of τ.

    Inside pixels get the distance (in pixels) to the nearest outside pixel centre, outside
    pixels minus the distance to the nearest inside pixel centre (so |d| >= 1 everywhere);
    then d is clipped to [−τ, τ] and divided by τ. An all-empty mask gives −1, an all-full one +1.

    Args:
        mask: (..., H, W) bool, e.g. (H, W) or (N, H, W); a tensor or an array.
        tau_px: τ > 0, the clip distance in pixels.
    Returns:
        (..., H, W) float32 on the CPU, values in [−1, 1].
    """
    if not tau_px > 0:
        raise ValueError(f"Expected tau_px > 0; got {tau_px}")
    mask = _as_masks("mask", mask)
    flat = mask.detach().cpu().reshape(-1, *mask.shape[-2:]).numpy().astype(np.uint8)  # (N, H, W)
    dist = np.empty(flat.shape, dtype=np.float32)
    for n, inside in enumerate(flat):
        if inside.all() or not inside.any():  # no boundary: saturate
            dist[n] = tau_px if inside.all() else -tau_px
            continue
        # distanceTransform: distance of every non-zero pixel to the nearest zero pixel.
        d_in = cv2.distanceTransform(inside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        d_out = cv2.distanceTransform(1 - inside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        dist[n] = d_in - d_out
    dist = np.clip(dist, -tau_px, tau_px) / np.float32(tau_px)
    return torch.from_numpy(dist).reshape(mask.shape)


def silhouette(y: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`signed_distance`: y: (..., H, W) float -> (..., H, W) bool, y > 0."""
    if not isinstance(y, torch.Tensor) or y.dim() < 2:
        raise ValueError(f"Expected y to be a tensor of shape (..., H, W); got {getattr(y, 'shape', type(y).__name__)}")
    return y > 0


def _overlap(a, b) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """|a ∩ b|, |a|, |b| per mask: (...,) each, from (..., H, W) bool masks of one shape."""
    a, b = _as_masks("a", a), _as_masks("b", b)
    if a.shape != b.shape:
        raise ValueError(f"Expected a and b to have one shape; got {tuple(a.shape)} and {tuple(b.shape)}")
    b = b.to(a.device)
    return (a & b).sum(dim=(-2, -1)), a.sum(dim=(-2, -1)), b.sum(dim=(-2, -1))


def iou(a, b) -> torch.Tensor:
    """Intersection over union |a ∩ b| / |a ∪ b| of bool masks (..., H, W) -> (...,) float32.

    1.0 where both masks are empty.
    """
    inter, na, nb = _overlap(a, b)
    union = na + nb - inter
    return torch.where(union > 0, inter / union.clamp(min=1), torch.ones_like(inter, dtype=torch.float32)).float()


def dice(a, b) -> torch.Tensor:
    """Dice overlap 2|a ∩ b| / (|a| + |b|) (eq. 6.1) of bool masks (..., H, W) -> (...,) float32.

    1.0 where both masks are empty.
    """
    inter, na, nb = _overlap(a, b)
    total = na + nb
    return torch.where(total > 0, 2 * inter / total.clamp(min=1), torch.ones_like(inter, dtype=torch.float32)).float()
