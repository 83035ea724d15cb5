"""Speeds after a blind start, set from the blob's motion across the line of sight
(``init.speed_frames``): the posterior mean against a brute-force one, and a fast vehicle that the
speeds' random walk alone loses."""

import math

import numpy as np
import pytest
import torch
from scipy.stats import linregress

from torch_atr.config import ConfigError, load_config
from torch_atr.data.synthetic import SceneConfig, SyntheticSequence
from torch_atr.tracking import Tracker, TrackerConfig
from torch_atr.tracking.initialise import SPEED_MEASUREMENT_FLOOR_MPS, speeds_from_track
from torch_atr.tracking.job import run_summary


def _config(*overrides: str) -> TrackerConfig:
    return load_config(TrackerConfig, None, list(overrides))


@pytest.mark.parametrize("noise", [0.0, 0.3])
def test_speeds_are_the_posterior_mean_of_a_brute_force_search(noise):
    """Each particle's speed maximises N(v; v0, σ0²) N(u; v s, σ_u²) over a fine grid of v, with u and
    its standard error from scipy's regression and s = axis · (sin h, 0, cos h)."""
    rng = np.random.default_rng(0)
    times = np.arange(11) / 30.0
    lateral = 23.0 - 6.0 * times + noise * rng.standard_normal(11)
    axis = np.array([math.cos(0.2), 0.0, -math.sin(0.2)])  # a camera turned 0.2 rad about the vertical
    heading = rng.uniform(0, 2 * math.pi, 64)
    v0 = rng.normal(0.0, 1.0, 64)
    prior_std = 1.5
    got = speeds_from_track(torch.tensor(times), torch.tensor(lateral), torch.tensor(axis), torch.tensor(heading),
                            torch.tensor(v0), prior_std).numpy()
    fit = linregress(times, lateral)
    sigma_u = max(fit.stderr, SPEED_MEASUREMENT_FLOOR_MPS)
    grid = np.linspace(-100, 100, 2_000_001)
    for h, v, g in zip(heading, v0, got):
        s = axis[0] * math.sin(h) + axis[2] * math.cos(h)
        cost = (grid - v) ** 2 / prior_std ** 2 + (fit.slope - s * grid) ** 2 / sigma_u ** 2
        assert g == pytest.approx(grid[cost.argmin()], abs=2e-4)


def test_side_on_particles_take_the_lateral_speed_and_head_on_ones_keep_theirs():
    times = torch.arange(11, dtype=torch.float64) / 30
    lateral = 5.0 + 8.0 * times  # 8 m/s to the right
    axis = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    heading = torch.tensor([math.pi / 2, 3 * math.pi / 2, 0.0, math.pi], dtype=torch.float64)
    v = speeds_from_track(times, lateral, axis, heading, torch.full((4,), 0.5, dtype=torch.float64), 1.0)
    assert v[0] == pytest.approx(8.0, abs=0.1) and v[1] == pytest.approx(-8.0, abs=0.1)  # facing left: backwards
    assert v[2:].tolist() == pytest.approx([0.5, 0.5])
    kept = speeds_from_track(times, lateral, axis, heading, torch.full((4,), 0.5, dtype=torch.float64), 0.0)
    assert kept.tolist() == [0.5] * 4


@pytest.mark.parametrize("times, lateral, prior", [([0.0, 0.1], [0.0, 1.0], 1.0), ([0.2] * 3, [0.0, 1.0, 2.0], 1.0),
                                                   ([0.0, 0.1, 0.2], [0.0, 1.0], 1.0),
                                                   ([0.0, 0.1, 0.2], [0.0, 1.0, 2.0], -1.0),
                                                   ([0.0, 0.1, 0.2], [0.0, math.nan, 2.0], 1.0),
                                                   ([0.0, math.inf, 0.2], [0.0, 1.0, 2.0], 1.0)])
def test_bad_tracks_are_refused(times, lateral, prior):
    with pytest.raises(ValueError):
        speeds_from_track(torch.tensor(times), torch.tensor(lateral), torch.tensor([1.0, 0, 0]), torch.zeros(2),
                          torch.zeros(2), prior)


def test_speed_frames_of_one_is_named():
    with pytest.raises(ConfigError, match="init.speed_frames"):
        _config("init.speed_frames=1")


def test_a_fast_vehicle_is_followed_once_its_speed_is_measured(model):
    """The BTR-70 at 10 m/s, 1000 m: with the speeds' random walk alone the windows fall behind
    and the vehicle is lost; measured from the blob over the first 10 frames, it is followed."""
    seq = SyntheticSequence("btr_70", SceneConfig(frames=60, speed_mps=10.0))
    errors = {}
    for frames in (0, 10):
        result = Tracker(model, seq.camera, _config("filter.particles=300", f"init.speed_frames={frames}"),
                         seed=0).run(seq, progress=False)
        m = run_summary(result, model, 20)
        errors[frames] = m["settled"]["horizontal_error_m"]
        if frames:
            assert abs(result.rows[-1]["speed"] - 10.0) < 1.0
            assert m["settled"]["overlap_ratio"] > 0.9 and m["lost_frames"] == 0
    assert errors[10] < 0.2 < 1.0 < errors[0]


def test_a_start_on_the_truth_keeps_its_speeds(model):
    """The thesis's start sets its own speed (``init.speed_mps``): no measurement follows it."""
    seq = SyntheticSequence("btr_70", SceneConfig(frames=15))
    rows = [Tracker(model, seq.camera, _config("init.mode=truth", "filter.particles=100", f"init.speed_frames={f}"),
                    seed=0).run(seq, progress=False).rows for f in (0, 10)]
    for a, b in zip(*rows):
        assert {k: v for k, v in a.items() if k != "step_ms"} == {k: v for k, v in b.items() if k != "step_ms"}


def test_an_estimate_behind_the_camera_leaves_the_speeds_alone(model):
    """Particles behind the camera have no lateral scale (their depth is negative): the speeds are
    not set from the blob, so the run is the one without the measurement. No restart (the blob,
    which no window reaches, would start the track blind again in front of the camera)."""
    seq = SyntheticSequence("btr_70", SceneConfig(frames=12))
    mask = np.zeros((seq.camera.height, seq.camera.width), dtype=bool)
    particles = torch.zeros(50, 6, dtype=torch.float64)
    particles[:, 2] = -100.0  # 100 m behind the camera
    particles[:, 4] = 2.0
    rows = []
    for frames in (0, 10):
        cfg = _config("filter.particles=50", f"init.speed_frames={frames}", "redetect.restart=0")
        tracker = Tracker(model, seq.camera, cfg, seed=0)
        tracker.reset(particles)
        run = []
        for i in range(12):
            mask[:] = False
            mask[200:210, 300 + 3 * i:330 + 3 * i] = True  # a blob moving right
            run.append(tracker.step(mask=mask.copy()))
        rows.append(run)
    for a, b in zip(*rows):
        assert {k: v for k, v in a.items() if k != "step_ms"} == {k: v for k, v in b.items() if k != "step_ms"}
    assert all(math.isfinite(r["speed"]) for r in rows[1])


def test_the_speed_track_leaves_out_blobs_cut_by_the_edge(model):
    """A blob moving right 3 px a frame that reaches the image's right edge after 6 frames: its
    cut centre then moves 1.5 px a frame. The speeds come from the 6 whole blobs alone, so a
    side-on particle takes the closed form 3 px · fps · depth / fx (a wide speed prior: the
    measurement alone)."""
    seq = SyntheticSequence("btr_70", SceneConfig(frames=1))
    camera = seq.camera
    truth = seq.truth(0)
    axis = camera.R[0]
    particles = torch.zeros(50, 6, dtype=torch.float64)
    particles[:, :3] = torch.tensor([truth.x, truth.y, truth.z], dtype=torch.float64)
    particles[:, 3] = math.atan2(float(axis[0]), float(axis[2]))  # heading along the camera's x axis
    depth = float(camera.world_to_sensor(particles[:1, :3])[0, 2])
    cfg = _config("filter.particles=50", "init.speed_std_mps=1000", "redetect.restart=0", "redetect.every=0",
                  "motion.sigma2_speed=0", "motion.sigma2_heading=0")
    tracker = Tracker(model, camera, cfg, seed=0)
    tracker.reset(particles)
    mask = np.zeros((camera.height, camera.width), dtype=bool)
    left = camera.width - 2 - 30 - 3 * 5  # frame 5: the last 2 px clear of the edge (init.border_px)
    rows = []
    for i in range(12):
        mask[:] = False
        mask[200:210, left + 3 * i:left + 3 * i + 30] = True
        rows.append(tracker.step(mask=mask.copy()))
    lateral = float(torch.linalg.vector_norm(axis[[0, 2]]))  # the heading's component along the camera's x axis
    expected = 3 * tracker.cfg.filter.fps * depth / camera.fx / lateral
    assert abs(rows[10]["speed"]) < 1 and rows[11]["speed"] == pytest.approx(expected, rel=1e-3)
