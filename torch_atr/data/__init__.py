"""Image sequences in: one :class:`Sequence` abstraction and :func:`open_sequence` for every source.

Sources: our folder format (:mod:`~torch_atr.data.folder`), SENSIAC ARF / AGT / bbox_met files
(:mod:`~torch_atr.data.sensiac`), videos and image folders (:mod:`~torch_atr.data.video`), frames
already in memory (:class:`~torch_atr.data.ArraySequence`). More sources plug in through
:func:`register_scheme`.
"""

from torch_atr.data.folder import FolderSequence, save_sequence
from torch_atr.data.memory import ArraySequence
from torch_atr.data.sensiac import (
    BBOX_MET_COLUMNS,
    AgtBlock,
    BboxMetRow,
    SensiacSequence,
    agt_frame_truths,
    read_agt,
    read_arf_header,
    read_bbox_met,
    write_agt,
    write_arf,
    write_bbox_met,
)
from torch_atr.data.sequence import (
    FrameTruth,
    Sequence,
    load_camera_json,
    open_sequence,
    register_scheme,
    registered_schemes,
)
from torch_atr.data.video import VideoSequence

__all__ = [
    "ArraySequence", "BBOX_MET_COLUMNS", "AgtBlock", "BboxMetRow", "FolderSequence", "FrameTruth", "Sequence",
    "SensiacSequence", "VideoSequence", "agt_frame_truths", "load_camera_json", "open_sequence",
    "read_agt", "read_arf_header", "read_bbox_met", "register_scheme", "registered_schemes",
    "save_sequence", "write_agt", "write_arf", "write_bbox_met",
]
