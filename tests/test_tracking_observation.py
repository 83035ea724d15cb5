"""The observation model against rendered ground truth and a per-particle reference of Table 5.1."""

import itertools
import math

import numpy as np
import pytest
import torch
from scipy import ndimage

from references import bilinear
from torch_atr.camera import Camera
from torch_atr.config import TemplateConfig
from torch_atr.data.synthetic import SceneConfig, SyntheticSequence
from torch_atr.pose import VehiclePose, view_of_pose
from torch_atr.render import render_mask, render_templates
from torch_atr.shape import iou, signed_distance, signed_distance_px
from torch_atr.tracking.observation import (cut_edges, frame_distance, log_likelihood, mask_box, observe,
                                            observe_windows, observed_cells, place_silhouette, project_windows,
                                            sample_windows, sees_image)

CFG = TemplateConfig()


@pytest.fixture(scope="module")
def scene():
    """The held-out BTR-70 at 1000 m: frames 0 and 40 of the simulator, with their truth."""
    return SyntheticSequence("btr_70", SceneConfig(frames=60))


@pytest.mark.parametrize("i", [0, 40])
def test_window_at_the_true_state_lands_on_the_rendered_silhouette(scene, i):
    """A particle at the true centre samples the rendered mask where the template at the true view
    has its silhouette, and the template placed back by the window covers the rendered mask."""
    t = scene.truth(i)
    mask = render_mask(scene.vehicle, scene.camera, scene.pose(i))
    centre = torch.tensor([[t.x, t.y, t.z]], dtype=torch.float64)
    z = observe(signed_distance_px(mask), scene.camera, centre, CFG, CFG.size_px)[0]
    template = render_templates(scene.vehicle, [t.theta], [t.phi], CFG)[0]
    assert template.sum() > 300
    assert iou(z > 0, template).item() >= 0.9
    uv, side = project_windows(scene.camera, centre, CFG.window_m)
    placed = place_silhouette(signed_distance(template, CFG.tau_px).double(), uv[0], side[0], mask.shape)
    assert iou(placed, mask).item() >= 0.9
    # Off by one vehicle length, the window misses.
    off = centre + torch.tensor([[7.0, 0.0, 0.0]], dtype=torch.float64)
    assert iou(observe(signed_distance_px(mask), scene.camera, off, CFG, CFG.size_px)[0] > 0, template) < 0.3


def test_window_size_is_f_w_over_depth():
    cam = Camera(2000.0, 1800.0, 320.0, 240.0, 640, 480)
    uv, side = project_windows(cam, torch.tensor([[1.0, -2.0, 100.0], [0.0, 0.0, -5.0]], dtype=torch.float64), 12.0)
    torch.testing.assert_close(side[0], torch.tensor([240.0, 216.0], dtype=torch.float64))
    torch.testing.assert_close(uv[0], torch.tensor([340.0, 276.0], dtype=torch.float64))
    assert side[1].isnan().all() and uv[1].isnan().all()  # behind the camera
    barrel = Camera(500.0, 500.0, 320.0, 240.0, 640, 480, dist=[-0.35, 0.15, 0.0, 0.0, -0.03])
    # 63° off the axis (r² = 3.84), beyond where k1..k3 fold back (r² = 2.30): its uv is NaN, and so its side
    uv, side = project_windows(barrel, torch.tensor([[0.0, 0.0, 50.0], [98.0, 0.0, 50.0]], dtype=torch.float64), 12.0)
    torch.testing.assert_close(side[0], torch.tensor([120.0, 120.0], dtype=torch.float64))
    assert uv[1].isnan().all() and side[1].isnan().all()


def test_sample_windows_matchesbilinear():
    g = torch.Generator().manual_seed(0)
    image = torch.rand(30, 40, generator=g, dtype=torch.float64)
    uv = torch.tensor([[20.0, 15.0], [3.2, 27.9], [39.5, -2.0], [math.nan, 3.0]], dtype=torch.float64)
    side = torch.tensor([[10.0, 6.0], [7.3, 7.3], [12.0, 12.0], [5.0, 5.0]], dtype=torch.float64)
    L = 5
    got = sample_windows(image, uv, side, L)
    for n in range(3):
        for a in range(L):
            for b in range(L):
                u = uv[n, 0].item() + ((b + 0.5) / L - 0.5) * side[n, 0].item()
                v = uv[n, 1].item() + ((a + 0.5) / L - 0.5) * side[n, 1].item()
                assert got[n, a, b].item() == pytest.approx(bilinear(image.numpy(), u, v), abs=1e-9)
    assert (got[3] == 0).all()  # a non-finite window samples nothing


def test_observe_windows_converts_with_the_geometric_mean_of_non_square_sides():
    """fx = 600, fy = 450: a window spans fx W / z by fy W / z pixels, and an image distance is
    S z / (√(fx fy) W) template pixels (the module docstring's step 3), then clipped to τ and divided
    by τ. On a distance image linear in u and v (bilinear sampling is exact there) the closed form,
    by numpy, at each cell centre."""
    fx, fy, cu, cv = 600.0, 450.0, 200.0, 150.0
    cam = Camera(fx, fy, cu, cv, 400, 300)
    centres = torch.tensor([[0.3, -0.2, 60.0], [-0.5, 0.4, 80.0]], dtype=torch.float64)
    uv, side = project_windows(cam, centres, CFG.window_m)
    vv, uu = np.mgrid[0:300, 0:400].astype(np.float64)
    distance = torch.from_numpy(0.08 * (uu - cu) - 0.05 * (vv - cv) + 1.0)
    L, S, tau = 16, CFG.size_px, CFG.tau_px
    got = observe_windows(distance, uv, side, CFG, L).numpy()
    offsets = (np.arange(L) + 0.5) / L - 0.5
    for n, (x, y, z) in enumerate(centres.tolist()):
        u = cu + fx * x / z + offsets * fx * CFG.window_m / z  # (L,) cell columns
        v = cv - fy * y / z + offsets * fy * CFG.window_m / z  # (L,) cell rows
        d = 0.08 * (u[None, :] - cu) - 0.05 * (v[:, None] - cv) + 1.0  # image pixels
        want = np.clip(d * S * z / (math.sqrt(fx * fy) * CFG.window_m), -tau, tau) / tau
        assert 0.1 < (np.abs(want) < 1).mean()  # not all clipped
        np.testing.assert_allclose(got[n], want, rtol=0, atol=1e-9)


def test_a_window_behind_the_camera_observes_exact_zeros():
    """The module docstring: a window behind the camera sees "nothing at all (0)". Its uv and side are
    NaN; its samples are 0 and so is its unit conversion (1 / NaN image px), so its cells are exact
    zeros, not NaN; the other windows are those observed without it."""
    cam = Camera(600.0, 450.0, 200.0, 150.0, 400, 300)
    centres = torch.tensor([[0.3, -0.2, 60.0], [0.0, 0.0, -5.0], [-0.5, 0.4, 80.0]], dtype=torch.float64)
    uv, side = project_windows(cam, centres, CFG.window_m)
    assert uv[1].isnan().all() and side[1].isnan().all()
    distance = signed_distance_px(np.pad(np.ones((40, 60), dtype=bool), ((130, 130), (170, 170))))
    got = observe_windows(distance, uv, side, CFG, 8)
    assert got.isfinite().all() and torch.equal(got[1], torch.zeros(8, 8, dtype=got.dtype))
    torch.testing.assert_close(got[[0, 2]], observe_windows(distance, uv[[0, 2]], side[[0, 2]], CFG, 8),
                               rtol=0, atol=0)


def test_place_silhouette_with_non_square_pixels_against_every_pixel():
    """Brute force per image pixel (u, v) of a window of sᵤ ≠ s_v: inside the window (|u − u_c| <= sᵤ/2,
    |v − v_c| <= s_v/2), at template coordinates ((u − u_c)/sᵤ + ½) S − ½ and ((v − v_c)/s_v + ½) S − ½,
    y sampled bilinearly (references.bilinear) is > 0."""
    S, H, W = 16, 40, 60
    y = torch.randn(S, S, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    uv, side = torch.tensor([30.3, 20.7], dtype=torch.float64), torch.tensor([24.6, 13.2], dtype=torch.float64)
    got = place_silhouette(y, uv, side, (H, W)).numpy()
    want = np.zeros((H, W), dtype=bool)
    for v in range(H):
        for u in range(W):
            du, dv = (u - 30.3) / 24.6, (v - 20.7) / 13.2
            if abs(du) <= 0.5 and abs(dv) <= 0.5:
                want[v, u] = bilinear(y.numpy(), (du + 0.5) * S - 0.5, (dv + 0.5) * S - 0.5) > 0
    assert 20 < want.sum() < 0.5 * 25 * 14
    np.testing.assert_array_equal(got, want)


def test_log_likelihood_is_eq_5_2():
    z = torch.zeros(2, 4, 4)
    y = torch.stack([torch.zeros(4, 4), torch.full((4, 4), 0.5)])
    torch.testing.assert_close(log_likelihood(z, y, 0.1), torch.tensor([0.0, -0.25 / 0.02]))
    with pytest.raises(ValueError, match="sigma"):
        log_likelihood(z, y, 0.0)
    with pytest.raises(ValueError, match=r"y to have shape \(2, 4, 4\)"):
        log_likelihood(z, y[:, :3], 0.1)


def test_observation_matches_a_per_particle_loop(scene):
    """observe() for N particles equals the recipe done one particle at a time: project, size the
    window f·W/z, sample bilinearly at the L × L cell centres, convert to template pixels, clip."""
    t = scene.truth(10)
    D = signed_distance_px(render_mask(scene.vehicle, scene.camera, scene.pose(10)))
    g = torch.Generator().manual_seed(1)
    centres = torch.tensor([t.x, t.y, t.z], dtype=torch.float64) + torch.randn(6, 3, generator=g,
                                                                                dtype=torch.float64) * 0.7
    L = 8
    got = observe(D, scene.camera, centres, CFG, L)
    f, Dn = scene.camera.fx, D.numpy()
    for n in range(6):
        x, y, z = centres[n].tolist()
        # A tilted camera: depth along its optical axis, pixel from its own projection.
        uv, depth = scene.camera.project(centres[n])
        s = f * CFG.window_m / depth.item()
        for a in range(L):
            for b in range(L):
                u = uv[0].item() + ((b + 0.5) / L - 0.5) * s
                v = uv[1].item() + ((a + 0.5) / L - 0.5) * s
                d = bilinear(Dn, u, v) * CFG.size_px / s
                want = min(max(d, -CFG.tau_px), CFG.tau_px) / CFG.tau_px
                assert got[n, a, b].item() == pytest.approx(want, abs=1e-5)


def test_view_of_a_particle_at_the_truth_is_the_true_view(scene):
    t = scene.truth(25)
    theta, phi = view_of_pose(VehiclePose(t.x, t.y, t.z, t.heading), scene.camera)
    assert theta.item() == pytest.approx(t.theta, abs=1e-12) and phi.item() == pytest.approx(t.phi, abs=1e-12)


def test_sees_image_against_every_pixel():
    """A window sees the image when some pixel's square (centre ± ½) meets its box, pixel by pixel
    on a 5 × 7 image; a non-finite window (behind the camera) sees nothing."""
    H, W = 5, 7
    g = torch.Generator().manual_seed(0)
    uv = torch.rand(2000, 2, generator=g, dtype=torch.float64) * torch.tensor([W + 8.0, H + 8.0]) - 4
    side = torch.rand(2000, 2, generator=g, dtype=torch.float64) * 4
    got = sees_image(uv, side, (H, W))
    cols, rows = torch.arange(W, dtype=torch.float64), torch.arange(H, dtype=torch.float64)
    for (u, v), (su, sv), sees in zip(uv.tolist(), side.tolist(), got.tolist()):
        meets_col = ((cols + 0.5 >= u - su / 2) & (cols - 0.5 <= u + su / 2)).any()
        meets_row = ((rows + 0.5 >= v - sv / 2) & (rows - 0.5 <= v + sv / 2)).any()
        assert sees == bool(meets_col and meets_row), (u, v, su, sv)
    assert 0.2 < got.double().mean() < 0.8  # both cases drawn
    nan = torch.tensor([[math.nan, 2.0]], dtype=torch.float64)
    assert not sees_image(nan, torch.ones(1, 2, dtype=torch.float64), (H, W))[0]
    with pytest.raises(ValueError, match="side"):
        sees_image(uv, side[:3], (H, W))


def test_mask_box_is_the_first_and_last_set_column_and_row():
    g = np.random.default_rng(1)
    for _ in range(200):  # against the set pixels' extremes, also on strided views (cv2 reads them as empty)
        full = g.random((9, 16)) < g.choice([0.0, 0.01, 0.05, 0.5])
        for mask in (full, full[:, ::2], full[::-1, 3:]):
            r, c = np.nonzero(mask)
            want = (c.min(), r.min(), c.max(), r.max()) if r.size else None
            assert mask_box(mask) == want, mask
            assert mask_box(mask.astype(np.float32) * 0.5) == want  # any dtype: its non-zero pixels
    with pytest.raises(ValueError, match="mask"):
        mask_box(np.ones(5, dtype=bool))


def test_cut_edges_are_those_the_blob_has_a_pixel_on():
    mask = np.zeros((5, 7), dtype=bool)
    assert cut_edges(mask) == (False, False, False, False)
    for (r, c), want in [((2, 0), (True, False, False, False)), ((0, 3), (False, True, False, False)),
                         ((2, 6), (False, False, True, False)), ((4, 3), (False, False, False, True)),
                         ((0, 6), (False, True, True, False)), ((1, 1), (False, False, False, False))]:
        one = mask.copy()
        one[r, c] = True
        assert cut_edges(one) == want, (r, c)
    g = np.random.default_rng(0)
    for _ in range(200):  # any margin, against the distance of every blob pixel to each edge
        blob = g.random((5, 7)) < 0.08
        margin = int(g.integers(0, 4))
        r, c = np.nonzero(blob)
        want = tuple(bool((d < margin).any()) for d in (c, r, 6 - c, 4 - r))
        assert cut_edges(blob, margin) == want, (blob, margin)
    with pytest.raises(ValueError, match="mask"):
        cut_edges(np.zeros(5, dtype=bool))


@pytest.mark.parametrize("cut", list(itertools.product([False, True], repeat=4)))
def test_observed_cells_against_every_cell(cut):
    """A cell of a window's L × L grid, centred at u + s((k + ½)/L − ½), is observed unless it lies
    beyond an edge (left, top, right, bottom) that cuts the blob, cell by cell on a 5 × 7 image; a
    non-finite window (behind the camera) observes none."""
    H, W, L = 5, 7, 4
    g = torch.Generator().manual_seed(0)
    uv = torch.rand(300, 2, generator=g, dtype=torch.float64) * torch.tensor([W + 8.0, H + 8.0]) - 4
    side = torch.rand(300, 2, generator=g, dtype=torch.float64) * 6
    columns, rows = observed_cells(uv, side, L, (H, W), cut)
    left, top, right, bottom = cut
    for n, ((u, v), (su, sv)) in enumerate(zip(uv.tolist(), side.tolist())):
        for k in range(L):
            cu, cv = u + su * ((k + 0.5) / L - 0.5), v + sv * ((k + 0.5) / L - 0.5)
            assert bool(columns[n, k]) == ((cu >= -0.5 or not left) and (cu <= W - 0.5 or not right)), (n, k)
            assert bool(rows[n, k]) == ((cv >= -0.5 or not top) and (cv <= H - 0.5 or not bottom)), (n, k)
    if any(cut):
        assert not (columns.all(1) & rows.all(1)).all()  # some window loses cells
    nan = torch.tensor([[math.nan, 2.0]], dtype=torch.float64)
    assert not observed_cells(nan, torch.ones(1, 2, dtype=torch.float64), L, (H, W), cut)[0].any()
    with pytest.raises(ValueError, match="side"):
        observed_cells(uv, side[:3], L, (H, W), cut)


def test_frame_distance_is_the_whole_frames_near_the_blob():
    """The region's distance equals scipy's signed distance of the whole frame wherever it is within
    the margin of the blob; an infinite margin is the whole frame (it raised OverflowError), and a
    NaN or negative one is refused by name."""
    mask = np.zeros((20, 30), dtype=bool)
    mask[6:11, 4:12] = True
    mask[9, 12:15] = True
    whole = ndimage.distance_transform_edt(mask) - ndimage.distance_transform_edt(~mask)
    for margin in (1.0, 2.5, 7.0, 1e9, math.inf):
        distance, (u0, v0) = frame_distance(mask, margin)
        h, w = distance.shape
        region = whole[v0:v0 + h, u0:u0 + w]
        near = np.abs(region) <= margin
        np.testing.assert_allclose(distance.numpy()[near], region[near], rtol=0, atol=1e-5)
        if margin > 30:
            assert (u0, v0, h, w) == (0, 0, 20, 30)
    for bad in (math.nan, -1.0):
        with pytest.raises(ValueError, match="margin"):
            frame_distance(mask, bad)


def test_the_window_functions_refuse_vectors_of_the_wrong_shape():
    """An (N, 1) image_px broadcast against the (N, L, L) samples to (N, N, L, L) without a word; a
    (1, 2) window, a blob box of 3 numbers or a position of 2 failed deep inside, or not at all."""
    from torch_atr.tracking.initialise import InitConfig, truth_particles
    from torch_atr.tracking.observation import blob_windows, observe_windows, place_silhouette

    template, uv, side = TemplateConfig(size_px=8, window_m=10.0, tau_px=2.0), torch.zeros(3, 2), torch.ones(3, 2)
    with pytest.raises(ValueError, match=r"image_px to have shape \(3\); got \(3, 1\)"):
        observe_windows(torch.zeros(5, 5), uv, side, template, 4, image_px=torch.ones(3, 1))
    with pytest.raises(ValueError, match=r"uv to have shape \(2\); got \(1, 2\)"):
        place_silhouette(torch.zeros(8, 8), torch.zeros(1, 2), torch.ones(2), (5, 5))
    with pytest.raises(ValueError, match=r"side to have shape \(2\); got \(1, 2\)"):
        place_silhouette(torch.zeros(8, 8), torch.zeros(2), torch.ones(1, 2), (5, 5))
    with pytest.raises(ValueError, match=r"blob_box to have shape \(4\); got \(3,\)"):
        blob_windows(torch.zeros(2, 4), torch.zeros(3), 8)
    with pytest.raises(ValueError, match=r"position to have shape \(3\); got \(2,\)"):
        truth_particles(torch.zeros(2), 0.0, 0.0, 4, InitConfig())


def test_blob_windows_take_one_window_size_for_all_boxes_or_one_per_box_never_a_vector():
    """One size per hypothesis (M,) with M = 2 was read as one window's (width, height). By hand: a box
    centred on the 8-px template's centre lies on the blob's centre; one centred 2 template px up and
    left of it lies 2 · side / 8 image px down and right of it."""
    from torch_atr.tracking.observation import blob_windows

    boxes = torch.tensor([[2.0, 2.0, 5.0, 5.0], [0.0, 0.0, 3.0, 3.0]])
    blob_box = torch.tensor([10.0, 20.0, 29.0, 39.0])
    with pytest.raises(ValueError, match=r"Expected side to have shape \(1, 2\) or \(2, 2\), .*; got \(2,\)"):
        blob_windows(boxes, blob_box, 8, torch.tensor([16.0, 8.0]))
    with pytest.raises(ValueError, match=r"Expected side to have shape \(1, 2\) or \(2, 2\), .*; got \(3, 2\)"):
        blob_windows(boxes, blob_box, 8, torch.ones(3, 2))
    uv, side = blob_windows(boxes, blob_box, 8, torch.tensor([[16.0, 8.0]]))
    assert uv.tolist() == [[19.5, 29.5], [23.5, 31.5]] and side.tolist() == [[16.0, 8.0], [16.0, 8.0]]
    uv, side = blob_windows(boxes, blob_box, 8, torch.tensor([[16.0, 16.0], [8.0, 8.0]]))
    assert uv.tolist() == [[19.5, 29.5], [21.5, 31.5]] and side.tolist() == [[16.0, 16.0], [8.0, 8.0]]
