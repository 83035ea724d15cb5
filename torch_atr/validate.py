"""The one validation layer for untrusted input: files, specs, configs and checkpoints from outside.

Every reader and config checks what it reads with these helpers, so a bad input fails the same
way everywhere: an :class:`InputError` (a ``ValueError``) whose message starts with the file
(and line or key) and says what was expected and what arrived. Numbers must be finite real
numbers (not bools, not strings); integers must be integers; sizes stay under the bounds below,
so no input can make a reader allocate more than a bounded amount of memory or loop for long.

Bounds (far above what the package meets: SENSIAC frames are 640 x 512, configs a few hundred
bytes, a SENSIAC ``.agt`` about a megabyte):

    MAX_IMAGE_SIDE    16384 px   one side of a frame or image
    MAX_IMAGE_PIXELS  2**26      pixels of a frame (128 MiB at 16 bits)
    MAX_TEXT_BYTES    64 MiB     a text file (.agt, .bbox_met, truth.csv)
    MAX_JSON_BYTES    16 MiB     a JSON file (meta.json, camera.json)
    MAX_MESH_BYTES    256 MiB    a mesh file (OBJ, STL, PLY, GLB, ...; reading one costs ~15 bytes a byte)
"""

from __future__ import annotations

import json
import math
import numbers
import os
import re
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from PIL import Image

MAX_IMAGE_SIDE = 16384
MAX_IMAGE_PIXELS = 2 ** 26
MAX_TEXT_BYTES = 64 * 2 ** 20
MAX_JSON_BYTES = 16 * 2 ** 20
MAX_MESH_BYTES = 256 * 2 ** 20
_WHOLE = 240  # characters of a value, key or override a message quotes whole
_HEAD = 40  # characters quoted of a longer one, before '…' and its length


class InputError(ValueError):
    """A file, spec, config or checkpoint from outside that fails validation.

    The message names the input (file and line or key) and says what was expected.
    """


def cut(text: str) -> str:
    """``text`` (a value, key or override as a message quotes it) whole up to 240 characters, a longer
    one as its first 40, '…' and its length: a huge override (``seed=`` and 100 000 digits) still makes
    a short one-line message."""
    return text if len(text) <= _WHOLE else f"{text[:_HEAD]}… ({len(text)} characters)"


def show(value: Any) -> str:
    """``repr(value)`` for an error message, shortened by :func:`cut`; an integer too long for ``repr``
    (Python's limit of 4300 digits) as its number of digits."""
    try:
        text = repr(value)
    except ValueError:
        if not isinstance(value, int):
            raise
        return f"an integer of about {int(abs(value).bit_length() * math.log10(2)) + 1} digits"
    return cut(text)


def _bounds(lo: float | None, hi: float | None, lo_open: bool = False) -> str:
    """" in [lo, hi]", " >= lo", " <= hi" or "" for an error message; lo excluded when ``lo_open``."""
    def show_bound(x: float) -> str:
        return str(x) if isinstance(x, int) else f"{x:g}"

    if lo is not None and hi is not None:
        return f" in {'(' if lo_open else '['}{show_bound(lo)}, {show_bound(hi)}]"
    if lo is not None:
        return f" {'>' if lo_open else '>='} {show_bound(lo)}"
    return "" if hi is None else f" <= {show_bound(hi)}"


def real(where: str, value: Any, lo: float | None = None, hi: float | None = None,
         lo_open: bool = False) -> float:
    """``value`` as a float after checking it is a finite real number in [lo, hi] (lo excluded
    when ``lo_open``); bools and strings are not numbers. ``InputError`` starting with ``where``."""
    expected = "a finite number" + _bounds(lo, hi, lo_open)
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputError(f"{where}: expected {expected}; got {show(value)}")
    try:
        x = float(value)
    except OverflowError:
        x = math.inf
    if not math.isfinite(x) or (lo is not None and (x <= lo if lo_open else x < lo)) or (hi is not None and x > hi):
        raise InputError(f"{where}: expected {expected}; got {show(value)}")
    return x


def integer(where: str, value: Any, lo: int | None = None, hi: int | None = None) -> int:
    """``value`` as an int after checking it is an integer (not a bool, not a float) in [lo, hi]."""
    expected = "an integer" + _bounds(lo, hi)
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InputError(f"{where}: expected {expected}; got {show(value)}")
    n = int(value)
    if (lo is not None and n < lo) or (hi is not None and n > hi):
        raise InputError(f"{where}: expected {expected}; got {show(value)}")
    return n


def parse_real(where: str, text: str) -> float:
    """A finite float from a text cell (``"1.5"``, ``" -3e2 "``); ``inf``, ``nan`` and ``1e400``
    are refused. ``InputError`` starting with ``where``."""
    try:
        x = float(text)
    except ValueError:
        raise InputError(f"{where}: expected a number; got {show(text)}") from None
    if not math.isfinite(x):
        raise InputError(f"{where}: expected a finite number; got {show(text)}")
    return x


def image_size(where: str, width: Any, height: Any) -> tuple[int, int]:
    """(width, height) after checking both are integers in [1, MAX_IMAGE_SIDE] and their product is
    at most MAX_IMAGE_PIXELS."""
    w = integer(f"{where}: width", width, 1, MAX_IMAGE_SIDE)
    h = integer(f"{where}: height", height, 1, MAX_IMAGE_SIDE)
    if w * h > MAX_IMAGE_PIXELS:
        raise InputError(f"{where}: {w} x {h} = {w * h} pixels; expected at most {MAX_IMAGE_PIXELS}")
    return w, h


def image_file_size(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) of an image file read from its header, without decoding the pixels (Pillow
    identifies the format), checked as :func:`image_size`; InputError naming the file for a file
    that is not an image or too large. Call it before decoding a file from outside."""
    path = Path(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # our bound is tighter
            with Image.open(path) as img:
                width, height = img.size
    except Image.DecompressionBombError as exc:
        raise InputError(f"{path}: image too large ({exc}); expected at most {MAX_IMAGE_PIXELS} pixels") from None
    except Exception as exc:  # Pillow's parsers raise many kinds on corrupt headers
        raise InputError(f"{path}: cannot be read as an image ({type(exc).__name__}: {show(str(exc))})") from None
    return image_size(str(path), width, height)


def opencv_can_open(path: str | os.PathLike) -> bool:
    """Whether OpenCV's file readers and writers take ``path``: they crash the process (a segmentation
    fault) on one that is not UTF-8 text (bytes of a Latin-1 name, which Python keeps as surrogates)."""
    try:
        os.fspath(path).encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


_SCAN_END = re.compile(rb"\xff[^\x00\xd0-\xd7\xff]")  # in scan data FF 00 is a stuffed FF, FF D0-D7 a restart


def _jpeg_cut_short(data: bytes) -> bool:
    """Whether a JPEG (``data`` starts with SOI) ends before its EOI marker: its segments walked by their
    lengths and its scans to the marker after them. Bytes after EOI (a camera's trailer) are not looked
    at; a byte where a marker belongs is left to the decoder (False)."""
    i = 2
    while i + 2 <= len(data):
        if data[i] != 0xFF:
            return False
        marker = data[i + 1]
        if marker == 0xFF:  # a fill byte before a marker
            i += 1
        elif marker == 0xD9:
            return False
        elif 0xD0 <= marker <= 0xD7 or marker == 0x01:  # markers without a length
            i += 2
        else:
            i += 2 + int.from_bytes(data[i + 2:i + 4], "big")
            if marker == 0xDA:  # entropy-coded data runs to the next marker
                end = _SCAN_END.search(data, i)
                if end is None:
                    return True
                i = end.start()
    return True


def read_image(path: str | os.PathLike, expect_size: tuple[int, int] | None = None,
               expected_by: str = "") -> np.ndarray:
    """An image file's pixels as stored (OpenCV's ``IMREAD_UNCHANGED``: (H, W) grey or (H, W, C)
    BGR, 8 or 16 bits), its header checked by :func:`image_file_size` before decoding, and against
    ``expect_size`` (width, height) if given (``expected_by`` names what expects it); InputError
    naming the file for one that is too large, of another size or cannot be decoded, and for a JPEG
    cut short (OpenCV fills its missing rows with grey, saying so only on stderr).

    The bytes are read by Python and decoded from memory: ``cv2.imread`` crashes the process on a
    path that is not UTF-8 text (a Latin-1 name from an old archive)."""
    width, height = image_file_size(path)
    if expect_size is not None and (width, height) != tuple(expect_size):
        raise InputError(f"{path}: image is {width} x {height} px; {expected_by} says {expect_size[0]} x "
                         f"{expect_size[1]}")
    data = Path(path).read_bytes()
    if data[:2] == b"\xff\xd8" and _jpeg_cut_short(data):
        raise InputError(f"{path}: the JPEG's data ends before its end-of-image marker: a file cut short")
    try:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:
        raise InputError(f"{path}: cannot be decoded ({' '.join(str(exc).split())})") from None
    if img is None:
        raise InputError(f"{path}: cannot be read as an image")
    return img


def rotation(where: str, value: Any, atol: float = 1e-6) -> list[list[float]]:
    """A 3 x 3 nested list of finite numbers whose rows are orthonormal (R Rᵀ = I within
    ``atol``, so det R = ±1: proper rotations and the left-handed world frames of camera.py)."""
    if not isinstance(value, (list, tuple)) or len(value) != 3 or not all(
            isinstance(row, (list, tuple)) and len(row) == 3 for row in value):
        raise InputError(f"{where}: expected a 3 x 3 matrix (a list of three rows of three numbers); "
                         f"got {show(value)}")
    R = [[real(f"{where}[{i}][{j}]", x) for j, x in enumerate(row)] for i, row in enumerate(value)]
    worst = max(abs(sum(R[i][k] * R[j][k] for k in range(3)) - (i == j)) for i in range(3) for j in range(3))
    if worst > atol:
        raise InputError(f"{where}: expected a rotation (orthonormal rows, R Rᵀ = I); R Rᵀ differs from I "
                         f"by {worst:.3g}")
    return R


def vector(where: str, value: Any, length: int) -> list[float]:
    """A list of ``length`` finite numbers."""
    if not isinstance(value, (list, tuple)) or len(value) != length:
        raise InputError(f"{where}: expected a list of {length} numbers; got {show(value)}")
    return [real(f"{where}[{i}]", x) for i, x in enumerate(value)]


def read_text(path: str | os.PathLike, max_bytes: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of ``path`` (a leading byte-order mark dropped).

    ``path`` may be a named pipe (``--config <(...)``). Raises FileNotFoundError naming a missing file,
    and InputError naming the file for a folder or a device, a file over ``max_bytes`` or bytes that
    are not UTF-8 (with the line and byte offset).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"File not found: {path}")
    pipe = path.is_fifo()  # a shell's <(...) or /dev/stdin from a pipe: its size is unknown until read
    if not (path.is_file() or pipe):
        raise InputError(f"{path}: expected a file; it is a folder or a device")
    with open(path, "rb") as fh:  # read(n) sets n bytes aside first: 64 MiB for every small file
        if pipe:
            chunks, size = [], 0
            while size <= max_bytes and (chunk := fh.read(1 << 16)):
                chunks.append(chunk)
                size += len(chunk)
            data = b"".join(chunks)
        else:
            data = fh.read(min(os.fstat(fh.fileno()).st_size, max_bytes) + 1)
    if len(data) > max_bytes:
        raise InputError(f"{path}: larger than {max_bytes} bytes; expected a small text file")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputError(f"{path}, line {line}: not UTF-8 text (byte 0x{data[exc.start]:02x} at byte offset "
                         f"{exc.start})") from None


def _no_constant(name: str) -> float:
    raise ValueError(f"{name} is not a finite number")


def _finite_float(text: str) -> float:
    x = float(text)
    if not math.isfinite(x):
        raise ValueError(f"{text} is not a finite number")
    return x


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict:
    d: dict = {}
    for key, value in pairs:
        if key in d:
            raise ValueError(f"key {show(key)} appears twice in one object, so one of its values would be dropped")
        d[key] = value
    return d


def read_json_object(path: str | os.PathLike, missing: str, max_bytes: int = MAX_JSON_BYTES) -> dict:
    """The JSON object in ``path``, with only finite numbers (``NaN``, ``Infinity`` and ``1e400``
    are refused) and no key twice in one object (Python's ``json`` keeps the last without a word).

    A missing file raises FileNotFoundError(``missing``); anything else wrong an InputError naming
    the file (and the line and column of a syntax error).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(missing)
    text = read_text(path, max_bytes)
    try:
        d = json.loads(text, parse_constant=_no_constant, parse_float=_finite_float, object_pairs_hook=_unique_keys)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}, line {exc.lineno}, column {exc.colno}: not valid JSON ({exc.msg})") from None
    except RecursionError:
        raise InputError(f"{path}: JSON nested too deeply") from None
    except ValueError as exc:  # a non-finite number, an integer of more than 4300 digits, a key twice
        raise InputError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(d, dict):
        raise InputError(f"{path}: expected a JSON object; got {type(d).__name__}")
    return d
