"""Safe writes: atomic files, temp files of killed writes cleaned up, nothing replaced unasked.

:func:`atomic_path` writes a file so that it is either its old or its new content, never half
written. Each write holds an exclusive ``flock`` on its temporary file ``.STEM.XXXXXXXX.tmp``
(STEM: :func:`hidden_stem`); the next write of the same target deletes the temporary files of that
target nobody holds, i.e. those of writes that were killed. :func:`check_output_file` and
:func:`check_output_dir` decide whether an entry point may write an output: never over something
that is not ours, and over our own only when the user said so (``--overwrite``).
"""

from __future__ import annotations

import csv
import errno
import fcntl
import hashlib
import io
import json
import logging
import math
import os
import re
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

import torch

log = logging.getLogger(__name__)

TEMP_CHARS = "[a-z0-9_]{8}"  # tempfile's random part
_STEM_BYTES = 64  # a longer NAME is shortened in its hidden files' names (hidden_stem)
_STEM_PREFIX_BYTES = 32  # how much of a shortened NAME they keep
_SET_ASIDE = ".replaced"  # claimed_output_dir: the suffix of a replaced run's files until the new run ends
_TEMP_SUFFIX = r"(\.[A-Za-z0-9]{1,8})?"  # an extension after .tmp, for writers that go by it (.mp4)
_ANY_TEMP = re.compile(rf"\..+\.{TEMP_CHARS}\.tmp{_TEMP_SUFFIX}")
RUN_CLAIM = ".torch_atr_run"  # written into a run folder as a run starts: an interrupted run's folder stays ours


class OutputExistsError(FileExistsError):
    """An output that exists and may not be replaced (not ours, or ours without ``--overwrite``)."""


@contextmanager
def unheld(candidate: Path) -> Iterator[bool]:
    """True, holding its lock for the block, when no live write holds ``candidate``; False when
    one does or it is gone."""
    try:
        fd = os.open(candidate, os.O_RDONLY)
    except OSError:  # gone already, or not ours to read
        yield False
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:  # a live write holds it
            yield False
            return
        yield True
    finally:
        os.close(fd)


def hidden_stem(name: str) -> str:
    """The STEM of the hidden files and folders ``.STEM.XXXXXXXX.tmp`` (``.saving``, ...) that a write
    of ``name`` makes beside it: ``name`` itself up to 64 bytes; a longer one's first characters (at most
    32 bytes), '~' and the first 16 hex digits of its SHA-256, so that their names stay far below the
    file system's 255-byte limit whatever the length of ``name``."""
    encoded = os.fsencode(name)
    if len(encoded) <= _STEM_BYTES:
        return name
    prefix = name[:_STEM_PREFIX_BYTES]
    while len(os.fsencode(prefix)) > _STEM_PREFIX_BYTES:  # whole characters only
        prefix = prefix[:-1]
    return f"{prefix}~{hashlib.sha256(encoded).hexdigest()[:16]}"


def _remove_stale_temps(path: Path) -> None:
    """Delete ``.STEM.XXXXXXXX.tmp`` files (:func:`hidden_stem`) beside ``path`` that no live write holds."""
    pattern = re.compile(rf"\.{re.escape(hidden_stem(path.name))}\.{TEMP_CHARS}\.tmp{_TEMP_SUFFIX}")
    for candidate in path.parent.iterdir():
        if pattern.fullmatch(candidate.name):
            with unheld(candidate) as stale:
                if stale:
                    candidate.unlink(missing_ok=True)
                    log.info("removed %s, left by an interrupted write of %s", candidate, path)


def _is_stale_temp(path: Path) -> bool:
    """True for the temporary file of a killed write (any target): the next write of it removes it."""
    if not _ANY_TEMP.fullmatch(path.name) or not path.is_file():
        return False
    with unheld(path) as stale:
        return stale


def _locked_temp(target: Path, suffix: str) -> tuple[int, Path]:
    """A new temporary file ``.STEM.XXXXXXXX.tmp`` + ``suffix`` beside ``target``, open and exclusively
    locked (until this write ends or its process dies): its descriptor and path.

    Between its creation and the lock, another write of the same target may take it for a killed write's and
    delete it; a file found unlinked once locked is left and another made."""
    while True:
        fd, tmp = tempfile.mkstemp(prefix=f".{hidden_stem(target.name)}.", suffix=".tmp" + suffix, dir=target.parent)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            if os.fstat(fd).st_nlink:
                return fd, Path(tmp)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            os.close(fd)
            raise
        os.close(fd)


@contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (ending ``.tmp`` + ``suffix``, e.g. ".mp4" for a
    writer that picks its format by the extension); on success rename it over ``path`` (for a
    symbolic link: beside and over the link's target, below).

    The temporary file is removed if the block raises, so nothing half written is left; one left
    by a killed write of the same target is removed when this write starts. A symbolic link is
    written through: its target gets the new content and the link stays (as ``>`` in a shell).
    """
    path = Path(path)
    if not re.fullmatch(_TEMP_SUFFIX, suffix):
        raise ValueError(f"suffix must be empty or a short extension like '.mp4'; got {suffix!r}")
    target = Path(os.path.realpath(path)) if path.is_symlink() else path
    if target.is_symlink():  # realpath stops in a loop of links (a -> b -> a), as a shell's > fails there
        raise OSError(errno.ELOOP, f"cannot write {path}: {os.strerror(errno.ELOOP)}")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_path = _locked_temp(target, suffix)
    except OSError as exc:  # name the file the user asked for, not our temporary one
        raise OSError(exc.errno, f"cannot write {path}: {exc.strerror}") from None
    try:
        _remove_stale_temps(target)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp makes 0600; give the file a plain file's mode
        yield tmp_path
        try:
            os.fsync(fd)  # the content on disk before the name: after a power cut, the old file or the new, not 0 bytes
            os.replace(tmp_path, target)
            sync_folder(target.parent)
        except OSError as exc:  # a full disk, a folder in the way: named as above
            raise OSError(exc.errno, f"cannot write {path}: {exc.strerror}") from None
    finally:
        tmp_path.unlink(missing_ok=True)
        os.close(fd)


def sync_tree(folder: str | os.PathLike) -> None:
    """fsync every file under ``folder``, then each folder from the deepest up, so that a folder written whole
    and then renamed into place (as :func:`~torch_atr.data.save_sequence` does) holds its content after a
    power cut, not empty files."""
    folder = Path(folder)
    for root, _, files in os.walk(folder, topdown=False):
        for name in files:
            fd = os.open(Path(root) / name, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        sync_folder(Path(root))


def sync_folder(folder: str | os.PathLike) -> None:
    """fsync ``folder``, so that a rename in it survives a power cut (where the system allows it)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # a folder we may write but not read
        return
    try:
        os.fsync(fd)
    except OSError:  # some file systems refuse fsync on a folder
        pass
    finally:
        os.close(fd)


def atomic_torch_save(obj, path: str | os.PathLike) -> None:
    """``torch.save`` through :func:`atomic_path`."""
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)


def strict_json(value):
    """``value`` for strict JSON: every non-finite float in its dicts, lists and tuples is None (null),
    and NumPy numbers are Python's (``json`` writes NaN as a bare ``NaN`` that strict readers, ours
    included, refuse, and knows no NumPy type)."""
    if hasattr(value, "dtype") and getattr(value, "shape", None) == ():  # a NumPy scalar
        value = value.item()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict_json(v) for v in value]
    return value


def atomic_write_text(text: str, path: str | os.PathLike) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def atomic_write_csv(rows: list[dict], path: str | os.PathLike, columns: list[str] | None = None) -> None:
    """Write dict rows as CSV atomically: header = ``columns`` (default: :func:`column_order`);
    missing values and NaN are empty cells; floats keep 6 significant digits."""
    if columns is None:
        columns = column_order(rows)

    def cell(value) -> str:
        if value is None or (isinstance(value, float) and math.isnan(value)):
            return ""
        return f"{value:.6g}" if isinstance(value, float) else str(value)

    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(columns)
    writer.writerows([cell(row.get(c)) for c in columns] for row in rows)
    atomic_write_text(buffer.getvalue(), path)


def column_order(rows: list[dict]) -> list[str]:
    """Every key of dict rows once, each after the key before it in the first row that has it: the
    rows' own order, whichever row comes first (a first row with fewer keys, say a frame without an
    estimate, does not push the later rows' keys to the end)."""
    order: list[str] = []
    for keys in dict.fromkeys(tuple(row) for row in rows):  # each distinct key sequence once
        at = 0
        for key in keys:
            if key in order:
                at = max(at, order.index(key) + 1)  # never back: a key met out of order keeps its place
            else:
                order.insert(at, key)
                at += 1
    return order


def check_output_file(path: str | os.PathLike, overwrite: bool, is_ours: Callable[[Path], bool], what: str) -> Path:
    """Check that ``path`` may be written; return it as a Path.

    Absent: fine. A folder, or a file ``is_ours`` rejects: refused even with ``overwrite``.
    A file of ours: refused unless ``overwrite``. Raises :class:`OutputExistsError` naming it.
    """
    path = Path(path)
    if not path.exists():
        return path
    if not path.is_file():
        raise OutputExistsError(f"{path} exists and is not a file; the {what} must be a file")
    if not is_ours(path):
        raise OutputExistsError(f"{path} exists and is not a {what}; refusing to replace it (even with "
                                f"--overwrite): move it away or write the {what} elsewhere")
    if not overwrite:
        raise OutputExistsError(f"{path} exists; pass --overwrite to replace it, or write the {what} elsewhere")
    return path


def check_output_dir(folder: str | os.PathLike, overwrite: bool, marker: str, is_ours: Callable[[Path], bool],
                     what: str) -> Path:
    """Check that the output folder ``folder`` may take a new run; return it as a Path.

    A finished run's folder holds the file ``marker`` (e.g. ``report.json``) that ``is_ours``
    recognises; an interrupted one holds the claim :func:`claim_output_dir` wrote for ``what``.
    Absent, or empty but for the temporary files of killed writes: fine. Holding our run, finished
    or not: refused unless ``overwrite``. Anything else (a file, a folder with other content, e.g.
    another tool's): refused even with ``overwrite``. Raises :class:`OutputExistsError` naming the
    folder.
    """
    folder = Path(folder)
    if not folder.exists():
        return folder
    if not folder.is_dir():
        raise OutputExistsError(f"{folder} exists and is not a folder; the {what} must be a folder")
    if all(_is_stale_temp(entry) for entry in folder.iterdir()):
        return folder
    finished = (folder / marker).is_file() and is_ours(folder / marker)
    if finished or claim_of(folder) == what:
        if not overwrite:
            held = f"a {what} ({marker})" if finished else f"an interrupted {what} (no {marker})"
            raise OutputExistsError(f"{folder} already holds {held}; pass --overwrite to replace it, or choose "
                                    f"another folder")
        return folder
    raise OutputExistsError(f"{folder} is not empty and holds no {marker} of ours (another tool's folder, or a run "
                            f"of an older version); refusing to write a {what} into it (even with --overwrite): "
                            f"delete it or choose another folder")


def claim_of(folder: Path) -> str | None:
    """What the claim in ``folder`` (:func:`write_claim`) says holds it; None where it has none."""
    try:
        claim = json.loads((folder / RUN_CLAIM).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    ok = isinstance(claim, dict) and claim.get("format") == RUN_CLAIM and isinstance(claim.get("what"), str)
    return claim["what"] if ok else None


def write_claim(folder: Path, what: str) -> None:
    """Claim ``folder`` (which exists) for ``what``: the folder of a run that may be interrupted stays ours."""
    atomic_write_text(json.dumps({"format": RUN_CLAIM, "what": what}) + "\n", folder / RUN_CLAIM)


@contextmanager
def claimed_output_dir(folder: Path, what: str, replaces: tuple[str, ...] = ()) -> Iterator[Path]:
    """Hold ``folder`` (checked by :func:`check_output_dir`) as this run's: a claim is written into
    it, creating it, before anything else, so that an unwritable folder is found before the work
    and a run killed midway leaves a folder that ``--overwrite`` may replace.

    Of the run it replaces, the files ``replaces`` names (glob patterns: its marker, so that the
    folder reads as interrupted until this run finishes, and every other output, since this run
    may not write the same ones: a model.pt beside a report of another model misleads) and the
    TensorBoard event files (or TensorBoard shows two runs as one) are set aside (renamed
    ``.NAME.replaced``) and deleted when the block ends; other files in the folder stay. If the
    block raises before anything was written (say a bad frame or value the work found), they come
    back and a claim it made (and the folders it created, ``folder`` and any above it) goes: the
    earlier run is as it was. Files set aside by a killed run are deleted.
    """
    made, claimed = _missing_folders(folder), (folder / RUN_CLAIM).exists()
    try:
        write_claim(folder, what)
    except OSError as exc:
        _remove_empty(made)
        if exc.errno is None:
            raise
        raise OSError(exc.errno, f"cannot write the {what} into {folder}: {os.strerror(exc.errno)}") from None
    for left in folder.glob(f".*{_SET_ASIDE}"):
        left.unlink(missing_ok=True)
    olds = sorted({p for pattern in (*replaces, "events.out.tfevents.*") for p in folder.glob(pattern) if p.is_file()})
    before = _listing(folder, skip=olds)
    aside = []
    try:
        for old in olds:
            aside.append((old, old.with_name(f".{old.name}{_SET_ASIDE}")))
            os.replace(*aside[-1])
    except OSError:  # a file that cannot be moved: those moved come back, not deleted at the next claim
        for old, kept in aside[:-1]:
            os.replace(kept, old)
        raise
    try:
        yield folder
    except BaseException:
        if _listing(folder, skip=[kept for _, kept in aside]) == before:  # nothing written: undo the claim
            for old, kept in aside:
                os.replace(kept, old)
            if not claimed:
                (folder / RUN_CLAIM).unlink(missing_ok=True)
            if made and all(_is_stale_temp(entry) for entry in folder.iterdir()):
                for entry in folder.iterdir():
                    entry.unlink()
                _remove_empty(made)
        raise
    finally:
        for _, kept in aside:
            kept.unlink(missing_ok=True)


def _missing_folders(folder: Path) -> list[Path]:
    """``folder`` and the folders above it that do not exist (a run would create them), deepest first."""
    missing = []
    for path in (folder, *folder.parents):
        if path.exists():
            break
        missing.append(path)
    return missing


def _remove_empty(folders: list[Path]) -> None:
    """Remove each of ``folders`` (deepest first) while it is empty; stop at the first that is not (or
    that may not be removed): those above it are not empty either."""
    for path in folders:
        try:
            path.rmdir()
        except OSError:
            if os.path.isdir(path):  # not empty: kept (one never created, by a write that failed, is passed)
                break


@contextmanager
def created_folders(folder: str | os.PathLike) -> Iterator[Path]:
    """Yield ``folder``; if the block raises, remove it and the folders above it that did not exist
    when the block began, each only while empty (a failed run leaves none of the empty folders it
    made, and never removes one that was there before)."""
    folder = Path(folder)
    made = _missing_folders(folder)
    try:
        yield folder
    except BaseException:
        _remove_empty(made)
        raise


def _listing(folder: Path, skip: list[Path]) -> dict[str, tuple[int, int]]:
    """{name: (mtime ns, size)} of the entries of ``folder`` but ``skip`` and killed writes' temp files."""
    names = {p.name for p in skip}
    return {e.name: (st.st_mtime_ns, st.st_size) for e in folder.iterdir()
            if e.name not in names and not _is_stale_temp(e) for st in (e.stat(),)}


def check_writable(path: str | os.PathLike) -> None:
    """Raise OSError naming ``path`` when its folder cannot be created or written to (so that a bad
    output path is reported before the work, not after)."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path.parent):
            pass
    except OSError as exc:
        there = next(p for p in path.parents if os.path.exists(p))  # the nearest: a file where a folder must be?
        if isinstance(exc, (FileExistsError, NotADirectoryError)) and not os.path.isdir(there):
            raise NotADirectoryError(errno.ENOTDIR, f"cannot write {path}: {os.strerror(errno.ENOTDIR)} ({there} is "
                                                    f"a file)") from None  # mkdir's "File exists" named neither
        raise OSError(exc.errno, f"cannot write {path}: {exc.strerror}") from None
