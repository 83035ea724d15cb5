"""One abstraction for every image sequence the tracker reads, and the one entry point to open one.

A :class:`Sequence` yields frames lazily (a 1800-frame 640 x 512 uint16 sequence is 1.2 GB, so no
reader holds more than the frame asked for), an optional :class:`~torch_atr.camera.Camera`, and
optional per-frame ground truth (:class:`FrameTruth`).

:func:`open_sequence` maps a spec string to a reader through a small scheme registry:

    path/to/folder                      our folder format (``folder.py``)
    folder:path/to/folder               the same, spelled out
    sensiac:FILE.arf[,calib=..,fps=..,layout=..]  a SENSIAC ARF with its AGT / bbox_met (``sensiac.py``)
    video:FILE[,calib=..,color=..,fps=..]  a video, image folder or glob (``video.py``)
    synthetic:...                       the scene simulator, once it registers itself

A scheme ``NAME`` not registered yet is looked up as the module ``torch_atr.data.NAME``, which
registers itself with :func:`register_scheme` when imported.
"""

from __future__ import annotations

import abc
import dataclasses
import difflib
import importlib
import logging
import math
import numbers
import operator
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from torch_atr.camera import Camera
from torch_atr.pose import check_sensor_like
from torch_atr.validate import InputError, read_json_object, real, show

logger = logging.getLogger(__name__)

TEXT_FIELDS: frozenset[str] = frozenset({"vehicle", "vehicle_class"})
MAX_CAMERA_HEIGHT_M = 1e4  # a camera height above the ground (Sequence.camera_height_m) is in (0, this] metres


def check_camera_height(where: str, height: Any) -> float:
    """A camera's height above flat ground (``Sequence.camera_height_m``): metres in (0,
    ``MAX_CAMERA_HEIGHT_M``], or NaN where unknown (given as None or NaN). InputError starting with
    ``where`` otherwise (0 or below put the ground at or above the camera)."""
    if height is None or (isinstance(height, numbers.Real) and not isinstance(height, bool) and math.isnan(height)):
        return math.nan
    return real(where, height, lo=0, hi=MAX_CAMERA_HEIGHT_M, lo_open=True)


@dataclass(frozen=True, eq=False)
class FrameTruth:
    """Ground truth of one frame; NaN (or ``""`` for names) where unknown.

    Attributes:
        x, y, z: the target's centre (the centre of its 3D bounding box) in the camera's world
            frame, metres: sensor-centred and ground-levelled (x right, y up, z forward
            horizontally; :mod:`torch_atr.pose`), the frame of the tracker's state. It is the
            sensor frame when the camera's rotation R is the identity.
        heading: direction of travel from +z towards +x in that frame, radians (METHOD.md).
        speed: metres per second.
        theta, phi: view Θ = (θ, φ) of the target, radians (METHOD.md).
        u, v: target centre in pixels (u right, v down).
        u0, v0, u1, v1: bounding box, upper-left (u0, v0) and lower-right (u1, v1) corners, pixels.
        vehicle: vehicle name (e.g. SENSIAC's ``TgtType``); vehicle_class: its class.
        range_m: sensor-to-target range as SENSIAC gives it, metres.
        aspect: the target's clockwise rotation seen from above away from facing the sensor
            (0 = front towards the sensor), radians; equal to θ of METHOD.md's view.
        time_s: time stamp, seconds: POSIX (UTC) in SENSIAC's AGT files; from the first frame in the
            simulator (i / fps).

    Numbers must be real numbers (int, float or numpy scalars; not bool, not str) and are stored
    as float. Equality treats NaN as equal to NaN, so a truth read back from disk equals the one
    written. An all-unknown truth means the same as no truth: :meth:`Sequence.truth` returns None
    for it.
    """

    x: float = math.nan
    y: float = math.nan
    z: float = math.nan
    heading: float = math.nan
    speed: float = math.nan
    theta: float = math.nan
    phi: float = math.nan
    u: float = math.nan
    v: float = math.nan
    u0: float = math.nan
    v0: float = math.nan
    u1: float = math.nan
    v1: float = math.nan
    vehicle: str = ""
    vehicle_class: str = ""
    range_m: float = math.nan
    aspect: float = math.nan
    time_s: float = math.nan

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name in TEXT_FIELDS:
                if not isinstance(value, str):
                    raise ValueError(f"FrameTruth.{f.name}: expected a string; got {value!r}")
            elif isinstance(value, numbers.Real) and not isinstance(value, bool):
                object.__setattr__(self, f.name, float(value))
            else:
                raise ValueError(f"FrameTruth.{f.name}: expected a number; got {value!r}")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, FrameTruth):
            return NotImplemented
        for f in dataclasses.fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if a != b and not (isinstance(a, float) and math.isnan(a) and math.isnan(b)):
                return False
        return True

    __hash__ = None  # NaN-aware equality has no matching hash

    def is_unknown(self) -> bool:
        """True when no field is known (every number NaN, every name empty)."""
        return self == FrameTruth()


TRUTH_FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(FrameTruth))


class Sequence(abc.ABC):
    """A lazily read image sequence.

    Frames are ``(H, W)`` uint16 (IR) or uint8 (grey), or ``(H, W, 3)`` uint8 colour in RGB order;
    an :class:`~torch_atr.data.ArraySequence` may also hold float32 or float64 frames (radiometric
    IR: the segmenter and tracker take them, ``save_sequence``'s image files do not).
    Subclasses set ``name``, ``fps``, ``camera`` and ``meta`` and implement ``__len__`` and
    ``_read_frame``; ``_truth`` defaults to "no ground truth".

    Attributes:
        name: a short name (file or folder stem).
        fps: frames per second; NaN when the source does not say.
        camera: the calibrated camera, or None for an uncalibrated sequence.
        camera_height_m: the camera centre's height above flat ground, metres, in
            (0, ``MAX_CAMERA_HEIGHT_M``], where the source knows it (the simulator does); NaN
            otherwise. With it the tracker's blind initialisation takes the range from the ground
            plane rather than the blob's size.
        meta: source-specific facts (paths found, layouts detected, ...), JSON-ready.
    """

    name: str
    fps: float
    camera: Camera | None
    camera_height_m: float = math.nan
    meta: dict

    @abc.abstractmethod
    def __len__(self) -> int:
        """Number of frames."""

    @abc.abstractmethod
    def _read_frame(self, i: int) -> np.ndarray:
        """Frame ``i`` (already range-checked) as a new array the caller owns."""

    def _truth(self, i: int) -> FrameTruth | None:
        return None

    def _index(self, i) -> int:
        n = len(self)
        try:
            if isinstance(i, (bool, np.bool_)):  # ints to operator.index (np.bool_ before NumPy 2): True read frame 1
                raise TypeError
            k = operator.index(i)
        except TypeError as exc:
            raise TypeError(f"{self.name}: frame index must be an integer; got {i!r}") from exc
        if k < 0:
            k += n
        if not 0 <= k < n:
            raise IndexError(f"{self.name}: frame index {i} out of range for a sequence of {n} frames")
        return k

    def frame(self, i: int) -> np.ndarray:
        """Frame ``i`` (negative counts from the end): (H, W) or (H, W, 3), a fresh array."""
        return self._read_frame(self._index(i))

    def truth(self, i: int) -> FrameTruth | None:
        """Ground truth of frame ``i``, or None where the source has none for it (an all-unknown
        FrameTruth counts as none)."""
        t = self._truth(self._index(i))
        return None if t is None or t.is_unknown() else t

    def __iter__(self) -> Iterator[np.ndarray]:
        for i in range(len(self)):
            yield self._read_frame(i)

    def close(self) -> None:
        """Release open files; the default holds none."""

    def __enter__(self) -> "Sequence":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        calib = "calibrated" if self.camera is not None else "uncalibrated"
        return f"{type(self).__name__}(name={self.name!r}, frames={len(self)}, fps={self.fps}, {calib})"


Opener = Callable[[str], Sequence]
_SCHEMES: dict[str, Opener] = {}
_BUILT_IN_ON_USE = ("synthetic",)  # schemes of modules here that register when first used (the simulator)
_SCHEME_RE = re.compile(r"[a-z][a-z0-9_]+")
SPEC_RE = re.compile(r"([A-Za-z][A-Za-z0-9_]+):(.*)", re.DOTALL)  # "scheme:rest" (absolute_spec splits specs so too)


def register_scheme(name: str, opener: Opener, replace: bool = False) -> None:
    """Make ``open_sequence("NAME:REST")`` call ``opener("REST")``.

    ``name`` is lower case, at least two characters (so a Windows drive letter is never a
    scheme). Registering a taken name with a different opener needs ``replace=True``.
    """
    if not _SCHEME_RE.fullmatch(name):
        raise ValueError(f"Scheme name must match [a-z][a-z0-9_]+; got {name!r}")
    if not callable(opener):
        raise ValueError(f"Scheme {name!r}: opener must be callable; got {type(opener).__name__}")
    if not replace and _SCHEMES.get(name, opener) is not opener:
        raise ValueError(f"Scheme {name!r} is already registered; pass replace=True to replace it")
    _SCHEMES[name] = opener


def registered_schemes() -> tuple[str, ...]:
    """Names of the schemes registered so far, sorted."""
    return tuple(sorted(_SCHEMES))


def open_sequence(spec: str | os.PathLike) -> Sequence:
    """Open the sequence ``spec`` names (see the module docstring for the forms).

    A spec without a ``scheme:`` prefix, or a path object (``pathlib.Path``), is a folder in our
    format. Raises ``InputError`` (a ``ValueError``) for a bad spec, unknown scheme or option and
    for a bad file, ``FileNotFoundError`` for a missing file, each naming it.
    """
    if isinstance(spec, os.PathLike):
        return _SCHEMES["folder"](os.fspath(spec))
    if not isinstance(spec, str) or not spec.strip():
        raise InputError(f"Expected a sequence spec string; got {show(spec)}")
    m = SPEC_RE.fullmatch(spec)
    if m is None:
        scheme, rest = "folder", spec  # FolderSequence expands a ~, as it does after "folder:"
    else:
        scheme, rest = m.group(1).lower(), m.group(2)
    if scheme not in _SCHEMES:
        try:
            importlib.import_module(f"{__package__}.{scheme}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__package__}.{scheme}":
                raise
    if scheme not in _SCHEMES:
        known = sorted(set(registered_schemes()) | set(_BUILT_IN_ON_USE))
        close = difflib.get_close_matches(scheme, known, n=1)
        raise InputError(f"Unknown scheme {scheme!r} in sequence spec {show(spec)}; known schemes: {', '.join(known)}"
                         + (f" (did you mean {close[0]}?)" if close else ""))
    return _SCHEMES[scheme](rest)


def parse_spec_options(spec: str, allowed: tuple[str, ...] | None = None,
                       has_target: bool = True) -> tuple[str, dict[str, str]]:
    """Split ``"TARGET,key=value,..."`` into the target and its options (values stripped).

    ``allowed``: the option names accepted, or None for any. ``has_target=False`` parses
    ``"key=value,..."`` (a blank spec: no options) and returns ``""`` as the target. Raises
    ``InputError`` naming the spec for an empty target, an option without ``=`` (an empty part
    included; after a target, saying that a path cannot hold a comma), a repeated option or one not in
    ``allowed``.
    """
    parts = spec.split(",")
    if has_target:
        target = parts.pop(0).strip()
        if not target:
            raise InputError(f"Sequence spec {show(spec)} names no file")
    else:
        target = ""
        parts = parts if spec.strip() else []
    options: dict[str, str] = {}
    for part in parts:
        key, sep, value = part.partition("=")
        key = key.strip()
        if not sep or not key:
            # A part after the file that names no option: most likely the rest of a path the comma split.
            path = has_target and bool(key) and key not in (allowed or ())
            raise InputError(f"Sequence spec {show(spec)}: expected key=value; got {show(part)}" + (
                ": commas separate a spec's key=value options, so a path with a comma cannot be given in a spec; "
                "rename or link it, or open it in Python with its reader, torch_atr.data.VideoSequence(PATH) or "
                "torch_atr.data.SensiacSequence(PATH)" if path else ""))
        if allowed is not None and key not in allowed:
            raise InputError(f"Sequence spec {show(spec)}: unknown option {show(key)}; "
                             f"allowed: {', '.join(sorted(allowed))}")
        if key in options:
            raise InputError(f"Sequence spec {show(spec)}: option {show(key)} given twice")
        options[key] = value.strip()
    return target, options


def check_fps(fps, source: str) -> float:
    """``fps`` as a float after checking it is a positive finite real number (not a bool);
    ``InputError`` naming ``source``."""
    if isinstance(fps, bool) or not isinstance(fps, numbers.Real) or not (math.isfinite(fps) and fps > 0):
        raise InputError(f"{source}: fps must be a positive number; got {show(fps)}")
    return float(fps)


def parse_fps(value: str, source: str) -> float:
    """A positive finite frame rate from an option string; ``InputError`` naming ``source``."""
    try:
        fps = float(value)
    except ValueError:
        fps = math.nan
    if not (math.isfinite(fps) and fps > 0):
        raise InputError(f"{source}: fps must be a positive number; got {show(value)}")
    return fps


def parse_reader_spec(scheme: str, rest: str, extra: tuple[str, ...] = ()) -> tuple[str, dict, dict[str, str]]:
    """Split the spec of a file reader taking ``camera=`` and ``fps=`` keywords.

    ``rest`` is ``"FILE[,calib=CAMERA.json][,fps=RATE][,OPTION=VALUE...]"`` with OPTION in
    ``extra``. Returns the file, the reader's keyword arguments (``camera``: a Camera or None;
    ``fps``: a float, present only when the spec gives it, so the reader's default applies
    otherwise) and the ``extra`` options given, as strings. Errors name the spec.
    """
    target, options = parse_spec_options(rest, ("calib", "fps") + extra)
    target = os.path.expanduser(target)  # ~ as a shell would: it does not expand one after "video:" or "calib="
    calib = options.pop("calib", None)
    kwargs: dict = {"camera": None if calib is None else load_camera_json(os.path.expanduser(calib))}
    if "fps" in options:
        kwargs["fps"] = parse_fps(options.pop("fps"), f"{scheme}:{rest}")
    return target, kwargs, options


def load_camera_json(path: str | Path) -> Camera:
    """A sequence's :class:`Camera` from a ``Camera.to_dict()`` JSON file; errors name the file (and key).

    Its world frame is the ground-levelled one the tracker works in (x right, y up, z forward;
    README, "Conventions"), so R, the camera's tilt, must be a proper rotation (det +1): a
    reflection is refused here rather than by the tracker after the warm-up. A camera whose optical
    axis points away from the world's forward z (R[2][2] <= 0: looking back, or straight down) is
    logged as a warning: its ranges come out negative.
    """
    path = Path(path)
    d = read_json_object(path, f"Camera calibration file not found: {path}")
    camera = Camera.from_dict(d, source=str(path))
    try:
        check_sensor_like(camera)
    except ValueError as exc:
        raise InputError(f"{path}, key 'R': {exc}; a sequence's R takes the ground-levelled world to the sensor "
                         f"frame (README, \"Conventions\")") from exc
    R = np.array(camera.R.tolist())
    if R[2, 2] <= 0:
        logger.warning("%s: R turns the camera's optical axis %.0f degrees away from the world's forward z; R is "
                       "the camera's tilt (README, \"Conventions\"), and ranges along a backward axis come out "
                       "negative", path, math.degrees(math.acos(np.clip(R[2, 2], -1, 1))))
    return camera
