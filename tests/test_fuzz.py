"""Property-based fuzzing of every untrusted input: SENSIAC ARF / AGT / bbox_met, our folder format,
``synthetic:`` and ``video:`` specs, train.py configs and checkpoints.

The property, for every generated or mutated input: either a clear exception of our types
(InputError, ConfigError, FileNotFoundError) whose message names the input, or a correct result
checked against an independent reference (the generator's own values, numpy/struct slicing,
Pillow's decoder, Python's float); never a hang (a 20 s timer per case), never more than 1 GiB of
new memory (RLIMIT_DATA per case), never NaN or inf where a value was given.

Profiles (tests/conftest.py): ``ci`` with the default suite, ``large`` with ``pytest -m slow``.
"""

from __future__ import annotations

import calendar
import contextlib
import csv
import functools
import io
import json
import math
import os
import resource
import signal
import struct
import tempfile
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import event, given, settings
from hypothesis import strategies as st
from PIL import Image

from torch_atr.camera import Camera
from torch_atr.config import ConfigError, ModelConfig, TemplateConfig, load_config
from torch_atr.data import (FolderSequence, FrameTruth, SensiacSequence, agt_frame_truths, open_sequence, read_agt,
                            read_bbox_met, save_sequence)
from torch_atr.data.sensiac import vehicle_class
from torch_atr.data.sequence import TRUTH_FIELDS, Sequence
from torch_atr.data.synthetic import MAX_FRAME_PIXELS, SceneConfig, SyntheticSequence, parse_synthetic_spec
from torch_atr.model import GenerativeShapeModel, load_checkpoint
from torch_atr.tracking.job import TrackConfig
from torch_atr.training import MAX_VIEWS, TrainConfig
from torch_atr.validate import MAX_IMAGE_PIXELS, InputError, show
from torch_atr.vehicles import load_catalog_vehicle

OUR_ERRORS = (InputError, FileNotFoundError)  # ConfigError is an InputError
MAGIC = 0xBBBBBAAD


class Hang(Exception):
    """A case ran past its time bound."""


def _vm_data() -> int:
    """Bytes of this process's private writable memory (what RLIMIT_DATA limits)."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmData:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmData in /proc/self/status")


@contextlib.contextmanager
def bounded(seconds: float = 20.0, new_bytes: int = 2 ** 30):
    """Run the block with at most ``new_bytes`` of new private memory (allocations beyond fail)
    and at most ``seconds`` of wall time (then Hang is raised in it)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_DATA)
    limit = _vm_data() + new_bytes
    resource.setrlimit(resource.RLIMIT_DATA, (limit if hard == resource.RLIM_INFINITY else min(limit, hard), hard))

    def on_alarm(signum, frame):
        raise Hang(f"a case ran longer than {seconds} s")

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        resource.setrlimit(resource.RLIMIT_DATA, (soft, hard))


def fuzz(weight: float = 1.0, **strategies):
    """Two tests of the property: under the "ci" profile, and under "large" marked slow; each
    runs the profile's case count x ``weight``. Pytest fixtures reach the property by name."""
    def make(prop):
        tests = []
        for profile in ("ci", "large"):
            base = settings.get_profile(profile)
            test = settings(base, max_examples=max(1, round(base.max_examples * weight)))(given(**strategies)(prop))
            tests.append(pytest.mark.slow(test) if profile == "large" else test)
        return tuple(tests)
    return make


def assert_names(exc: BaseException, *names: str) -> None:
    """The exception is one of ours and its message names one of ``names``."""
    assert isinstance(exc, OUR_ERRORS), f"{type(exc).__name__} is not one of our error types: {exc}"
    assert any(str(n) in str(exc) for n in names), f"the message does not name {names}: {exc}"
    event("refused with a clear error")


def assert_truth_ok(t: FrameTruth | None) -> None:
    """A truth's numbers are finite or NaN (unknown): never inf."""
    if t is not None:
        for f in TRUTH_FIELDS:
            value = getattr(t, f)
            assert isinstance(value, str) or not math.isinf(value), f"{f} = {value}"


# ------------------------------------------------------------------------------------------- ARF

def _valid_stamp(words) -> bool:
    year, day, hour, minute, sec, ms = words
    return 1970 <= year <= 2100 and 1 <= day <= 366 and hour < 24 and minute < 60 and sec < 61 and ms < 1000


@st.composite
def arf_cases(draw):
    """(file bytes, layout argument, well formed?, true layout): a valid ARF with 0-3 of its header
    fields, its size or the layout argument corrupted."""
    fields = {"magic": MAGIC, "rows": draw(st.integers(1, 6)), "cols": draw(st.integers(1, 6)), "image_type": 5,
              "frames": draw(st.integers(1, 5)), "offset": draw(st.sampled_from([32, 32, 36, 64])), "flags": 0}
    layout = draw(st.sampled_from(["contiguous", "trailer40"]))
    if layout == "trailer40":
        fields["flags"] = 0x10
    stamps, tail, forced = "valid", "none", None
    corruptions = draw(st.lists(st.sampled_from(
        ["magic", "image_type", "rows", "cols", "frames", "offset", "flags", "stamps", "tail", "forced"]), max_size=3))
    for what in corruptions:
        if what == "magic":
            fields["magic"] = draw(st.sampled_from([0, 0xADBABBBB, MAGIC ^ 1]))
        elif what == "image_type":
            fields["image_type"] = draw(st.sampled_from([0, 3, 7, 2 ** 32 - 1]))
        elif what in ("rows", "cols"):
            fields[what] = draw(st.sampled_from([0, 16385, 65535, 8193, 2 ** 32 - 1]))
        elif what == "frames":
            fields["frames"] = draw(st.sampled_from([0, 6, 2 ** 31, 2 ** 32 - 1]))
        elif what == "offset":
            fields["offset"] = draw(st.sampled_from([0, 16, 31, 2 ** 32 - 1]))
        elif what == "flags":
            fields["flags"] = draw(st.sampled_from([0, 0x10, 0x1, 0x11, 0xFFFFFFFF]))
        elif what == "stamps":
            stamps = draw(st.sampled_from(["random", "zeros"]))
        elif what == "tail":
            tail = draw(st.sampled_from(["junk40", "cut", "extra"]))
        else:
            forced = draw(st.sampled_from(["contiguous", "trailer40", "bogus"]))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    rows, cols, frames, offset = fields["rows"], fields["cols"], fields["frames"], fields["offset"]
    head = struct.pack(">8I", fields["magic"], 2, rows, cols, fields["image_type"], frames, offset, fields["flags"])
    fb = rows * cols * 2
    if 32 <= offset <= 64 and fb * min(frames, 6) <= 10 ** 5:
        body = rng.integers(0, 256, offset - 32, dtype=np.uint8).tobytes()
        for k in range(min(frames, 5)):  # a corrupted frame count of 6 finds only 5 frames
            body += rng.integers(0, 256, fb, dtype=np.uint8).tobytes()
            if layout == "trailer40":
                if stamps == "valid":
                    body += struct.pack(">10I", 1, 2, 3, 4, 2004, 1 + k, 12, 30, k, 999)
                elif stamps == "random":
                    body += rng.integers(0, 256, 40, dtype=np.uint8).tobytes()
                else:
                    body += bytes(40)
    else:
        body = rng.integers(0, 256, draw(st.integers(0, 200)), dtype=np.uint8).tobytes()
    data = head + body
    if tail == "junk40":
        data += rng.integers(0, 256, 40 * min(frames, 5), dtype=np.uint8).tobytes()
    elif tail == "cut":
        data = data[: draw(st.integers(0, len(data) - 1))]
    elif tail == "extra":
        data += rng.integers(0, 256, draw(st.integers(1, 100)), dtype=np.uint8).tobytes()
    well_formed = (fields["magic"] == MAGIC and fields["image_type"] == 5 and 1 <= rows <= 6 and 1 <= cols <= 6
                   and 1 <= frames <= 5 and 32 <= offset <= 64 and tail == "none" and forced is None
                   and (layout == "trailer40") == bool(fields["flags"] & 0x10))
    return data, forced, well_formed, layout


def _arf_property(case):
    data, forced, well_formed, true_layout = case
    with tempfile.TemporaryDirectory() as tmp, bounded():
        path = Path(tmp) / "clip.arf"
        path.write_bytes(data)
        try:
            seq = SensiacSequence(path, layout=forced)
        except OUR_ERRORS as exc:
            assert not well_formed, f"a well-formed {true_layout} file was refused: {exc}"
            assert_names(exc, path)
            return
        # Independent reader: struct for the header, numpy slices of the bytes for the frames.
        magic, _, rows, cols, image_type, n, offset, flags = struct.unpack(">8I", data[:32])
        assert magic == MAGIC and image_type == 5 and rows * cols <= MAX_IMAGE_PIXELS
        chosen = seq.meta["arf_layout"]
        fb = rows * cols * 2
        stride = fb + (40 if chosen == "trailer40" else 0)
        assert offset + n * stride <= len(data) and len(seq) == n
        if forced is not None:
            assert chosen == forced
        else:
            assert len(data) == offset + n * stride  # no bytes are ignored unless the user says so
            if flags & 0x10:
                assert chosen == "trailer40"
            elif chosen == "trailer40" and n > 1:
                assert all(_valid_stamp(struct.unpack_from(">6I", data, offset + i * stride + fb + 16)) for i in range(n))
        event("accepted, equal to the reference")
        if well_formed:
            assert chosen == true_layout
        for i in range(n):
            want = np.frombuffer(data, ">u2", count=rows * cols, offset=offset + i * stride).reshape(rows, cols)
            np.testing.assert_array_equal(seq.frame(i), want)


test_fuzz_arf_reader, test_fuzz_arf_reader_large = fuzz(case=arf_cases())(_arf_property)


# ------------------------------------------------------------------------------------------- AGT

# Target types: SENSIAC's, spelt as its files do, with their classes written out here; or any other text (class
# ""). Hypothesis also draws the package's own string literals, so other text can spell "suv" or "BTR70".
_SENSIAC_TYPES = [("BTR70", "apc"), ("T-72", "tank"), ("bmp 2", "apc"), ("Ford F150", "pickup"), ("ISUZU_SUV", "suv"),
                  ("ZSU-23-4", "tank")]
_names = st.one_of(st.sampled_from(_SENSIAC_TYPES), st.text(
    st.characters(blacklist_categories=("Cs", "Cc"), blacklist_characters='"'), min_size=1, max_size=12).filter(
        lambda name: vehicle_class(name) == "").map(lambda name: (name, "")))
_reals = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e12, max_value=1e12)


@st.composite
def agt_documents(draw):
    """(text, expected truths): AGT written by this test's own writer, in the layouts of the spec."""
    n = draw(st.integers(0, 4))
    lines = ["Agt", "{", "  TgtSect {"]
    expected = []
    next_line = draw(st.booleans())  # values on the line after their key, as in the 1999 spec's examples

    def attr(key, *values):
        if next_line and draw(st.booleans()):
            lines.extend([f"        {key}", "        " + " ".join(values)])
        else:
            lines.append(f"        {key} " + " ".join(values))

    for _ in range(n):
        lines += ["    TgtUpd", "    {"]
        values = {}
        if draw(st.booleans()):
            year, day = draw(st.integers(1970, 2100)), draw(st.integers(1, 365))
            hms = draw(st.tuples(st.integers(0, 23), st.integers(0, 59), st.integers(0, 59), st.integers(0, 999)))
            lines.append(f"      Time {year} {day} {hms[0]} {hms[1]} {hms[2]} {hms[3]}")
            values["time_s"] = (calendar.timegm((year, 1, 1, 0, 0, 0)) + (day - 1) * 86400 + hms[0] * 3600
                                + hms[1] * 60 + hms[2] + hms[3] / 1000)
        if draw(st.booleans()):
            lines += ["      Tgt", "      {"]
            if draw(st.booleans()):
                name, cls = draw(_names)
                attr("TgtType", f'"{name}"')
                values["vehicle"], values["vehicle_class"] = name, cls
            if draw(st.booleans()):
                r = draw(_reals)
                attr("Range", f'"{r!r}"')
                values["range_m"] = r
            if draw(st.booleans()):
                a = draw(_reals)
                attr("Aspect", f'"{a!r}"')
                values["aspect"] = math.radians(a)
            if draw(st.booleans()):
                u, v = draw(_reals), draw(_reals)
                attr("PixLoc", repr(u), repr(v))
                values["u"], values["v"] = u, v
            if draw(st.booleans()):
                attr("Comment", '"kept but unused"')
            lines.append("      }")
        lines.append("    }")
        expected.append(FrameTruth(**values) if values else None)
    lines += ["  }", "}"]
    return "\n".join(lines) + "\n", expected


def _agt_valid_property(doc):
    text, expected = doc
    with tempfile.TemporaryDirectory() as tmp, bounded():
        path = Path(tmp) / "t.agt"
        path.write_text(text, encoding="utf-8")
        got = agt_frame_truths(read_agt(path), str(path))
    event("accepted, equal to the reference")
    assert len(got) == len(expected)
    for g, e in zip(got, expected):
        if e is None:
            assert g is None
            continue
        for f in TRUTH_FIELDS:
            a, b = getattr(g, f), getattr(e, f)
            if f == "time_s" and not math.isnan(b):
                assert a == pytest.approx(b, abs=1e-6)
            else:
                assert a == b or (isinstance(a, float) and math.isnan(a) and math.isnan(b)), f


_mutations = st.lists(st.tuples(st.sampled_from(["insert", "delete", "replace"]), st.floats(0, 1),
                                st.sampled_from([b"{", b"}", b'"', b"\n", b" ", b"Tgt", b"1e400", b"inf", b"nan",
                                                 b"\xff", b"\xc3", b"x", b"-", b"9" * 30, b"Agt {", b"  ", b"\n\n",
                                                 b"\t", b"\r\n"])),
                      min_size=1, max_size=6)


def _mutate(data: bytes, mutations) -> bytes:
    for op, where, chunk in mutations:
        i = int(where * len(data))
        if op == "insert":
            data = data[:i] + chunk + data[i:]
        elif op == "delete":
            data = data[:i] + data[i + len(chunk):]
        else:
            data = data[:i] + chunk + data[i + len(chunk):]
    return data


def _agt_mutated_property(doc, mutations):
    data = _mutate(doc[0].encode("utf-8"), mutations)
    with tempfile.TemporaryDirectory() as tmp, bounded():
        path = Path(tmp) / "t.agt"
        path.write_bytes(data)
        try:
            truths = agt_frame_truths(read_agt(path), str(path))
        except OUR_ERRORS as exc:
            assert_names(exc, path)
            return
    event("accepted, no inf")
    for t in truths:
        assert_truth_ok(t)


test_fuzz_agt_reads_what_was_written, test_fuzz_agt_reads_what_was_written_large = fuzz(
    0.5, doc=agt_documents())(_agt_valid_property)
test_fuzz_agt_mutated, test_fuzz_agt_mutated_large = fuzz(doc=agt_documents(), mutations=_mutations)(
    _agt_mutated_property)


# -------------------------------------------------------------------------------------- bbox_met

_bad_cells = st.sampled_from(["inf", "-inf", "1e400", "nan", "", " ", "abc", "-1", "0", "+2", "0x10", "1e3"])
_cell_text = st.one_of(
    st.integers(-3, 10 ** 6).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["inf", "-inf", "1e400", "nan", "", " ", "abc", " 3.5 ", "1_0", "+2", "0x10", "٣"]),
    st.text(st.characters(blacklist_categories=("Cs",)), max_size=8),
)


@st.composite
def bbox_rows(draw):
    """Rows of mostly valid frames and corners (each cell sometimes bad), other cells any text."""
    rows = []
    for _ in range(draw(st.integers(0, 4))):
        cells = [draw(st.text(st.characters(blacklist_categories=("Cs",)), max_size=8)) for _ in range(18)]
        frames = st.one_of(st.integers(1, 10 ** 6).map(str), st.integers(1, 99).map(lambda n: f" {n} "))
        corners = st.one_of(st.floats(-1e6, 1e6).map(repr), st.integers(-9, 999).map(str))
        cells[5] = draw(st.one_of(frames, _bad_cells, _cell_text) if draw(st.integers(0, 5)) == 0 else frames)
        for k in (9, 10):
            cells[k] = draw(st.one_of(corners, _bad_cells, _cell_text) if draw(st.integers(0, 5)) == 0 else corners)
        if draw(st.integers(0, 7)) == 0:
            cells = cells[:17] if draw(st.booleans()) else cells + ["x"]
        rows.append(cells)
    return rows


def _reference_corner(cell: str) -> float | None:
    try:
        x = float(cell.strip())
    except ValueError:
        return None
    return x if math.isfinite(x) else None


def _bbox_property(rows, damage):
    buffer = io.StringIO()
    csv.writer(buffer).writerows(rows)
    data = buffer.getvalue().encode("utf-8")
    if damage == "latin1":
        data += b"caf\xe9\n"
    elif damage == "huge_field":
        data += b'"' + b"x" * 140_000 + b'"\n'
    elif damage == "nul":
        data += b"a,\x00,b\n"
    # The reference: the generator's cells and the documented rules (18 cells, a frame of
    # decimal digits >= 1, finite float corners, all-blank rows skipped).
    expected = []
    valid = damage == "plain"
    for cells in rows:
        if not any(c.strip() for c in cells):
            continue
        frame = cells[5].strip() if len(cells) > 5 else ""
        corners = [_reference_corner(cells[k]) for k in (9, 10)] if len(cells) == 18 else [None]
        if len(cells) != 18 or not (frame.isdecimal() and len(frame) <= 18 and int(frame) >= 1) or None in corners:
            valid = False
            break
        expected.append((int(frame), tuple(corners)))
    with tempfile.TemporaryDirectory() as tmp, bounded():
        path = Path(tmp) / "m.bbox_met"
        path.write_bytes(data)
        try:
            got = read_bbox_met(path)
        except OUR_ERRORS as exc:
            assert not valid, f"a valid file was refused: {exc}"
            assert_names(exc, path)
            return
    event("accepted, equal to the reference")
    assert valid, "an invalid file was accepted"
    assert [(r.frame, r.upper_left) for r in got] == expected


test_fuzz_bbox_met, test_fuzz_bbox_met_large = fuzz(
    rows=bbox_rows(), damage=st.sampled_from(["plain", "plain", "plain", "latin1", "huge_field", "nul"]))(_bbox_property)


def _sensiac_property(n, doc, mutations, rows, layout_option):
    """An ARF with its AGT (mutated or not) and bbox_met found beside it, through the sensiac: spec."""
    frames = np.arange(n * 12, dtype=np.uint16).reshape(n, 3, 4)
    with tempfile.TemporaryDirectory() as tmp:
        arf = Path(tmp) / "seq.arf"
        arf.write_bytes(struct.pack(">8I", MAGIC, 2, 3, 4, 5, n, 32, 0) + frames.astype(">u2").tobytes())
        agt = arf.with_suffix(".agt")
        agt.write_bytes(_mutate(doc[0].encode("utf-8"), mutations) if mutations else doc[0].encode("utf-8"))
        buffer = io.StringIO()
        csv.writer(buffer).writerows(rows)
        arf.with_suffix(".bbox_met").write_text(buffer.getvalue(), encoding="utf-8")
        spec = f"sensiac:{arf}" + (f",layout={layout_option}" if layout_option else "")
        with bounded():
            try:
                seq = open_sequence(spec)
                truths = [seq.truth(i) for i in range(len(seq))]
                got = [seq.frame(i) for i in range(len(seq))]
            except OUR_ERRORS as exc:
                assert_names(exc, arf, agt, arf.with_suffix(".bbox_met"), spec)
                return
    event("accepted, equal to the reference")
    assert len(truths) == n and seq.meta["arf_layout"] == "contiguous"
    for t in truths:
        assert_truth_ok(t)
    np.testing.assert_array_equal(np.stack(got), frames)


test_fuzz_sensiac_sequence, test_fuzz_sensiac_sequence_large = fuzz(
    0.5, n=st.integers(1, 4), doc=agt_documents(), mutations=st.one_of(st.just([]), _mutations), rows=bbox_rows(),
    layout_option=st.sampled_from([None, None, "contiguous"]))(_sensiac_property)


# ------------------------------------------------------------------------------- folder format

class _Frames(Sequence):
    def __init__(self, frames, truths, camera):
        self.frames, self.truths, self.camera = frames, truths, camera
        self.name, self.fps, self.meta = "fz", 30.0, {}

    def __len__(self):
        return len(self.frames)

    def _read_frame(self, i):
        return self.frames[i].copy()

    def _truth(self, i):
        return self.truths[i]


_json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-2 ** 70, 2 ** 70), st.floats(allow_nan=True),
              st.text(max_size=6), st.sampled_from([0, 1, 2, 3, 4, 640, 10 ** 9, 1e400, -1.0, 0.5])),
    lambda inner: st.lists(inner, max_size=4), max_leaves=10)


def _png(width: int, height: int, depth: int, colour: int) -> bytes:
    def chunk(kind: bytes, payload: bytes) -> bytes:
        return struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", zlib.crc32(kind + payload))

    header = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"\0" * 32))
            + chunk(b"IEND", b""))


@st.composite
def folder_damage(draw):
    target = draw(st.sampled_from(["meta", "camera", "camera_R", "truth", "frame", "frame_header", "none"]))
    if target in ("meta", "camera"):
        keys = (["format", "format_version", "name", "fps", "frames", "dtype", "shape"] if target == "meta"
                else ["fx", "fy", "cx", "cy", "width", "height", "dist", "t", "R"])
        return target, draw(st.sampled_from(keys)), draw(_json_values)
    if target == "camera_R":
        return target, draw(st.integers(0, 8)), draw(st.one_of(st.floats(allow_nan=True), st.sampled_from(
            [1.0, -1.0, 0.0, 1.0000001, "1", True])))
    if target == "truth":
        return target, (draw(st.integers(0, 2)), draw(st.integers(0, len(TRUTH_FIELDS) - 1))), draw(_cell_text)
    if target == "frame":
        return target, draw(st.integers(0, 1)), draw(st.binary(max_size=64))
    if target == "frame_header":
        dims = st.sampled_from([1, 3, 4, 5, 60000, 2 ** 31 - 1, 0])
        return target, (draw(dims), draw(dims)), (draw(st.sampled_from([1, 8, 16])), draw(st.sampled_from([0, 2, 3])))
    return target, None, None


def _folder_property(damages, seed):
    rng = np.random.default_rng(seed)
    frames = [rng.integers(0, 65536, (3, 4), dtype=np.uint16) for _ in range(2)]
    truths = [FrameTruth(x=1.5, z=float(rng.uniform(900, 1100)), vehicle="t72"), None]
    camera = Camera(500.0, 500.0, 1.5, 1.0, 4, 3, R=np.eye(3), t=[0.0, 1.0, 2.0])
    undamaged = all(target == "none" for target, _, _ in damages)
    with tempfile.TemporaryDirectory() as tmp:
        folder = save_sequence(_Frames(frames, truths, camera), Path(tmp) / "s", progress=False)
        for target, key, value in damages:
            if target in ("meta", "camera", "camera_R"):
                path = folder / ("meta.json" if target == "meta" else "camera.json")
                d = json.loads(path.read_text())
                R = d.get("R")
                if target == "camera_R" and isinstance(R, list) and len(R) == 3 and all(
                        isinstance(row, list) and len(row) == 3 for row in R):
                    R[key // 3][key % 3] = value
                elif target != "camera_R":
                    d[key] = value
                path.write_text(json.dumps(d))  # NaN, Infinity written as such, as other tools do
            elif target == "truth":
                path = folder / "truth.csv"
                rows = list(csv.reader(io.StringIO(path.read_text())))
                row, col = key
                rows[1 + row if row < len(rows) - 1 else 1][col] = value
                buffer = io.StringIO()
                csv.writer(buffer).writerows(rows)
                path.write_text(buffer.getvalue())
            elif target == "frame":
                (folder / "frames" / f"{key:06d}.png").write_bytes(value)
            elif target == "frame_header":
                (folder / "frames" / "000001.png").write_bytes(_png(*key, *value))
        with bounded():
            try:
                seq = FolderSequence(folder)
                got = [seq.frame(i) for i in range(len(seq))]
                got_truths = [seq.truth(i) for i in range(len(seq))]
            except OUR_ERRORS as exc:
                assert not undamaged, f"an undamaged folder was refused: {exc}"
                assert_names(exc, folder)
                return
        event("accepted, equal to the reference")
        # Independent reference: Pillow decodes each frame; the camera's R is orthonormal.
        for i, frame in enumerate(got):
            with Image.open(folder / "frames" / f"{i:06d}.png") as img:
                np.testing.assert_array_equal(frame, np.asarray(img).astype(frame.dtype))
            assert frame.shape == tuple(seq.meta["shape"])
        for t in got_truths:
            assert_truth_ok(t)
        if seq.camera is not None:
            R = seq.camera.R.numpy()
            assert np.isfinite(seq.camera.K.numpy()).all() and np.allclose(R @ R.T, np.eye(3), atol=1e-5)
        if undamaged:
            for a, b in zip(got, frames):
                np.testing.assert_array_equal(a, b)


test_fuzz_folder_format, test_fuzz_folder_format_large = fuzz(
    damages=st.lists(folder_damage(), min_size=1, max_size=3), seed=st.integers(0, 2 ** 32 - 1))(_folder_property)


# ------------------------------------------------------------------------------ synthetic: spec

_SCENE_KEYS = [f for f in SceneConfig.__dataclass_fields__] + ["range", "colour", "vehicle"]
_spec_values = st.one_of(
    st.integers(-10, 10 ** 6).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from([".inf", "-.inf", ".nan", "1e400", "1e-300", "true", "false", "null", "", "[1, 2]", "{a: 1}",
                     "0", "1", "64", "2000", "100000", "1e9", "3.5", "t_72", "'x'"]),
)


# Plausible values (three times in four), so that accepted scenes, and small rendered ones, are common too.
_SCENE_PLAUSIBLE = {
    "range": ["1000", "2000", "3500", "400"], "width": ["64", "96", "640"], "height": ["48", "64", "512"],
    "frames": ["1", "5", "300"], "fps": ["30", "25.0"], "focal_px": ["2500", "10000", "500"],
    "psf_sigma_px": ["0", "0.5", "3"], "psf_sigma_per_km": ["0", "2"], "occluder_width_m": ["0", "10"],
    "night": ["true", "false"], "tilt_deg": ["null", "1.5", "-3"], "start_deg": ["null", "180", "90"],
    "seed": ["0", "7"], "speed_mps": ["0", "5", "20"], "clutter_k": ["0", "2"], "noise_k": ["0", "0.5"],
    "turret_sweep_deg": ["0", "30"], "camera_height_m": ["2", "20"], "ground_k": ["null", "280", "300"]}


@st.composite
def synthetic_specs(draw):
    keys = draw(st.lists(st.sampled_from(_SCENE_KEYS + list(_SCENE_PLAUSIBLE) * 3), max_size=5, unique=True))
    options = {k: draw(st.sampled_from(_SCENE_PLAUSIBLE[k]) if k in _SCENE_PLAUSIBLE and draw(st.integers(0, 3))
                       else _spec_values) for k in keys}
    parts = ["vehicle=t_72"] + [f"{k}={v}" for k, v in options.items() if k != "vehicle"]
    if draw(st.integers(0, 3)) == 0:  # a small frame, rendered by the property
        parts += ["width=64", "height=48", "focal_px=2500"]
    if draw(st.booleans()):
        parts = draw(st.permutations(parts))
    return ",".join(parts)


@pytest.fixture(scope="module")
def t72():
    return load_catalog_vehicle("t_72")


def _synthetic_property(t72, spec):
    with bounded():
        try:
            vehicle, cfg = parse_synthetic_spec(spec)
            seq = SyntheticSequence(t72, cfg)
            small = cfg.width * cfg.height <= 96 * 96
            frame = seq.frame(0) if small else None
            truth = seq.truth(0) if small else None
        except OUR_ERRORS as exc:
            assert_names(exc, spec, show(spec), "scene")  # a long spec is shown shortened
            return
    event("accepted, rendered" if frame is not None else "accepted")
    assert vehicle == "t_72"
    for name in SceneConfig.__dataclass_fields__:
        value = getattr(cfg, name)
        assert not isinstance(value, float) or math.isfinite(value), name
    assert cfg.width * cfg.height <= MAX_FRAME_PIXELS and cfg.psf_sigma <= 100
    if frame is not None:
        assert frame.dtype == np.uint16 and frame.shape == (cfg.height, cfg.width)
        assert_truth_ok(truth)


test_fuzz_synthetic_spec, test_fuzz_synthetic_spec_large = fuzz(spec=synthetic_specs())(_synthetic_property)


# ---------------------------------------------------------------------------------- video: spec

@functools.cache
def _avi() -> bytes:
    """A 5-frame 32 x 24 grey MJPG AVI, the seed of the video mutations."""
    import cv2

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "v.avi"
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (32, 24), False)
        for i in range(5):
            writer.write(np.full((24, 32), 40 * i, np.uint8))
        writer.release()
        return path.read_bytes()


@st.composite
def video_cases(draw):
    options = draw(st.lists(st.sampled_from(["color=1", "color=0", "color=maybe", "fps=25", "fps=-1", "fps=inf",
                                             "fps=nan", "calib=nope.json", "speed=2", "fps=1e400"]), max_size=2))
    if draw(st.integers(0, 3)) == 0:  # a video file with a few bytes changed
        return "video", draw(st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), min_size=1, max_size=8)), options
    images = []
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["good8", "good16", "good8", "header", "junk", "truncated"]))
        if kind in ("good8", "good16"):
            images.append((kind, None))
        elif kind == "header":
            dims = st.sampled_from([1, 4, 5, 70000, 2 ** 31 - 1, 0])
            images.append((kind, (draw(dims), draw(dims), draw(st.sampled_from([8, 16])), draw(st.sampled_from([0, 2, 6])))))
        else:
            images.append((kind, draw(st.binary(max_size=40))))
    return "images", images, options


def _video_property(case):
    kind, detail, options = case
    names = [o.partition("=")[2] for o in options]
    with tempfile.TemporaryDirectory() as tmp:
        if kind == "video":
            target = Path(tmp) / "v.avi"
            data = bytearray(_avi())
            for where, byte in detail:
                data[int(where * (len(data) - 1))] = byte
            target.write_bytes(bytes(data))
        else:
            target = Path(tmp) / "imgs"
            target.mkdir()
            good = np.random.default_rng(len(detail)).integers(0, 256, (4, 5), dtype=np.uint8)
            for k, (image, spec) in enumerate(detail):
                path = target / f"f{k}.png"
                if image == "good8":
                    Image.fromarray(good).save(path)
                elif image == "good16":
                    Image.fromarray(good.astype(np.uint16) * 257).save(path)
                elif image == "header":
                    path.write_bytes(_png(*spec))
                elif image == "junk":
                    path.write_bytes(spec)
                else:
                    Image.fromarray(good).save(path)
                    path.write_bytes(path.read_bytes()[: len(spec) + 8])
        spec = ",".join([f"video:{target}"] + options)
        with bounded():
            try:
                seq = open_sequence(spec)
                got = {i: seq.frame(i) for i in sorted({0, min(1, len(seq) - 1), len(seq) - 1})}
            except OUR_ERRORS as exc:
                assert_names(exc, target, spec, *names)
                return
        event("accepted")
        assert all(f.dtype in (np.uint8, np.uint16) and f.shape[:2] == got[0].shape[:2] for f in got.values())
        if kind == "images" and "color=1" not in options:  # independent reference: Pillow's decoding
            for k, frame in got.items():
                with Image.open(target / f"f{k}.png") as img:
                    if img.mode in ("L", "I;16"):  # grey as stored (colour is converted with OpenCV's weights)
                        np.testing.assert_array_equal(frame, np.asarray(img))


test_fuzz_video_spec, test_fuzz_video_spec_large = fuzz(0.5, case=video_cases())(_video_property)


# --------------------------------------------------------------------------------------- configs

_config_keys = ["name", "checkpoint", "log_dir", "tensorboard", "seed", "evaluate_test_split",
                "template.size_px", "template.window_m", "template.tau_px", "views.azimuth_step_deg",
                "views.elevation_step_deg", "views.elevation_max_deg", "model.pixel_rank", "model.ridge",
                "model.init_width", "model.class_penalty", "model.width_steps", "model.width_lr", "model.ridg",
                "template", "views.x"]
_yaml_values = st.one_of(
    _spec_values,
    st.sampled_from(["../../..", "/abs", "a/b", "ok_name", "..", ".hidden", "\x00", "x" * 200]).map(json.dumps),
)


_CONFIG_PLAUSIBLE = {
    "name": ["run1", "a.b-c_2"], "seed": ["0", "3"], "tensorboard": ["false"], "template.size_px": ["32", "64"],
    "template.window_m": ["12.0", "8"], "template.tau_px": ["4", "6.0"], "views.azimuth_step_deg": ["12", "30"],
    "views.elevation_step_deg": ["10", "20.0"], "model.pixel_rank": ["null", "48"], "model.ridge": ["1.0e-4", "0"],
    "model.init_width": ["null", "0.3"], "model.width_steps": ["0", "10"], "model.width_lr": ["0.05"]}


@st.composite
def config_entries(draw, max_size):
    keys = draw(st.lists(st.sampled_from(_config_keys + list(_CONFIG_PLAUSIBLE) * 3), max_size=max_size))
    return [(k, draw(st.sampled_from(_CONFIG_PLAUSIBLE[k]) if k in _CONFIG_PLAUSIBLE and draw(st.integers(0, 3))
                     else _yaml_values)) for k in keys]


@st.composite
def config_cases(draw):
    entries = draw(config_entries(5))
    lines, sections = [], {}
    for key, value in entries:
        top, _, sub = key.partition(".")
        if sub:
            sections.setdefault(top, []).append(f"  {sub}: {value}")
        else:
            lines.append(f"{top}: {value}")
    text = "\n".join(lines + [f"{s}:\n" + "\n".join(v) for s, v in sections.items()]) + "\n"
    overrides = [f"{k}={v}" for k, v in draw(config_entries(3))]
    return text, overrides


def _config_property(case):
    text, overrides = case
    with tempfile.TemporaryDirectory() as tmp, bounded():
        path = Path(tmp) / "c.yaml"
        path.write_text(text, encoding="utf-8")
        try:
            cfg = load_config(TrainConfig, path, overrides)
        except ConfigError as exc:
            assert_names(exc, path, *overrides)
            return
        event("accepted")
        # Independent checks of what a config may never hold.
        for section in (cfg, cfg.template, cfg.views, cfg.model):
            for name in section.__dataclass_fields__:
                value = getattr(section, name)
                assert not isinstance(value, float) or math.isfinite(value), name
        assert isinstance(cfg.template, TemplateConfig) and isinstance(cfg.model, ModelConfig)
        assert 8 <= cfg.template.size_px <= 512 and 0 <= cfg.model.ridge <= 1000
        assert len(cfg.views.grid()[0]) <= MAX_VIEWS
        log_dir = Path(tmp) / "runs"
        assert (log_dir / cfg.name).resolve().parent == log_dir.resolve()  # the run folder stays in log_dir
        assert not os.path.isabs(cfg.name) and "/" not in cfg.name


test_fuzz_train_config, test_fuzz_train_config_large = fuzz(case=config_cases())(_config_property)


_TRACK_PLAUSIBLE = {
    "tracker.filter.particles": ["200", "5000"], "tracker.filter.method": ["I", "IV"],
    "tracker.filter.sigma": ["0.02", "0.5"], "tracker.filter.likelihood_px": ["16", "32"],
    "tracker.filter.resample": ["residual", "stratified"], "tracker.filter.resample_ess": ["0.5", "1.0"],
    "tracker.motion.sigma2_x": ["0.1", "0"], "tracker.motion.sigma2_alpha": ["1.0"],
    "tracker.init.mode": ["truth", "blind"], "tracker.init.alpha_steps": ["8"],
    "tracker.init.camera_height_m": ["null", "5.0"], "tracker.segmentation.learning_rate": ["0.01", "-1"],
    "tracker.adapt.every": ["0", "10"], "frames": ["null", "30"], "seed": ["1"], "out": ["runs/x"],
    "device": ["cpu"], "sequence": ["synthetic:vehicle=t_72"]}
_track_keys = list(_TRACK_PLAUSIBLE) + ["tracker.filter.particle", "tracker.motion", "tracker.x.y", "video"]


@st.composite
def track_overrides(draw):
    keys = draw(st.lists(st.sampled_from(_track_keys), max_size=4))
    return [f"{k}={draw(st.sampled_from(_TRACK_PLAUSIBLE[k]) if k in _TRACK_PLAUSIBLE and draw(st.integers(0, 2)) else _yaml_values)}"
            for k in keys]


def _track_config_property(overrides):
    with bounded():
        try:
            cfg = load_config(TrackConfig, None, overrides)
        except ConfigError as exc:
            assert_names(exc, *overrides, *map(repr, overrides))  # messages quote an override with repr
            return
    event("accepted")
    tracker = cfg.tracker
    for section in (cfg, tracker.filter, tracker.motion, tracker.init, tracker.segmentation, tracker.adapt):
        for name in section.__dataclass_fields__:
            value = getattr(section, name)
            assert not isinstance(value, float) or math.isfinite(value), name
    assert 1 <= tracker.filter.particles <= 10_000_000 and tracker.filter.sigma > 0
    assert tracker.filter.method in ("I", "II", "III", "IV") and tracker.init.mode in ("blind", "truth")


test_fuzz_track_config, test_fuzz_track_config_large = fuzz(weight=0.5, overrides=track_overrides())(
    _track_config_property)


# ----------------------------------------------------------------------------------- checkpoints

@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    """(model, its checkpoint's bytes, the checkpoint as a version-1 payload without checksum)."""
    g = torch.Generator().manual_seed(0)
    model = GenerativeShapeModel.fit(torch.rand(3, 6, 8, 8, generator=g) * 2 - 1, torch.linspace(0, 5, 6),
                                     torch.linspace(0, 0.6, 6), ["a", "b", "c"], [0, 0, 1], ["car", "tank"],
                                     TemplateConfig(size_px=8, window_m=4.0, tau_px=2.0),
                                     ModelConfig(pixel_rank=5, ridge=1e-3))
    path = tmp_path_factory.mktemp("ckpt") / "model.pt"
    model.save(path, extra={"note": "fuzz"})
    raw = torch.load(path, weights_only=True)
    del raw["sha256"]
    return model, path.read_bytes(), {**raw, "format_version": 1}


def _finite_reconstructions(model) -> None:
    g = torch.Generator().manual_seed(1)
    alpha, theta = torch.rand(2, 5, generator=g) * 2 * math.pi
    phi = torch.rand(5, generator=g)
    with torch.no_grad():
        assert torch.isfinite(model(alpha, theta, phi)).all()


def _checkpoint_bytes_property(checkpoint, flips, how):
    model, data, _ = checkpoint
    damaged = bytearray(data)
    if how == "flip":
        for where, x in flips:
            damaged[int(where * (len(data) - 1))] ^= x
    elif how == "truncate":
        damaged = damaged[: int(flips[0][0] * len(data))]
    else:
        damaged += bytes(x for _, x in flips)
    with tempfile.TemporaryDirectory() as tmp, bounded():
        path = Path(tmp) / "model.pt"
        path.write_bytes(bytes(damaged))
        try:
            loaded, extra = load_checkpoint(path)
        except OUR_ERRORS as exc:
            assert_names(exc, path)
            return
    event("accepted, equal to the original")
    # The checksum guarantees that whatever loads is the original, exactly, in every tensor.
    assert extra == {"note": "fuzz"}
    for k, v in model.state_dict().items():
        assert torch.equal(loaded.state_dict()[k], v), k


test_fuzz_checkpoint_bytes, test_fuzz_checkpoint_bytes_large = fuzz(
    flips=st.lists(st.tuples(st.floats(0, 1), st.integers(1, 255)), min_size=1, max_size=8),
    how=st.sampled_from(["flip", "flip", "flip", "truncate", "append"]))(_checkpoint_bytes_property)

_tensors = st.builds(
    lambda dtype, shape, values: torch.tensor(values[: math.prod(shape)] + [0.0] * (math.prod(shape) - len(values)),
                                              dtype=torch.float64).reshape(shape).to(dtype),
    st.sampled_from([torch.float32, torch.float32, torch.float64, torch.float16, torch.int64, torch.int32, torch.bool]),
    st.lists(st.integers(0, 11), min_size=0, max_size=3).map(tuple),
    st.lists(st.one_of(st.floats(-1e7, 1e7), st.sampled_from([math.nan, math.inf, 0.0, 1.0, 2.0])), max_size=20),
)
_MODEL_ARG_KEYS = ["num_centres", "num_vehicles", "pixel_rank", "vehicle_names", "vehicle_classes", "class_names",
                   "template", "new_key"]
_STATE_KEYS = ["rbf.centres_theta", "rbf.centres_phi", "rbf.log_width", "core.core", "core.pixel_basis",
               "core.identity_vectors", "core.relative_error", "identity.knots", "identity.coefficients",
               "identity.alphas", "identity.order", "identity.labels", "new.buffer"]


def _checkpoint_content_property(checkpoint, where, key, value, tensor, seed):
    raw = checkpoint[2]
    payload = {**raw, "model_args": dict(raw["model_args"]), "state_dict": dict(raw["state_dict"])}
    if where == "model_args":
        payload["model_args"][key[0]] = value
    elif where == "state":
        payload["state_dict"][key[1]] = tensor
    elif where == "state_same_shape" and key[1] in raw["state_dict"]:
        old = raw["state_dict"][key[1]]
        rng = np.random.default_rng(seed)
        if old.is_floating_point():
            noisy = rng.normal(0, 10.0 ** rng.integers(-3, 9), tuple(old.shape))
            if key[1] == "identity.knots":
                noisy.sort()  # usually increasing, so that the random weights around it get loaded
            payload["state_dict"][key[1]] = torch.from_numpy(noisy).to(old.dtype)
        else:
            payload["state_dict"][key[1]] = torch.from_numpy(rng.permutation(old.numel()) if rng.random() < 0.5
                                                             else rng.integers(-1, 3, old.numel()))
    else:
        payload["format_version" if where == "version" else "other"] = value
    with tempfile.TemporaryDirectory() as tmp, bounded():
        path = Path(tmp) / "model.pt"
        torch.save(payload, path)
        try:
            loaded, _ = load_checkpoint(path)
        except OUR_ERRORS as exc:
            assert_names(exc, path)
            return
        event("accepted, finite reconstructions")
        for k, v in payload["state_dict"].items():
            assert torch.equal(loaded.state_dict()[k], v), k
        _finite_reconstructions(loaded)  # never NaN from a checkpoint that loads


test_fuzz_checkpoint_content, test_fuzz_checkpoint_content_large = fuzz(
    where=st.sampled_from(["model_args", "state", "state_same_shape", "version", "top"]),
    key=st.tuples(st.sampled_from(_MODEL_ARG_KEYS), st.sampled_from(_STATE_KEYS)), value=_json_values,
    tensor=_tensors, seed=st.integers(0, 2 ** 32 - 1))(_checkpoint_content_property)
