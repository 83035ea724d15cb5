"""Per-frame estimates from weighted particles (Table 5.1 step 3, METHOD.md "Estimate").

Linear quantities (x, y, z, v) take the weighted mean and covariance; angles (heading h and
identity α) the circular weighted mean atan2(Σ w sin a, Σ w cos a), since a plain mean of angles
is wrong across 0 / 2π (the mean of 0.1 and 2π − 0.1 is 0, not π).

The weighted sums are elementwise products and ``sum``, not BLAS products: a matrix-vector product
gave last-bit differences between identical runs (the BLAS library's threading is not fixed),
and the tracker promises the same run for the same seed and thread count (a sum over more than
32 768 particles is split by thread, so another thread count may move its last bit). For the same
reason the class posterior is a masked ``sum``, not ``index_add_``, whose CUDA kernel adds with
atomics in no fixed order.
"""

from __future__ import annotations

import torch

from torch_atr._checks import check_shape
from torch_atr.pose import wrap_angle


def _check(values: torch.Tensor, weights: torch.Tensor, dims: tuple) -> None:
    check_shape("weights", weights, ("N",))
    if weights.shape[0] == 0:
        raise ValueError(f"Expected at least one particle; got weights of shape {tuple(weights.shape)}")
    check_shape("values", values, (weights.shape[0], *dims))


def weighted_mean_cov(values: torch.Tensor, weights: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Weighted mean (D,) and covariance (D, D) Σ wⱼ (xⱼ − μ)(xⱼ − μ)ᵀ of values (N, D), weights (N,) summing to 1."""
    _check(values, weights, (None,))
    w = weights[:, None]
    mean = (w * values).sum(0)  # sums, not BLAS: bitwise reproducible (module docstring)
    centred = values - mean
    weighted = w * centred  # one (N, D) column of products at a time, not an (N, D, D) temporary: 10⁷ particles
    return mean, torch.stack([(weighted * centred[:, j:j + 1]).sum(0) for j in range(values.shape[1])], dim=1)


def circular_mean(angles: torch.Tensor, weights: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Weighted circular mean of angles (N,) radians with weights (N,) summing to 1.

    Returns the mean in [0, 2π) and the mean resultant length R = |Σ w e^{ia}| in [0, 1]
    (1: all equal; 0: no preferred direction, where the mean is arbitrary).
    """
    _check(angles, weights, ())
    s, c = (weights * torch.sin(angles)).sum(), (weights * torch.cos(angles)).sum()
    return wrap_angle(torch.atan2(s, c)), torch.hypot(s, c).clamp_max(1.0)  # weights' rounding: Σ w may pass 1


def class_posterior(classes: torch.Tensor, weights: torch.Tensor, num_classes: int) -> torch.Tensor:
    """Posterior weight per class: Σ of the weights of the particles in each class.

    classes: (N,) int64 in [0, C); weights: (N,); num_classes: C. Returns (C,).
    """
    _check(classes, weights, ())
    if classes.is_floating_point() or classes.dtype == torch.bool:
        raise ValueError(f"Expected integer classes; got {classes.dtype}")
    if not bool(((classes >= 0) & (classes < num_classes)).all()):  # they would fall silently out of the sum
        raise ValueError(f"Expected classes in [0, {num_classes}); got min {int(classes.min())}, "
                         f"max {int(classes.max())}")
    member = classes[:, None] == torch.arange(num_classes, device=classes.device)  # (N, C)
    return torch.where(member, weights[:, None], torch.zeros((), dtype=weights.dtype, device=weights.device)).sum(0)
