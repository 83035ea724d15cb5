"""Readers (and writers, for tests and conversion) of the SENSIAC / DSIAC ATR database files.

``.arf`` video. A 32-byte big-endian header of eight uint32 (magic 0xBBBBBAAD, version, rows,
cols, image type, frame count, data offset, subheader flags), then per frame rows x cols
big-endian uint16 pixels (image types 1, 2 and 5: ten_bit, twelve_bit, short_word). Some files
follow each frame with a 40-byte trailer (in public readers: ten uint32 x, y, azimuth,
elevation, year, day, hour, min, sec, ms), some do not; the
layout, ``"contiguous"`` or ``"trailer40"``, is recorded in ``meta["arf_layout"]``. The file
size decides it when it fits one layout only, unless the header's subheader flags declare
per-frame data (bit 0x10, "frame data" in public readers) and the size has no room for it: that
contradiction is refused. A size that fits the trailers also fits contiguous frames followed by
40 bytes a frame of something else; that file is read as "trailer40" only when the header
declares it, when it has a single frame, or when every would-be trailer holds a valid time
stamp; otherwise it is refused, naming both readings. ``layout=`` (the reader's argument, the
spec's option) decides explicitly. Frames are at most 16384 px a side and 2**26 pixels
(:mod:`torch_atr.validate`), memory-mapped, never read ahead.

``.agt`` ground truth ("ARF Ground Truth", a small keyword language). A bare word followed by
``{`` opens a block, ``}`` closes it; every other line is ``Key value...`` with quoted strings
or numbers, e.g. ``TgtType "BTR70"``, ``Range "1000.5"``, ``PixLoc 320 256``,
``Time year julian_day hour min sec ms``. A value may also sit on the line after its key, and
several keys may share a line (the grammar takes line breaks as white space). The frames are the
``TgtUpd`` blocks of ``Agt -> TgtSect``, in order, or, when each carries a ``Keyword "Frame# N"``
line (1-based), at the frames they name. A frame's target is its first ``Tgt`` with a
``TgtType`` (the specification gives one to targets scored for ATR only). ``Aspect`` is in
degrees, 0 when the target faces the sensor, clockwise seen from above; it is kept in
``FrameTruth.aspect`` (in radians), which equals θ of METHOD.md's view Θ. The elevation φ needs
the sensor's calibration and is left unknown. ``TgtType`` names the vehicle; its class comes
from :data:`SENSIAC_CLASSES`, the thesis's grouping of SENSIAC's targets (thesis 1: tanks T72,
2S3, ZSU23; APCs BTR70, BRDM2, BMP2; the Isuzu SUV; the Ford pickup) and of our SENSIAC-like
test split, matched on letters and digits alone ("BMP2", "bmp_2" and "BMP-2" alike); any other
vehicle's class is left unknown.

``.bbox_met`` per-frame bounding-box metadata, a comma-separated file of 18 columns and no
header. The only public loader we found (a DSIAC tool on GitHub) names the first eleven
columns: site, ?, ?, sensor, scenario, frame (1-based), ply_id, ?, ?, upper-left x, upper-left
y; and it takes the box as symmetric about the AGT ``PixLoc`` (width = 2 (PixLoc - upper
left)). We follow it: ``BBOX_MET_COLUMNS`` names those columns, ``unknown_K`` the others, which
are kept verbatim; the lower-right corner is 2 PixLoc - upper-left when the AGT gives PixLoc.

Companion files are found by stem beside the ARF, or in the DSIAC layout ``../agt/STEM.agt``
and ``../metric/STEM.bbox_met``; each is optional.
"""

from __future__ import annotations

import calendar
import csv
import dataclasses
import io
import logging
import math
import os
import re
import struct
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Iterable

import numpy as np

from torch_atr.camera import Camera
from torch_atr.data.sequence import FrameTruth, Sequence, check_fps, parse_reader_spec, register_scheme
from torch_atr.io import atomic_path, atomic_write_text
from torch_atr.validate import InputError, image_size, parse_real, read_text, show

logger = logging.getLogger(__name__)

ARF_MAGIC = 0xBBBBBAAD
ARF_HEADER = struct.Struct(">8I")
ARF_TRAILER_BYTES = 40
ARF_VERSION = 2
ARF_IMAGE_TYPE_U16 = 5  # "short_word" in public ARF readers
# The image types stored as one 16-bit word a pixel: "ten_bit", "twelve_bit" and "short_word" in the
# public Python ARF reader's type map (type 0 is eight_bit, 6 and up 32- and 64-bit words).
ARF_WORD_TYPES = {1: "ten_bit", 2: "twelve_bit", ARF_IMAGE_TYPE_U16: "short_word"}
ARF_FLAG_FRAMEDATA = 0x10  # subheader flag bit 4: per-frame data (the 40-byte trailers) follows each frame
ARF_LAYOUTS = ("contiguous", "trailer40")
SENSIAC_FPS = 30.0  # thesis ch. 6.2; the ARF header carries no frame rate


@dataclass(frozen=True)
class ArfHeader:
    """The eight header words of an ARF file."""

    magic: int
    version: int
    rows: int
    cols: int
    image_type: int
    frames: int
    offset: int
    flags: int

    @property
    def frame_bytes(self) -> int:
        return self.rows * self.cols * 2


def read_arf_header(path: str | os.PathLike, layout: str | None = None) -> tuple[ArfHeader, str]:
    """Read and check an ARF header; return it and the layout (``"contiguous"``/``"trailer40"``).

    ``layout`` None decides from the size and the header (module docstring); a layout given is
    used if the file holds all its frames (bytes beyond them are ignored with a warning).
    Raises ``InputError`` naming the file and byte offset for a bad magic, an image type other
    than 16-bit, zero or too many rows, cols or frames, a truncated file, or a size that matches
    neither layout, contradicts the header or fits both.
    """
    path = Path(path)
    if layout is not None and layout not in ARF_LAYOUTS:
        raise InputError(f"{path}: layout must be one of {', '.join(ARF_LAYOUTS)}; got {show(layout)}")
    size = path.stat().st_size
    with open(path, "rb") as fh:
        raw = fh.read(ARF_HEADER.size)
    if len(raw) < ARF_HEADER.size:
        raise InputError(f"{path}: truncated ARF header: the file ends at byte offset {size}, "
                         f"inside the {ARF_HEADER.size}-byte header")
    h = ArfHeader(*ARF_HEADER.unpack(raw))
    if h.magic != ARF_MAGIC:
        raise InputError(f"{path}: bad ARF magic 0x{h.magic:08X} at byte offset 0; expected 0x{ARF_MAGIC:08X}")
    if h.image_type not in ARF_WORD_TYPES:
        raise InputError(f"{path}: ARF image type {h.image_type} (byte offset 16) is not supported; this reader "
                         f"reads types {', '.join(f'{k} ({v})' for k, v in ARF_WORD_TYPES.items())}, 16-bit pixels")
    if h.rows == 0 or h.cols == 0:
        raise InputError(f"{path}: ARF header gives rows={h.rows}, cols={h.cols} (byte offsets 8, 12); "
                         f"a frame needs at least one pixel")
    image_size(f"{path}: ARF header (rows, cols at byte offsets 8, 12)", h.cols, h.rows)
    if h.frames == 0:
        raise InputError(f"{path}: ARF header gives a frame count of 0 (byte offset 20)")
    if h.offset < ARF_HEADER.size:
        raise InputError(f"{path}: ARF data offset {h.offset} (byte offset 24) points inside the "
                         f"{ARF_HEADER.size}-byte header")
    fb = h.frame_bytes
    need = {"contiguous": h.offset + h.frames * fb, "trailer40": h.offset + h.frames * (fb + ARF_TRAILER_BYTES)}
    declared = bool(h.flags & ARF_FLAG_FRAMEDATA)
    if layout is not None:
        stride = fb + (ARF_TRAILER_BYTES if layout == "trailer40" else 0)
        if size < need[layout]:
            _truncated(path, h, stride, size)
        if size > need[layout]:
            logger.warning("%s: layout %s given; ignoring the %d bytes after frame %d", path, layout,
                           size - need[layout], h.frames - 1)
        return h, layout
    hint = "open it with layout=contiguous or layout=trailer40 (spec: sensiac:FILE.arf,layout=...) if you know which"
    if size == need["contiguous"]:
        if declared:
            raise InputError(f"{path}: the header's flags 0x{h.flags:X} (byte offset 28) declare per-frame data "
                             f"(bit 0x10), but the size, {size} bytes, has room for {h.frames} contiguous frames "
                             f"only; {hint}")
        return h, "contiguous"
    if size == need["trailer40"]:
        if declared or h.frames == 1 or _trailers_hold_times(path, h):
            return h, "trailer40"
        raise InputError(f"{path}: ARF size {size} bytes fits two layouts: {h.frames} frames each followed by a "
                         f"{ARF_TRAILER_BYTES}-byte trailer, or {h.frames} contiguous frames followed by "
                         f"{h.frames * ARF_TRAILER_BYTES} other bytes; the header's flags 0x{h.flags:X} do not "
                         f"declare per-frame data (bit 0x10) and the would-be trailers hold no valid time stamps; "
                         f"{hint}")
    if size < need["contiguous"]:
        _truncated(path, h, fb, size)
    data = size - h.offset
    strides = (("contiguous", fb), ("trailer40", fb + ARF_TRAILER_BYTES))
    whole = [f"{data // stride} {name} frames" for name, stride in strides if data % stride == 0]
    count = (f"; its data holds exactly {' or '.join(whole)}, not the header's {h.frames} (byte offset 20)"
             if whole else "")
    raise InputError(f"{path}: ARF size {size} bytes matches neither layout: {need['contiguous']} bytes "
                     f"without per-frame trailers, {need['trailer40']} bytes with {ARF_TRAILER_BYTES}-byte "
                     f"trailers{count}; {hint}")


def _truncated(path: Path, h: ArfHeader, stride: int, size: int) -> None:
    """Raise the InputError of a file too short for the header's frames at ``stride`` bytes each."""
    k = max(0, (size - h.offset) // stride)
    what = f"{stride} bytes with its trailer" if stride != h.frame_bytes else f"{stride} bytes"
    raise InputError(f"{path}: truncated ARF: frame {k} of {h.frames} starts at byte offset "
                     f"{h.offset + k * stride} and needs {what}, but the file ends at byte offset {size}")


def _trailers_hold_times(path: Path, h: ArfHeader) -> bool:
    """True when every 40-byte trailer of a "trailer40" reading holds a valid time (uint32 words
    5-10: year 1970-2100, day of the year, hour, minute, second, millisecond)."""
    stride = h.frame_bytes + ARF_TRAILER_BYTES
    mm = np.memmap(path, dtype=np.uint8, mode="r", offset=h.offset, shape=(h.frames, stride))
    words = np.ascontiguousarray(mm[:, h.frame_bytes + 16:stride]).view(">u4").astype(np.int64)  # (frames, 6)
    del mm
    year, day, hour, minute, sec, ms = words.T
    return bool(((1970 <= year) & (year <= 2100) & (1 <= day) & (day <= 366) & (hour < 24) & (minute < 60)
                 & (sec < 61) & (ms < 1000)).all())


def write_arf(path: str | os.PathLike, frames: Iterable[np.ndarray], gap: bool = False) -> int:
    """Write (H, W) uint16 frames as an ARF file; return the frame count.

    ``frames``: an (N, H, W) uint16 array or any iterable of (H, W) uint16 arrays (a Sequence
    works). ``gap=True`` follows each frame with a 40-byte trailer of zeros and sets the header's
    flag 0x10 that declares it. The header says version 2, image type 5 (16-bit), data offset 32.
    Written atomically.
    """
    path = Path(path)
    n, shape = 0, None
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(bytes(ARF_HEADER.size))
        for img in frames:
            if not isinstance(img, np.ndarray) or img.ndim != 2 or img.dtype != np.uint16:
                got = f"{img.shape} {img.dtype}" if isinstance(img, np.ndarray) else type(img).__name__
                raise ValueError(f"{path}: frame {n}: expected an (H, W) uint16 array; got {got}")
            if shape is not None and img.shape != shape:
                raise ValueError(f"{path}: frame {n} is {img.shape}; frame 0 was {shape}")
            shape = img.shape
            fh.write(img.astype(">u2", copy=False).tobytes())
            if gap:
                fh.write(bytes(ARF_TRAILER_BYTES))
            n += 1
        if n == 0:
            raise ValueError(f"{path}: no frames to write; an ARF needs at least one")
        fh.seek(0)
        fh.write(ARF_HEADER.pack(ARF_MAGIC, ARF_VERSION, shape[0], shape[1], ARF_IMAGE_TYPE_U16, n,
                                 ARF_HEADER.size, ARF_FLAG_FRAMEDATA if gap else 0))
    return n


# --------------------------------------------------------------------------------------- AGT

@dataclass
class AgtAttr:
    """One ``Key value...`` line: the values as written (quotes removed) and its line number."""

    key: str
    values: tuple[str, ...]
    line: int


@dataclass
class AgtBlock:
    """One ``Name { ... }`` block: its attributes and sub-blocks in file order (unknown keys kept)."""

    name: str
    line: int
    attrs: list[AgtAttr] = field(default_factory=list)
    blocks: list["AgtBlock"] = field(default_factory=list)

    def find(self, name: str) -> list["AgtBlock"]:
        """Sub-blocks called ``name``, in order."""
        return [b for b in self.blocks if b.name == name]

    def attr(self, key: str) -> AgtAttr | None:
        """The first attribute called ``key``, or None."""
        return next((a for a in self.attrs if a.key == key), None)


_IDENT_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_#]*")
_AGT_TOKEN_RE = re.compile(r'"[^"]*"|"|[{}]|[^\s{}"]+')


def _agt_tokens(text: str, source: str) -> list[tuple[str, str, int, bool]]:
    """(kind, text, line, first_on_line); kind is ``{``, ``}``, ``str`` (quoted) or ``word``."""
    tokens = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        for j, m in enumerate(_AGT_TOKEN_RE.finditer(line)):
            tok = m.group()
            if tok == '"':
                raise InputError(f"{source}, line {line_no}: unterminated string")
            kind = tok if tok in "{}" else "str" if tok.startswith('"') else "word"
            tokens.append((kind, tok[1:-1] if kind == "str" else tok, line_no, j == 0))
    return tokens


# The specification's keywords (its lex source) and AGTJ's Keyword and PixBox. The grammar takes
# line breaks as white space, so one of these ends the values before it: ``Tgt { TgtType "T72"
# PixLoc 10 20 }`` holds two attributes.
AGT_KEYWORDS = frozenset((
    "Agt TgtSect TgtUpd Tgt TgtAbs TgtSenRel SenSect SenUpd PrjSect Comment Keyword PixRange Aspect Azimuth "
    "Elevation Fov LatLong Name Obscuration PlyId Pitch PixLoc PixBox Range Roll Scenario Site Stake TgtType "
    "Time Utm").split())


def _opens_value(token: tuple[str, str, int, bool]) -> bool:
    kind, tok, _, _ = token
    return kind == "str" or (kind == "word" and not _IDENT_RE.fullmatch(tok))


def _is_value(tokens: list[tuple[str, str, int, bool]], j: int, line: int) -> bool:
    """Whether token j, on ``line``, is a value: a string or word that is not a keyword and not
    the name of a block (a word followed by ``{``)."""
    kind, tok, tok_line, _ = tokens[j]
    if tok_line != line or kind not in ("str", "word"):
        return False
    return kind == "str" or not (tok in AGT_KEYWORDS or (j + 1 < len(tokens) and tokens[j + 1][0] == "{"))


def parse_agt(text: str, source: str = "<agt>") -> AgtBlock:
    """Parse AGT text into its ``Agt`` block; ``InputError`` naming ``source`` and the line."""
    tokens = _agt_tokens(text, source)
    root = AgtBlock("", 0)
    stack = [root]
    i = 0
    while i < len(tokens):
        kind, tok, line, _ = tokens[i]
        if kind == "}":
            if len(stack) == 1:
                raise InputError(f"{source}, line {line}: '}}' closes no open block")
            stack.pop()
            i += 1
            continue
        if kind == "{":
            raise InputError(f"{source}, line {line}: '{{' opens a block with no name")
        if kind == "str" or not _IDENT_RE.fullmatch(tok):
            raise InputError(f"{source}, line {line}: value {show(tok)} has no keyword before it")
        if i + 1 < len(tokens) and tokens[i + 1][0] == "{":
            block = AgtBlock(tok, line)
            stack[-1].blocks.append(block)
            stack.append(block)
            i += 2
            continue
        values, j = [], i + 1
        while j < len(tokens) and _is_value(tokens, j, line):
            values.append(tokens[j][1])
            j += 1
        # A key alone on its line takes its values from the next line if that opens with a
        # quoted string or a number (the layout of the 1999 spec's examples).
        if not values and j < len(tokens) and tokens[j][3] and _opens_value(tokens[j]):
            cont = tokens[j][2]
            while j < len(tokens) and _is_value(tokens, j, cont):
                values.append(tokens[j][1])
                j += 1
        if stack[-1] is root:
            raise InputError(f"{source}, line {line}: attribute {show(tok)} outside any block")
        stack[-1].attrs.append(AgtAttr(tok, tuple(values), line))
        i = j
    if len(stack) > 1:
        last = tokens[-1][2]
        raise InputError(f"{source}, line {stack[-1].line}: block {show(stack[-1].name)} opened here is "
                         f"never closed (the file ends at line {last})")
    agts = root.find("Agt")
    others = [b for b in root.blocks if b.name != "Agt"]
    if others:
        raise InputError(f"{source}, line {others[0].line}: top-level block {show(others[0].name)}; "
                         f"expected a single 'Agt' block")
    if not agts:
        raise InputError(f"{source}: no 'Agt' block")
    if len(agts) > 1:
        raise InputError(f"{source}, line {agts[1].line}: a second 'Agt' block; expected exactly one")
    return agts[0]


def read_agt(path: str | os.PathLike) -> AgtBlock:
    """Parse an ``.agt`` file (UTF-8, at most 64 MiB) into its ``Agt`` block (errors name the file and line)."""
    path = Path(path)
    return parse_agt(read_text(path), source=str(path))


def _numbers(attr: AgtAttr, count: int, source: str) -> list[float]:
    if len(attr.values) != count:
        raise InputError(f"{source}, line {attr.line}: {attr.key} expects {count} number(s); "
                         f"got {len(attr.values)}: {' '.join(attr.values) or '(none)'}")
    return [parse_real(f"{source}, line {attr.line}: {attr.key}", v) for v in attr.values]


def _agt_time(attr: AgtAttr, source: str) -> float:
    """``Time year julian_day hour min sec ms`` -> POSIX seconds, taking the time as UTC."""
    nums = _numbers(attr, 6, source)
    if any(not x.is_integer() for x in nums):
        raise InputError(f"{source}, line {attr.line}: Time expects six integers; got {' '.join(attr.values)}")
    year, day, hour, minute, sec, ms = (int(x) for x in nums)
    invalid = InputError(f"{source}, line {attr.line}: Time {' '.join(attr.values)} is not a valid "
                         f"year, julian day, hour, min, sec, ms")
    if not (1 <= year <= 9999 and 1 <= day <= 365 + calendar.isleap(year) and 0 <= hour < 24 and 0 <= minute < 60
            and 0 <= sec < 61 and 0 <= ms < 1000):
        raise invalid
    try:  # a leap second at the very end of 9999 is past the last datetime
        t = datetime(year, 1, 1, tzinfo=timezone.utc) + timedelta(days=day - 1, hours=hour, minutes=minute,
                                                                    seconds=sec, milliseconds=ms)
    except OverflowError:
        raise invalid from None
    return t.timestamp()


SENSIAC_CLASSES = {  # TgtType, lower case, letters and digits only -> class (module docstring)
    "t72": "tank", "2s3": "tank", "2s3akatsiya": "tank", "zsu23": "tank", "zsu234": "tank",
    "btr70": "apc", "brdm2": "apc", "bmp2": "apc",
    "pickup": "pickup", "fordpickup": "pickup", "fordf150": "pickup",
    "suv": "suv", "isuzusuv": "suv", "isuzurodeo": "suv",
}


def vehicle_class(vehicle: str) -> str:
    """The class of a SENSIAC target type (:data:`SENSIAC_CLASSES`), or "" for another vehicle."""
    return SENSIAC_CLASSES.get(re.sub(r"[^a-z0-9]", "", vehicle.lower()), "")


_FRAME_NUMBER_RE = re.compile(r"\s*Frame#\s*(\d+)\s*", re.IGNORECASE)  # a Keyword's whole value
AGT_MAX_FRAME = 2**24  # 155 hours at 30 Hz; a larger Frame# is not a frame of any ARF


def _frame_number(upd: AgtBlock, source: str) -> int | None:
    """The 1-based frame a ``TgtUpd``'s ``Keyword "Frame# N"`` names, or None (a comment that
    mentions a frame is not one)."""
    for a in upd.attrs:
        if a.key == "Keyword" and (m := _FRAME_NUMBER_RE.fullmatch(" ".join(a.values))):
            digits = m.group(1).lstrip("0") or "0"
            if digits == "0" or len(digits) > 8 or int(digits) > AGT_MAX_FRAME:
                raise InputError(f"{source}, line {a.line}: Frame# {m.group(1)}: frames count from 1 "
                                 f"to at most {AGT_MAX_FRAME}")
            return int(digits)
    return None


def _agt_truths(agt: AgtBlock, source: str) -> tuple[dict[int, FrameTruth | None], bool]:
    """:func:`agt_frame_truths` as {frame index: truth}, one entry a ``TgtUpd`` (a Frame# far beyond the
    others costs nothing), and whether the blocks number their frames."""
    updates: list[tuple[AgtBlock, int | None, FrameTruth | None]] = []
    multi = 0
    for sect in agt.find("TgtSect"):
        for upd in sect.find("TgtUpd"):
            values: dict = {}
            time = upd.attr("Time")
            if time is not None:
                values["time_s"] = _agt_time(time, source)
            tgts = upd.find("Tgt")
            multi += len(tgts) > 1
            if tgts:  # the first target scored for ATR; a Tgt without TgtType is a false alarm or clutter
                tgt = next((t for t in tgts if t.attr("TgtType") is not None), tgts[0])
                if (a := tgt.attr("TgtType")) is not None:
                    values["vehicle"] = " ".join(a.values)
                    values["vehicle_class"] = vehicle_class(values["vehicle"])
                if (a := tgt.attr("Range")) is not None:
                    values["range_m"] = _numbers(a, 1, source)[0]
                if (a := tgt.attr("Aspect")) is not None:
                    values["aspect"] = math.radians(_numbers(a, 1, source)[0])
                if (a := tgt.attr("PixLoc")) is not None:
                    values["u"], values["v"] = _numbers(a, 2, source)
                if (a := tgt.attr("PixBox")) is not None:
                    values["u0"], values["v0"], values["u1"], values["v1"] = _numbers(a, 4, source)
            updates.append((upd, _frame_number(upd, source), FrameTruth(**values) if values else None))
    if multi:
        logger.warning("%s: %d frames list more than one Tgt; using the first with a TgtType of each", source, multi)
    numbered = [u for u in updates if u[1] is not None]
    if not numbered:
        return dict(enumerate(t for _, _, t in updates)), False
    if len(numbered) < len(updates):
        missing = next(upd for upd, k, _ in updates if k is None)
        raise InputError(f"{source}, line {missing.line}: this TgtUpd has no Frame# line, but the TgtUpd at line "
                         f"{numbered[0][0].line} has one; which frame it holds is unknown")
    truths: dict[int, FrameTruth | None] = {}
    first: dict[int, AgtBlock] = {}
    for upd, k, t in updates:
        if k in first:
            raise InputError(f"{source}, line {upd.line}: TgtUpd numbers frame {k}, as the TgtUpd at line "
                             f"{first[k].line} does")
        first[k] = upd
        truths[k - 1] = t
    return truths, True


def agt_frame_truths(agt: AgtBlock, source: str = "<agt>") -> list[FrameTruth | None]:
    """Per-frame truth (None where a frame has no time and no target): the ``TgtUpd`` blocks in
    order, one a frame, or, when each names its frame in a ``Keyword "Frame# N"`` line (1-based,
    as the ATR database's files do), each at its frame, None between them. Raises
    ``InputError`` naming the line when only some are numbered or two name the same frame."""
    truths = _agt_truths(agt, source)[0]
    return [truths.get(i) for i in range(max(truths, default=-1) + 1)]


def _fmt(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else repr(float(x))


def write_agt(path: str | os.PathLike, truths: Iterable[FrameTruth | None]) -> None:
    """Write one ``TgtUpd`` per frame (an empty one for None) with the fields AGT can hold:
    time, vehicle (``TgtType``), ``Range``, ``Aspect`` (degrees), ``PixLoc``, ``PixBox``.
    Written atomically."""
    lines = ["Agt", "{", "  TgtSect", "  {"]
    for i, t in enumerate(truths):
        lines += ["    TgtUpd", "    {"]
        if t is not None and math.isfinite(t.time_s):
            try:
                dt = datetime(1970, 1, 1, tzinfo=timezone.utc) + timedelta(milliseconds=round(t.time_s * 1000))
            except OverflowError:
                raise ValueError(f"{path}: frame {i}: time {t.time_s} s is outside the years 1-9999 AGT can "
                                 f"hold") from None
            lines.append(f"      Time {dt.year} {dt.timetuple().tm_yday} {dt.hour} {dt.minute} {dt.second} "
                         f"{dt.microsecond // 1000}")
        tgt = []
        if t is not None:
            if '"' in t.vehicle or "\n" in t.vehicle:
                raise ValueError(f"{path}: frame {i}: vehicle name {t.vehicle!r} cannot be quoted in AGT")
            if t.vehicle:
                tgt.append(f'TgtType "{t.vehicle}"')
            if math.isfinite(t.range_m):
                tgt.append(f'Range "{_fmt(t.range_m)}"')
            if math.isfinite(t.aspect):
                tgt.append(f'Aspect "{_fmt(math.degrees(t.aspect))}"')
            if math.isfinite(t.u) and math.isfinite(t.v):
                tgt.append(f"PixLoc {_fmt(t.u)} {_fmt(t.v)}")
            box = (t.u0, t.v0, t.u1, t.v1)
            if all(map(math.isfinite, box)):
                tgt.append("PixBox " + " ".join(map(_fmt, box)))
        if tgt:
            lines += ["      Tgt", "      {"] + [f"        {s}" for s in tgt] + ["      }"]
        lines.append("    }")
    lines += ["  }", "}"]
    atomic_write_text("\n".join(lines) + "\n", path)


# --------------------------------------------------------------------------------- bbox_met

BBOX_MET_COLUMNS: tuple[str, ...] = (
    "site", "unknown_1", "unknown_2", "sensor", "scenario", "frame", "ply_id", "unknown_7",
    "unknown_8", "upper_left_u", "upper_left_v", "unknown_11", "unknown_12", "unknown_13",
    "unknown_14", "unknown_15", "unknown_16", "unknown_17")
_COL = {name: k for k, name in enumerate(BBOX_MET_COLUMNS)}


@dataclass(frozen=True)
class BboxMetRow:
    """One ``.bbox_met`` row: its 18 cells as written, and the parsed frame and corner.

    ``frame`` is 1-based as in the file; ``upper_left`` is (u, v) in pixels.
    """

    cells: tuple[str, ...]
    frame: int
    upper_left: tuple[float, float]

    def __getitem__(self, column: str) -> str:
        """The cell of a named column (see ``BBOX_MET_COLUMNS``)."""
        return self.cells[_COL[column]]


def _bbox_met_row(cells: list[str], where: str) -> BboxMetRow:
    if len(cells) != len(BBOX_MET_COLUMNS):
        raise InputError(f"{where}: expected {len(BBOX_MET_COLUMNS)} columns; got {len(cells)}")
    cells = [c.strip() for c in cells]
    frame_cell = cells[_COL["frame"]]
    if not frame_cell.isdecimal() or len(frame_cell) > 18:
        raise InputError(f"{where}, column 'frame': expected an integer; got {show(frame_cell)}")
    frame = int(frame_cell)
    if frame < 1:
        raise InputError(f"{where}, column 'frame': frames count from 1; got {frame}")
    u, v = (parse_real(f"{where}, column {name!r}", cells[_COL[name]]) for name in ("upper_left_u", "upper_left_v"))
    return BboxMetRow(tuple(cells), frame, (u, v))


def read_bbox_met(path: str | os.PathLike) -> list[BboxMetRow]:
    """Rows of a ``.bbox_met`` file (UTF-8, at most 64 MiB; blank lines skipped); errors name the
    file and line. Corners must be finite numbers."""
    path = Path(path)
    rows = []
    reader = csv.reader(io.StringIO(read_text(path), newline=""))
    try:
        for cells in reader:
            if cells and any(c.strip() for c in cells):
                rows.append(_bbox_met_row(cells, f"{path}, line {reader.line_num}"))
    except csv.Error as exc:
        raise InputError(f"{path}, line {reader.line_num}: not a CSV file we can read ({exc})") from None
    return rows


def write_bbox_met(path: str | os.PathLike, rows: Iterable[Iterable[object]]) -> None:
    """Write rows of 18 cells (see ``BBOX_MET_COLUMNS``); each row is checked as the reader
    would. Written atomically."""
    path = Path(path)
    checked = [_bbox_met_row([str(c) for c in row], f"{path}, row {k}") for k, row in enumerate(rows)]
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        csv.writer(fh).writerows(r.cells for r in checked)


# --------------------------------------------------------------------------------- sequence

def _companion(arf: Path, given: str | os.PathLike | None, suffix: str, folder: str) -> Path | None:
    if given is not None:
        given = Path(given)
        if not given.is_file():
            raise FileNotFoundError(f"{suffix} file not found: {given}")
        return given
    for candidate in (arf.with_suffix(suffix), arf.parent.parent / folder / (arf.stem + suffix)):
        if candidate.is_file():
            return candidate
    return None


class SensiacSequence(Sequence):
    """A SENSIAC sequence: frames from the ARF, truth from the AGT and bbox_met where present.

    Args:
        arf_path: the ``.arf`` file.
        camera: a calibrated camera (SENSIAC ships none), or None.
        fps: frame rate, positive; SENSIAC records at 30 Hz and the ARF does not say.
        agt_path, bbox_met_path: companion files; None = look beside the ARF by stem.
        layout: ``"contiguous"`` or ``"trailer40"``; None decides from the file (module docstring).
    Frames are (rows, cols) native uint16, each a fresh copy out of the memory map, which is
    opened last, once every check has passed.
    """

    def __init__(self, arf_path: str | os.PathLike, camera: Camera | None = None, fps: float = SENSIAC_FPS,
                 agt_path: str | os.PathLike | None = None, bbox_met_path: str | os.PathLike | None = None,
                 layout: str | None = None):
        arf = Path(arf_path)
        self.fps = check_fps(fps, str(arf))
        if not arf.is_file():
            raise FileNotFoundError(f"ARF file not found: {arf}")
        header, layout = read_arf_header(arf, layout)
        logger.info("%s: ARF layout %s, %d frames of %d x %d", arf, layout, header.frames, header.cols, header.rows)
        if camera is not None and (camera.height, camera.width) != (header.rows, header.cols):
            raise InputError(f"{arf}: camera is {camera.width} x {camera.height} px; frames are "
                             f"{header.cols} x {header.rows}")
        self._header = header
        self.name = arf.stem
        self.camera = camera
        agt = _companion(arf, agt_path, ".agt", "agt")
        met = _companion(arf, bbox_met_path, ".bbox_met", "metric")
        agt_truths, numbered = _agt_truths(read_agt(agt), str(agt)) if agt is not None else ({}, False)
        met_rows = read_bbox_met(met) if met is not None else []
        self._truths = _merge_truth(header.frames, agt_truths, met_rows, str(arf), numbered)
        self.meta = {"arf": str(arf), "agt": None if agt is None else str(agt),
                     "bbox_met": None if met is None else str(met), "arf_layout": layout,
                     "arf_version": header.version, "arf_image_type": header.image_type,
                     "arf_flags": header.flags, "arf_data_offset": header.offset,
                     "agt_frames": max(agt_truths, default=-1) + 1, "bbox_met_rows": len(met_rows)}
        stride = header.frame_bytes + (ARF_TRAILER_BYTES if layout == "trailer40" else 0)
        self._mm: np.memmap | None = np.memmap(arf, dtype=">u2", mode="r", offset=header.offset,
                                               shape=(header.frames, stride // 2))

    def __len__(self) -> int:
        return self._header.frames

    def _read_frame(self, i: int) -> np.ndarray:
        if self._mm is None:
            raise ValueError(f"{self.name}: the sequence is closed")
        h = self._header
        return self._mm[i, : h.rows * h.cols].astype(np.uint16).reshape(h.rows, h.cols)

    def _truth(self, i: int) -> FrameTruth | None:
        return self._truths[i]

    def close(self) -> None:
        self._mm = None


def _merge_truth(n: int, agt: dict[int, FrameTruth | None], met: list[BboxMetRow], source: str,
                 numbered: bool = False) -> list[FrameTruth | None]:
    """Per frame: the AGT truth, with the bbox_met upper-left corner (and the lower-right one
    mirrored about PixLoc) where the AGT has no PixBox. ``numbered``: the AGT's frames were placed
    by their Frame# lines, so only frames beyond the ARF's are worth a warning."""
    if numbered:
        if max(agt) >= n:
            logger.warning("%s: the AGT numbers frames up to %d, the ARF has %d; ignoring the truth beyond it",
                           source, max(agt) + 1, n)
    elif agt and len(agt) != n:
        logger.warning("%s: the AGT has %d frames, the ARF %d; matching by index", source, len(agt), n)
    times = [t.time_s for _, t in sorted(agt.items()) if t is not None and math.isfinite(t.time_s)]
    if any(b < a for a, b in zip(times, times[1:])):
        logger.warning("%s: the AGT's times run backwards (frames out of order, or another file's?); the truth keeps "
                       "them, the tracker's clock does not use them", source)
    corners: dict[int, tuple[float, float]] = {}
    for row in met:
        corners.setdefault(row.frame - 1, row.upper_left)
    if len(corners) < len(met):
        logger.warning("%s: %d bbox_met rows share a frame with another; using each frame's first",
                       source, len(met) - len(corners))
    beyond = sum(k >= n for k in corners)
    if beyond:
        logger.warning("%s: %d bbox_met rows name frames beyond the ARF's %d", source, beyond, n)
    truths: list[FrameTruth | None] = []
    for i in range(n):
        t = agt.get(i)
        if i in corners and (t is None or math.isnan(t.u0)):
            u0, v0 = corners[i]
            base = t if t is not None else FrameTruth()
            u1 = 2 * base.u - u0  # NaN without PixLoc
            v1 = 2 * base.v - v0
            t = dataclasses.replace(base, u0=u0, v0=v0, u1=u1, v1=v1)
        truths.append(t)
    return truths


def _open_spec(rest: str) -> SensiacSequence:
    target, kwargs, options = parse_reader_spec("sensiac", rest, ("layout",))
    return SensiacSequence(target, **kwargs, **options)


register_scheme("sensiac", _open_spec)
