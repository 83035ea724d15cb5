"""ShapeAppearance at its edges: empty particle sets, non-finite queries."""

import math

import pytest
import torch

from torch_atr.tracking import METHODS, ShapeAppearance


@pytest.mark.parametrize("method", METHODS)
def test_no_particles_give_no_templates(model, method):
    """N = 0 raised "torch.cat(): expected a non-empty list of Tensors" in Methods I–III (IV, with no
    reconstruction, gave the empty result)."""
    K, V, S = model.core.num_vehicles, model.rbf.num_centres, model.template.size_px
    templates = torch.zeros(K, V, S, S) if method == "IV" else None
    app = ShapeAppearance(model, method, 16, templates)
    none = torch.zeros(0)
    with torch.no_grad():
        assert app(none, none, none).shape == (0, 16, 16)
        assert app.squared_errors(torch.zeros(0, 16, 16), none, none, none).shape == (0,)
        observed = torch.ones(0, 16, 16, dtype=torch.bool)
        assert app.squared_errors(torch.zeros(0, 16, 16), none, none, none, observed).shape == (0,)


@pytest.mark.parametrize("method", METHODS)
def test_a_non_finite_query_predicts_nan_in_every_method(model, method):
    """Snapping took a NaN α to vehicle 0 (II, IV) and a NaN θ or φ to view 0 (III, IV), so such a
    particle was weighed as a real shape where Method I, and the filter's −inf for a non-finite
    likelihood, give it none. The finite queries keep their values."""
    K, V, S = model.core.num_vehicles, model.rbf.num_centres, model.template.size_px
    templates = torch.ones(K, V, S, S) if method == "IV" else None
    app = ShapeAppearance(model, method, 16, templates)
    alpha = torch.tensor([math.nan, 1.0, 1.0, math.inf, 1.0])
    theta = torch.tensor([1.0, math.nan, 1.0, 1.0, 1.0])
    phi = torch.tensor([0.1, 0.1, math.nan, 0.1, 0.1])
    with torch.no_grad():
        y = app(alpha, theta, phi)
        errors = app.squared_errors(torch.zeros(5, 16, 16), alpha, theta, phi)
        finite = app(alpha[4:], theta[4:], phi[4:])
    assert y[:4].isnan().all(dim=(1, 2)).all() and errors[:4].isnan().all()
    assert finite.isfinite().all() and errors[4].isfinite()
    torch.testing.assert_close(y[4:], finite, atol=1e-6, rtol=0)  # a matmul's rows vary in the last bit with N


@pytest.mark.parametrize("method", ["I", "II", "III"])
def test_the_squared_error_of_a_perfect_fit_is_not_below_zero(model, method):
    """‖z − y‖² of z = y, against the direct sum: the pooled-basis expansion ‖z‖² − 2 (Bᵀz)·c + cᵀGc
    cancelled to −1e-3 in float32, a log-likelihood above 0 that grows as 1/σ²."""
    app = ShapeAppearance(model, method, 32)
    g = torch.Generator().manual_seed(0)
    alpha, theta, phi = (torch.rand(2000, generator=g) * 2 * math.pi, torch.rand(2000, generator=g) * 2 * math.pi,
                         torch.rand(2000, generator=g) * 0.6)
    with torch.no_grad():
        z = app(alpha, theta, phi)
        errors = app.squared_errors(z, alpha, theta, phi)
    direct = (z.double() - app(alpha, theta, phi).double()).square().sum(dim=(1, 2))
    assert bool((errors >= 0).all())
    torch.testing.assert_close(errors.double(), direct, atol=5e-3, rtol=0)


def test_coords_refuse_queries_of_different_lengths(model):
    """alpha (3,) with theta, phi (5,) returned (3, r) from the first three views without a word."""
    app = ShapeAppearance(model, "I", 16)
    alpha, views = torch.ones(3), torch.full((5,), 0.3)
    with pytest.raises(ValueError, match=r"Expected theta to have shape \(3\); got \(5,\)"):
        app.coords(alpha, views, views)
    with pytest.raises(ValueError, match=r"Expected phi to have shape \(5\); got \(3,\)"):
        app.coords(torch.ones(5), views, torch.full((3,), 0.3))
    with pytest.raises(ValueError, match=r"Expected alpha to have shape \(N\); got \(5, 1\)"):
        app.coords(torch.ones(5, 1), views, views)


def test_pool_images_refuses_fewer_than_two_dims():
    """A 1-D tensor raised a bare IndexError reading its rows; pooled images equal the block means."""
    from torch_atr.tracking.appearance import pool_images

    with pytest.raises(ValueError, match=r"Expected images to be a tensor of shape \(\.\.\., S, S\); got \(16,\)"):
        pool_images(torch.zeros(16), 4)
    images = torch.arange(2 * 16, dtype=torch.float64).reshape(2, 4, 4)
    want = torch.tensor([[[(images[k, 2 * i:2 * i + 2, 2 * j:2 * j + 2]).mean() for j in range(2)] for i in range(2)]
                         for k in range(2)], dtype=torch.float64)
    torch.testing.assert_close(pool_images(images, 2), want)
