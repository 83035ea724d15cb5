"""Frames in memory as a sequence: round trip through the folder format, tracking, clear errors."""

import math
import re
from pathlib import Path

import numpy as np
import pytest

from torch_atr.camera import Camera
from torch_atr.data import ArraySequence, open_sequence, save_sequence
from torch_atr.data.sequence import FrameTruth
from torch_atr.data.synthetic import SceneConfig, SyntheticSequence
from torch_atr.validate import InputError

CKPT = Path(__file__).resolve().parents[1] / "checkpoints" / "default.pt"


@pytest.fixture(scope="module")
def bmp():
    return SyntheticSequence("bmp_2", SceneConfig(frames=12, seed=3))


def test_frames_and_truth_round_trip_through_the_folder_format(bmp, tmp_path):
    frames = np.stack([bmp.frame(i) for i in range(len(bmp))])  # (T, H, W) uint16: the reference
    truths = [bmp.truth(i) for i in range(len(bmp))]
    seq = ArraySequence(frames, camera=bmp.camera, fps=30.0, truths=truths, camera_height_m=bmp.camera_height_m,
                        name="mine")
    assert len(seq) == 12 and seq.fps == 30.0 and seq.camera is bmp.camera
    again = open_sequence(str(save_sequence(seq, tmp_path / "mine", progress=False)))
    for i in (0, 11, -1):
        np.testing.assert_array_equal(again.frame(i), frames[i])
        assert again.truth(i) == truths[i]
    assert again.camera_height_m == bmp.camera_height_m
    seq.frame(0)[:] = 0  # a copy: the caller's frames stay
    assert frames[0].any()


def test_a_tracker_runs_on_frames_in_memory_as_on_the_same_frames_on_disk(bmp, tmp_path):
    """Reference: the folder reader on the same frames, saved (neither has target-free frames)."""
    from torch_atr.config import load_config
    from torch_atr.model import GenerativeShapeModel
    from torch_atr.tracking import Tracker, TrackerConfig

    model = GenerativeShapeModel.from_checkpoint(CKPT)
    seq = ArraySequence([bmp.frame(i) for i in range(len(bmp))], camera=bmp.camera, fps=bmp.fps,  # a list too
                        truths=[bmp.truth(i) for i in range(len(bmp))], camera_height_m=bmp.camera_height_m)
    disk = open_sequence(str(save_sequence(seq, tmp_path / "disk", progress=False)))
    cfg = load_config(TrackerConfig, None, ["filter.particles=100"])
    rows = [[{k: v for k, v in row.items() if k != "step_ms"} for row in
             Tracker(model, bmp.camera, cfg, seed=0).run(s, progress=False).rows] for s in (seq, disk)]
    assert rows[0] == rows[1] and "x" in rows[0][-1] and "true_x" in rows[0][-1]


def test_bad_arrays_are_named():
    grey = np.zeros((4, 6), np.uint8)
    camera = Camera(fx=10.0, fy=10.0, cx=3.0, cy=2.0, width=6, height=4)
    for args, kwargs, message in [
            ((np.zeros((4, 6), np.uint8),), {}, "frames: expected a (T, H, W) or (T, H, W, 3) array; got shape (4, 6)"),
            (([],), {}, "frames: expected a non-empty array or list of frames"),
            (([grey, np.zeros((4, 6), np.int32)],), {}, "frames[1]: expected an (H, W) or (H, W, 3) array of"),
            (([grey, np.zeros((5, 6), np.uint8)],), {},
             "frames[1]: shape (5, 6), dtype uint8, but frames[0] has shape (4, 6)"),
            (([grey],), {"camera": Camera(fx=10.0, fy=10.0, cx=3.0, cy=2.0, width=8, height=4)},
             "camera: 8 x 4 px, but the frames are 6 x 4"),
            ((np.zeros((2, 0, 6), np.uint8),), {}, "frames: height: expected an integer in [1, 16384]; got 0"),
            (([grey],), {"truths": [None, None]}, "truths: expected a list of 1 entries"),
            (([grey],), {"fps": 0.0}, "fps must be a positive number"),
            (([grey],), {"camera_height_m": math.nan}, "camera_height_m (metres, or None): expected a finite"),
            (([grey],), {"camera_height_m": 1e6}, "camera_height_m (metres, or None): expected a finite number in "
                                                 "(0, 10000]"),
            (([grey],), {"truths": [{"x": 1}]}, "truths[0]: expected a FrameTruth or None"),
            (([grey],), {"truths": 5}, "truths: expected a list of 1 entries"),
            ((np.zeros((48, 64, 3), np.uint8),), {}, "reads as 48 frames 3 pixels wide; for one colour frame pass"),
            (([grey],), {"camera": Camera.from_opencv(np.diag([10.0, 10.0, 1.0]), [], [0.0] * 3, [0.0] * 3, 6, 4)},
             "camera: Expected a camera whose world frame is sensor-like")]:
        with pytest.raises(InputError, match=re.escape(message)):
            ArraySequence(*args, **kwargs)
    seq = ArraySequence([grey], camera=camera)
    assert math.isnan(seq.fps) and math.isnan(seq.camera_height_m) and seq.truth(0) is None


def test_the_callers_lists_changed_later_do_not_change_the_sequence():
    """Frames and truths were checked when the sequence was made but the caller's lists were kept: a frame of
    another shape appended later was read as frame 2 (length 3, while truth(2) raised a bare IndexError), and a
    truth replaced later was returned. The frame arrays themselves are still not copied."""
    frames = [np.zeros((4, 6), np.uint8), np.ones((4, 6), np.uint8)]
    truths = [FrameTruth(x=0.0), FrameTruth(x=1.0)]
    seq = ArraySequence(frames, truths=truths)
    frames.append(np.zeros((9, 9), np.uint16))
    truths[1] = FrameTruth(x=5.0)
    assert len(seq) == 2 and seq.truth(1) == FrameTruth(x=1.0) and seq.truth(-1).x == 1.0
    with pytest.raises(IndexError, match="frame index 2 out of range for a sequence of 2 frames"):
        seq.frame(2)
    np.testing.assert_array_equal(seq.frame(-1), np.ones((4, 6), np.uint8))
