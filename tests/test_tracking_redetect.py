"""Re-detection: the hypothesis grid against per-view reconstructions, hypotheses at a known depth,
the tracker recovering particles put on the wrong class, and the view search mending particles put
on a reversed heading without moving the identity (each against the same run without it)."""

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from torch_atr.config import ConfigError, load_config
from torch_atr.data.synthetic import SceneConfig, SyntheticSequence
from torch_atr.model import GenerativeShapeModel
from torch_atr.shape import signed_distance_px
from torch_atr.tracking import ShapeAppearance, Tracker, TrackerConfig
from torch_atr.tracking import filter as filter_module
from torch_atr.tracking.estimates import circular_mean
from torch_atr.tracking.filter import RedetectConfig
from torch_atr.tracking.initialise import HypothesisGrid, InitConfig, best_hypotheses, blind_hypotheses, truth_alpha
from torch_atr.tracking.motion import ALPHA, HEADING

CKPT = Path(__file__).resolve().parents[1] / "checkpoints" / "default.pt"


@pytest.fixture(scope="module")
def btr():
    """The held-out BTR-70 (an APC) at 1000 m, 21 frames."""
    return SyntheticSequence("btr_70", SceneConfig(frames=21))


def _box(mask: np.ndarray) -> list[float]:
    rows, cols = np.nonzero(mask)
    return [cols.min(), rows.min(), cols.max(), rows.max()]


def test_hypothesis_grid_boxes_are_the_silhouettes_of_each_view_and_are_kept_within_the_tolerance(model):
    """Each box is that of the model's full reconstruction y(α, θ, φ) > 0 queried one view at a time
    (α-major; Method I's: test_tracker has each method's own); a φ within the tolerance reuses them,
    one beyond recomputes them."""
    cfg = InitConfig(alpha_steps=4, azimuth_steps=3)
    grid = HypothesisGrid(ShapeAppearance(model, "I", 32), cfg, tolerance=0.01)

    def reference(phi: float) -> torch.Tensor:
        boxes = []
        for a in range(4):
            for b in range(3):
                with torch.no_grad():
                    y = model(torch.tensor([a * math.pi / 2]), torch.tensor([b * 2 * math.pi / 3]), torch.tensor([phi]))
                boxes.append(_box(y[0].numpy() > 0))
        return torch.tensor(boxes, dtype=torch.float64)

    first = grid.boxes(0.1)
    assert torch.equal(first, reference(0.1))
    assert grid.boxes(0.105) is first
    assert torch.equal(grid.boxes(0.5), reference(0.5))
    grid.forget()
    assert grid.boxes(0.5) is not first and torch.equal(grid.boxes(0.5), reference(0.5))


def test_best_hypotheses_keep_each_class_its_share_against_brute_force():
    g = torch.Generator().manual_seed(0)
    log_lik = torch.randn(500, generator=g, dtype=torch.float64)
    log_lik[torch.randperm(500, generator=g)[:100]] = -math.inf
    classes = torch.randint(0, 5, (500,), generator=g)
    classes[log_lik.isinf()] = 5  # class 5 has no valid hypothesis: no share
    ranked = sorted(range(500), key=lambda i: -log_lik[i].item())
    for count, per_class in ((16, 3), (3, 1), (100, 20)):
        expected = [[i for i in ranked if classes[i] == c and math.isfinite(log_lik[i])][:per_class] for c in range(5)]
        got = best_hypotheses(log_lik, count, classes).tolist()
        assert sorted(got) == sorted(i for e in expected for i in e)
        for e in expected:  # best first within each class
            assert [i for i in got if i in e] == e
    assert best_hypotheses(log_lik, 16).tolist() == ranked[:16]
    assert best_hypotheses(torch.full((4,), -math.inf), 16).numel() == 1  # never empty
    with pytest.raises(ValueError, match="classes"):
        best_hypotheses(log_lik, 16, classes[:10])


def test_hypotheses_at_a_known_depth_all_lie_at_it(model, btr):
    """``known_depth`` overrides the ground: every hypothesis's centre has that sensor depth (R p + t)_z."""
    mask = np.zeros((512, 640), dtype=bool)
    mask[250:262, 300:340] = True
    states, log_lik = blind_hypotheses(torch.from_numpy(mask), signed_distance_px(mask), btr.camera,
                                       ShapeAppearance(model, "I", 32), InitConfig(alpha_steps=6, azimuth_steps=4),
                                       0.02, btr.camera_height_m, known_depth=987.0)
    valid = log_lik.isfinite()
    assert valid.sum() > 12
    depth = states[valid, :3] @ btr.camera.R[2].double() + float(btr.camera.t[2])
    assert torch.allclose(depth, torch.full_like(depth, 987.0), atol=1e-6)


def test_hypotheses_of_chosen_alphas_are_those_rows_of_the_whole_grid(model, btr):
    """``alpha_index`` scores the grid's rows of those α only (α-major), the same as the whole grid does
    (an indexing check: the whole grid's boxes are tested against per-view reconstructions above)."""
    mask = np.zeros((512, 640), dtype=bool)
    mask[250:262, 300:340] = True
    args = (torch.from_numpy(mask), signed_distance_px(mask), btr.camera, ShapeAppearance(model, "I", 32),
            InitConfig(alpha_steps=6, azimuth_steps=4), 0.02, btr.camera_height_m)
    states, log_lik = blind_hypotheses(*args)
    index = torch.tensor([5, 0, 1])
    some, some_lik = blind_hypotheses(*args, alpha_index=index)
    rows = (index[:, None] * 4 + torch.arange(4)).flatten()
    assert torch.equal(some, states[rows]) and torch.equal(some_lik, log_lik[rows])


def _reversed_heading_run(model, seq, view_every: int, frames: int = 10) -> list[dict]:
    """The thesis's start on the T-72's truth, but every particle turned round (h + π: the mirror
    image of its silhouette, the gun on the wrong side); no search of the identity."""
    cfg = load_config(TrackerConfig, None, ["init.mode=truth", "filter.particles=200", "init.alpha_steps=24",
                                            "init.azimuth_steps=24", "redetect.every=0",
                                            f"redetect.view_every={view_every}"])
    tracker = Tracker(model, seq.camera, cfg, seed=3)
    tracker.warm_up(seq.warmup_frames(20))
    tracker.initialise(seq.truth(0))
    particles = tracker.particles.clone()
    particles[:, HEADING] = torch.remainder(particles[:, HEADING] + math.pi, 2 * math.pi)
    tracker.reset(particles)
    return [tracker.step(seq.frame(i)) for i in range(frames)]


def _angle(a: torch.Tensor | float) -> torch.Tensor:
    return (torch.as_tensor(a) + math.pi) % (2 * math.pi) - math.pi


def test_view_search_turns_a_reversed_heading_round_and_keeps_the_identity(monkeypatch):
    """The particles' shapes cannot walk half a turn (the control run stays reversed); searching the
    view every frame finds the right one. Every hypothesis it scores lies within one grid step of
    the particles' α (their circular mean), and the particles it redraws take α values the particles
    held before it (drawn by weight), so the identity stays theirs."""
    model = GenerativeShapeModel.from_checkpoint(CKPT)
    seq = SyntheticSequence("t_72", SceneConfig(frames=10))
    without = _reversed_heading_run(model, seq, 0)
    scored = []

    def spy(*args, **kwargs):
        states, log_lik = blind_hypotheses(*args, **kwargs)
        scored.append(states[:, ALPHA])
        return states, log_lik

    estimates, redrawn, search = [], [], Tracker._redetect

    def search_spy(self, *args, **kwargs):
        estimates.append(circular_mean(self.particles[:, ALPHA].double(), self.log_weights.exp().double())[0])
        before = self.particles.clone()
        out = search(self, *args, **kwargs)
        changed = (self.particles != before).any(1)
        redrawn.append((int(changed.sum()), bool(torch.isin(self.particles[changed, ALPHA], before[:, ALPHA]).all())))
        return out

    monkeypatch.setattr(filter_module, "blind_hypotheses", spy)
    monkeypatch.setattr(Tracker, "_redetect", search_spy)
    with_ = _reversed_heading_run(model, seq, 1)
    assert abs(_angle(without[-1]["theta"] - seq.truth(9).theta)) > 2.5
    assert abs(_angle(with_[-1]["theta"] - seq.truth(9).theta)) < 0.3
    assert all(r["class"] == "tank" and r["p_tank"] > 0.99 for r in with_)
    step = 2 * math.pi / 24  # the grid's α step
    assert len(scored) == 9 and all(_angle(a - e).abs().max() < 1.5 * step for a, e in zip(scored, estimates))
    assert sum(n for n, _ in redrawn) > 0 and all(kept for _, kept in redrawn)  # redrawn with an α the particles had


def test_view_searches_every_kth_frame_after_any_start():
    assert [f for f in range(35) if RedetectConfig(view_every=10).view_searches(f)] == [10, 20, 30]
    assert not any(RedetectConfig().view_searches(f) for f in range(100))


def _wrong_class_run(model, seq, every: int, margin: float = 5.0, frames: int = 21) -> list[dict]:
    """The thesis's start on the truth, but every particle's α on the car class's centre (the BTR-70
    is an APC); rows of ``frames`` frames."""
    cfg = load_config(TrackerConfig, None, ["init.mode=truth", "filter.particles=200", "init.alpha_steps=24",
                                            "init.azimuth_steps=24", f"redetect.every={every}",
                                            f"redetect.margin={margin}", "redetect.until=0"])
    tracker = Tracker(model, seq.camera, cfg, seed=3)
    tracker.warm_up(seq.warmup_frames(20))
    tracker.initialise(seq.truth(0))
    particles = tracker.particles.clone()
    particles[:, ALPHA] = truth_alpha(model, "none", "car", "class")
    tracker.reset(particles)
    return [tracker.step(seq.frame(i)) for i in range(frames)]


def test_redetection_puts_particles_stuck_on_the_wrong_class_back_on_the_right_one(model, btr):
    """With σ²_α small the car particles cannot walk to the APC arc in 20 frames (the control run);
    re-detection at frame 10 finds the APC on the blob and the class posterior follows it."""
    without = _wrong_class_run(model, btr, every=0)
    with_ = _wrong_class_run(model, btr, every=10)
    assert without[-1]["p_apc"] < 0.5
    assert with_[9] == {**without[9], "step_ms": with_[9]["step_ms"]}  # nothing changes before frame 10
    assert with_[-1]["p_apc"] > 0.9 and with_[-1]["class"] == "apc"
    truth = btr.truth(20)
    assert abs(with_[-1]["x"] - truth.x) < 1.0


def test_redetection_that_never_fires_leaves_the_run_as_it_was(model, btr):
    """The search draws nothing from the generator and changes nothing unless a hypothesis beats
    every particle by the margin."""
    plain = _wrong_class_run(model, btr, every=0, frames=8)
    searched = _wrong_class_run(model, btr, every=1, margin=1e6, frames=8)
    for a, b in zip(plain, searched):
        assert {**a, "step_ms": 0} == {**b, "step_ms": 0}


def test_redetection_searches_every_kth_frame_up_to_until():
    assert [f for f in range(100) if RedetectConfig(every=10, until=35).searches(f)] == [10, 20, 30]
    assert [f for f in range(45) if RedetectConfig(every=20, until=0).searches(f)] == [20, 40]
    assert [f for f in range(100) if RedetectConfig().searches(f)] == [10]  # the default: one search
    assert not any(RedetectConfig(every=0, until=50).searches(f) for f in range(100))
    # then every later_every frames after until (long runs)
    assert [f for f in range(1000) if RedetectConfig(later_every=300).searches(f)] == [10, 300, 600, 900]
    assert [f for f in range(120) if RedetectConfig(every=10, until=35, later_every=50).searches(f)] == [
        10, 20, 30, 50, 100]
    assert [f for f in range(45) if RedetectConfig(every=20, until=0, later_every=7).searches(f)] == [20, 40]
    with pytest.raises(ConfigError, match="later_every"):
        RedetectConfig(later_every=-1)


def _spy_searches(tracker: Tracker) -> list[int]:
    """The list that the tracker's re-detection searches will append their frame numbers to."""
    searched, search = [], tracker._redetect

    def spy(*args, **kwargs):
        searched.append(tracker._frames)
        return search(*args, **kwargs)

    tracker._redetect = spy
    return searched


def test_redetection_counts_frames_from_the_track_start(model, btr):
    """A target first seen at frame 5 (blind start there) is searched 5 and 10 frames later, and
    not at 15 and 20 (after ``until``)."""
    cfg = load_config(TrackerConfig, None, ["filter.particles=100", "init.alpha_steps=12", "init.azimuth_steps=12",
                                            "redetect.every=5", "redetect.until=10"])
    tracker = Tracker(model, btr.camera, cfg, seed=0)
    tracker.warm_up(btr.warmup_frames(20))
    searched = _spy_searches(tracker)
    empty = np.zeros(btr.frame(0).shape[:2], dtype=bool)
    for _ in range(5):
        tracker.step(mask=empty)
    for i in range(len(btr)):
        tracker.step(btr.frame(i))
    assert searched == [10, 15]


def _searches_after_a_truth_start(model, seq, *overrides: str) -> list[int]:
    """The frames searched in the first 12 after ``initialise`` (the thesis's start on the truth)."""
    cfg = load_config(TrackerConfig, None, ["init.mode=truth", "filter.particles=100", "init.alpha_steps=12",
                                            "init.azimuth_steps=12", *overrides])
    tracker = Tracker(model, seq.camera, cfg, seed=0)
    tracker.warm_up(seq.warmup_frames(20))
    tracker.initialise(seq.truth(0))
    searched = _spy_searches(tracker)
    for i in range(12):
        tracker.step(seq.frame(i))
    return searched


@pytest.mark.parametrize("after_truth", [False, True])
def test_redetection_follows_a_start_on_the_truth_only_when_asked(model, btr, after_truth):
    """After ``initialise`` (the truth) the default never searches; ``after_truth`` searches at
    frame 10 as after a blind start."""
    searched = _searches_after_a_truth_start(model, btr, f"redetect.after_truth={after_truth}")
    assert searched == ([10] if after_truth else [])


def test_view_searches_follow_a_start_on_the_truth_too(model, btr):
    """View searches keep the identity, so unlike the full search they follow the thesis's start:
    every 5th frame, frame 10 included (no full search there after a truth start)."""
    assert _searches_after_a_truth_start(model, btr, "redetect.view_every=5") == [5, 10]


@pytest.mark.parametrize("override", ["redetect.every=-1", "redetect.margin=-1", "redetect.share=0",
                                      "redetect.share=1.5", "redetect.until=-1", "redetect.every=30",
                                      "redetect.view_every=-1"])
def test_bad_redetection_settings_are_named(override):
    with pytest.raises(ConfigError, match="redetect"):
        load_config(TrackerConfig, None, [override])


def test_redetection_with_every_particle_behind_the_camera_places_nothing(model, btr):
    """At a non-positive estimated range no hypothesis is valid, so nothing is redrawn (the run is
    the one without re-detection) and the estimates stay finite."""
    def run(every: int) -> list[dict]:
        cfg = load_config(TrackerConfig, None, ["filter.particles=50", "init.alpha_steps=8", "init.azimuth_steps=8",
                                                f"redetect.every={every}"])
        tracker = Tracker(model, btr.camera, cfg, seed=1)
        tracker.warm_up(btr.warmup_frames(20))
        truth = btr.truth(0)
        behind = torch.tensor([truth.x, truth.y, -truth.z, truth.heading, 0.0, 1.0]).repeat(50, 1)
        tracker.reset(behind + torch.randn(50, 6, generator=torch.Generator().manual_seed(0)) * 0.1)
        return [tracker.step(btr.frame(i)) for i in range(3)]

    plain, searched = run(0), run(1)
    assert [{**r, "step_ms": 0} for r in plain] == [{**r, "step_ms": 0} for r in searched]
    assert all(math.isfinite(v) for r in searched for v in r.values() if isinstance(v, float))


def test_a_frame_lost_after_a_redetection_keeps_the_weights_normalised(model, btr, caplog):
    """At σ = 0.007 a blob dilated by 4 px is explained by no particle, and the hypotheses the search
    finds on it beat every particle but underflow too: the frame is lost with particles redrawn at
    1/N among weights that never resample (``resample_ess`` 0) and have gathered on a few. The
    weights still sum to 1 (they summed to 1.2 and the ESS refused them, a ValueError from
    ``step``), and so does the class posterior."""
    cfg = load_config(TrackerConfig, None, ["filter.particles=50", "filter.sigma=0.007", "filter.resample_ess=0",
                                            "redetect.after_truth=true"])
    tracker = Tracker(model, btr.camera, cfg, seed=0)
    tracker.warm_up(btr.warmup_frames(20))
    tracker.initialise(btr.truth(0))
    for i in range(10):
        tracker.step(btr.frame(i))
    assert float(tracker.log_weights.exp().max()) > 0.5  # the redrawn particles' 1/N would not sum with them to 1
    blob = cv2.dilate(tracker.last_mask.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    with caplog.at_level("DEBUG", logger="torch_atr.tracking.filter"):
        row = tracker.step(mask=blob)
    assert any("re-detection redrew 10 particles" in r.getMessage() for r in caplog.records)
    assert row["lost"] == 1
    assert abs(float(tracker.log_weights.double().exp().sum()) - 1) < 1e-6
    assert abs(sum(v for k, v in row.items() if k.startswith("p_")) - 1) < 1e-6
    assert 1 <= row["ess"] <= 50 and all(math.isfinite(v) for v in row.values() if isinstance(v, float))
