"""Our on-disk sequence format: a folder any image viewer and spreadsheet can open.

    FOLDER/
      frames/000000.png ...  one PNG per frame: 16-bit for uint16 frames, 8-bit otherwise
      meta.json              format, format_version, name, fps, frames, dtype, shape, source;
                             optional camera_height_m (above flat ground, metres; null or absent
                             = unknown), which gives the tracker's blind start its ground plane
      camera.json            ``Camera.to_dict()``; absent = uncalibrated
      truth.csv              one row per frame, header = FrameTruth fields, empty cell = unknown
                             (a row of empty cells = no truth for that frame, which is also how
                             an all-unknown FrameTruth is written); absent = no truth

:func:`save_sequence` writes the folder into a temporary folder beside the target and renames
it into place at the end, so a crash leaves no half-written sequence; it replaces only an empty
folder or (with ``overwrite=True``) an earlier sequence folder. A save that was killed leaves its
hidden temporary folder (``.STEM.XXXXXXXX.saving`` or ``.STEM.XXXXXXXX.superseded``), which the
next save of the same folder removes. STEM is the folder's NAME, or for a NAME of more than 64 bytes
its first characters (at most 32 bytes), '~' and 16 hex digits of its SHA-256: a hidden name is at
most 85 bytes, so any NAME the file system allows can be saved. :class:`FolderSequence` reads it
lazily: opening checks the file list and parses the small CSV, frames are read on demand.
"""

from __future__ import annotations

import csv
import fcntl
import io
import json
import logging
import math
import os
import re
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from torch_atr.data.sequence import (TEXT_FIELDS, TRUTH_FIELDS, FrameTruth, Sequence,
                                     check_camera_height, check_fps, load_camera_json, register_scheme)
from torch_atr.io import TEMP_CHARS, hidden_stem, strict_json, sync_folder, sync_tree, unheld
from torch_atr.validate import (InputError, image_file_size, image_size, integer, parse_real, read_image,
                                read_json_object, read_text, real, show)

logger = logging.getLogger(__name__)

FORMAT = "torch_atr.sequence"
FORMAT_VERSION = 1
_FRAME_RE = re.compile(r"\d{6,}\.png")
FRAME_RULE = "(H, W) uint8/uint16 or (H, W, 3) uint8"
_WRITING = ".saving"  # .STEM.XXXXXXXX.saving: a save's new sequence until it is renamed to NAME
_SUPERSEDED = ".superseded"  # .STEM.XXXXXXXX.superseded: holds NAME, the sequence a save replaces, until deleted
_WRITTEN = frozenset({"frames", "truth.csv", "camera.json", "meta.json"})  # what a save writes in its folder


def _is_stored_frame(shape: tuple[int, ...], dtype: str) -> bool:
    """True for a frame shape and dtype name we store: ``FRAME_RULE``."""
    return (len(shape) == 2 and dtype in ("uint8", "uint16")) or (
        len(shape) == 3 and shape[2] == 3 and dtype == "uint8")


def _frame_filename(i: int) -> str:
    """File name of frame ``i`` inside ``frames/``."""
    return f"{i:06d}.png"


def _check_frame(name: str, i: int, img, like: np.ndarray | None = None) -> None:
    """Raise ``ValueError`` unless ``img`` is a frame we store (``FRAME_RULE``, colour in RGB
    order), shaped like ``like`` if given."""
    if not isinstance(img, np.ndarray):
        raise ValueError(f"{name}: frame {i}: expected a numpy array; got {type(img).__name__}")
    if not _is_stored_frame(img.shape, str(img.dtype)):
        raise ValueError(f"{name}: frame {i}: expected {FRAME_RULE}; got {img.shape} {img.dtype}")
    if like is not None and (img.shape != like.shape or img.dtype != like.dtype):
        raise ValueError(f"{name}: frame {i} is {img.shape} {img.dtype}; frame 0 was {like.shape} {like.dtype}")


class FolderSequence(Sequence):
    """A sequence stored in our folder format (see the module docstring)."""

    def __init__(self, folder: str | os.PathLike):
        self.folder = Path(os.path.expanduser(folder))  # ~ as a shell would, for specs from config files
        if not self.folder.exists():
            raise FileNotFoundError(f"Sequence folder not found: {self.folder}")
        if not self.folder.is_dir():
            raise InputError(f"{self.folder} is a file, not a sequence folder; open a video with "
                             f"'video:PATH' or an ARF with 'sensiac:PATH'")
        self.meta = _read_meta(self.folder / "meta.json")
        self.name = self.meta["name"]
        self.fps = math.nan if self.meta["fps"] is None else float(self.meta["fps"])
        height = self.meta.get("camera_height_m")
        self.camera_height_m = math.nan if height is None else float(height)
        self._n = self.meta["frames"]
        self._shape = tuple(self.meta["shape"])
        self._dtype = np.dtype(self.meta["dtype"])
        _check_frame_files(self.folder / "frames", self._n)
        first = self.folder / "frames" / _frame_filename(0)
        width, height = image_file_size(first)  # the header only: meta.json's shape checked before the camera's
        if (height, width) != self._shape[:2]:
            raise InputError(f"{first}: image is {width} x {height} px; meta.json's shape {list(self._shape)} "
                             f"(H, W) says {self._shape[1]} x {self._shape[0]}")
        cam_path = self.folder / "camera.json"
        self.camera = load_camera_json(cam_path) if cam_path.exists() else None
        if self.camera is not None and (self.camera.height, self.camera.width) != self._shape[:2]:
            raise InputError(f"{cam_path}: camera is {self.camera.width} x {self.camera.height} px; "
                             f"frames are {self._shape[1]} x {self._shape[0]}")
        truth_path = self.folder / "truth.csv"
        self._truths = _read_truth_csv(truth_path, self._n) if truth_path.exists() else None

    def __len__(self) -> int:
        return self._n

    def _read_frame(self, i: int) -> np.ndarray:
        path = self.folder / "frames" / _frame_filename(i)
        img = read_image(path, (self._shape[1], self._shape[0]), "meta.json")  # a wrong size found before decoding
        if img.ndim == 3 and img.shape[2] == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        if img.shape != self._shape or img.dtype != self._dtype:
            raise InputError(f"{path}: image is {img.shape} {img.dtype}; meta.json says "
                             f"{self._shape} {self._dtype}")
        return img

    def _truth(self, i: int) -> FrameTruth | None:
        return None if self._truths is None else self._truths[i]


def _read_meta(path: Path) -> dict:
    """meta.json, checked: our format and version, a name, fps null or > 0, camera_height_m absent,
    null or in (0, MAX_CAMERA_HEIGHT_M], frames >= 1 and a frame shape and dtype we store within the image bounds of
    :mod:`torch_atr.validate`; no key but these and what :func:`save_sequence` writes (source, source_meta)."""
    meta = read_json_object(path, f"Not a sequence folder: {path} is missing (a folder of plain images opens "
                                  f"with 'video:{path.parent}')")
    required = ("format", "format_version", "name", "fps", "frames", "dtype", "shape")
    missing = [k for k in required if k not in meta]
    if missing:
        raise InputError(f"{path}: missing key(s) {', '.join(missing)}")
    unknown = sorted(set(meta) - set(required) - {"camera_height_m", "source", "source_meta"})
    if unknown:  # a misspelt camera_height_m would leave the height unknown unnoticed
        raise InputError(f"{path}: unknown key(s) {', '.join(unknown)}")
    if meta["format"] != FORMAT:
        raise InputError(f"{path}: format is {show(meta['format'])}; expected {FORMAT!r}")
    integer(f"{path}, key 'format_version' (this reader knows 1..{FORMAT_VERSION})", meta["format_version"], 1,
            FORMAT_VERSION)
    if not isinstance(meta["name"], str):
        raise InputError(f"{path}, key 'name': expected a string; got {show(meta['name'])}")
    if meta["fps"] is not None:
        real(f"{path}, key 'fps' (or null)", meta["fps"], lo=0, lo_open=True)
    check_camera_height(f"{path}, key 'camera_height_m' (or null)", meta.get("camera_height_m"))
    integer(f"{path}, key 'frames'", meta["frames"], lo=1)
    shape, dtype = meta["shape"], meta["dtype"]
    if not (isinstance(shape, list) and len(shape) in (2, 3) and isinstance(dtype, str)
            and all(isinstance(s, int) and not isinstance(s, bool) for s in shape)
            and _is_stored_frame(tuple(shape), dtype)):
        raise InputError(f"{path}: shape {show(shape)} with dtype {show(dtype)} is not a frame we store ({FRAME_RULE})")
    image_size(f"{path}, key 'shape'", shape[1], shape[0])
    return meta


def _check_frame_files(frames_dir: Path, n: int) -> None:
    """Check that ``frames_dir`` holds exactly the frames 0..n-1, in time linear in the files
    present (not in ``n``, which comes from meta.json)."""
    if not frames_dir.is_dir():
        raise FileNotFoundError(f"Frames folder not found: {frames_dir}")
    present = {p.name for p in frames_dir.iterdir() if not p.name.startswith(".")}
    extra = sorted(name for name in present
                   if not (_FRAME_RE.fullmatch(name) and int(name[:-4]) < n
                           and name == _frame_filename(int(name[:-4]))))
    found = len(present) - len(extra)
    if found < n:
        examples = []
        i = 0
        while len(examples) < 3 and i < n:  # at most len(present) + 3 steps
            if _frame_filename(i) not in present:
                examples.append(_frame_filename(i))
            i += 1
        raise InputError(f"{frames_dir}: {n - found} of the {n} frames in meta.json are missing, "
                         f"e.g. {', '.join(examples)}")
    if extra:
        kind = "frames beyond" if all(_FRAME_RE.fullmatch(e) for e in extra) else "files not among"
        raise InputError(f"{frames_dir}: {len(extra)} {kind} the {n} frames in meta.json, "
                         f"e.g. {', '.join(extra[:3])}")


def _cell(value) -> str:
    if isinstance(value, str):
        return value
    return "" if math.isnan(value) else repr(value)


def _write_truth_csv(path: Path, truths: list[FrameTruth | None]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(TRUTH_FIELDS)
        for t in truths:
            writer.writerow(["" if t is None else _cell(getattr(t, f)) for f in TRUTH_FIELDS])


def _read_truth_csv(path: Path, n: int) -> list[FrameTruth | None]:
    """Rows of ``truth.csv``: a FrameTruth per row, None for a row of empty cells. Numbers must be
    finite (an empty cell is unknown); more rows than the ``n`` frames are refused, naming the
    first one past them; blank lines at the end are ignored, elsewhere refused. (The file is read
    whole, within ``read_text``'s size bound.)"""
    truths: list[FrameTruth | None] = []
    reader = csv.reader(io.StringIO(read_text(path), newline=""))
    try:
        header = next(reader, None)
        if not header:  # a blank first line read as a header of no columns: every row then had too many
            raise InputError(f"{path}: {'empty file' if header is None else 'line 1 is blank'}; expected a header row "
                             f"of FrameTruth fields")
        unknown = [c for c in header if c not in TRUTH_FIELDS]
        if unknown:
            raise InputError(f"{path}, line 1: unknown column(s) {', '.join(map(show, unknown[:5]))}; "
                             f"known: {', '.join(TRUTH_FIELDS)}")
        if len(set(header)) != len(header):
            raise InputError(f"{path}, line 1: repeated column names in {header}")
        rows = [(reader.line_num, cells) for cells in reader]
        while rows and not rows[-1][1]:  # blank lines at the end, as editors leave them
            rows.pop()
        for line, cells in rows:
            where = f"{path}, line {line} (frame {len(truths)})"
            if len(truths) == n:
                raise InputError(f"{where}: more rows than the {n} frames in meta.json")
            if not cells:
                raise InputError(f"{where}: a blank line; every frame needs a row (its cells may be empty)")
            if len(cells) != len(header):
                raise InputError(f"{where}: expected {len(header)} columns; got {len(cells)}")
            values = {key: cell if key in TEXT_FIELDS else parse_real(f"{where}, column {key!r}", cell)
                      for key, cell in zip(header, cells) if cell != ""}
            truths.append(FrameTruth(**values) if values else None)
    except csv.Error as exc:
        raise InputError(f"{path}, line {reader.line_num}: not a CSV file we can read ({exc})") from None
    if len(truths) != n:
        raise InputError(f"{path}: {len(truths)} rows for the {n} frames in meta.json")
    return truths


def save_sequence(seq: Sequence, folder: str | os.PathLike, progress: bool = True,
                  overwrite: bool = False) -> Path:
    """Write ``seq`` (frames, camera, camera height, truth, meta) to ``folder`` in our format;
    return the folder.

    An existing empty ``folder`` is replaced. A non-empty one is refused (``FileExistsError``
    naming it) unless ``overwrite=True`` and it is a sequence folder (its ``meta.json`` says our
    format), so no other folder is ever deleted. Everything is written into a temporary folder
    beside ``folder``, flushed to disk file by file (fsync) and renamed into place at the end, so that after a
    power cut ``folder`` holds the old sequence or the whole new one; the folder gets the mode a new folder
    gets (0o777 less the umask). What :class:`FolderSequence` would refuse to read (an fps or a
    camera height out of range, an infinite truth value) is refused before anything is written.

    A save that is killed (no clean-up runs) leaves its temporary folder behind, and one killed
    while swapping leaves the sequence it was replacing in a hidden folder beside ``folder`` (see
    the module docstring). Each save holds an exclusive ``flock`` on the folders it writes until it
    ends, so those nobody holds are a killed save's: this save removes the temporary folders of
    earlier saves of ``folder`` before it writes, and the replaced sequences once its own sequence
    is in place (the sequences a save with ``overwrite=True`` was asked to replace). A folder that
    holds anything a save does not write is left alone.
    """
    folder = Path(os.path.expanduser(folder))
    if folder.name in ("", ".", ".."):
        raise ValueError(f"save_sequence: {str(folder)!r} names no folder to create; give one such as runs/clip")
    n = len(seq)
    if n == 0:
        raise ValueError(f"{seq.name}: cannot save a sequence with no frames")
    fps = float(seq.fps)
    if not math.isnan(fps):
        check_fps(fps, f"{seq.name} (not saved)")
    height = check_camera_height(f"{seq.name} (not saved): camera_height_m (metres, or NaN)", seq.camera_height_m)
    try:
        exists = folder.exists()
    except OSError as exc:  # a name too long for the file system: one line naming it
        raise OSError(exc.errno, f"save_sequence: cannot write {folder}: {exc.strerror}") from None
    if exists:
        if not folder.is_dir():
            raise FileExistsError(f"{folder} exists and is not a folder")
        if any(folder.iterdir()):
            if not overwrite:
                raise FileExistsError(f"{folder} is not empty; pass overwrite=True to replace it")
            if not _is_sequence_folder(folder):
                raise FileExistsError(f"{folder} is not a sequence folder (no meta.json with format "
                                      f"{FORMAT!r}); refusing to replace it even with overwrite=True")
    folder.parent.mkdir(parents=True, exist_ok=True)
    _remove_left_by_killed_saves(folder, _WRITING, _WRITTEN)
    tmp, lock = _held_folder(folder, _WRITING)
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes 0700; give the folder a plain folder's mode
        (tmp / "frames").mkdir()
        first = None
        truths = []
        for i in tqdm(range(n), desc=f"saving {seq.name}", unit="frame", disable=not progress):
            img = seq.frame(i)
            _check_frame(seq.name, i, img, like=first)
            first = img if first is None else first
            out = tmp / "frames" / _frame_filename(i)
            ok, png = cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR) if img.ndim == 3 else img)
            if not ok:
                raise OSError(f"cv2.imencode could not encode {seq.name}'s frame {i} as PNG")
            png.tofile(out)  # not cv2.imwrite, which crashes the process on a path that is not UTF-8
            truths.append(_savable_truth(seq.name, i, seq.truth(i)))
        if any(t is not None for t in truths):
            _write_truth_csv(tmp / "truth.csv", truths)
        if seq.camera is not None:
            (tmp / "camera.json").write_text(json.dumps(seq.camera.to_dict(), indent=1), encoding="utf-8")
        meta = {"format": FORMAT, "format_version": FORMAT_VERSION, "name": seq.name, "fps": fps, "frames": n,
                "dtype": str(first.dtype), "shape": list(first.shape), "camera_height_m": height,
                "source": type(seq).__name__, "source_meta": seq.meta}
        (tmp / "meta.json").write_text(json.dumps(strict_json(meta), indent=1, default=str, allow_nan=False),
                                       encoding="utf-8")
        sync_tree(tmp)
        _swap_in(tmp, folder)
        sync_folder(folder.parent)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        os.close(lock)
    _remove_left_by_killed_saves(folder, _SUPERSEDED, frozenset({folder.name}))
    logger.info("saved %d frames of %s to %s", n, seq.name, folder)
    return folder


def _savable_truth(name: str, i: int, truth: FrameTruth | None) -> FrameTruth | None:
    """``truth`` after checking that truth.csv can hold it: every number finite or NaN (unknown)."""
    if truth is not None:
        for field in TRUTH_FIELDS:
            value = getattr(truth, field)
            if field not in TEXT_FIELDS and math.isinf(value):
                raise ValueError(f"{name} (not saved): frame {i}'s truth {field} is {value}; expected a finite "
                                 f"number or NaN (unknown)")
    return truth


def _is_sequence_folder(folder: Path) -> bool:
    """True when ``folder/meta.json`` is a JSON object whose format is ours."""
    try:
        meta = read_json_object(folder / "meta.json", "")
    except (OSError, ValueError):
        return False
    return meta.get("format") == FORMAT


def _swap_in(tmp: Path, folder: Path) -> None:
    """Rename ``tmp`` to ``folder``. An existing ``folder`` is first moved into a held
    ``.STEM.XXXXXXXX.superseded`` folder, put back if the rename fails, and deleted after it."""
    if not folder.exists():
        os.replace(tmp, folder)
        return
    old, lock = _held_folder(folder, _SUPERSEDED)
    try:
        os.replace(folder, old / folder.name)
        try:
            os.replace(tmp, folder)
        except BaseException:
            os.replace(old / folder.name, folder)
            old.rmdir()
            raise
        shutil.rmtree(old)
    finally:
        os.close(lock)


def _held_folder(folder: Path, kind: str) -> tuple[Path, int]:
    """A new empty folder ``.STEM.XXXXXXXX{kind}`` beside ``folder`` (STEM: ``io.hidden_stem``) and
    an open descriptor that holds an exclusive ``flock`` on it until the caller closes it. The kernel
    drops the lock when the process ends, however it ends, so one that nobody holds was left by a
    killed save (:func:`_remove_left_by_killed_saves`)."""
    try:
        path = Path(tempfile.mkdtemp(prefix=f".{hidden_stem(folder.name)}.", suffix=kind, dir=folder.parent))
    except OSError as exc:  # name the folder the user asked for, not our hidden one
        raise OSError(exc.errno, f"save_sequence: cannot write {folder}: {exc.strerror}") from None
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
    except OSError:  # a file system that cannot lock folders (NFS): nor can a later save, which keeps it
        pass
    return path, fd


def _remove_left_by_killed_saves(folder: Path, kind: str, holds: frozenset[str]) -> None:
    """Delete the ``.STEM.XXXXXXXX{kind}`` folders beside ``folder`` (see :func:`_held_folder`) that
    no live save holds and that hold nothing but entries named in ``holds``: those that killed saves
    of ``folder`` left. Anything else (a file or link of that name, a folder with other entries, one
    the file system cannot lock) stays; one that cannot be removed is logged, not raised."""
    pattern = re.compile(rf"\.{re.escape(hidden_stem(folder.name))}\.{TEMP_CHARS}{re.escape(kind)}")
    for candidate in folder.parent.iterdir():
        if not pattern.fullmatch(candidate.name) or candidate.is_symlink() or not candidate.is_dir():
            continue
        with unheld(candidate) as stale:
            try:
                if stale and {entry.name for entry in candidate.iterdir()} <= holds:
                    shutil.rmtree(candidate)
                    logger.info("removed %s, left by a save of %s that was killed", candidate, folder)
            except OSError as exc:
                logger.warning("could not remove %s, left by a save of %s that was killed: %s", candidate, folder,
                               exc)


register_scheme("folder", FolderSequence)
