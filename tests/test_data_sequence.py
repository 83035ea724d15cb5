"""Sequence abstraction, open_sequence and our folder format: round trips and malformed input."""

import errno
import fcntl
import json
import logging
import math
import os
import re
import signal
import stat
import struct
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np
import pytest

from torch_atr.camera import Camera
from torch_atr.data import (
    FolderSequence,
    FrameTruth,
    Sequence,
    load_camera_json,
    open_sequence,
    register_scheme,
    save_sequence,
)
from torch_atr.data import sequence as sequence_module
from torch_atr.data.sequence import parse_spec_options
from torch_atr.data.synthetic import SceneConfig, SyntheticSequence
from torch_atr.validate import InputError


class ListSequence(Sequence):
    """An in-memory sequence to feed the writers."""

    def __init__(self, frames, truths=None, camera=None, name="mem", fps=25.0, fail_at=None):
        self.frames, self.truths = frames, truths
        self.camera, self.name, self.fps, self.meta = camera, name, fps, {"made_by": "test"}
        self.fail_at = fail_at

    def __len__(self):
        return len(self.frames)

    def _read_frame(self, i):
        if i == self.fail_at:
            raise RuntimeError("disk on fire")
        return self.frames[i].copy()

    def _truth(self, i):
        return None if self.truths is None else self.truths[i]


def _camera(w, h):
    return Camera(500.0, 510.0, w / 2 - 0.5, h / 2 + 0.25, w, h, dist=[0.01, -0.002, 0.0, 0.0, 0.0],
                  R=np.eye(3), t=[0.5, -1.0, 2.0])


def _truths(n):
    rng = np.random.default_rng(1)
    out = []
    for i in range(n):
        if i == 2:
            out.append(None)
            continue
        out.append(FrameTruth(x=float(rng.normal()), y=-1.5, z=float(1000 + 10 * i),
                              heading=float(rng.uniform(0, 6.28)),
                              speed=3.25, u=320.5 + i, v=256.0, u0=300.0, v0=240.0, u1=341.0, v1=272.0,
                              vehicle="BTR70, APC" if i % 2 else "T72", vehicle_class="apc",
                              range_m=1000.5, aspect=0.1 * i, time_s=1.08e9 + i / 30))
    out[3] = FrameTruth(vehicle="only-a-name")
    return out


def test_a_saved_sequence_is_on_disk_before_it_is_renamed_into_place(tmp_path, disk_events):
    """A power cut after the rename must not leave a sequence of empty frames: every file the save wrote
    (frames, truth, camera, meta) and every folder in it is fsynced before the folder is renamed into place,
    and the parent folder after."""
    events = disk_events
    n = 4
    seq = ListSequence([np.full((8, 10), i, np.uint8) for i in range(n)], _truths(n), camera=_camera(10, 8))
    out = save_sequence(seq, tmp_path / "seq", progress=False)
    renames = [e for e in events if e[0] == "replace" and e[2] == str(out)]
    assert len(renames) == 1
    at, tmp = events.index(renames[0]), renames[0][1]
    synced = {e[1] for e in events[:at] if e[0] == "fsync"}
    written = {str(p).replace(str(out), tmp) for p in [out, *out.rglob("*")]}
    assert len(written) == n + 5  # the folder, frames/, n frames, truth.csv, camera.json, meta.json
    assert written <= synced, sorted(written - synced)
    assert ("fsync", str(tmp_path)) in events[at:]


@pytest.mark.parametrize("kind", ["uint16", "uint8", "rgb"])
def test_folder_round_trip(tmp_path, kind):
    rng = np.random.default_rng(0)
    n, h, w = 6, 24, 32
    if kind == "uint16":
        frames = [rng.integers(0, 65536, (h, w), dtype=np.uint16) for _ in range(n)]
    elif kind == "uint8":
        frames = [rng.integers(0, 256, (h, w), dtype=np.uint8) for _ in range(n)]
    else:
        frames = [rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for _ in range(n)]
    truths = _truths(n)
    seq = ListSequence(frames, truths, camera=_camera(w, h), name="run1")
    out = save_sequence(seq, tmp_path / "seq", progress=False)
    assert out == tmp_path / "seq"
    back = open_sequence(str(out))
    assert isinstance(back, FolderSequence)
    assert len(back) == n and back.name == "run1" and back.fps == 25.0
    for i in range(n):
        f = back.frame(i)
        assert f.dtype == frames[i].dtype and f.shape == frames[i].shape
        assert f.tobytes() == frames[i].tobytes()
        assert back.truth(i) == truths[i]
    assert [f.tobytes() for f in back] == [f.tobytes() for f in frames]
    assert back.camera.to_dict() == seq.camera.to_dict()
    assert [f.tobytes() for f in open_sequence(out)] == [f.tobytes() for f in frames]  # a Path is a folder too
    assert math.isnan(back.camera_height_m)  # the source did not know it
    meta = json.loads((out / "meta.json").read_text())
    assert meta["frames"] == n and meta["dtype"] == str(frames[0].dtype) and meta["shape"] == list(frames[0].shape)
    assert meta["source"] == "ListSequence" and meta["source_meta"] == {"made_by": "test"}
    assert open_sequence(f"folder:{out}").frame(-1).tobytes() == frames[-1].tobytes()


def test_truth_csv_is_readable_by_hand(tmp_path):
    """The CSV holds exactly the values written (csv module as the independent reader)."""
    import csv

    seq = ListSequence([np.zeros((4, 5), np.uint8)] * 2, [FrameTruth(z=12.5, vehicle="a,b"), None])
    save_sequence(seq, tmp_path / "s", progress=False)
    with open(tmp_path / "s" / "truth.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert rows[0]["z"] == "12.5" and rows[0]["vehicle"] == "a,b" and rows[0]["x"] == ""
    assert all(v == "" for v in rows[1].values())


def test_no_truth_no_camera(tmp_path):
    seq = ListSequence([np.ones((3, 4), np.uint16)], fps=math.nan)
    save_sequence(seq, tmp_path / "s", progress=False)
    assert not (tmp_path / "s" / "truth.csv").exists() and not (tmp_path / "s" / "camera.json").exists()
    back = open_sequence(str(tmp_path / "s"))
    assert back.camera is None and back.truth(0) is None and math.isnan(back.fps)


def test_save_refuses_what_the_reader_would_refuse_before_writing(tmp_path, monkeypatch):
    """A saved folder always opens: values the reader refuses are refused first, and nothing is
    written; NumPy numbers are saved as numbers, non-finite metadata as null; ~ is the home folder
    and "." names no folder."""
    frames = [np.zeros((4, 5), np.uint8)] * 2
    for seq, message in [(ListSequence(frames, [FrameTruth(x=math.inf), None]), "frame 0's truth x is inf"),
                         (ListSequence(frames, fps=-3.0), "fps must be a positive number; got -3.0"),
                         (ListSequence(frames, fps=math.inf), "fps must be a positive number; got inf")]:
        with pytest.raises(ValueError, match=re.escape(message)):
            save_sequence(seq, tmp_path / "s", progress=False)
        assert not (tmp_path / "s").exists() and list(tmp_path.iterdir()) == []
    high = ListSequence(frames)
    high.camera_height_m = 1e6
    with pytest.raises(ValueError, match=r"camera_height_m .*got 1000000"):
        save_sequence(high, tmp_path / "s", progress=False)
    seq = ListSequence(frames, fps=np.float32(25))
    seq.camera_height_m, seq.meta = np.float64(4.5), {"gain": math.nan, "level": np.float32(0.5)}
    back = open_sequence(str(save_sequence(seq, tmp_path / "s", progress=False)))  # the reader's checks pass
    assert back.fps == 25.0 and back.camera_height_m == 4.5
    assert json.loads((tmp_path / "s" / "meta.json").read_text())["source_meta"] == {"gain": None, "level": 0.5}
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert save_sequence(seq, "~/clip", progress=False) == tmp_path / "home" / "clip"
    for unknown_user in ("~nobody_torch_atr/clip", "~nobody_torch_atr"):  # kept as written, as a shell keeps it:
        with pytest.raises(FileNotFoundError, match="~nobody_torch_atr"):  # Path.expanduser raised RuntimeError
            FolderSequence(unknown_user)
    monkeypatch.chdir(tmp_path / "home")
    for bad in (".", "..", ""):
        with pytest.raises(ValueError, match="names no folder to create"):
            save_sequence(seq, bad, progress=False)
    assert sorted(p.name for p in (tmp_path / "home").iterdir()) == ["clip"]


def test_save_refuses_non_empty_folder_and_overwrites(tmp_path):
    target = tmp_path / "s"
    target.mkdir()
    seq = ListSequence([np.full((3, 4), 5, np.uint8)])
    save_sequence(seq, target, progress=False)  # an empty folder is replaced
    (target / "keep.txt").write_text("x")
    seq = ListSequence([np.full((3, 4), 7, np.uint8)])
    with pytest.raises(FileExistsError, match=re.escape(f"{target} is not empty; pass overwrite=True")):
        save_sequence(seq, target, progress=False)
    assert (target / "keep.txt").exists() and open_sequence(str(target)).frame(0)[0, 0] == 5
    save_sequence(seq, target, progress=False, overwrite=True)
    assert not (target / "keep.txt").exists()
    assert open_sequence(str(target)).frame(0)[0, 0] == 7
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]


@pytest.mark.parametrize("meta", [None, "{not json", '{"format": "something.else"}', "[1]"])
def test_overwrite_never_replaces_a_foreign_folder(tmp_path, meta):
    target = tmp_path / "photos"
    target.mkdir()
    (target / "holiday.jpg").write_bytes(b"precious")
    if meta is not None:
        (target / "meta.json").write_text(meta)
    seq = ListSequence([np.zeros((3, 4), np.uint8)])
    with pytest.raises(FileExistsError, match=re.escape(f"{target} is not a sequence folder")):
        save_sequence(seq, target, progress=False, overwrite=True)
    assert (target / "holiday.jpg").read_bytes() == b"precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos"]


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_saved_folder_has_a_plain_folder_mode(tmp_path, umask):
    """The folder's mode is what os.mkdir gives under the umask (mkdtemp alone gives 0700)."""
    seq = ListSequence([np.zeros((3, 4), np.uint8)])
    old = os.umask(umask)
    try:
        out = save_sequence(seq, tmp_path / "s", progress=False)
        (tmp_path / "reference").mkdir()
    finally:
        os.umask(old)
    want = stat.S_IMODE((tmp_path / "reference").stat().st_mode)
    assert want == 0o777 & ~umask
    assert stat.S_IMODE(out.stat().st_mode) == want


def test_save_crash_leaves_nothing(tmp_path):
    seq = ListSequence([np.zeros((3, 4), np.uint8)] * 5, fail_at=3)
    with pytest.raises(RuntimeError, match="disk on fire"):
        save_sequence(seq, tmp_path / "s", progress=False)
    assert list(tmp_path.iterdir()) == []


_KILLED_SAVE = """
import os, signal, sys
from pathlib import Path
import numpy as np
from torch_atr.data import ArraySequence, save_sequence

target, when = Path(sys.argv[1]), sys.argv[2]


class KilledAtFrame2(ArraySequence):
    def _read_frame(self, i):
        if when == "writing" and i == 2:
            os.kill(os.getpid(), signal.SIGKILL)
        return super()._read_frame(i)


def replace_then_die(src, dst, real=os.replace):
    real(src, dst)
    if Path(src) == target:  # the earlier sequence was just moved aside, the new one not yet in
        os.kill(os.getpid(), signal.SIGKILL)


os.replace = replace_then_die
save_sequence(KilledAtFrame2(np.full((4, 3, 4), 9, np.uint8)), target, progress=False, overwrite=True)
"""


def _kill_a_save(target: Path, when: str) -> None:
    """Run ``_KILLED_SAVE`` of ``target`` in a child process, killed while ``when``."""
    repo = Path(__file__).resolve().parents[1]
    child = subprocess.run([sys.executable, "-c", _KILLED_SAVE, str(target), when], cwd=repo,
                           env={**os.environ, "PYTHONPATH": str(repo)}, capture_output=True, text=True)
    assert child.returncode == -signal.SIGKILL, child.stderr


LONG_NAME = "n" * 250  # the file system allows 255 bytes; a hidden folder named after it in full would not fit


@pytest.mark.parametrize("name", ["s", LONG_NAME])
@pytest.mark.parametrize("when", ["writing", "swapping"])
def test_the_next_save_removes_what_a_killed_save_left(tmp_path, when, name):
    """A save killed (SIGKILL: no clean-up runs) while writing its frames, or between moving the
    earlier sequence aside and renaming the new one in, leaves a hidden folder beside the target;
    the next save of that target removes it, a target with a long name too."""
    target = tmp_path / name
    save_sequence(ListSequence([np.full((3, 4), 5, np.uint8)]), target, progress=False)
    _kill_a_save(target, when)
    left = [p for p in tmp_path.iterdir() if p.name != name]
    assert left and all(p.name.startswith(f".{name[:32]}") and p.is_dir() for p in left)
    if when == "writing":  # the earlier sequence is untouched
        assert len(left) == 1 and open_sequence(str(target)).frame(0)[0, 0] == 5
    else:  # the new sequence and, moved aside, the earlier one are in leftovers; the target is gone
        aside = [p / name for p in left if (p / name).is_dir()]
        assert len(left) == 2 and len(aside) == 1 and not target.exists()
        assert open_sequence(str(aside[0])).frame(0)[0, 0] == 5
    save_sequence(ListSequence([np.full((3, 4), 7, np.uint8)]), target, progress=False, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]
    assert open_sequence(str(target)).frame(0)[0, 0] == 7


def test_long_names_sharing_a_beginning_keep_each_others_leftovers(tmp_path):
    """A killed save of one long-named target is left alone by saves of another whose name begins
    alike, and removed by the next save of its own."""
    mine, other = tmp_path / LONG_NAME, tmp_path / (LONG_NAME[:-1] + "o")
    save_sequence(ListSequence([np.full((3, 4), 5, np.uint8)]), other, progress=False)
    _kill_a_save(other, "writing")
    left = {p.name for p in tmp_path.iterdir()} - {other.name}
    assert len(left) == 1
    save_sequence(ListSequence([np.full((3, 4), 7, np.uint8)]), mine, progress=False)
    save_sequence(ListSequence([np.full((3, 4), 8, np.uint8)]), mine, progress=False, overwrite=True)
    assert {p.name for p in tmp_path.iterdir()} == left | {mine.name, other.name}
    save_sequence(ListSequence([np.full((3, 4), 9, np.uint8)]), other, progress=False, overwrite=True)
    assert {p.name for p in tmp_path.iterdir()} == {mine.name, other.name}
    assert open_sequence(str(mine)).frame(0)[0, 0] == 8 and open_sequence(str(other)).frame(0)[0, 0] == 9


def test_a_name_too_long_for_the_file_system_is_refused_naming_it(tmp_path):
    target = tmp_path / ("n" * 256)
    with pytest.raises(OSError) as info:
        save_sequence(ListSequence([np.zeros((3, 4), np.uint8)]), target, progress=False)
    too_long = errno.ENAMETOOLONG
    assert str(info.value) == f"[Errno {too_long}] save_sequence: cannot write {target}: {os.strerror(too_long)}"
    assert list(tmp_path.iterdir()) == []


def test_a_save_removes_only_unheld_leftovers_of_its_own_target(tmp_path):
    """What a live save holds (its flock), another target's leftovers, look-alikes holding other
    things, links and older temporary names stay; an unheld leftover of the target goes."""
    seq = ListSequence([np.zeros((3, 4), np.uint8)])
    dead = [tmp_path / ".s.dead0001.saving", tmp_path / ".s.dead0002.superseded"]
    live = tmp_path / ".s.live0001.saving"
    kept = [tmp_path / ".other.dead0001.saving", tmp_path / ".s.dead01.saving", tmp_path / ".s.dead0001.tmp",
            tmp_path / ".s.notes001.saving", tmp_path / ".s.notes002.superseded", live]
    for p in dead + kept:
        (p / "frames").mkdir(parents=True)
    (dead[1] / "frames").rmdir()
    (dead[1] / "s" / "frames").mkdir(parents=True)  # the sequence a killed save was replacing
    (tmp_path / ".s.notes001.saving" / "notes.txt").write_text("mine")
    (tmp_path / ".s.file0001.saving").write_text("a file")
    (tmp_path / ".s.link0001.saving").symlink_to(tmp_path / ".s.dead01.saving")
    kept += [tmp_path / ".s.file0001.saving", tmp_path / ".s.link0001.saving"]
    fd = os.open(live, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # as a live save holds its folders
        save_sequence(seq, tmp_path / "s", progress=False)
    finally:
        os.close(fd)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["s"] + [p.name for p in kept])
    assert (tmp_path / ".s.notes001.saving" / "notes.txt").read_text() == "mine"


def test_a_failed_swap_puts_the_earlier_sequence_back(tmp_path, monkeypatch):
    target = tmp_path / "s"
    save_sequence(ListSequence([np.full((3, 4), 5, np.uint8)]), target, progress=False)
    real, failed = os.replace, []

    def replace(src, dst):  # the rename of the new sequence onto the target fails, once
        if Path(dst) == target and not failed:
            failed.append(src)
            raise OSError(28, "No space left on device")
        real(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(OSError, match="No space left"):
        save_sequence(ListSequence([np.full((3, 4), 7, np.uint8)]), target, progress=False, overwrite=True)
    monkeypatch.setattr(os, "replace", real)
    assert failed and sorted(p.name for p in tmp_path.iterdir()) == ["s"]
    assert open_sequence(str(target)).frame(0)[0, 0] == 5


def test_save_rejects_mixed_frames(tmp_path):
    seq = ListSequence([np.zeros((3, 4), np.uint8), np.zeros((3, 5), np.uint8)], name="mixed")
    with pytest.raises(ValueError, match=r"mixed: frame 1 is \(3, 5\)"):
        save_sequence(seq, tmp_path / "s", progress=False)
    seq = ListSequence([np.zeros((3, 4), np.float32)], name="floaty")
    with pytest.raises(ValueError, match="floaty: frame 0: expected"):
        save_sequence(seq, tmp_path / "s", progress=False)
    assert list(tmp_path.iterdir()) == []


_SAVE_TO_A_LATIN1_NAME = """
import os, sys
import numpy as np
from torch_atr.data import ArraySequence, save_sequence
frames = np.arange(2 * 3 * 4 * 3, dtype=np.uint8).reshape(2, 3, 4, 3)
save_sequence(ArraySequence(frames), os.fsdecode(sys.argv[1].encode() + b"/cl\\xe9"), progress=False)
"""


def test_a_save_to_a_folder_named_in_bytes_that_are_not_utf8_writes_its_frames(tmp_path):
    """cv2.imwrite crashed the process (SIGSEGV) on such a path, so the save runs in a child
    process; its PNGs are read back byte-wise, with OpenCV's decoder alone."""
    import cv2

    target = os.path.join(os.fsencode(tmp_path), b"cl\xe9")
    try:
        os.mkdir(target)
        os.rmdir(target)
    except OSError:
        pytest.skip("this file system refuses names that are not UTF-8")
    repo = Path(__file__).resolve().parents[1]
    child = subprocess.run([sys.executable, "-c", _SAVE_TO_A_LATIN1_NAME, str(tmp_path)], cwd=repo,
                           env={**os.environ, "PYTHONPATH": str(repo)}, capture_output=True, text=True)
    assert child.returncode == 0, child.stderr
    frames = np.arange(2 * 3 * 4 * 3, dtype=np.uint8).reshape(2, 3, 4, 3)
    for i in range(2):
        png = np.fromfile(os.path.join(target, b"frames", b"%06d.png" % i), np.uint8)
        np.testing.assert_array_equal(cv2.imdecode(png, cv2.IMREAD_UNCHANGED)[..., ::-1], frames[i])


@pytest.fixture
def saved(tmp_path):
    seq = ListSequence([np.full((3, 4), i, np.uint8) for i in range(4)], _truths(4)[:4])
    return save_sequence(seq, tmp_path / "s", progress=False)


def test_missing_and_extra_frames(saved):
    (saved / "frames" / "000002.png").unlink()
    with pytest.raises(ValueError, match=r"frames.*1 of the 4 frames in meta.json are missing, e.g. 000002.png"):
        FolderSequence(saved)


def test_extra_frame(saved):
    (saved / "frames" / "000004.png").write_bytes((saved / "frames" / "000000.png").read_bytes())
    with pytest.raises(ValueError, match=r"1 frames beyond the 4 frames in meta.json, e.g. 000004.png"):
        FolderSequence(saved)


def _rewrite_csv_line(saved, line_no, new):
    path = saved / "truth.csv"
    lines = path.read_text().splitlines()
    lines[line_no - 1] = new
    path.write_text("\n".join(lines) + "\n")
    return path


def test_csv_wrong_column_count(saved):
    path = _rewrite_csv_line(saved, 3, "1,2,3")
    with pytest.raises(ValueError, match=re.escape(f"{path}, line 3 (frame 1): expected 18 columns; got 3")):
        FolderSequence(saved)


def test_csv_blank_lines_at_the_end_are_ignored_elsewhere_named(saved):
    path = saved / "truth.csv"
    text = path.read_text()
    truths = [FolderSequence(saved).truth(i) for i in range(4)]
    path.write_bytes(text.replace("\n", "\r\n").encode() + b"\r\n\r\n")  # as an editor on Windows leaves it
    assert [FolderSequence(saved).truth(i) for i in range(4)] == truths
    _rewrite_csv_line(saved, 3, "")
    with pytest.raises(ValueError, match=re.escape(f"{path}, line 3 (frame 1): a blank line; every frame needs a row")):
        FolderSequence(saved)


def test_csv_with_a_blank_first_line_is_named_not_read_as_a_header_of_no_columns(saved):
    """The blank line was the header: every row then had "expected 0 columns; got 18"."""
    path = saved / "truth.csv"
    path.write_text("\n" + path.read_text())
    with pytest.raises(ValueError, match=re.escape(f"{path}: line 1 is blank; expected a header row of FrameTruth")):
        FolderSequence(saved)


def test_a_shape_given_as_width_height_is_blamed_on_meta_json(tmp_path):
    """meta.json's [W, H] against 4 x 3 frames and a 4 x 3 camera: the mistake is meta.json's."""
    folder = save_sequence(ListSequence([np.zeros((3, 4), np.uint8)] * 2, camera=_camera(4, 3)), tmp_path / "s",
                           progress=False)
    meta = json.loads((folder / "meta.json").read_text())
    (folder / "meta.json").write_text(json.dumps({**meta, "shape": [4, 3]}))
    with pytest.raises(ValueError, match=re.escape("000000.png: image is 4 x 3 px; meta.json's shape [4, 3] (H, W) "
                                                   "says 3 x 4")):
        FolderSequence(folder)


def test_csv_non_numeric(saved):
    cells = [""] * 18
    cells[2] = "far"  # z
    path = _rewrite_csv_line(saved, 4, ",".join(cells))
    want = f"{path}, line 4 (frame 2), column 'z': expected a number; got 'far'"
    with pytest.raises(ValueError, match=re.escape(want)):
        FolderSequence(saved)


def test_csv_unknown_column_and_row_count(saved):
    path = saved / "truth.csv"
    text = path.read_text()
    path.write_text(text.replace("time_s", "colour", 1))
    with pytest.raises(ValueError, match=r"line 1: unknown column\(s\) 'colour'"):
        FolderSequence(saved)
    path.write_text("\n".join(text.splitlines()[:-1]) + "\n")
    with pytest.raises(ValueError, match=r"truth.csv: 3 rows for the 4 frames"):
        FolderSequence(saved)


def test_bad_meta(saved):
    meta = json.loads((saved / "meta.json").read_text())
    (saved / "meta.json").write_text(json.dumps({**meta, "dtype": "float32"}))
    with pytest.raises(ValueError, match=r"meta.json: shape \[3, 4\] with dtype 'float32'"):
        FolderSequence(saved)
    (saved / "meta.json").write_text(json.dumps({**meta, "frames": 0}))
    with pytest.raises(ValueError, match="meta.json, key 'frames': expected an integer >= 1; got 0"):
        FolderSequence(saved)
    (saved / "meta.json").unlink()
    with pytest.raises(FileNotFoundError, match=re.escape(f"meta.json is missing (a folder of plain images opens with "
                                                          f"'video:{saved}')")):
        open_sequence(str(saved))


def test_a_huge_frame_count_fails_fast_without_listing_expected_names(saved):
    """meta.json claiming 10⁹ frames once built 10⁹ names before checking (minutes, GBs)."""
    meta = json.loads((saved / "meta.json").read_text())
    (saved / "meta.json").write_text(json.dumps({**meta, "frames": 10 ** 9}))
    start = time.perf_counter()
    with pytest.raises(InputError, match=r"frames: 999999996 of the 1000000000 frames in meta.json are missing, "
                                         r"e.g. 000004.png, 000005.png, 000006.png"):
        FolderSequence(saved)
    assert time.perf_counter() - start < 1.0
    (saved / "meta.json").write_text(json.dumps({**meta, "frames": 1e9}))
    with pytest.raises(InputError, match="key 'frames': expected an integer >= 1; got 1000000000.0"):
        FolderSequence(saved)


def test_the_camera_height_travels_with_the_folder(tmp_path):
    """The simulator knows its camera's height above the ground (the blind start's ground plane);
    a saved copy keeps it, and a folder without the key (older ones) reads as unknown."""
    scene = SceneConfig(frames=2, camera_height_m=7.25)
    back = open_sequence(str(save_sequence(SyntheticSequence("btr_70", scene), tmp_path / "s", progress=False)))
    assert back.camera_height_m == 7.25
    meta = json.loads((tmp_path / "s" / "meta.json").read_text())
    del meta["camera_height_m"]
    (tmp_path / "s" / "meta.json").write_text(json.dumps(meta))
    assert math.isnan(FolderSequence(tmp_path / "s").camera_height_m)


def test_meta_json_refuses_unknown_keys(tmp_path):
    """A misspelt camera_hieght_m was ignored: the blind start had no ground plane and the range was off by 1000 m.
    Every key save_sequence writes (source and source_meta too) still reads."""
    scene = SceneConfig(frames=2, camera_height_m=7.25)
    folder = save_sequence(SyntheticSequence("btr_70", scene), tmp_path / "s", progress=False)
    meta = json.loads((folder / "meta.json").read_text())
    assert {"source", "source_meta", "camera_height_m"} <= set(meta) and FolderSequence(folder).camera_height_m == 7.25
    meta["camera_hieght_m"] = meta.pop("camera_height_m")
    (folder / "meta.json").write_text(json.dumps({**meta, "Notes": "x"}))
    with pytest.raises(InputError, match=re.escape(f"{folder / 'meta.json'}: unknown key(s) Notes, camera_hieght_m")
                       + "$"):
        FolderSequence(folder)


@pytest.mark.parametrize("edit, message", [
    (lambda m: {**m, "fps": True}, r"key 'fps' \(or null\): expected a finite number > 0; got True"),
    (lambda m: {**m, "camera_height_m": -2.0}, r"key 'camera_height_m' \(or null\): expected a finite number in "
                                               r"\(0, 10000\]; got -2.0"),
    (lambda m: {**m, "camera_height_m": 1e300}, r"key 'camera_height_m' \(or null\): expected a finite number in "
                                                r"\(0, 10000\]; got 1e\+300"),
    (lambda m: {**m, "camera_height_m": "5"}, r"key 'camera_height_m' \(or null\): expected a finite number in "
                                              r"\(0, 10000\]; got '5'"),
    (lambda m: {**m, "format_version": True}, "key 'format_version'"),
    (lambda m: {**m, "shape": [3, 100000]}, r"key 'shape': width: expected an integer in \[1, 16384\]"),
    (lambda m: {**m, "shape": [3.0, 4]}, r"shape \[3.0, 4\] with dtype 'uint8' is not a frame we store"),
    (lambda m: {**m, "name": 5}, "key 'name': expected a string; got 5"),
])
def test_bad_meta_values_name_the_key(saved, edit, message):
    meta = json.loads((saved / "meta.json").read_text())
    (saved / "meta.json").write_text(json.dumps(edit(meta)))
    with pytest.raises(InputError, match=rf"^{saved / 'meta.json'}.*{message}"):
        FolderSequence(saved)


def test_meta_and_truth_must_be_utf8_and_finite(saved):
    meta = saved / "meta.json"
    meta.write_bytes(meta.read_bytes().replace(b'"name": "', b'"name": "\xff'))
    with pytest.raises(InputError, match=rf"^{meta}, line \d+: not UTF-8 text \(byte 0xff"):
        FolderSequence(saved)
    meta.write_bytes(meta.read_bytes().replace(b"\xff", b""))
    truth = saved / "truth.csv"
    header, first, *rest = truth.read_text().splitlines()
    for bad in ("inf", "-inf", "1e400", "nan"):
        cells = first.split(",")
        cells[header.split(",").index("x")] = bad
        truth.write_text("\n".join([header, ",".join(cells), *rest]) + "\n")
        with pytest.raises(InputError, match=rf"^{truth}, line 2 \(frame 0\), column 'x': expected a finite number; "
                                             rf"got '{bad}'"):
            FolderSequence(saved)
    truth.write_text(header + "\n" + '"' + "x" * 200_000 + '"\n')
    with pytest.raises(InputError, match=rf"^{truth}, line 2: not a CSV file we can read \(field larger than field "
                                         r"limit"):
        FolderSequence(saved)
    truth.write_text("\n".join([header, first, *rest, first]) + "\n")
    with pytest.raises(InputError, match=rf"^{truth}, line 6 \(frame 4\): more rows than the 4 frames"):
        FolderSequence(saved)


def test_a_png_header_claiming_a_huge_image_is_refused_before_decoding(saved):
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    def png(width, height):
        return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
                + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b""))

    frame = saved / "frames" / "000002.png"
    seq = FolderSequence(saved)
    frame.write_bytes(png(60000, 60000))
    with pytest.raises(InputError, match=rf"^{frame}: image too large .*3600000000 pixels.*expected at most 67108864"):
        seq.frame(2)
    frame.write_bytes(png(5000, 5000))
    with pytest.raises(InputError, match=rf"^{frame}: image is 5000 x 5000 px; meta.json says 4 x 3"):
        seq.frame(2)
    frame.write_bytes(b"not a png at all")
    with pytest.raises(InputError, match=rf"^{frame}: cannot be read as an image"):
        seq.frame(2)


def test_index_errors_name_index_and_length(saved):
    seq = FolderSequence(saved)
    with pytest.raises(IndexError, match="frame index 4 out of range for a sequence of 4 frames"):
        seq.frame(4)
    with pytest.raises(IndexError, match="frame index -5 out of range for a sequence of 4 frames"):
        seq.truth(-5)
    for index in (1.0, True, np.bool_(True)):  # True was frame 1
        with pytest.raises(TypeError, match="frame index must be an integer"):
            seq.frame(index)
    assert seq.frame(np.int64(3))[0, 0] == 3 and seq.frame(-4)[0, 0] == 0


def test_frame_truth_checks_and_equality():
    a = FrameTruth(x=1, vehicle="T72")
    assert a == FrameTruth(x=1.0, vehicle="T72") and a != FrameTruth(x=1.0)
    assert isinstance(a.x, float) and math.isnan(a.y)
    assert FrameTruth().is_unknown() and not a.is_unknown()
    assert FrameTruth(u0=np.int64(3), v0=np.float32(0.5)) == FrameTruth(u0=3.0, v0=0.5)
    with pytest.raises(ValueError, match="FrameTruth.z: expected a number; got 'far'"):
        FrameTruth(z="far")
    for bad in ("12", True, np.bool_(False), None, [1.0]):
        with pytest.raises(ValueError, match=re.escape(f"FrameTruth.range_m: expected a number; got {bad!r}")):
            FrameTruth(range_m=bad)
    with pytest.raises(ValueError, match="FrameTruth.vehicle: expected a string"):
        FrameTruth(vehicle=3)


def test_all_unknown_truth_is_no_truth(tmp_path):
    """truth(i) is None both for None and for FrameTruth(), before and after a round trip."""
    frames = [np.zeros((3, 4), np.uint8)] * 3
    seq = ListSequence(frames, [FrameTruth(), None, FrameTruth(speed=2.0)])
    assert [seq.truth(i) for i in range(3)] == [None, None, FrameTruth(speed=2.0)]
    back = open_sequence(str(save_sequence(seq, tmp_path / "a", progress=False)))
    assert [back.truth(i) for i in range(3)] == [None, None, FrameTruth(speed=2.0)]
    only_unknown = ListSequence(frames[:1], [FrameTruth()])
    out = save_sequence(only_unknown, tmp_path / "b", progress=False)
    assert not (out / "truth.csv").exists() and open_sequence(str(out)).truth(0) is None


def test_parse_spec_options():
    assert parse_spec_options(" f.arf , calib = c.json,fps=3", ("fps", "calib")) == (
        "f.arf", {"calib": "c.json", "fps": "3"})
    assert parse_spec_options("a=1,anything=x", None, has_target=False) == ("", {"a": "1", "anything": "x"})
    assert parse_spec_options("  ", has_target=False) == ("", {})
    with pytest.raises(ValueError, match=r"expected key=value; got ''"):
        parse_spec_options("a=1,,b=2", has_target=False)
    with pytest.raises(ValueError, match=r"option 'a' given twice"):
        parse_spec_options("a=1,a=2", has_target=False)
    with pytest.raises(ValueError, match=r"unknown option 'z'; allowed: a, b"):
        parse_spec_options("f,z=1", ("b", "a"))


def test_open_sequence_errors(tmp_path):
    unknown = r"Unknown scheme 'nosuch' in sequence spec 'nosuch:x'; known schemes: .*folder"
    with pytest.raises(ValueError, match=unknown):
        open_sequence("nosuch:x")
    # The simulator registers on first use; a typo of it is still named, with the scheme meant.
    with pytest.raises(ValueError, match=r"known schemes: .*synthetic.* \(did you mean synthetic\?\)$"):
        open_sequence("syntetic:vehicle=t_72")
    with pytest.raises(FileNotFoundError, match=re.escape(str(tmp_path / "absent"))):
        open_sequence(str(tmp_path / "absent"))
    (tmp_path / "clip.avi").write_bytes(b"x")
    with pytest.raises(ValueError, match="is a file, not a sequence folder; open a video with 'video:PATH'"):
        open_sequence(str(tmp_path / "clip.avi"))
    with pytest.raises(ValueError, match="Expected a sequence spec string"):
        open_sequence("  ")
    with pytest.raises(ValueError, match=r"unknown option 'speed'; allowed: calib, color, fps"):
        open_sequence(f"video:{tmp_path / 'clip.avi'},speed=2")
    with pytest.raises(ValueError, match=r"expected key=value; got 'color'"):
        open_sequence(f"video:{tmp_path / 'clip.avi'},color")
    with pytest.raises(ValueError, match="names no file"):
        open_sequence("video:,color=1")
    with pytest.raises(ValueError, match="option 'fps' given twice"):
        open_sequence(f"video:{tmp_path / 'clip.avi'},fps=3,fps=4")


def test_a_path_with_a_comma_is_said_to_need_another_route(tmp_path):
    """``video:/tmp/a,b.avi`` said "expected key=value; got 'b.avi'", as if the user had written an option."""
    clip = tmp_path / "a,b.avi"
    clip.write_bytes(b"x")
    for scheme in ("video", "sensiac"):
        with pytest.raises(InputError) as info:
            open_sequence(f"{scheme}:{clip},fps=3")
        assert str(info.value) == (
            f"Sequence spec '{clip},fps=3': expected key=value; got 'b.avi': commas separate a spec's key=value "
            f"options, so a path with a comma cannot be given in a spec; rename or link it, or open it in Python with "
            f"its reader, torch_atr.data.VideoSequence(PATH) or torch_atr.data.SensiacSequence(PATH)")
    with pytest.raises(InputError, match=r"expected key=value; got 'color'$"):  # an option without its value
        open_sequence(f"video:{tmp_path / 'clip.avi'},color")


def test_register_scheme(monkeypatch, tmp_path):
    monkeypatch.setattr(sequence_module, "_SCHEMES", dict(sequence_module._SCHEMES))
    made = []

    def opener(rest):
        made.append(rest)
        return ListSequence([np.zeros((2, 2), np.uint8)], name=rest)

    register_scheme("toy", opener)
    register_scheme("toy", opener)  # same opener again: fine (module re-import)
    assert open_sequence("toy:a,b=c").name == "a,b=c" and made == ["a,b=c"]
    assert open_sequence("TOY:x").name == "x"
    with pytest.raises(ValueError, match="'toy' is already registered"):
        register_scheme("toy", lambda rest: None)
    register_scheme("toy", lambda rest: "replaced", replace=True)
    assert open_sequence("toy:q") == "replaced"
    for bad in ("c", "Toy", "1x", "a-b"):
        with pytest.raises(ValueError, match="Scheme name must match"):
            register_scheme(bad, opener)


def test_unknown_scheme_is_looked_up_as_a_module(monkeypatch):
    monkeypatch.setattr(sequence_module, "_SCHEMES", dict(sequence_module._SCHEMES))
    imported = []

    def import_module(name):
        imported.append(name)
        if name == "torch_atr.data.plugged":
            register_scheme("plugged", lambda rest: rest.upper())
            return
        raise ModuleNotFoundError(f"No module named {name!r}", name=name)

    monkeypatch.setattr(sequence_module, "importlib", types.SimpleNamespace(import_module=import_module))
    assert open_sequence("plugged:abc") == "ABC"
    assert open_sequence("plugged:d") == "D"
    with pytest.raises(ValueError, match="Unknown scheme 'missing'"):
        open_sequence("missing:x")
    assert imported == ["torch_atr.data.plugged", "torch_atr.data.missing"]


def test_load_camera_json_errors(tmp_path, caplog):
    cam = _camera(40, 30)
    path = tmp_path / "cam.json"
    path.write_text(json.dumps(cam.to_dict()))
    assert load_camera_json(path).to_dict() == cam.to_dict()
    d = cam.to_dict()
    del d["fy"]
    path.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=re.escape(f"{path}: missing key(s) fy")):
        load_camera_json(path)
    path.write_text("{not json")
    with pytest.raises(ValueError, match=re.escape(f"{path}, line 1, column 2: not valid JSON")):
        load_camera_json(path)
    with pytest.raises(FileNotFoundError, match="nope.json"):
        load_camera_json(tmp_path / "nope.json")
    # R is the tilt from the ground-levelled world, a rotation: a reflection is named with its file and key.
    d = cam.to_dict()
    d["R"] = [[1, 0, 0], [0, 1, 0], [0, 0, -1]]
    path.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=re.escape(f"{path}, key 'R': Expected a camera whose world frame is "
                                                   f"sensor-like") + ".*got det R = -1.000"):
        load_camera_json(path)
    d["R"] = [[1, 0, 0], [0, -1, 0], [0, 0, -1]]  # det +1, but turned 180 degrees about x: looking back
    path.write_text(json.dumps(d))
    with caplog.at_level(logging.WARNING):
        load_camera_json(path)
    assert "optical axis 180 degrees away from the world's forward z" in caplog.text


def test_camera_size_must_match_frames(tmp_path):
    seq = ListSequence([np.zeros((3, 4), np.uint8)], camera=_camera(40, 30))
    save_sequence(seq, tmp_path / "s", progress=False)
    with pytest.raises(ValueError, match=r"camera.json: camera is 40 x 30 px; frames are 4 x 3"):
        open_sequence(str(tmp_path / "s"))
