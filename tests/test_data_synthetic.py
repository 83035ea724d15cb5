"""The IR scene simulator against geometry worked out by hand, ray casting, scipy and its own static scene."""

import dataclasses
import math
import re
import tracemalloc
import warnings

import cv2
import numpy as np
import pytest
import torch
import trimesh
from scipy import ndimage

from torch_atr.camera import Camera
from torch_atr.config import ConfigError
from torch_atr.data import FolderSequence, open_sequence, save_sequence
from torch_atr.data.synthetic import (BODY, ENGINE_DECK, EXHAUST, RUNNING_GEAR, SceneConfig, SyntheticSequence,
                                      parse_synthetic_spec, surface_parts, visible_faces, visible_scene)
from torch_atr.pose import VehiclePose, body_to_world
from torch_atr.render import render_mask
from torch_atr.segmentation import ForegroundSegmenter
from torch_atr.vehicles.specs import SPLITS

TWO_PI = 2 * math.pi
SMALL = {"width": 160, "height": 128, "focal_px": 2500.0}  # the whole 100 m circle in view at 1000 m


def _wrap(a: float) -> float:
    """Angle difference wrapped to (−π, π]."""
    return math.remainder(a, TWO_PI)


def _view_by_hand(t) -> tuple[float, float]:
    """(θ, φ) from METHOD.md's definitions: the camera (world origin) seen from the body frame.

    Forward is (sin h, 0, cos h); the body's left is forward turned a quarter towards −x,
    (−cos h, 0, sin h); up is +y.
    """
    d = -np.array([t.x, t.y, t.z])
    forward = np.array([math.sin(t.heading), 0.0, math.cos(t.heading)])
    left = np.array([-math.cos(t.heading), 0.0, math.sin(t.heading)])
    theta = math.atan2(d @ left, d @ forward) % TWO_PI
    return theta, math.atan2(d[1], math.hypot(d @ forward, d @ left))


@pytest.fixture(scope="module")
def t72():
    return SyntheticSequence("t_72", SceneConfig(frames=300))


def test_truth_centre_and_box_are_those_of_the_true_mask(t72):
    for i in (0, 100, 299):
        mask, t = t72.true_mask(i), t72.truth(i)
        rows, cols = np.nonzero(mask)
        assert mask.sum() > 500
        assert 0 < rows.min() and rows.max() < mask.shape[0] - 1 and 0 < cols.min() and cols.max() < mask.shape[1] - 1
        assert (t.u, t.v) == pytest.approx((cols.mean(), rows.mean()), abs=1e-6)  # wholly inside the frame
        assert (t.u0, t.v0, t.u1, t.v1) == (cols.min(), rows.min(), cols.max(), rows.max())
        # The truth position is the bounding-box centre: the body origin (footprint centre on
        # the ground) lifted by half the vehicle's height; its projection is near the centroid.
        origin = t72.pose(i)
        assert (t.x, t.y, t.z) == pytest.approx((origin.x, origin.y + t72.vehicle.mesh.extents[2] / 2, origin.z))
        uv, _ = t72.camera.project(torch.tensor([t.x, t.y, t.z]))
        assert abs(float(uv[1]) - t.v) < 3.0  # (not u: a forward gun moves the box centre off the centroid)


def test_true_mask_is_render_mask_with_the_scene_camera(t72):
    for i in (0, 150):
        np.testing.assert_array_equal(t72.true_mask(i), render_mask(t72.vehicle, t72.camera, t72.pose(i)).numpy())
    parts = t72.part_map(150)
    np.testing.assert_array_equal(parts >= 0, t72.true_mask(150))
    assert set(np.unique(parts[parts >= 0])) <= {BODY, RUNNING_GEAR, ENGINE_DECK, EXHAUST}


def test_positions_speed_and_heading_follow_the_circle():
    cfg = SceneConfig(frames=120, range_m=2000.0, speed_mps=7.0, start_deg=30.0, clockwise=False, **SMALL)
    seq = SyntheticSequence("isuzu_rodeo", cfg)
    truths = [seq.truth(i) for i in range(len(seq))]
    pos = np.array([[t.x, t.y, t.z] for t in truths])
    np.testing.assert_allclose(np.hypot(pos[:, 0], pos[:, 2] - cfg.range_m), cfg.circle_diameter_m / 2, atol=1e-9)
    np.testing.assert_allclose(pos[:, 1], -cfg.camera_height_m + seq.vehicle.mesh.extents[2] / 2)
    step = pos[2:] - pos[:-2]  # central differences over 2 frames
    np.testing.assert_allclose(np.linalg.norm(step, axis=1) * cfg.fps / 2, cfg.speed_mps, rtol=1e-3)
    for t, d in zip(truths[1:-1], step):
        assert abs(_wrap(t.heading - math.atan2(d[0], d[2]))) < 1e-3
        assert t.speed == cfg.speed_mps
    assert truths[0].x == pytest.approx(50 * math.sin(math.radians(30.0)))
    assert truths[7].time_s == pytest.approx(7 / 30)


def test_view_angles_match_the_geometry():
    cfg = SceneConfig(frames=1900, speed_mps=10.0, **SMALL)  # more than a lap
    seq = SyntheticSequence("bmp_2", cfg)
    for i in range(0, len(seq), 97):
        t = seq.truth(i)
        theta, phi = _view_by_hand(t)
        assert abs(_wrap(t.theta - theta)) < 1e-9 and t.phi == pytest.approx(phi, abs=1e-9)
        assert t.aspect == t.theta and 0 <= t.theta < TWO_PI
    # Driving straight at the camera (right-most point, clockwise): the front is seen.
    towards = SyntheticSequence("bmp_2", dataclasses.replace(cfg, frames=1, start_deg=90.0)).truth(0)
    assert abs(_wrap(towards.theta)) < 0.06 and abs(_wrap(towards.heading - math.pi)) < 1e-9
    # Crossing to the right at the near point (counter-clockwise): the right side, θ = 3π/2.
    right = SyntheticSequence("bmp_2", dataclasses.replace(cfg, frames=1, start_deg=180.0, clockwise=False)).truth(0)
    assert abs(_wrap(right.theta - 1.5 * math.pi)) < 1e-9 and abs(_wrap(right.heading - math.pi / 2)) < 1e-9
    centre_height = SyntheticSequence("bmp_2", cfg).vehicle.mesh.extents[2] / 2
    assert right.phi == pytest.approx(math.atan2(cfg.camera_height_m - centre_height, cfg.range_m - 50.0), abs=1e-9)


def test_apparent_length_is_focal_times_length_over_range():
    for name in ("t_72", "isuzu_rodeo"):
        for range_m in (1000.0, 2500.0):
            seq = SyntheticSequence(name, SceneConfig(frames=1, range_m=range_m, start_deg=180.0))
            t = seq.truth(0)
            expected = seq.cfg.focal_px * seq.vehicle.mesh.extents[0] / t.z
            assert t.u1 - t.u0 + 1 == pytest.approx(expected, rel=0.1)
            assert t.range_m == pytest.approx(t.z, rel=1e-3)


def test_target_out_of_view_has_truth_but_no_box():
    seq = SyntheticSequence("btr_70", SceneConfig(frames=1, start_deg=90.0))  # x = 50 m: beyond the 64 m field
    t = seq.truth(0)
    assert not seq.true_mask(0).any() and math.isnan(t.u0) and math.isnan(t.v1)
    assert t.u > seq.cfg.width and math.isfinite(t.theta) and t.x == pytest.approx(50.0)


def test_determinism_and_random_access():
    cfg = SceneConfig(frames=6, seed=5, **SMALL)
    a, b = SyntheticSequence("brdm_2", cfg), SyntheticSequence("brdm_2", cfg)
    np.testing.assert_array_equal(a.frame(3), b.frame(3))
    sequential = list(a)
    np.testing.assert_array_equal(sequential[4], SyntheticSequence("brdm_2", cfg).frame(4))
    np.testing.assert_array_equal(next(a.warmup_frames(1)), next(b.warmup_frames(1)))
    other = SyntheticSequence("brdm_2", dataclasses.replace(cfg, seed=6))
    assert not np.array_equal(other.frame(3), a.frame(3))
    assert other.truth(3) == a.truth(3)  # the seed changes noise and clutter, not the geometry
    assert not np.array_equal(sequential[3], sequential[4])


def test_frames_neither_read_nor_advance_the_global_random_generators():
    """The scene's seed and a tracker's (which seeds torch's generators) are independent: the frames are the
    same whatever torch's and NumPy's global state, and reading them leaves that state as it was."""
    cfg = SceneConfig(frames=3, seed=2, **SMALL)
    frames = []
    for global_seed in (0, 1):
        torch.manual_seed(global_seed)
        np.random.seed(global_seed)
        before = torch.get_rng_state(), np.random.get_state()[1].copy()
        seq = SyntheticSequence("brdm_2", cfg)
        frames.append([seq.frame(i) for i in range(3)] + list(seq.warmup_frames(2)))
        assert torch.equal(torch.get_rng_state(), before[0]) and np.array_equal(np.random.get_state()[1], before[1])
    for a, b in zip(*frames):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("clockwise", [True, False])
def test_runs_of_one_and_two_frames_are_centred_on_the_near_point(clockwise):
    """start_deg=None: one frame at the near point, side-on; two frames straddling it, one frame's step apart."""
    sign = 1.0 if clockwise else -1.0
    one = SyntheticSequence("isuzu_rodeo", SceneConfig(frames=1, clockwise=clockwise, **SMALL)).truth(0)
    assert (one.x, one.z) == pytest.approx((0.0, 950.0), abs=1e-9)
    assert one.heading == pytest.approx(math.pi + sign * math.pi / 2)  # moving left (clockwise) or right
    assert one.theta == pytest.approx(math.pi / 2 if clockwise else 3 * math.pi / 2)  # left or right side seen
    seq = SyntheticSequence("isuzu_rodeo", SceneConfig(frames=2, clockwise=clockwise, **SMALL))
    a, b = seq.truth(0), seq.truth(1)
    half = 5.0 / 50.0 / 30.0 / 2  # half a frame's angle on the circle: speed / radius / fps / 2
    assert (a.x, b.x) == pytest.approx((sign * 50 * math.sin(half), -sign * 50 * math.sin(half)), abs=1e-12)
    assert a.z == pytest.approx(b.z) and a.z == pytest.approx(1000.0 - 50 * math.cos(half))
    assert math.hypot(b.x - a.x, b.z - a.z) == pytest.approx(2 * 50 * math.sin(half))  # the chord of one step
    assert (b.time_s - a.time_s) == pytest.approx(1 / 30)


def test_background_is_static_and_noise_is_white():
    seq = SyntheticSequence("zsu_23_4", SceneConfig(frames=2))
    warm = [w.astype(np.float64) for w in seq.warmup_frames(2)]
    far = ~cv2.dilate(seq.true_mask(1).astype(np.uint8), np.ones((25, 25), np.uint8)).astype(bool)
    for diff in (seq.frame(1) - warm[0], warm[1] - warm[0]):
        assert abs(diff[far].mean()) < 1.0
        assert diff[far].std() == pytest.approx(math.sqrt(2) * seq.cfg.noise_k * 100.0, rel=0.05)  # 100 counts per K
        centred = diff - diff[far].mean()
        for axis in (0, 1):  # lag-1 correlation down the columns and along the rows
            n = diff.shape[axis] - 1
            a, b = centred.take(range(n), axis), centred.take(range(1, n + 1), axis)
            pairs = far.take(range(n), axis) & far.take(range(1, n + 1), axis)
            assert abs(np.corrcoef(a[pairs], b[pairs])[0, 1]) < 0.05


def _contrast(seq: SyntheticSequence, i: int) -> float:
    """Mean counts on the target minus the mean of a ring of background around it."""
    frame, mask = seq.frame(i).astype(np.float64), seq.true_mask(i)
    ring = cv2.dilate(mask.astype(np.uint8), np.ones((15, 15), np.uint8)).astype(bool) & ~cv2.dilate(
        mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    return frame[mask].mean() - frame[ring].mean()


def test_read_out_saturates_at_the_ends_of_its_range_without_wrapping():
    """Counts above 16383 (a 10,000 K body) and below 0 (a 231 K sky with 3 K of noise) are clipped, as a sensor
    saturates, never wrapped (a uint16 cast of -5 is 65531); visible grey levels above 255 (albedo 1 textured up to
    1.99, all ambient light) stay 255. The scene before read-out is finite."""
    hot = SyntheticSequence("isuzu_rodeo", SceneConfig(frames=1, body_k=1e4, sky_k=231.0, noise_k=3.0, **SMALL))
    frame, mask = hot.frame(0), hot.true_mask(0)
    assert frame.dtype == np.uint16 and frame.max() == 2 ** 14 - 1 and frame.min() == 0
    assert (frame[mask] > 14000).mean() > 0.9 and np.isfinite(hot.scene(0)).all()
    bright = SyntheticSequence("ford_f150", visible_scene(frames=1, width=160, height=120, focal_px=120.0,
                                                          body_albedo=1.0, ambient=1.0, texture_contrast=0.99))
    grey, scene = bright.frame(0), bright.scene(0)
    assert grey.dtype == np.uint8 and scene.max() > 300 and grey.max() == 255
    np.testing.assert_array_equal(grey[scene > 270], 255)  # 270: beyond any noise draw (σ 2)


def test_night_target_is_warmer_and_day_has_less_contrast():
    night = SyntheticSequence("t_72", SceneConfig(frames=1))
    day = SyntheticSequence("t_72", SceneConfig(frames=1, night=False))
    assert _contrast(night, 0) > 300  # > 3 K
    assert 0 < _contrast(day, 0) < 0.5 * _contrast(night, 0)
    assert day.cfg.temperatures()["ground_k"] > night.cfg.temperatures()["ground_k"]


def test_night_engine_and_exhaust_are_warmer_than_the_body():
    """Seen from 150 m up (the engine deck in view) driving left at the near point, noise-free."""
    for name, engine_on_the_right in (("t_72", True), ("ford_f150", False)):  # rear engine, front engine
        seq = SyntheticSequence(name, SceneConfig(frames=1, start_deg=180.0, camera_height_m=150.0, noise_k=0.0))
        assert seq.truth(0).heading == pytest.approx(1.5 * math.pi)  # towards −x: the rear is on the right
        scene, parts = seq.scene(0), seq.part_map(0)
        body = scene[parts == BODY].mean()
        for part in (ENGINE_DECK, EXHAUST):
            assert (parts == part).sum() >= 10
            assert scene[parts == part].mean() > body + 5.0  # kelvin
        deck_u, body_u = np.nonzero(parts == ENGINE_DECK)[1].mean(), np.nonzero(parts == BODY)[1].mean()
        assert (deck_u > body_u) == engine_on_the_right


def _fitted_psf_sigma(range_m: float) -> float:
    """PSF σ that best maps the noise-free sharp frame onto the blurred one with scipy's Gaussian."""
    cfg = SceneConfig(frames=1, range_m=range_m, noise_k=0.0)
    blurred = SyntheticSequence("t_72", cfg)
    sharp = SyntheticSequence("t_72", dataclasses.replace(cfg, psf_sigma_px=0.0, psf_sigma_per_km=0.0))
    t = blurred.truth(0)
    sigmas = np.arange(0.3, 3.0, 0.01)
    reach = math.ceil(4 * sigmas[-1])  # gaussian_filter's kernel radius (truncate=4) at the largest σ
    # The target box with a 15 px margin, filtered in a crop wider by the kernel's reach (as the full frame).
    m = 15 + reach
    crop = (slice(int(t.v0) - m, int(t.v1) + m + 1), slice(int(t.u0) - m, int(t.u1) + m + 1))
    a, b = sharp.frame(0)[crop].astype(np.float64), blurred.frame(0)[crop].astype(np.float64)
    assert a.shape == (t.v1 - t.v0 + 1 + 2 * m, t.u1 - t.u0 + 1 + 2 * m)  # the crop lies inside the frame
    box = (slice(reach, -reach), slice(reach, -reach))
    errors = [np.square(ndimage.gaussian_filter(a, s)[box] - b[box]).mean() for s in sigmas]
    return float(sigmas[int(np.argmin(errors))])


def test_sky_cools_above_the_horizon_and_a_steep_view_is_all_ground():
    """Above the horizon row v_h the sky goes from the horizon's temperature to the sky's as
    exp(−(v_h − v) / (H / 8)) (closed form on the sharp scene); a view so steep that the horizon lies
    far above the frame is ground only, without the overflow warning the unused sky rows gave."""
    seq = SyntheticSequence("t_72", SceneConfig(frames=1))
    scene, cfg, temps = seq._static_scene()[0], seq.cfg, seq._temps
    H = cfg.height
    v_h = (H - 1) / 2 - cfg.focal_px * math.tan(cfg.tilt_rad)
    rows = np.arange(H)[np.arange(H) <= v_h]
    assert 0 < rows.size < H
    horizon_k = temps["ground_k"] + cfg.ground_gradient_k / 2
    sky = temps["sky_k"] + (horizon_k - temps["sky_k"]) * np.exp(-(v_h - rows) / (H / 8))
    np.testing.assert_allclose(scene[rows], np.repeat(sky[:, None], cfg.width, axis=1), rtol=1e-6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        steep = SyntheticSequence("t_72", SceneConfig(frames=1, height=32, width=64, focal_px=4000, range_m=5000,
                                                      tilt_deg=45.0))
        assert np.isfinite(steep._static_scene()[0]).all() and np.isfinite(steep.frame(0).astype(float)).all()


def test_blur_grows_with_range():
    near, far = _fitted_psf_sigma(1000.0), _fitted_psf_sigma(3500.0)
    cfg = SceneConfig()
    assert near == pytest.approx(cfg.psf_sigma_px + cfg.psf_sigma_per_km * 1.0, abs=0.05)  # documented law
    assert far == pytest.approx(cfg.psf_sigma_px + cfg.psf_sigma_per_km * 3.5, abs=0.05)
    assert far > near + 0.5


def _check_occluder_projection(occluder: np.ndarray, cfg: SceneConfig) -> None:
    """The occluder's pixels against its wall projected by hand: z = occluder range (by default
    20 m before the circle's near point), x within occluder_x_m ± width / 2, from the ground line
    y = −camera_height_m up to a top 0.75 to 1.25 times occluder_height_m above it; camera tilted
    down by τ (sensor y = cos τ y + sin τ z, depth = −sin τ y + cos τ z)."""
    z_occ = cfg.range_m - cfg.circle_diameter_m / 2 - 20.0
    tau = math.atan2(cfg.camera_height_m, cfg.range_m)
    cx, cy, f = (cfg.width - 1) / 2, (cfg.height - 1) / 2, cfg.focal_px

    def pixel(x: float, height: float) -> tuple[float, float]:
        y = height - cfg.camera_height_m
        depth = -math.sin(tau) * y + math.cos(tau) * z_occ
        return cx + f * x / depth, cy - f * (math.cos(tau) * y + math.sin(tau) * z_occ) / depth

    u_left, v_ground = pixel(cfg.occluder_x_m - cfg.occluder_width_m / 2, 0.0)
    u_right, _ = pixel(cfg.occluder_x_m + cfg.occluder_width_m / 2, 0.0)
    v_low_top, v_high_top = pixel(cfg.occluder_x_m, 0.75 * cfg.occluder_height_m)[1], pixel(
        cfg.occluder_x_m, 1.25 * cfg.occluder_height_m)[1]
    rows, cols = np.nonzero(occluder)
    assert abs(cols.min() - u_left) <= 1.0 and abs(cols.max() - u_right) <= 1.0
    assert np.array_equal(np.unique(cols), np.arange(cols.min(), cols.max() + 1))
    for u in range(cols.min(), cols.max() + 1):
        column = np.nonzero(occluder[:, u])[0]
        assert abs(column.max() - v_ground) <= 1.0  # stands on the ground line
        assert v_high_top - 1.0 <= column.min() <= v_low_top + 1.0  # its bushy top
        assert len(column) == column.max() - column.min() + 1  # one solid run


def test_occluder_hides_part_of_the_target():
    cfg = SceneConfig(frames=1, start_deg=180.0, occluder_width_m=12.0, occluder_x_m=2.0)
    seq = SyntheticSequence("t_72", cfg)
    true, visible = seq.true_mask(0), seq.visible_mask(0)
    assert not (visible & ~true).any()
    assert 0.1 * true.sum() < (true & ~visible).sum() < 0.9 * true.sum()
    occluder = seq.occluder_mask()
    _check_occluder_projection(occluder, cfg)
    # The occluder is static scene: it is in the warm-up frames, and the hidden target adds nothing.
    warm = next(seq.warmup_frames(1)).astype(np.float64)
    hidden = occluder & true & ~cv2.dilate(visible.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    assert hidden.sum() > 20
    assert abs((seq.frame(0) - warm)[hidden].mean()) < 5.0
    clear = SyntheticSequence("t_72", dataclasses.replace(cfg, occluder_width_m=0.0))
    np.testing.assert_array_equal(clear.visible_mask(0), clear.true_mask(0))


def test_turret_sweep_turns_the_turret_only_where_there_is_one():
    cfg = SceneConfig(frames=60, turret_sweep_deg=90.0, turret_period_s=4.0)
    still_cfg = dataclasses.replace(cfg, turret_sweep_deg=0.0)
    swept, still = SyntheticSequence("t_72", cfg), SyntheticSequence("t_72", still_cfg)
    np.testing.assert_array_equal(swept.true_mask(0), still.true_mask(0))  # sin(0) = 0
    assert (swept.true_mask(30) != still.true_mask(30)).sum() > 50  # a quarter period: 90°
    assert swept.truth(30).heading == still.truth(30).heading
    car = SyntheticSequence("ford_f150", dataclasses.replace(cfg, **SMALL))
    car_still = SyntheticSequence("ford_f150", dataclasses.replace(still_cfg, **SMALL))
    np.testing.assert_array_equal(car.frame(30), car_still.frame(30))


def test_segmentation_of_the_simulator_at_1000m():
    seq = SyntheticSequence("btr_70", SceneConfig(frames=300))
    segmenter = ForegroundSegmenter()
    segmenter.warm_up(seq.warmup_frames(50))
    ious = []
    for i in range(0, 300, 12):  # 25 frames
        mask, visible = segmenter(seq.frame(i)), seq.visible_mask(i)
        ious.append((mask & visible).sum() / (mask | visible).sum())
    assert np.mean(ious) >= 0.8 and min(ious) > 0.6


def test_every_test_split_vehicle_can_be_simulated():
    for spec in SPLITS["test"]:
        seq = SyntheticSequence(spec.name, SceneConfig(frames=1))
        frame, t = seq.frame(0), seq.truth(0)
        assert frame.shape == (512, 640) and frame.dtype == np.uint16 and frame.max() < 2 ** 14
        assert t.vehicle == spec.name and t.vehicle_class == spec.cls and seq.visible_mask(0).sum() > 100


@pytest.mark.parametrize("range_m", [1000.0, 2500.0])
def test_the_truth_position_projects_onto_the_box_centre_side_on(range_m):
    """The truth's x, y, z (metres, the scene camera's world frame) is the 3D box's centre: seen side-on at the
    near point its projection is the centre of the silhouette's box, to the half pixel the box's whole-pixel
    edges allow, for every test-split vehicle (their meshes are centred on their boxes, guns included)."""
    for spec in SPLITS["test"]:
        seq = SyntheticSequence(spec.name, SceneConfig(frames=1, range_m=range_m))
        t = seq.truth(0)
        assert abs(_wrap(t.theta - math.pi / 2)) < 1e-9  # the left side, clockwise
        uv, _ = seq.camera.project(torch.tensor([t.x, t.y, t.z], dtype=torch.float64))
        np.testing.assert_allclose(uv.numpy(), [(t.u0 + t.u1) / 2, (t.v0 + t.v1) / 2], atol=0.51, err_msg=spec.name)


def test_truth_range_is_slant_and_the_scene_camera_is_the_docstrings_pinhole():
    """Closed forms of the module docstring in numpy, where the camera's height matters (the visible scene: 6.5 m up,
    13 m from the circle's centre): at start_deg a the vehicle's centre is (r sin a, −h + height / 2, range + r cos a)
    and range_m its Euclidean norm (the slant range; the horizontal one is 15 % shorter there); the camera a
    pinhole with principal point ((W − 1) / 2, (H − 1) / 2) (pixel (0, 0) the top-left pixel's centre) and world ->
    sensor R = [[1, 0, 0], [0, cos τ, sin τ], [0, −sin τ, cos τ]] (τ = tilt_deg, here 32°): u = cx + f X / Z,
    v = cy − f Y / Z; with tilt_deg null, τ = atan2(h, range): the circle's centre on the ground at the image's."""
    cfg = visible_scene(frames=1, start_deg=150.0)
    seq = SyntheticSequence("isuzu_rodeo", cfg)
    t = seq.truth(0)
    r, a, h = cfg.circle_diameter_m / 2, math.radians(150.0), cfg.camera_height_m
    centre = np.array([r * math.sin(a), -h + seq.vehicle.mesh.extents[2] / 2, cfg.range_m + r * math.cos(a)])
    np.testing.assert_allclose([t.x, t.y, t.z], centre, atol=1e-9)
    assert t.range_m == pytest.approx(float(np.linalg.norm(centre)), rel=1e-9)
    aimed = SceneConfig(frames=1, tilt_deg=None, **SMALL)
    for scene, tau in ((cfg, math.radians(32.0)), (aimed, math.atan2(aimed.camera_height_m, aimed.range_m))):
        h, d = scene.camera_height_m, scene.range_m
        R = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(tau), math.sin(tau)], [0.0, -math.sin(tau), math.cos(tau)]])
        points = np.array([[0.0, -h, d], [r * math.sin(a), -h + 1.0, d + r * math.cos(a)], [3.0, -h, d - 4.0],
                           [-4.0, 1.0, d + 2.0]])
        q = points @ R.T
        f, cx, cy = scene.focal_px, (scene.width - 1) / 2, (scene.height - 1) / 2
        expected = np.stack([cx + f * q[:, 0] / q[:, 2], cy - f * q[:, 1] / q[:, 2]], axis=1)
        uv, depth = SyntheticSequence("isuzu_rodeo", scene).camera.project(torch.tensor(points, dtype=torch.float64))
        np.testing.assert_allclose(uv.numpy(), expected, atol=1e-9)
        np.testing.assert_allclose(depth.numpy(), q[:, 2], atol=1e-9)
    np.testing.assert_allclose(expected[0], [cx, cy], atol=1e-9)  # aimed: the circle's centre at the image centre


def test_open_sequence_spec(tmp_path):
    seq = open_sequence("synthetic:vehicle=T-72,range=2000,frames=5,seed=3,night=false,tilt_deg=0.5")
    assert isinstance(seq, SyntheticSequence) and len(seq) == 5 and seq.vehicle.name == "t_72"
    assert (seq.cfg.range_m, seq.cfg.seed, seq.cfg.night, seq.cfg.tilt_deg) == (2000.0, 3, False, 0.5)
    box = trimesh.creation.box(extents=(4.0, 2.0, 1.5))
    box.export(tmp_path / "crate.obj")
    crate = open_sequence(f"synthetic:vehicle={tmp_path / 'crate.obj'},frames=2")
    assert crate.vehicle.cls == "unknown" and crate.truth(1).vehicle == "crate"
    bad = {
        "synthetic:vehicle=t_72,colour=red": "colour",
        "synthetic:vehicle=t_72,frames=abc": "frames",
        "synthetic:vehicle=t_72,frames=0": "frames=0",
        "synthetic:vehicle=t_72,range=10": "range_m=10.0",
        "synthetic:vehicle=t_72,seed=1,seed=2": "'seed' given twice",
        "synthetic:frames=3": "missing vehicle",
        "synthetic:vehicle=t_72,frames": "expected key=value",
        "synthetic:vehicle=leopard_1": "leopard_1",
    }
    for spec, words in bad.items():
        with pytest.raises(ValueError, match=words):
            open_sequence(spec)


def test_config_errors_name_the_field():
    with pytest.raises(ConfigError, match=r"noise_k=-1"):
        SceneConfig(noise_k=-1)
    for key, value in (("body_k", 1e300), ("ground_gradient_k", 1e308), ("noise_k", 1e300), ("clutter_k", 1e300),
                       ("top_delta_k", -1e308)):  # they overflowed in the renderer (NaN frames)
        with pytest.raises(ConfigError, match=re.escape(f"{key}={value!r} (expected") + ".*10000"):
            SceneConfig(**{key: value})
    with pytest.raises(ConfigError, match=r"occluder_range_m=990"):
        SceneConfig(occluder_range_m=990.0)
    with pytest.raises(ValueError, match="SceneConfig"):
        SyntheticSequence("t_72", {"frames": 3})


def test_python_values_of_the_wrong_kind_are_named():
    """SceneConfig(night="false") ran a night scene and clockwise="false" a clockwise one (a non-empty string is
    truthy); frames=2.5, seed=1.5 and width=160.0 failed later in len(), the noise generator or torch.randn with a
    TypeError naming none of them. (Specs and files are typed by load_config before SceneConfig sees them.)"""
    for key, value, kind in (("night", "false", "true or false"), ("clockwise", "false", "true or false"),
                             ("frames", 2.5, "an integer"), ("seed", 1.5, "an integer"), ("width", 160.0, "an integer"),
                             ("frames", True, "an integer"), ("range_m", "1000", "a number"),
                             ("tilt_deg", True, "a number or null"), ("band", None, "text")):
        with pytest.raises(ConfigError, match=re.escape(f"{key}={value!r} (expected {kind})")):
            SceneConfig(**{key: value})
    numpy_typed = SceneConfig(frames=np.int64(3), fps=np.float64(30.0), night=np.False_, **SMALL)
    assert len(SyntheticSequence("isuzu_rodeo", numpy_typed)) == 3 and not numpy_typed.night


@pytest.mark.parametrize("option, words", [
    ("width=100000", r"width=100000 \(expected in \[1, 4096\]\)"),
    ("height=4096,width=4096", r"width x height at most 4194304"),
    ("psf_sigma_px=1e6", r"psf_sigma_px=1000000.0 \(expected in \[0, 100\]\)"),
    ("psf_sigma_per_km=1000", r"psf_sigma_per_km=1000.0 \(expected >= 0, with psf_sigma_px \+ psf_sigma_per_km"),
    ("clutter_stretch=1000", r"clutter_scale_px x clutter_stretch at most 100 px"),
    ("frames=100000000", r"frames=100000000 \(expected in \[1, 10\*\*7\]\)"),
    ("occluder_width_m=1e15", r"occluder_width_m=1000000000000000.0 \(expected in \[0, 10000\]\)"),
    ("fps=.inf", "option fps=.inf: fps: expected a finite number; got inf"),
    ("range=1e400", "option range_m=1e400: range_m: expected a finite number; got inf"),
    ("seed=true", "seed: expected an integer; got True"),
    ("night=1", "night: expected true/false; got 1"),
    # The circle's angle and the turret's phase overflowed: NaN poses reported as 'the vehicle reaches behind the
    # camera' (fps, circle_diameter_m), and 'math domain error' (turret_period_s).
    ("fps=5e-324", r"fps=5e-324 \(expected in \[0.001, 10000\]\)"),
    ("circle_diameter_m=1e-300,fps=1e-10", r"circle_diameter_m=1e-300 \(expected in \[0.001, 10000\]\)"),
    ("turret_sweep_deg=30,turret_period_s=1e-300,fps=1e-3", r"turret_period_s=1e-300 \(expected >= 0.001\)"),
])
def test_spec_values_are_bounded(option, words):
    spec = f"vehicle=t_72,{option}"
    with pytest.raises(ConfigError, match=rf"^synthetic spec {re.escape(repr(spec))}: .*{words}"):
        parse_synthetic_spec(spec)


def test_a_vehicle_too_large_in_the_image_is_refused_before_rendering():
    with pytest.raises(ConfigError, match=r"t_72 \(\d+.\d m across\) would span \d+ px at the circle's nearest point, "
                                          r"150 m away; expected at most 512"):
        SyntheticSequence("t_72", SceneConfig(range_m=200.0))


def test_visible_floor_memory_does_not_grow_with_the_frame_height():
    # The static floor's 3 x 3 sub-samples of a whole frame at once took 4.5 GB at 2048 x 2048 (and 0.5 GB at
    # 640 x 480); numpy's allocations are traced by tracemalloc.
    peaks = []
    for height in (48, 384):
        seq = SyntheticSequence("ford_f150", visible_scene(frames=1, width=128, height=height))
        tracemalloc.start()
        next(seq.warmup_frames(1))  # builds the static scene
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert peaks[1] < 2 * peaks[0], f"peak traced memory {peaks[0] / 2**20:.1f} MB at 48 rows, " \
                                    f"{peaks[1] / 2**20:.1f} MB at 384"


def test_save_sequence_round_trip(tmp_path):
    seq = SyntheticSequence("ford_f150", SceneConfig(frames=3, **SMALL))
    back = FolderSequence(save_sequence(seq, tmp_path / "seq", progress=False))
    assert len(back) == 3 and back.fps == seq.fps and back.camera.to_dict() == seq.camera.to_dict()
    for i in range(3):
        np.testing.assert_array_equal(back.frame(i), seq.frame(i))
        assert back.truth(i) == seq.truth(i)


def test_visible_faces_against_ray_casting():
    """The nearest face and the seen point at every pixel centre, against trimesh's ray casting."""
    mesh = SyntheticSequence("t_72", SceneConfig(frames=1)).vehicle.mesh
    c, s = math.cos(0.35), math.sin(0.35)
    camera = Camera(300.0, 300.0, 79.5, 59.5, 160, 120, R=[[1, 0, 0], [0, c, s], [0, -s, c]])  # 20° down
    R, t = body_to_world(VehiclePose(1.0, -9.0, 25.0, 2.3))  # seen from 20° above: turret over the hull
    world = torch.as_tensor(mesh.vertices) @ R.T + t  # (M, 3)
    uv, depth = camera.project(world)
    face, weights = visible_faces(uv, depth, torch.as_tensor(mesh.faces), 120, 160)
    v, u = np.mgrid[0:120, 0:160]
    rays = camera.pixel_rays(torch.as_tensor(np.stack([u, v], -1).reshape(-1, 2), dtype=torch.float64))
    rays = (rays @ camera.R).numpy()  # sensor -> world: Rᵀ d
    scene = trimesh.Trimesh(world.numpy(), mesh.faces, process=False)
    hit_face, hit_ray, hit_at = scene.ray.intersects_id(np.zeros_like(rays), rays, multiple_hits=False,
                                                       return_locations=True)
    ref = np.full(120 * 160, -1)
    ref[hit_ray] = hit_face
    got = face.reshape(-1).numpy()
    assert (got >= 0).sum() > 1500
    assert ((got >= 0) != (ref >= 0)).mean() < 0.002  # pixel centres on silhouette edges may differ
    both = hit_ray[got[hit_ray] >= 0]
    corners = world.numpy()[mesh.faces[got[both]]]  # (n, 3, 3)
    seen = np.einsum("nk,nkd->nd", weights.reshape(-1, 3).numpy()[both], corners)
    dist = np.linalg.norm(seen - hit_at[got[hit_ray] >= 0], axis=1)
    assert np.mean(dist < 1e-6) > 0.99
    # Where the faces differ, they are coplanar (overlapping or neighbouring parts of one surface).
    other = got[both] != ref[both]
    normals = scene.face_normals
    assert np.all(np.abs(np.sum(normals[got[both][other]] * normals[ref[both][other]], axis=1)) > 1 - 1e-9)
    off_image, _ = visible_faces(uv + 1000.0, depth, torch.as_tensor(mesh.faces), 120, 160)
    assert (off_image == -1).all()
    with pytest.raises(ValueError, match="depth"):
        visible_faces(uv, depth[:-1], torch.as_tensor(mesh.faces), 120, 160)


def test_surface_parts_by_hand():
    box = trimesh.creation.box(extents=(6.0, 3.0, 2.0)).apply_translation((0.0, 0.0, 1.0))  # x in [-3, 3]
    top, side, back, front = (int(np.argmax(box.face_normals @ n)) for n in
                              np.array([[0, 0, 1.0], [0, 1.0, 0], [-1.0, 0, 0], [1.0, 0, 0]]))
    points = np.array([[-2.5, 0, 2], [2.5, 0, 2], [0, 1.5, 0.3], [0, 1.5, 1.2], [-3, 0, 1.2], [-3, 0, 0.3],
                       [3, 0, 0.3]])
    faces = np.array([top, top, side, side, back, back, front])
    tank = [ENGINE_DECK, BODY, RUNNING_GEAR, BODY, EXHAUST, RUNNING_GEAR, RUNNING_GEAR]
    pickup = [BODY, ENGINE_DECK, RUNNING_GEAR, BODY, BODY, EXHAUST, RUNNING_GEAR]
    np.testing.assert_array_equal(surface_parts(box, points, faces, "tank"), tank)
    np.testing.assert_array_equal(surface_parts(box, points, faces, "pickup"), pickup)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        surface_parts(box, points[:, :2], faces, "tank")


def test_a_focal_length_the_camera_refuses_is_named_as_the_scenes():
    """Camera refuses fx below 1e-3 px; the scene said focal_px=1e-4 was fine and the error then named fx."""
    with pytest.raises(ConfigError, match=r"^scene: bad value\(s\) focal_px=0.0001 \(expected in \[0.001, 1e6\]\)"):
        SceneConfig(focal_px=1e-4)


def _scene_blurred_by_scipy(seq: SyntheticSequence, sigma: float) -> np.ndarray:
    """(H, W) float64: frame 0's composed scene (the vehicle's cover and radiance laid over the sharp static
    scene, the occluder in front) blurred by scipy with a sampled Gaussian of σ px reaching ceil(4 σ), mirrored
    at the frame's edges (scipy's 'mirror', OpenCV's REFLECT_101)."""
    target = seq._target(0)
    h, w = target.cover.shape
    sharp, _, occluder = seq._static_scene()
    window = (slice(target.v0, target.v0 + h), slice(target.u0, target.u0 + w))
    cover = np.where(occluder[window], 0.0, target.cover)
    reference = sharp.astype(np.float64)
    reference[window] += np.where(cover > 0, target.radiance - cover * sharp[window], 0.0)
    x = np.arange(-math.ceil(4 * sigma), math.ceil(4 * sigma) + 1)
    kernel = np.exp(-x ** 2 / (2 * sigma ** 2))
    for axis in (0, 1):
        reference = ndimage.correlate1d(reference, kernel / kernel.sum(), axis=axis, mode="mirror")
    return reference


def test_a_vehicle_at_the_frames_edge_is_blurred_as_the_whole_frame_is():
    """The frame is the whole composed scene blurred, mirrored at the frame's edges (scipy's 'mirror', OpenCV's
    REFLECT_101; a sampled Gaussian reaching 4 σ). The vehicle's part was blurred with zeros beyond the edge,
    so a T-72 touching the right edge (frame 0 of this run) was up to 2.5 K too dark in its last columns."""
    seq = SyntheticSequence("t_72", SceneConfig(frames=400, seed=1))
    target = seq._target(0)
    assert target.u0 + target.cover.shape[1] == seq.cfg.width  # the scenario: it touches the edge
    assert np.abs(seq.scene(0) - _scene_blurred_by_scipy(seq, seq.cfg.psf_sigma)).max() < 1e-3


def test_a_vehicle_inside_the_frame_is_blurred_as_the_whole_frame_is():
    """Where 4 σ is a whole number of pixels (σ = 1 px) the kernel reaches exactly the window's padding, and
    the mirror at a window edge inside the frame read the vehicle's first row back into the outer ring,
    doubling the kernel's tail there (1.1 mK off for the 0.1 mK of float32 rounding). Reference: the
    whole composed scene blurred by scipy, mirrored at the frame's edges (REFLECT_101)."""
    seq = SyntheticSequence("t_72", SceneConfig(frames=10, seed=0, psf_sigma_px=1.0, psf_sigma_per_km=0.0))
    target = seq._target(0)
    h, w = target.cover.shape
    assert 4 < target.u0 and target.u0 + w < seq.cfg.width - 4 and 4 < target.v0 and target.v0 + h < seq.cfg.height - 4
    assert seq.cfg.psf_sigma == 1.0  # the scenario: 4 σ a whole number of pixels
    assert np.abs(seq.scene(0) - _scene_blurred_by_scipy(seq, 1.0)).max() < 3e-4


def test_the_psf_grows_with_the_circles_centre_range_not_the_vehicles():
    """σ = psf_sigma_px + psf_sigma_per_km · range_m / 1 km, range_m the circle's centre's (module docstring), also
    where the vehicle is far nearer (a 1000 m circle at 2000 m: the near point is 1500 m away): σ = 0.5 · 2 = 1 px.
    Reference: the whole composed scene blurred by scipy with that σ, mirrored at the frame's edges."""
    seq = SyntheticSequence("t_72", SceneConfig(frames=1, range_m=2000.0, circle_diameter_m=1000.0,
                                                psf_sigma_px=0.0, psf_sigma_per_km=0.5))
    assert seq.truth(0).z == pytest.approx(1500.0, abs=5.0)  # the scenario: the vehicle at the near point
    assert np.abs(seq.scene(0) - _scene_blurred_by_scipy(seq, 1.0)).max() < 3e-4


def test_the_atmosphere_dims_the_target_by_its_own_slant_range():
    """T_app = ground_k + exp(−extinction_per_km · slant / 1 km) (T − ground_k) with slant the camera -> vehicle
    centre distance (module docstring), worked out in numpy from the closed-form centre at the near point of a
    1000 m circle at 2000 m (1500 m away, not the circle centre's 2000 m). One temperature on every part, no
    top delta, clutter, gradient, blur or noise: the scene inside the silhouette is T_app (float32)."""
    cfg = SceneConfig(frames=1, range_m=2000.0, circle_diameter_m=1000.0, extinction_per_km=1.0, body_k=300.0,
                      running_gear_k=300.0, engine_deck_k=300.0, exhaust_k=300.0, top_delta_k=0.0, clutter_k=0.0,
                      ground_gradient_k=0.0, psf_sigma_px=0.0, psf_sigma_per_km=0.0, noise_k=0.0)
    seq = SyntheticSequence("t_72", cfg)
    slant = math.hypot(-cfg.camera_height_m + seq.vehicle.mesh.extents[2] / 2, cfg.range_m - cfg.radius_m)
    ground = cfg.temperatures()["ground_k"]
    inside = ndimage.binary_erosion(seq.true_mask(0), iterations=2)
    assert inside.sum() > 100
    np.testing.assert_allclose(seq.scene(0)[inside], ground + math.exp(-slant / 1000.0) * (300.0 - ground), atol=1e-4)
