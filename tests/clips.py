"""Simulated sequences seen as a user's files: without their camera, or without target-free frames."""

import math

import numpy as np

from torch_atr.data.sequence import Sequence
from torch_atr.data.synthetic import SyntheticSequence


class Clip(Sequence):
    """A simulated sequence with its frames and truth. ``camera=False``: uncalibrated (no camera,
    no camera height). ``warmup=False``: no target-free ``warmup_frames``, as a video has none."""

    def __init__(self, seq: SyntheticSequence, camera: bool = True, warmup: bool = True):
        self.seq, self.name, self.fps, self.meta = seq, seq.name, seq.fps, {}
        self.camera = seq.camera if camera else None
        self.camera_height_m = seq.camera_height_m if camera else math.nan
        if warmup:
            self.warmup_frames = seq.warmup_frames

    def __len__(self) -> int:
        return len(self.seq)

    def _read_frame(self, i: int) -> np.ndarray:
        return self.seq.frame(i)

    def _truth(self, i: int):
        return self.seq.truth(i)
