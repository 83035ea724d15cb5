"""Joint tracking and recognition (chapter 5): a particle filter over [x, y, z, h, v] and α.

:class:`Tracker` runs Table 5.1 on tensors: :mod:`~torch_atr.tracking.motion` (eq. 5.1, 5.3),
:mod:`~torch_atr.tracking.observation` (windows and eq. 5.2), :mod:`~torch_atr.tracking.appearance`
(Methods I–IV), :mod:`~torch_atr.tracking.resampling`, :mod:`~torch_atr.tracking.estimates` and
:mod:`~torch_atr.tracking.initialise` (truth or blind). :class:`BlobTracker` tracks view and
identity on the blob of an uncalibrated sequence (no camera).
"""

from torch_atr.tracking.appearance import METHODS, ShapeAppearance
from torch_atr.tracking.blob import BlobTracker
from torch_atr.tracking.filter import AdaptConfig, FilterConfig, RedetectConfig, Tracker, TrackerConfig, TrackResult
from torch_atr.tracking.initialise import InitConfig
from torch_atr.tracking.motion import MotionConfig, predict
from torch_atr.tracking.resampling import SCHEMES, effective_sample_size, resample

__all__ = [
    "AdaptConfig", "BlobTracker", "FilterConfig", "InitConfig", "METHODS", "MotionConfig", "RedetectConfig", "SCHEMES",
    "ShapeAppearance",
    "TrackResult", "Tracker", "TrackerConfig", "effective_sample_size", "predict", "resample",
]
