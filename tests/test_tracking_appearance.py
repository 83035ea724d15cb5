"""ShapeAppearance at its edges: empty particle sets."""

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
