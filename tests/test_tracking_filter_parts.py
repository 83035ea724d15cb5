"""Motion model, resampling schemes and weighted estimates against closed forms, their
definitions and brute force."""

import math

import numpy as np
import pytest
import torch

from torch_atr.config import ConfigError
from torch_atr.tracking.estimates import circular_mean, class_posterior, weighted_mean_cov
from torch_atr.tracking.motion import ALPHA, HEADING, MotionConfig, predict
from torch_atr.tracking.resampling import SCHEMES, effective_sample_size, resample

TWO_PI = 2 * math.pi


def test_predict_is_eq_5_1_and_5_3_particle_by_particle():
    """The batched step equals eq. 5.1 / 5.3 written out for each particle with the same draws."""
    cfg = MotionConfig(sigma2_x=0.2, sigma2_y=0.5, sigma2_z=0.3, sigma2_heading=0.05, sigma2_speed=2.0, sigma2_alpha=0.4)
    g = torch.Generator().manual_seed(0)
    p = torch.rand(7, 6, generator=g, dtype=torch.float64) * torch.tensor([10, 2, 1000, TWO_PI, 8, TWO_PI])
    p[0, HEADING], p[0, ALPHA] = TWO_PI - 1e-3, 1e-3  # near the wrap
    dt = 1 / 30
    out = predict(p, dt, cfg, torch.Generator().manual_seed(5))
    w = torch.randn(7, 6, generator=torch.Generator().manual_seed(5), dtype=torch.float64)  # the same draws
    std = [math.sqrt(v * dt) for v in (0.2, 0.5, 0.3, 0.05, 2.0, 0.4)]
    for j in range(7):
        x, y, z, h, v, a = p[j].tolist()
        want = [x + v * math.sin(h) * dt + std[0] * w[j, 0], y + std[1] * w[j, 1],
                z + v * math.cos(h) * dt + std[2] * w[j, 2], (h + std[3] * w[j, 3]) % TWO_PI,
                v + std[4] * w[j, 4], (a + std[5] * w[j, 5]) % TWO_PI]
        np.testing.assert_allclose(out[j].numpy(), np.array(want, dtype=np.float64), rtol=1e-12, atol=1e-12)
    assert ((out[:, [HEADING, ALPHA]] >= 0) & (out[:, [HEADING, ALPHA]] < TWO_PI)).all()


def test_predict_wraps_heading_and_alpha_that_cross_0_or_2pi_either_way():
    """Particles 1e-3 rad either side of the wrap with σ 0.1 rad per step: about half of them cross 0
    or 2π, each way, in h and in α. Each result is the particle's h + σ w (α + σ w) with the same
    draws, taken % 2π (Python's float remainder), and lies in [0, 2π)."""
    n = 400
    cfg = MotionConfig(sigma2_heading=0.3, sigma2_alpha=0.3)  # σ = √(0.3 / 30) = 0.1 rad per step
    p = torch.zeros(n, 6, dtype=torch.float64)
    p[: n // 2, HEADING], p[n // 2:, HEADING] = 1e-3, TWO_PI - 1e-3
    p[::2, ALPHA], p[1::2, ALPHA] = TWO_PI - 1e-3, 1e-3
    dt = 1 / 30
    out = predict(p, dt, cfg, torch.Generator().manual_seed(7))
    w = torch.randn(n, 6, generator=torch.Generator().manual_seed(7), dtype=torch.float64)  # the same draws
    std = math.sqrt(0.3 * dt)
    for column in (HEADING, ALPHA):
        raw = [a + std * float(d) for a, d in zip(p[:, column].tolist(), w[:, column])]
        assert sum(r < 0 for r in raw) > n // 8 and sum(r >= TWO_PI for r in raw) > n // 8  # crossed both ways
        want = np.array([r % TWO_PI for r in raw])
        np.testing.assert_allclose(out[:, column].numpy(), want, rtol=0, atol=1e-12)
        assert ((out[:, column] >= 0) & (out[:, column] < TWO_PI)).all()


def test_predict_noise_has_the_per_second_variance():
    cfg = MotionConfig()
    p = torch.zeros(200_000, 6, dtype=torch.float64)
    p[:, HEADING], p[:, ALPHA] = math.pi, math.pi
    dt = 0.5
    out = predict(p, dt, cfg, torch.Generator().manual_seed(1))
    var = out.var(dim=0)
    want = torch.tensor([0.1, 1.0, 0.1, cfg.sigma2_heading, 1.0, cfg.sigma2_alpha], dtype=torch.float64) * dt
    torch.testing.assert_close(var, want, rtol=0.02, atol=0)
    with pytest.raises(ValueError, match="dt"):
        predict(p[:3], 0.0, cfg)
    with pytest.raises(ConfigError, match="sigma2_x"):
        MotionConfig(sigma2_x=float("inf"))


def test_predict_is_deterministic_under_a_seed():
    p = torch.rand(50, 6)
    a = predict(p, 0.1, MotionConfig(), torch.Generator().manual_seed(3))
    b = predict(p, 0.1, MotionConfig(), torch.Generator().manual_seed(3))
    assert torch.equal(a, b) and not torch.equal(a, predict(p, 0.1, MotionConfig(), torch.Generator().manual_seed(4)))


@pytest.mark.parametrize("scheme", SCHEMES)
def test_resampling_expected_counts_are_n_w(scheme):
    """Unbiasedness, the definition: E[count_j] = N w_j, over many seeded draws."""
    w = torch.tensor([0.5, 0.0, 0.05, 0.3, 0.15], dtype=torch.float64)
    n, trials = w.shape[0], 4000
    g = torch.Generator().manual_seed(0)
    counts = torch.stack([torch.bincount(resample(w, scheme, g), minlength=n) for _ in range(trials)]).double()
    assert (counts.sum(1) == n).all() and (counts[:, 1] == 0).all()
    np.testing.assert_allclose(counts.mean(0).numpy(), (n * w).numpy(), atol=0.05)
    if scheme == "systematic":  # particle j gets ⌊N wⱼ⌋ or ⌈N wⱼ⌉ copies
        assert ((counts - n * w).abs() < 1).all()
    if scheme == "residual":  # at least ⌊N wⱼ⌋ copies
        assert (counts >= (n * w).floor()).all()


def test_each_scheme_draws_as_its_definition_says():
    """w = (1, 3, 3, 1) / 8, N = 4: the schemes share their expected counts (above) but not their draws.
    Closed forms over the strata [k/4, (k + 1)/4) against the cumulative weights (1/8, 1/2, 7/8, 1):
    only the first and last strata can pick two particles (the outer one with probability 1/2).
    Systematic, one offset for all, picks exactly one of the outer two; stratified, an offset each,
    both with probability 1/4 and never one twice; multinomial the first at least twice with
    probability 1 − (7/8)⁴ − 4 (1/8)(7/8)³ and the second never with (5/8)⁴; residual keeps
    ⌊N w⌋ = one copy of each middle particle and draws two from the residuals (1/2 each): the
    first at least twice with probability 1/16."""
    w = torch.tensor([1.0, 3.0, 3.0, 1.0], dtype=torch.float64) / 8
    g = torch.Generator().manual_seed(0)
    counts = {s: torch.stack([torch.bincount(resample(w, s, g), minlength=4) for _ in range(2000)]) for s in SCHEMES}
    outer = {s: c[:, 0] + c[:, 3] for s, c in counts.items()}
    assert (outer["systematic"] == 1).all()
    assert (counts["stratified"][:, [0, 3]] <= 1).all()
    assert float((outer["stratified"] == 2).double().mean()) == pytest.approx(0.25, abs=0.035)
    twice = 1 - (7 / 8) ** 4 - 4 * (1 / 8) * (7 / 8) ** 3
    assert float((counts["multinomial"][:, 0] >= 2).double().mean()) == pytest.approx(twice, abs=0.025)
    assert float((counts["multinomial"][:, 1] == 0).double().mean()) == pytest.approx((5 / 8) ** 4, abs=0.03)
    assert (counts["residual"][:, 1:3] >= 1).all()
    assert float((counts["residual"][:, 0] >= 2).double().mean()) == pytest.approx(1 / 16, abs=0.02)


def test_residual_keeps_the_integer_parts_and_schemes_are_seeded():
    w = torch.tensor([0.42, 0.38, 0.2], dtype=torch.float64)
    idx = resample(w, "residual", torch.Generator().manual_seed(0))
    counts = torch.bincount(idx, minlength=3)
    assert counts.sum() == 3 and (counts >= torch.tensor([1, 1, 0])).all()  # ⌊N w⌋ = 1, 1, 0 kept
    w10 = torch.full((10,), 0.1, dtype=torch.float64)
    assert torch.equal(resample(w10, "residual"), torch.arange(10))  # N w_j = 1: exactly one copy each
    # The filter's float32 weights, exp of a log-softmax: N w_j rounds to 0.9999998, which gave no copy at all
    # and drew every ancestor multinomially (619 of 1000 particles kept).
    for log_w, copies in ((torch.zeros(1000), torch.ones(1000)), (torch.tensor([0.0, 0.0, -math.inf, -math.inf]),
                                                                   torch.tensor([2, 2, 0, 0]))):
        w = torch.log_softmax(log_w, 0).exp()
        assert w.dtype == torch.float32
        got = torch.bincount(resample(w, "residual", torch.Generator().manual_seed(0)), minlength=len(w))
        assert torch.equal(got, copies.long())
    for scheme in SCHEMES:
        a = resample(w, scheme, torch.Generator().manual_seed(9))
        assert torch.equal(a, resample(w, scheme, torch.Generator().manual_seed(9)))
    with pytest.raises(ValueError, match="Unknown resampling scheme 'bootstrap'"):
        resample(w, "bootstrap")


def test_effective_sample_size():
    assert effective_sample_size(torch.full((8,), 1 / 8)).item() == pytest.approx(8)
    assert effective_sample_size(torch.tensor([1.0, 0.0, 0.0])).item() == pytest.approx(1)
    assert effective_sample_size(torch.tensor([0.5, 0.5, 0.0, 0.0])).item() == pytest.approx(2)


@pytest.mark.parametrize("weights", [[2.0, 1.0, 1.0], [math.nan, 0.5, 0.5], [0.0, 0.0, 0.0], [-0.5, 1.0, 0.5],
                                     [math.inf, 0.0, 0.0]])
def test_weights_that_are_not_a_distribution_are_refused(weights):
    """Unnormalised weights gave systematic resampling all ancestors 0 (its cumulative sum no
    longer sorted); NaN, zero and negative ones picked the last particle or crashed residual's."""
    w = torch.tensor(weights)
    for scheme in SCHEMES:
        with pytest.raises(ValueError, match="Expected finite weights >= 0 summing to 1"):
            resample(w, scheme)
    with pytest.raises(ValueError, match="summing to 1"):
        effective_sample_size(w)


def test_circular_mean_against_brute_force():
    """The circular mean minimises Σ w (1 − cos(a − m)); check on a fine grid, across the seam."""
    g = torch.Generator().manual_seed(2)
    for centre in (0.05, math.pi, TWO_PI - 0.05):
        a = (centre + torch.randn(40, generator=g, dtype=torch.float64) * 0.3) % TWO_PI
        w = torch.rand(40, generator=g, dtype=torch.float64)
        w /= w.sum()
        mean, r = circular_mean(a, w)
        grid = torch.linspace(0, TWO_PI, 20001, dtype=torch.float64)
        cost = (w[None, :] * (1 - torch.cos(a[None, :] - grid[:, None]))).sum(1)
        best = grid[cost.argmin()]
        assert abs(math.remainder(mean.item() - best.item(), TWO_PI)) < 1e-3
        assert 0.8 < r.item() <= 1 and 0 <= mean.item() < TWO_PI
    # The plain mean of 0.1 and 2π − 0.1 is π; the circular mean is 0.
    m, _ = circular_mean(torch.tensor([0.1, TWO_PI - 0.1], dtype=torch.float64), torch.tensor([0.5, 0.5]).double())
    assert min(m.item(), TWO_PI - m.item()) < 1e-12


def test_weighted_mean_cov_and_class_posterior_against_numpy():
    g = torch.Generator().manual_seed(4)
    x = torch.randn(30, 4, generator=g, dtype=torch.float64)
    w = torch.rand(30, generator=g, dtype=torch.float64)
    w /= w.sum()
    mean, cov = weighted_mean_cov(x, w)
    np.testing.assert_allclose(mean.numpy(), np.average(x.numpy(), axis=0, weights=w.numpy()))
    np.testing.assert_allclose(cov.numpy(), np.cov(x.numpy().T, aweights=w.numpy(), bias=True), atol=1e-12)
    classes = torch.tensor([0, 2, 2, 1, 0, 2])
    ww = torch.tensor([0.1, 0.2, 0.3, 0.05, 0.15, 0.2], dtype=torch.float64)
    np.testing.assert_allclose(class_posterior(classes, ww, 4).numpy(), [0.25, 0.05, 0.7, 0.0])


def test_a_result_column_no_row_has_is_named_not_nan():
    """A typo ("xx") read as a run without estimates: all NaN. Text columns come back as text."""
    from torch_atr.tracking import TrackResult

    result = TrackResult([{"frame": 0, "lost": 1}, {"frame": 1, "lost": 0, "x": 2.5, "class": "suv"}], [], 1.0)
    np.testing.assert_array_equal(result.column("x"), [math.nan, 2.5])  # missing before the start: NaN
    assert result.column("class").tolist() == ["", "suv"]  # and no text before it
    with pytest.raises(ValueError, match="No row has a column 'xx'; columns: frame, lost, x"):
        result.column("xx")


def test_predict_needs_floating_particles():
    with pytest.raises(ValueError, match="floating particles; got torch.int64"):
        predict(torch.zeros(3, 6, dtype=torch.long), 0.1, MotionConfig())


@pytest.mark.parametrize("scheme", SCHEMES)
def test_particles_of_zero_weight_are_never_ancestors(scheme):
    """Weights summing to 1 only within the tolerance (float32 normalisation) ended the cumulative
    weights early, and the last strata then fell on the trailing particles of weight 0 (dead ones,
    log weight −inf): systematic and stratified drew one every time."""
    w = torch.cat([torch.full((1000,), 0.9991 / 1000, dtype=torch.float64), torch.zeros(1000, dtype=torch.float64)])
    for seed in range(5):
        assert (resample(w, scheme, torch.Generator().manual_seed(seed)) < 1000).all()


def test_systematic_points_do_not_round_onto_a_last_particle_of_zero_weight():
    """In float32, (N − 1 + u) / N rounds to 1 for u within N·2⁻²⁴ of 1 (once in 2000 frames at
    N = 10⁴; seed 2469 draws u = 0.99972), and a point at 1 took the last particle whatever its weight."""
    n = 10_000
    w = torch.cat([torch.full((n - 1,), 1 / (n - 1)), torch.zeros(1)])
    assert torch.rand((), generator=torch.Generator().manual_seed(2469)) > 1 - 2 ** -11
    assert (resample(w, "systematic", torch.Generator().manual_seed(2469)) < n - 1).all()


def test_estimates_of_no_particles_are_refused():
    """The weighted mean and covariance of no particles came out as zeros (a vehicle at the camera),
    the circular mean as 0 and the class posterior as all zeros."""
    none = torch.zeros(0, dtype=torch.float64)
    with pytest.raises(ValueError, match="Expected at least one particle; got weights of shape \\(0,\\)"):
        weighted_mean_cov(torch.zeros(0, 4, dtype=torch.float64), none)
    with pytest.raises(ValueError, match="at least one particle"):
        circular_mean(none, none)
    with pytest.raises(ValueError, match="at least one particle"):
        class_posterior(torch.zeros(0, dtype=torch.long), none, 3)


def test_mean_resultant_length_of_equal_angles_is_one():
    """Equal angles have R = 1 exactly; float32 weights that sum to 1 + 1.2e-7 gave R above 1,
    outside the documented [0, 1]."""
    w = torch.full((1000,), 1e-3)
    assert w.sum().item() > 1
    mean, r = circular_mean(torch.full((1000,), 0.3), w)
    assert r.item() == 1.0 and mean.item() == pytest.approx(0.3, abs=1e-6)


@pytest.mark.parametrize("classes", [[0, 3], [-1, 0]])
def test_class_posterior_names_classes_out_of_range(classes):
    """A class index outside [0, C) raised "index out of range in self" (on a GPU, a device-side assert)."""
    with pytest.raises(ValueError, match=r"Expected classes in \[0, 3\); got min -?\d, max \d"):
        class_posterior(torch.tensor(classes), torch.tensor([0.5, 0.5]), 3)
    with pytest.raises(ValueError, match="Expected integer classes; got torch.float32"):
        class_posterior(torch.tensor([0.0, 1.0]), torch.tensor([0.5, 0.5]), 3)
