"""Ground contact: the silhouette's lowest point against analytic edges, the periodic table
against numpy, H(α)/2 against the training meshes' heights, and the tracker holding every
particle on the ground."""

import math

import numpy as np
import pytest
import torch

from torch_atr.config import TemplateConfig, load_config
from torch_atr.data.synthetic import SceneConfig, SyntheticSequence
from torch_atr.pose import camera_centre
from torch_atr.tracking import Tracker, TrackerConfig
from torch_atr.tracking.ground import bottom_edge_px, half_heights, interpolate_periodic
from torch_atr.tracking.motion import ALPHA, Y
from torch_atr.vehicles import load_catalog_vehicle


@pytest.mark.parametrize("bottom", [21.0, 20.7, 13.25])
def test_bottom_edge_is_the_analytic_edge_of_a_box(bottom):
    rows = torch.arange(32, dtype=torch.float64) + 0.5  # pixel centres
    vertical = torch.minimum(rows - 10.0, bottom - rows)  # signed distance to a band [10, bottom]
    sdf = vertical[:, None].expand(32, 32).clone()
    sdf[:, :5] = -1.0  # columns outside the box
    assert bottom_edge_px(sdf[None]).item() == pytest.approx(bottom, abs=1e-9)
    assert math.isnan(bottom_edge_px(-torch.ones(1, 8, 8)).item())
    with pytest.raises(ValueError, match="signed"):
        bottom_edge_px(torch.ones(8, 8))


def test_periodic_interpolation_matches_numpy():
    table = torch.tensor([1.0, 3.0, 2.0, 5.0], dtype=torch.float64)
    alpha = torch.tensor([0.0, 0.4, 2.0, 5.9, 6.28, -0.3, 7.0], dtype=torch.float64)
    grid = np.arange(4) * (2 * math.pi / 4)
    expected = np.interp(np.mod(alpha.numpy(), 2 * math.pi), grid, table.numpy(), period=2 * math.pi)
    np.testing.assert_allclose(interpolate_periodic(table, alpha).numpy(), expected, atol=1e-12)


def test_half_heights_match_the_training_meshes(model):
    table = half_heights(model)
    for k in range(0, len(model.vehicle_names), 7):
        bounds = load_catalog_vehicle(model.vehicle_names[k]).mesh.bounds
        got = interpolate_periodic(table, model.alphas[k:k + 1]).item()
        assert got == pytest.approx((bounds[1][2] - bounds[0][2]) / 2, abs=0.15), model.vehicle_names[k]


class _BoxModel:
    """The least of a model half_heights reads: ``alphas`` (dtype and device), ``template`` and a call
    (α, θ, φ) -> (B, S, S) signed distances. Each is an analytic box, its rows [S/2 − 6, bottom(α)]
    (edges from the top edge, pixel r's centre at r + ½) and columns from 10: seen side-on (θ = π/2,
    φ = 0) bottom(α) = S/2 + 5 + 3 sin α, from any other view 4 rows higher."""

    def __init__(self):
        self.alphas = torch.zeros(3, dtype=torch.float64)
        self.template = TemplateConfig(size_px=48, window_m=10.0)

    def bottom(self, alpha):
        return self.template.size_px / 2 + 5 + 3 * torch.sin(alpha)

    def __call__(self, alpha, theta, phi):
        S = self.template.size_px
        side_on = (theta == math.pi / 2) & (phi == 0)
        bottom = torch.where(side_on, self.bottom(alpha), self.bottom(alpha) - 4)[:, None]
        rows = torch.arange(S, dtype=torch.float64) + 0.5
        sdf = torch.minimum(rows - (S / 2 - 6), bottom - rows)[:, :, None].expand(-1, S, S).clone()
        sdf[:, :, :10] = -1.0  # columns outside the box
        return sdf


def test_half_heights_are_the_side_views_bottom_below_the_window_centre_in_metres():
    """Against the module docstring's closed form on an analytic box model: H(α)/2 is the side view's
    bottom edge b(α) below the window's centre (S/2 from its top edge), at W / S metres per template
    pixel: (b − S/2) W / S, at α = 2π k / grid."""
    stub = _BoxModel()
    alpha = torch.arange(16, dtype=torch.float64) * (2 * math.pi / 16)
    S, W = stub.template.size_px, stub.template.window_m
    want = (stub.bottom(alpha) - S / 2) * W / S
    torch.testing.assert_close(half_heights(stub, grid=16), want, rtol=0, atol=1e-9)


def test_ground_contact_puts_every_particle_half_its_height_above_the_ground(model):
    seq = SyntheticSequence("btr_70", SceneConfig(frames=3))
    cfg = load_config(TrackerConfig, None, ["filter.particles=200", "init.mode=truth", "filter.ground_contact=true"])
    tracker = Tracker(model, seq.camera, cfg, seed=0)
    tracker.run(seq, progress=False)
    ground_y = float(camera_centre(seq.camera)[1]) - seq.camera_height_m
    expected = ground_y + interpolate_periodic(half_heights(model), tracker.particles[:, ALPHA])
    torch.testing.assert_close(tracker.particles[:, Y], expected)


def test_periodic_interpolation_of_a_non_finite_alpha_is_nan():
    """NaN or infinite α (a diverged particle) made the index −2⁶³ and raised "index
    -9223372036854775808 is out of bounds" (on a GPU, a device-side assert); now NaN like any
    other arithmetic on NaN, and the finite entries unchanged."""
    table = torch.tensor([1.0, 3.0, 2.0, 5.0], dtype=torch.float64)
    got = interpolate_periodic(table, torch.tensor([math.nan, math.inf, -math.inf, math.pi / 4], dtype=torch.float64))
    assert got[:3].isnan().all() and got[3].item() == pytest.approx(2.0)


def test_ground_contact_follows_the_heights_of_adapted_kernel_widths():
    """Kernel-width adaptation changes the silhouettes and so their heights; the half-heights were computed once,
    with the widths of the first frame, and held every particle at the old heights."""
    import copy

    from conftest import SHIPPED_CHECKPOINT
    from torch_atr.model import GenerativeShapeModel

    model = GenerativeShapeModel.from_checkpoint(SHIPPED_CHECKPOINT)  # its own copy: adaptation changes the widths
    seq = SyntheticSequence("btr_70", SceneConfig(frames=3))
    cfg = load_config(TrackerConfig, None, ["filter.particles=200", "init.mode=truth", "filter.ground_contact=true",
                                            "adapt.every=1", "adapt.steps=3", "adapt.lr=0.05",
                                            f"init.camera_height_m={seq.camera_height_m}"])  # run() would copy it
    tracker = Tracker(model, seq.camera, cfg, seed=0)
    tracker.warm_up(seq.warmup_frames(20))
    tracker.initialise(seq.truth(0))
    tracker.step(seq.frame(0))
    tracker.step(seq.frame(1))
    adapted = copy.deepcopy(model)  # the widths frame 2's prediction holds its particles with
    tracker.step(seq.frame(2))
    ground_y = float(camera_centre(seq.camera)[1]) - seq.camera_height_m
    expected = ground_y + interpolate_periodic(half_heights(adapted), tracker.particles[:, ALPHA])
    torch.testing.assert_close(tracker.particles[:, Y], expected)


@pytest.mark.parametrize("height", [0.0, -5.0, math.inf, "5"])
def test_a_sequences_camera_height_out_of_range_is_refused_naming_the_sequence(model, height):
    """The sequences shipped refuse a camera height outside (0, 1e4] m, but the tracker took a Sequence of one's
    own's as given (float(height)): with a truth start and ground contact, 0 or -5 m held every particle on a
    ground at or above the camera without a word, and '5' was read as 5 m."""
    seq = SyntheticSequence("btr_70", SceneConfig(frames=2))
    seq.camera_height_m = height
    cfg = load_config(TrackerConfig, None, ["filter.particles=50", "init.mode=truth", "filter.ground_contact=true"])
    with pytest.raises(ValueError, match=rf"^{seq.name}: camera_height_m \(metres above the ground; NaN or None: "
                                         rf"unknown\): expected a finite number in \(0, 10000\]"):
        Tracker(model, seq.camera, cfg, seed=0).run(seq, progress=False)
