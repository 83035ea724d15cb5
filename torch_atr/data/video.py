"""Video files (any codec OpenCV reads) and image folders or glob patterns as sequences.

Frames come out grey uint8 (``color=False``, the default) or RGB uint8 (``color=True``); a
16-bit grey image (an IR frame saved as PNG or TIFF) or video (GRAY16LE, e.g. FFV1) stays uint16
when read grey. Image files
are ordered naturally (``frame2`` before ``frame10``), folder by folder for a glob; hidden files are
not frames. These sources carry no ground truth.
Frame sizes are checked against the bounds of :mod:`torch_atr.validate` before any decoding
(an image file's header, a video's reported size).
"""

from __future__ import annotations

import glob
import logging
import math
import os
import re
from pathlib import Path

import cv2
import numpy as np

from torch_atr.camera import Camera
from torch_atr.data.sequence import Sequence, check_fps, parse_reader_spec, register_scheme
from torch_atr.validate import InputError, image_size, opencv_can_open, read_image, show

logger = logging.getLogger(__name__)

_GRAY16 = "Y1\x00\x10"  # FFmpeg's tag of GRAY16LE (16-bit grey, as lossless IR video is stored: FFV1)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".pnm", ".webp")


def natural_key(name: str) -> list:
    """Sort key that orders embedded numbers by value: ``img2 < img10``. Each run of digits is one
    whole number, as ``ls -v`` reads it (``cam1.2 < cam1.10``), so the decimals of time stamps
    compare right only when they have a fixed width (``t_1.250 < t_1.500``)."""
    # The odd parts are the digit runs (str.isdigit also takes ², which int() refuses).
    return [int(part) if i % 2 else part.lower() for i, part in enumerate(re.split(r"(\d+)", name))]


def _file_order(path: Path) -> tuple[list, str]:
    """Sort key of image files: natural, folder by folder (a glob's matches in several folders keep
    each folder's frames together), then the path itself (``img1`` and ``img01`` in a fixed order)."""
    return [natural_key(part) for part in path.parts], str(path)


def _convert(img: np.ndarray, color: bool, source: str) -> np.ndarray:
    """BGR(A) or grey OpenCV image -> grey (H, W) or RGB (H, W, 3) uint8 (uint16 grey kept)."""
    if img.dtype not in (np.uint8, np.uint16):
        raise InputError(f"{source}: pixel type {img.dtype} is not supported (uint8 or uint16)")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    elif img.ndim != 2 and not (img.ndim == 3 and img.shape[2] == 3):
        raise InputError(f"{source}: image of shape {img.shape} is neither grey nor colour")
    if not color:
        return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)  # colour frames are 8-bit
    return cv2.cvtColor(img, cv2.COLOR_GRAY2RGB if img.ndim == 2 else cv2.COLOR_BGR2RGB)


class VideoSequence(Sequence):
    """A video file, a folder of images, or a glob pattern of images.

    Args:
        path: a video file, an image folder, or a glob pattern such as ``"run/*.png"``.
        camera: the calibrated camera, or None (uncalibrated).
        color: RGB (H, W, 3) uint8 frames instead of grey (H, W).
        fps: frame rate; None = the video's own rate, NaN for images (they carry none).
    Video frames are read by seeking (``CAP_PROP_POS_FRAMES``) unless they follow the last one read.
    OpenCV seeks by timestamp, and in some files (an H.264 MPEG-TS with B-frames, a variable frame
    rate) lands on another frame without a word; a frame whose timestamp after a seek is not its own
    is read again from the start of the video, frame by frame.
    """

    def __init__(self, path: str | os.PathLike, camera: Camera | None = None, color: bool = False,
                 fps: float | None = None):
        self.path = str(path)
        if fps is not None:
            fps = check_fps(fps, self.path)
        self.color = bool(color)
        self.camera = camera
        self._cap, self._raw = None, False
        self._files: list[Path] = []
        p = Path(self.path)
        if p.is_dir():
            self._files = sorted((f for f in p.iterdir() if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES
                                  and not f.name.startswith(".")), key=_file_order)  # not macOS's ._ files
            if not self._files:
                raise FileNotFoundError(f"{p}: no image files ({', '.join(IMAGE_SUFFIXES)})")
            self.name = p.name
        elif not p.exists() and any(c in self.path for c in "*?["):
            self._files = sorted((Path(f) for f in glob.glob(self.path) if Path(f).is_file()), key=_file_order)
            if not self._files:
                raise FileNotFoundError(f"No files match the pattern {self.path!r}")
            self.name = p.parent.name or self.path
        elif p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES:
            raise InputError(f"{p}: one image is not a sequence; give its folder (video:{p.parent}) or a glob "
                             f"(video:{p.parent / ('*' + p.suffix)})")
        elif p.is_file():
            h, w = self._open_video(p)
        else:
            raise FileNotFoundError(f"Video file or image folder not found: {p}")
        if self._files:
            self._n = len(self._files)
            self._first = self._read_image(0)
            h, w = self._first.shape[:2]
            self.fps = math.nan
            self.meta = {"path": self.path, "kind": "images", "color": self.color,
                         "first_file": str(self._files[0]), "last_file": str(self._files[-1])}
        if fps is not None:
            self.fps = fps
        if camera is not None and (camera.height, camera.width) != (h, w):
            self.close()
            raise InputError(f"{self.path}: the camera is {camera.width} x {camera.height} px but the "
                             f"frames are {w} x {h}")
        logger.info("%s: %d frames of %d x %d (%s), fps %s", self.path, self._n, w, h, self.meta["kind"], self.fps)

    def _open_video(self, p: Path) -> tuple[int, int]:
        """Open the video ``p``, set its name, fps, length and meta; return its (height, width)."""
        if not opencv_can_open(p):
            raise InputError(f"{show(str(p))}: the path is not UTF-8 text, and OpenCV's video reader crashes the "
                             f"process (a segmentation fault) on such a path; rename the file")
        cap = cv2.VideoCapture(str(p))
        if not cap.isOpened():
            raise InputError(f"{p}: OpenCV cannot open it as a video")
        self._raw = _pixel_format(cap) == _GRAY16
        if self._raw:  # OpenCV's conversion to 8-bit BGR kept a 16-bit IR stream's top 8 bits: 1900 read as 7
            cap.release()
            cap = _capture(str(p), raw=True)
        try:
            count = cap.get(cv2.CAP_PROP_FRAME_COUNT)
            if not (math.isfinite(count) and count >= 1):
                raise InputError(f"{p}: the video reports no frames")
            w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
            image_size(f"{p}: the video's frame size", w, h)
            n = _readable_frames(cap, int(count), p)
        except BaseException:
            cap.release()
            raise
        rate = cap.get(cv2.CAP_PROP_FPS)
        fourcc = int(cap.get(cv2.CAP_PROP_FOURCC))
        self._cap, self._pos, self._n = cap, -1, n  # -1: the first read seeks to its frame
        self.name = p.stem
        self.fps = rate if 0 < rate < math.inf else math.nan
        self.meta = {"path": self.path, "kind": "video", "color": self.color, "video_fps": rate,
                     "fourcc": "".join(chr((fourcc >> 8 * k) & 0xFF) for k in range(4)).strip("\0")}
        return h, w

    def __len__(self) -> int:
        return self._n

    def _read_image(self, i: int) -> np.ndarray:
        path = self._files[i]
        img = _convert(read_image(path), self.color, str(path))
        if i > 0 and (img.shape != self._first.shape or img.dtype != self._first.dtype):
            raise InputError(f"{path}: image is {img.shape} {img.dtype}; {self._files[0].name} was "
                             f"{self._first.shape} {self._first.dtype}")
        return img

    def _read_frame(self, i: int) -> np.ndarray:
        if self._files:
            return self._read_image(i)
        if self._cap is None:
            raise ValueError(f"{self.path}: the sequence is closed")
        sought = i != self._pos
        if sought:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, i)
        ok, img = self._cap.read()
        if sought and not (ok and self._read_at(i)):  # landed elsewhere, or the read after the seek failed
            ok, img = self._read_from_start(i)
        if not ok:
            self._pos = -1
            raise InputError(f"{self.path}: cannot read frame {i} of {self._n}")
        self._pos = i + 1
        return _convert(img, self.color, f"{self.path} frame {i}")

    def _read_at(self, i: int) -> bool:
        """Whether the frame just read is frame ``i`` by its timestamp (true where the video gives no rate)."""
        rate = self._cap.get(cv2.CAP_PROP_FPS)
        if not 0 < rate < math.inf:
            return True
        return abs(self._cap.get(cv2.CAP_PROP_POS_MSEC) - 1000.0 * i / rate) < 500.0 / rate

    def _read_from_start(self, i: int) -> tuple[bool, np.ndarray | None]:
        """Frame ``i`` from a capture opened afresh, the ``i`` frames before it decoded and dropped."""
        logger.debug("%s: a seek to frame %d landed elsewhere; reading from the start", self.path, i)
        self._cap.release()
        self._cap = _capture(self.path, self._raw)
        for _ in range(i):
            if not self._cap.grab():
                return False, None
        return self._cap.read()

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


def _pixel_format(cap: cv2.VideoCapture) -> str:
    """The decoder's pixel format of an opened video as its four characters (FFmpeg's raw tag)."""
    code = int(cap.get(cv2.CAP_PROP_CODEC_PIXEL_FORMAT))
    return "".join(chr((code >> 8 * k) & 0xFF) for k in range(4))


def _capture(path: str, raw: bool) -> cv2.VideoCapture:
    """A capture of ``path``; ``raw``: without the conversion to 8-bit BGR (a 16-bit grey stream's
    frames come out uint16; OpenCV supports this for GRAY16LE, not for colour formats)."""
    return cv2.VideoCapture(path, cv2.CAP_ANY, [cv2.CAP_PROP_CONVERT_RGB, 0]) if raw else cv2.VideoCapture(path)


def _readable_frames(cap: cv2.VideoCapture, count: int, path: Path) -> int:
    """The frames of an opened video that can be read: ``count``, the header's claim, when its last
    frame reads; else the frames before the first that does not (found by bisection, log₂ count
    seeks), with a warning: a truncated file (a copy cut short, a recording stopped hard) claims
    frames it no longer holds. A video with a frame after the claimed last is refused: its count is
    an estimate (an MPEG program stream's, from its duration), and seeks by frame number in such a
    file land on other frames. The capture's position is left anywhere."""
    def reads(i: int) -> bool:
        cap.set(cv2.CAP_PROP_POS_FRAMES, i)
        return cap.grab()

    if reads(count - 1):
        if cap.grab():
            raise InputError(f"{path}: the video claims {count} frames but holds more (frame {count} reads too): "
                             f"its frame count is an estimate, and OpenCV cannot find its frames by number; "
                             f"convert it to a video with an index (ffmpeg -i IN -c:v ffv1 OUT.mkv) or to images")
        return count
    if not reads(0):
        raise InputError(f"{path}: cannot read its first frame (the video claims {count})")
    good, bad = 0, count - 1
    while bad - good > 1:
        mid = (good + bad) // 2
        good, bad = (mid, bad) if reads(mid) else (good, mid)
    logger.warning("%s: the video claims %d frames but only the first %d can be read (cut short?); those are used",
                   path, count, bad)
    return bad


_TRUE = ("1", "true", "yes", "on")
_FALSE = ("0", "false", "no", "off")


def _open_spec(rest: str) -> VideoSequence:
    target, kwargs, opts = parse_reader_spec("video", rest, ("color",))
    color = opts.get("color", "0").lower()
    if color not in _TRUE + _FALSE:
        raise InputError(f"video:{rest}: color must be one of {'/'.join(_TRUE + _FALSE)}; got {opts['color']!r}")
    return VideoSequence(target, color=color in _TRUE, **kwargs)


register_scheme("video", _open_spec)
