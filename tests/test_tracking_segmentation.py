"""Segmentation fed by the tracker: a global brightness ramp and a second moving vehicle, against
the simulator's true masks."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from torch_atr.config import load_config
from torch_atr.data.sequence import Sequence
from torch_atr.data.synthetic import SceneConfig, SyntheticSequence
from torch_atr.model import GenerativeShapeModel
from torch_atr.segmentation import ForegroundSegmenter, SegmentationConfig, fit_gain
from torch_atr.shape import iou
from torch_atr.tracking import Tracker, TrackerConfig
from torch_atr.tracking.filter import tracker_segmentation

CKPT = Path(__file__).resolve().parents[1] / "checkpoints" / "default.pt"
FRAMES = 30


class Composite(Sequence):
    """Frames of ``a`` with a global gain ramp (1 → ``gain_end``) and, optionally, the target of ``b``
    added (b's frame minus one of its target-free frames: b's target, plus noise)."""

    def __init__(self, a: SyntheticSequence, b: SyntheticSequence | None = None, gain_end: float = 1.0):
        self.a, self.b, self.gain_end = a, b, gain_end
        self.name, self.fps, self.camera, self.meta = "composite", a.fps, a.camera, {}
        self.camera_height_m = a.camera_height_m
        self._b_background = next(b.warmup_frames(1)).astype(np.float64) if b is not None else None

    def __len__(self) -> int:
        return len(self.a)

    def warmup_frames(self, n: int):
        return self.a.warmup_frames(n)

    def gain(self, i: int) -> float:
        return 1.0 + (self.gain_end - 1.0) * i / (len(self) - 1)

    def _read_frame(self, i: int) -> np.ndarray:
        frame = self.a.frame(i).astype(np.float64)
        if self.b is not None:
            frame += self.b.frame(i) - self._b_background
        return np.clip(frame * self.gain(i), 0, 65535).astype(np.uint16)

    def _truth(self, i: int):
        return self.a.truth(i)


@pytest.fixture(scope="module")
def car():
    return SyntheticSequence("isuzu_rodeo", SceneConfig(frames=FRAMES))


def test_fit_gain_recovers_gain_and_offset_despite_a_target():
    rng = np.random.default_rng(0)
    background = rng.uniform(50, 200, size=(60, 80))
    frame = 0.8 * background + 12 + rng.normal(0, 0.5, size=background.shape)
    frame[20:30, 30:50] = 250  # a bright target the fit must ignore
    a, b = fit_gain(frame, background, np.ones(frame.shape, dtype=bool))
    assert a == pytest.approx(0.8, abs=0.01) and b == pytest.approx(12, abs=1.0)
    assert fit_gain(frame, np.full(frame.shape, 7.0), np.ones(frame.shape, dtype=bool)) == (1.0, 0.0)


def test_fit_gain_leaves_out_pixels_without_data():
    """A NaN or infinite pixel in a float frame (or background) is no data: the fit is that of the
    other pixels (one NaN made it (1, 0), the fit's fallback for a background without contrast)."""
    rng = np.random.default_rng(1)
    background = rng.uniform(50, 200, size=(60, 80))
    frame = 0.8 * background + 12 + rng.normal(0, 0.5, size=background.shape)
    valid = np.ones(frame.shape, dtype=bool)
    holes = np.zeros(frame.shape, dtype=bool)
    holes[3, 3] = holes[10, 20:25] = holes[40, 7] = True
    want = fit_gain(frame, background, ~holes)
    assert want[0] == pytest.approx(0.8, abs=0.01) and want[1] == pytest.approx(12, abs=1.0)
    for bad in (np.nan, np.inf, -np.inf):
        dead = frame.copy()
        dead[holes] = bad
        assert fit_gain(dead, background, valid) == want
        dead_background = background.copy()
        dead_background[holes] = bad
        assert fit_gain(frame, dead_background, valid) == want


def test_fit_gain_refuses_images_of_other_shapes_and_a_valid_that_is_not_bool():
    """A uint8 0/1 valid was taken as a fancy index (rows 0 and 1 over and over), and a background of
    another shape raised numpy's IndexError."""
    frame, background = np.zeros((6, 8)), np.zeros((6, 8))
    valid = np.ones((6, 8), dtype=bool)
    with pytest.raises(ValueError, match=r"Expected valid to be a bool array of the frame's shape \(6, 8\); got "
                                         r"shape \(6, 8\), dtype uint8"):
        fit_gain(frame, background, valid.astype(np.uint8))
    with pytest.raises(ValueError, match=r"Expected valid .*; got shape \(6, 7\), dtype bool"):
        fit_gain(frame, background, valid[:, :7])
    with pytest.raises(ValueError, match=r"Expected background to have the frame's shape \(6, 8\); got shape \(8, 6\)"):
        fit_gain(frame, background.T, valid)
    with pytest.raises(ValueError, match=r"Expected frame to have shape \(H, W\); got shape \(48,\)"):
        fit_gain(frame.ravel(), background.ravel(), valid.ravel())


def test_brightness_ramp_breaks_a_frozen_background_not_the_compensated_one(car):
    ramp = Composite(car, gain_end=0.9)  # a 10 % drop in 1 s, as a cloud or a gain change
    frozen = ForegroundSegmenter(SegmentationConfig())
    fed = ForegroundSegmenter(tracker_segmentation())
    for seg in (frozen, fed):
        seg.warm_up(ramp.warmup_frames(50))
    last = FRAMES - 1
    ious = []
    for i in range(FRAMES):
        frame = ramp.frame(i)
        m_frozen = frozen(frame)
        ious.append(iou(torch.from_numpy(fed(frame)), torch.from_numpy(car.visible_mask(i))).item())
    assert ious[-1] > 0.6 and min(ious) > 0.5
    assert iou(torch.from_numpy(m_frozen), torch.from_numpy(car.visible_mask(last))).item() < 0.3
    assert fed.gain[0] == pytest.approx(ramp.gain(last), abs=0.02)


def test_tracker_follows_its_vehicle_past_a_bigger_one_and_through_a_ramp(car):
    """A tank drives the same circle 10 m ahead of the SUV: the largest blob would be the tank, the
    blob nearest the prediction is the SUV."""
    tank = SyntheticSequence("t_72", SceneConfig(frames=FRAMES, start_deg=191.0))
    scene = Composite(car, tank, gain_end=0.93)
    model = GenerativeShapeModel.from_checkpoint(CKPT)
    cfg = load_config(TrackerConfig, None, ["init.mode=truth", "filter.particles=300"])
    result = Tracker(model, scene.camera, cfg, seed=0).run(scene, progress=False)
    assert sum(r["lost"] for r in result.rows) == 0
    assert all(r["class"] == "suv" for r in result.rows[5:])
    assert max(abs(r["x"] - r["true_x"]) for r in result.rows) < 1.0
    assert not np.isnan([r.get("overlap", math.nan) for r in result.rows]).any()
