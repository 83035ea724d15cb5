"""Resampling schemes of a particle filter and the effective sample size, batched over particles.

Each scheme takes normalised weights (N,) and returns N ancestor indices whose expected counts
are N·wⱼ (unbiased). They differ in variance: multinomial draws N independent ancestors;
stratified one uniform in each of N strata of the cumulative weights; systematic one shared
uniform offset for all strata (the default: cheapest, lowest variance in practice); residual
keeps ⌊N wⱼ⌋ copies of each particle and fills the rest multinomially. Names and behaviour
follow the ``particles``, filterpy and Stone Soup packages (Douc, Cappé & Moulines 2005, "Comparison
of resampling schemes for particle filtering").

Every scheme is a few tensor operations (``torch.searchsorted`` on the cumulative weights), no
loop over particles; randomness comes from the passed generator.
"""

from __future__ import annotations

import torch

from torch_atr._checks import check_shape

SCHEMES = ("systematic", "stratified", "residual", "multinomial")
_COPY_TOLERANCE = 1e-9  # residual: N wⱼ this short of an integer counts as that integer (float64 rounding)
WEIGHT_SUM_TOLERANCE = 1e-3  # |Σ w − 1| allowed: float32 rounding over 10⁷ particles stays far below


def _check_weights(weights: torch.Tensor) -> None:
    """Normalised weights or ValueError: unnormalised ones would bias the cumulative weights of
    every scheme, and NaN or negative ones pick arbitrary ancestors."""
    check_shape("weights", weights, ("N",))
    if weights.shape[0] == 0 or not weights.is_floating_point():
        raise ValueError(f"Expected a non-empty floating weight vector; got {weights.dtype} {tuple(weights.shape)}")
    total = weights.sum()
    if not bool(torch.isfinite(weights).all() & (weights >= 0).all() & ((total - 1).abs() <= WEIGHT_SUM_TOLERANCE)):
        raise ValueError(f"Expected finite weights >= 0 summing to 1 (normalise them first); got sum "
                         f"{total.item():.6g}, min {weights.min().item():.6g}")


def _inverse_cdf(weights: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Indices j with C_{j−1} <= point < C_j for sorted points in [0, 1), C the cumulative weights
    divided by their total, in float64: C ends at exactly 1 after the last particle of non-zero
    weight, so weights summing to 1 only within rounding send no point to trailing zero weights. The sum is taken
    on the CPU: CUDA's floating-point cumsum adds in no fixed order (PyTorch lists it among its nondeterministic
    operations), and the filter promises the same run for the same seed."""
    cdf = torch.cumsum(weights.to("cpu", torch.float64), 0).to(weights.device)
    cdf = cdf / cdf[-1]
    return torch.searchsorted(cdf, points.to(cdf), right=True).clamp_max(weights.shape[0] - 1)


def systematic_resample(weights: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """Ancestors at (k + u) / N, k = 0…N−1, with one u ~ U[0, 1). weights: (N,) summing to 1. Returns (N,) int64."""
    _check_weights(weights)
    n = weights.shape[0]
    u = torch.rand((), generator=generator, dtype=weights.dtype, device=weights.device)
    # points in float64: in float32 (N − 1 + u) / N rounds to 1 for u near 1
    return _inverse_cdf(weights, (torch.arange(n, dtype=torch.float64, device=weights.device) + u) / n)


def stratified_resample(weights: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """Ancestors at (k + u_k) / N with independent u_k ~ U[0, 1). weights: (N,) summing to 1. Returns (N,) int64."""
    _check_weights(weights)
    n = weights.shape[0]
    u = torch.rand(n, generator=generator, dtype=weights.dtype, device=weights.device)
    # points in float64: in float32 (N − 1 + u) / N rounds to 1 for u near 1
    return _inverse_cdf(weights, (torch.arange(n, dtype=torch.float64, device=weights.device) + u) / n)


def multinomial_resample(weights: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """N independent ancestors drawn with probabilities ``weights``: (N,) summing to 1. Returns (N,) int64."""
    _check_weights(weights)
    n = weights.shape[0]
    u, _ = torch.rand(n, generator=generator, dtype=weights.dtype, device=weights.device).sort()
    return _inverse_cdf(weights, u)


def residual_resample(weights: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """⌊N wⱼ⌋ copies of particle j, the remaining R = N − Σ⌊N wⱼ⌋ drawn multinomially from the
    residuals N wⱼ − ⌊N wⱼ⌋. weights: (N,) summing to 1. Returns (N,) int64, sorted."""
    _check_weights(weights)
    n = weights.shape[0]
    # In float64 and with a tolerance: in float32, N wⱼ of uniform weights rounds to 0.9999998 and no
    # particle would get its certain copy.
    scaled = weights.double() / weights.double().sum() * n
    copies = (scaled + _COPY_TOLERANCE).floor().long()
    deterministic = torch.repeat_interleave(torch.arange(n, device=weights.device), copies)[:n]
    rest = n - deterministic.shape[0]
    if rest == 0:
        return deterministic
    residual = (scaled - copies).clamp_min(0)  # sums to rest
    u, _ = torch.rand(rest, generator=generator, dtype=weights.dtype, device=weights.device).sort()
    drawn = _inverse_cdf(residual, u)  # which divides by their total
    return torch.cat([deterministic, drawn]).sort().values


RESAMPLERS = {"systematic": systematic_resample, "stratified": stratified_resample,
              "residual": residual_resample, "multinomial": multinomial_resample}


def resample(weights: torch.Tensor, scheme: str = "systematic", generator: torch.Generator | None = None
             ) -> torch.Tensor:
    """Ancestor indices by ``scheme`` (one of :data:`SCHEMES`). weights: (N,) summing to 1. Returns (N,) int64."""
    if scheme not in RESAMPLERS:
        raise ValueError(f"Unknown resampling scheme {scheme!r}; expected one of {', '.join(SCHEMES)}")
    return RESAMPLERS[scheme](weights, generator)


def effective_sample_size(weights: torch.Tensor) -> torch.Tensor:
    """ESS = 1 / Σ wⱼ² of normalised weights (N,): N for uniform weights, 1 for one particle. Returns ()."""
    _check_weights(weights)
    return 1.0 / weights.square().sum()
