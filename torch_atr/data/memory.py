"""Frames already in memory as a :class:`~torch_atr.data.Sequence`: a stack of frames from your
own pipeline, tracked with ``Tracker.run``, or written with ``save_sequence`` like any source
when its frames are of a kind a folder stores (uint8 or uint16 grey, uint8 RGB).

    seq = ArraySequence(frames, camera=camera, fps=30.0)   # frames: (T, H, W) uint16, say
    result = Tracker(model, seq.camera, cfg).run(seq)
"""

from __future__ import annotations

import math
from typing import Sequence as Items

import numpy as np

from torch_atr._checks import describe_array
from torch_atr.camera import Camera
from torch_atr.data.sequence import MAX_CAMERA_HEIGHT_M, FrameTruth, Sequence, check_fps
from torch_atr.pose import check_sensor_like
from torch_atr.segmentation import FRAME_DTYPES
from torch_atr.validate import InputError, image_size, real, show


class ArraySequence(Sequence):
    """T frames held in memory, with an optional camera and per-frame truth.

    Args:
        frames: (T, H, W) or (T, H, W, 3) array, or a list of T frames of one shape and dtype
            (uint8, uint16, float32 or float64; colour in RGB order), T >= 1. The frames are kept as
            given, not copied (the list is); :meth:`frame` returns a copy.
        camera: the frames' calibrated camera (of their size, world frame sensor-like as the
            tracker's: ``pose.check_sensor_like``), or None: uncalibrated.
        fps: frames per second; None: unknown (the tracker then takes ``tracker.filter.fps``).
        truths: None, or T entries, each a :class:`FrameTruth` or None (no truth for that frame).
        camera_height_m: the camera centre's height above flat ground, metres, in (0, 10000];
            None: unknown.
        name: a short name for logs and run folders.
    Raises:
        InputError (a ValueError) naming the argument and what was expected.
    """

    def __init__(self, frames, camera: Camera | None = None, fps: float | None = None,
                 truths: Items[FrameTruth | None] | None = None, camera_height_m: float | None = None,
                 name: str = "arrays"):
        if isinstance(frames, np.ndarray):
            if frames.ndim not in (3, 4):
                raise InputError(f"frames: expected a (T, H, W) or (T, H, W, 3) array; got shape {frames.shape}")
            if frames.ndim == 3 and frames.shape[2] == 3:
                raise InputError(f"frames: shape {frames.shape} reads as {frames.shape[0]} frames 3 pixels wide; "
                                 f"for one colour frame pass frames[None] or [frame]")
            frames = list(frames)
        if not isinstance(frames, (list, tuple)) or not frames:
            raise InputError(f"frames: expected a non-empty array or list of frames; got {show(frames)}")
        first = frames[0]
        for i, f in enumerate(frames):
            if not isinstance(f, np.ndarray) or f.dtype not in FRAME_DTYPES or not (
                    f.ndim == 2 or f.ndim == 3 and f.shape[2] == 3):
                raise InputError(f"frames[{i}]: expected an (H, W) or (H, W, 3) array of "
                                 f"{'/'.join(np.dtype(d).name for d in FRAME_DTYPES)}; got {describe_array(f)}")
            if (f.shape, f.dtype) != (first.shape, first.dtype):
                raise InputError(f"frames[{i}]: {describe_array(f)}, but frames[0] has shape {first.shape}, "
                                 f"dtype {first.dtype}")
        height, width = first.shape[:2]
        image_size("frames", width, height)  # an empty (0-pixel) frame, say
        if camera is not None:
            if not isinstance(camera, Camera):
                raise InputError(f"camera: expected a Camera or None; got {type(camera).__name__}")
            if (camera.height, camera.width) != (height, width):
                raise InputError(f"camera: {camera.width} x {camera.height} px, but the frames are {width} x {height}")
            try:
                check_sensor_like(camera)
            except ValueError as exc:
                raise InputError(f"camera: {exc}") from exc
        if truths is not None:
            if not isinstance(truths, (list, tuple)) or len(truths) != len(frames):
                raise InputError(f"truths: expected a list of {len(frames)} entries, one a frame; got {show(truths)}")
            for i, t in enumerate(truths):
                if not (t is None or isinstance(t, FrameTruth)):
                    raise InputError(f"truths[{i}]: expected a FrameTruth or None; got {show(t)}")
        if camera_height_m is not None:
            camera_height_m = real("camera_height_m (metres, or None)", camera_height_m, lo=0, hi=MAX_CAMERA_HEIGHT_M,
                                   lo_open=True)
        if not isinstance(name, str) or not name.strip():
            raise InputError(f"name: expected a non-empty string; got {show(name)}")
        # The lists are copied (not the frames): a frame or truth the caller changes later is not one checked here.
        self._frames, self._truths = tuple(frames), None if truths is None else tuple(truths)
        self.camera, self.name = camera, name
        self.fps = math.nan if fps is None else check_fps(fps, "ArraySequence")
        self.camera_height_m = math.nan if camera_height_m is None else float(camera_height_m)
        self.meta = {"kind": "arrays", "frames": len(frames), "shape": list(first.shape), "dtype": first.dtype.name}

    def __len__(self) -> int:
        return len(self._frames)

    def _read_frame(self, i: int) -> np.ndarray:
        return self._frames[i].copy()

    def _truth(self, i: int) -> FrameTruth | None:
        return None if self._truths is None else self._truths[i]
