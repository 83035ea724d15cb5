import errno
import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from torch_atr import io as atomic_io
from torch_atr.io import (RUN_CLAIM, OutputExistsError, atomic_path, atomic_write_csv, atomic_write_text,
                          check_output_dir, check_output_file, check_writable, claimed_output_dir, created_folders)

REPO = Path(__file__).resolve().parents[1]


def test_atomic_write_replaces_whole_file_and_leaves_no_temp(tmp_path):
    target = tmp_path / "sub" / "report.json"
    atomic_write_text("old", target)
    atomic_write_text("new", target)
    assert target.read_text() == "new"
    assert sorted(p.name for p in target.parent.iterdir()) == ["report.json"]
    umask = os.umask(0)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask


def test_a_symbolic_link_is_written_through(tmp_path):
    """As a shell's ``>``: the link's target (relative, in another folder, or not yet there) gets the content,
    and the link stays a link; the temporary file lives beside the target, not the link."""
    (tmp_path / "store").mkdir()
    (tmp_path / "store" / "v3.pt").write_text("old")
    link = tmp_path / "runs" / "default.pt"
    link.parent.mkdir()
    link.symlink_to(Path("..") / "store" / "v3.pt")
    dangling = tmp_path / "runs" / "next.pt"
    dangling.symlink_to(tmp_path / "store" / "v4.pt")
    with atomic_path(link) as tmp:
        assert tmp.parent == tmp_path / "store"
        tmp.write_text("new")
    atomic_write_text("fresh", dangling)
    assert link.is_symlink() and dangling.is_symlink()
    assert (tmp_path / "store" / "v3.pt").read_text() == "new"
    assert (tmp_path / "store" / "v4.pt").read_text() == "fresh"
    assert sorted(p.name for p in (tmp_path / "store").iterdir()) == ["v3.pt", "v4.pt"]
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")  # a loop: refused as the shell refuses it, both links kept
    with pytest.raises(OSError, match=f"^\\[Errno {errno.ELOOP}\\] cannot write {tmp_path / 'a'}: "):
        atomic_write_text("x", tmp_path / "a")
    assert subprocess.run(["sh", "-c", f"echo x > '{tmp_path / 'a'}'"], capture_output=True).returncode != 0
    assert (tmp_path / "a").is_symlink() and (tmp_path / "b").is_symlink()


def test_failed_write_keeps_the_old_content(tmp_path):
    target = tmp_path / "model.pt"
    atomic_write_text("good", target)
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("crash while writing")
    assert target.read_text() == "good"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.pt"]


def test_stale_temps_of_the_target_only_are_removed_and_live_ones_kept(tmp_path):
    target = tmp_path / "model.pt"
    stale = [tmp_path / ".model.pt.abcd1234.tmp", tmp_path / ".model.pt.zz_99xyz.tmp",
             tmp_path / ".model.pt.q1w2e3r4.tmp.mp4"]  # atomic_path(suffix=".mp4"), for a video writer
    others = [tmp_path / ".model.pt.bak.abcd1234.tmp",  # another target's temp (model.pt.bak)
              tmp_path / ".other.pt.abcd1234.tmp", tmp_path / "notes.tmp"]
    for p in stale + others:
        p.write_text("left by a killed write")
    with atomic_path(target) as tmp:
        tmp.write_text("new")
        # A concurrent write of the same target holds its temp locked: it is not touched.
        with atomic_path(target) as other:
            other.write_text("concurrent")
            assert tmp.exists()
    assert target.read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["model.pt"] + [p.name for p in others])


def test_a_long_legal_name_is_written_and_its_killed_writes_cleaned(tmp_path):
    """A name of 241-255 bytes is legal, but '.NAME.XXXXXXXX.tmp' beside it was not ('File name too
    long'); the temporary file is now named after a shortened stem, still found as a killed write's."""
    name = "é" * 120 + ".json"  # 245 bytes in UTF-8
    target = tmp_path / name
    atomic_write_text("first", target)
    def stem(n: str) -> str:  # its first 32 bytes (16 'é'), '~' and 16 hex digits of its SHA-256
        return n[:16] + "~" + hashlib.sha256(n.encode()).hexdigest()[:16]

    left = tmp_path / f".{stem(name)}.abcd1234.tmp"
    left.write_text("left by a killed write")
    other = tmp_path / f".{stem('é' * 121 + '.json')}.abcd1234.tmp"  # a longer name's
    other.write_text("another target's")
    atomic_write_text("second", target)
    assert target.read_text() == "second"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([name, other.name])


def _kill_mid_write(target: Path, code: str) -> None:
    """Run ``code`` (it writes ``target`` through atomic_path) in a child and SIGKILL it once its
    temporary file has grown past 1 MiB, i.e. in the middle of the write."""
    child = subprocess.Popen([sys.executable, "-c", code, str(target)], cwd=REPO,
                             env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and child.poll() is None:
            temps = list(target.parent.glob(f".{target.name}.*.tmp"))
            if any(p.stat().st_size > 2 ** 20 for p in temps if p.exists()):
                break
            time.sleep(0.001)
        assert child.poll() is None, "the child finished its write before it could be killed"
        child.send_signal(signal.SIGKILL)
    finally:
        child.kill()
        child.wait()
    assert child.returncode == -signal.SIGKILL


def test_sigkill_during_checkpoint_write_keeps_the_previous_checkpoint(tmp_path):
    import torch

    from torch_atr.io import atomic_torch_save

    target = tmp_path / "model.pt"
    atomic_torch_save({"version": 1, "w": torch.arange(10)}, target)
    before = target.read_bytes()
    _kill_mid_write(target, "import sys, torch\nfrom torch_atr.io import atomic_torch_save\n"
                            "atomic_torch_save({'version': 2, 'w': torch.ones(32 * 2 ** 20)}, sys.argv[1])")
    assert target.read_bytes() == before
    assert torch.load(target, weights_only=True)["version"] == 1
    assert len(list(tmp_path.glob(".model.pt.*.tmp"))) == 1  # the killed write's temp file
    atomic_torch_save({"version": 3}, target)  # the next write of the target cleans it up
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.pt"]
    assert torch.load(target, weights_only=True) == {"version": 3}


def test_sigkill_during_report_write_keeps_the_previous_report(tmp_path):
    target = tmp_path / "report.json"
    atomic_write_text('{"run": 1}', target)
    _kill_mid_write(target, "import sys\nfrom torch_atr.io import atomic_write_text\n"
                            "atomic_write_text('[' + '1, ' * (32 * 2 ** 20) + '2]', sys.argv[1])")
    assert target.read_text() == '{"run": 1}'
    assert len(list(tmp_path.glob(".report.json.*.tmp"))) == 1
    atomic_write_text('{"run": 2}', target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json"]


def test_check_output_file(tmp_path):
    ours = tmp_path / "model.pt"
    assert check_output_file(ours, False, lambda p: True, "checkpoint") == ours  # absent: fine
    ours.write_text("x")
    with pytest.raises(OutputExistsError, match=f"^{ours} exists; pass --overwrite to replace it"):
        check_output_file(ours, False, lambda p: True, "checkpoint")
    assert check_output_file(ours, True, lambda p: True, "checkpoint") == ours
    with pytest.raises(OutputExistsError, match=f"^{ours} exists and is not a checkpoint; refusing to replace it "
                                                r"\(even with --overwrite\)"):
        check_output_file(ours, True, lambda p: False, "checkpoint")
    with pytest.raises(OutputExistsError, match="is not a file"):
        check_output_file(tmp_path, True, lambda p: True, "checkpoint")


def test_check_output_dir(tmp_path):
    def is_ours(p):
        return p.read_text() == "ours"

    run = tmp_path / "run"
    assert check_output_dir(run, False, "report.json", is_ours, "run") == run
    run.mkdir()
    assert check_output_dir(run, False, "report.json", is_ours, "run") == run  # empty: fine
    (run / "report.json").write_text("ours")
    with pytest.raises(OutputExistsError, match=rf"^{run} already holds a run \(report.json\); pass --overwrite"):
        check_output_dir(run, False, "report.json", is_ours, "run")
    assert check_output_dir(run, True, "report.json", is_ours, "run") == run
    (run / "report.json").write_text("someone else's")
    with pytest.raises(OutputExistsError, match="holds no report.json of ours"):
        check_output_dir(run, True, "report.json", is_ours, "run")
    (run / "report.json").unlink()
    (run / "notes.txt").write_text("x")
    with pytest.raises(OutputExistsError, match=r"not empty and holds no report.json of ours .*even with --overwrite"):
        check_output_dir(run, True, "report.json", is_ours, "run")
    with pytest.raises(OutputExistsError, match="is not a folder"):
        check_output_dir(run / "notes.txt", True, "report.json", is_ours, "run")


def _is_ours(p):
    return p.read_text() == "ours"


def test_a_killed_run_leaves_a_folder_overwrite_may_replace(tmp_path):
    run = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        with claimed_output_dir(run, "run"):
            raise KeyboardInterrupt  # before anything was written: the claim and the new folder go
    assert not run.exists()
    with claimed_output_dir(run, "run"):
        (run / "events.out.tfevents.1.host").write_text("tensorboard")
        stale = run / ".report.json.abcd1234.tmp"  # a write killed midway: nobody holds its lock
        stale.write_text("half")
    # No report.json: the run died. Ours by its claim: --overwrite replaces it, and only it.
    with pytest.raises(OutputExistsError, match=rf"^{run} already holds an interrupted run \(no report.json\); "
                                                "pass --overwrite"):
        check_output_dir(run, False, "report.json", _is_ours, "run")
    assert check_output_dir(run, True, "report.json", _is_ours, "run") == run
    with pytest.raises(OutputExistsError, match="holds no report.json of ours"):  # another tool's claim is not ours
        check_output_dir(run, True, "report.json", _is_ours, "tracking run")
    (run / "report.json").write_text("ours")  # finished after all
    assert check_output_dir(run, True, "report.json", _is_ours, "run") == run
    with claimed_output_dir(run, "run", replaces=("report.json",)):
        assert not (run / "events.out.tfevents.1.host").exists()  # TensorBoard shows the new run alone
        with pytest.raises(OutputExistsError, match="interrupted run"):  # until the new report is written
            check_output_dir(run, False, "report.json", _is_ours, "run")
        (run / "figure.png").write_text("png")
    assert stale.exists()  # left for the next write of report.json to remove
    (run / RUN_CLAIM).unlink()
    with pytest.raises(OutputExistsError, match="holds no report.json of ours"):
        check_output_dir(run, True, "report.json", _is_ours, "run")


def test_a_folder_of_killed_writes_alone_counts_as_empty(tmp_path):
    (tmp_path / ".metrics.json.abcd1234.tmp").write_text("half")
    assert check_output_dir(tmp_path, False, "metrics.json", _is_ours, "run") == tmp_path
    with atomic_path(tmp_path / "estimates.csv") as live:  # a live write holds its temp file: not empty
        live.write_text("x")
        with pytest.raises(OutputExistsError, match="holds no metrics.json of ours"):
            check_output_dir(tmp_path, True, "metrics.json", _is_ours, "run")


def test_unwritable_outputs_are_named_before_the_work(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(OSError, match=f"^.*cannot write {blocker}/model.pt: "):
        check_writable(blocker / "model.pt")
    with pytest.raises(OSError, match=f"cannot write {blocker}/report.json: "):
        atomic_write_text("{}", blocker / "report.json")
    with pytest.raises(OSError, match=f"^.*cannot write the run into {blocker}/run: "):
        with claimed_output_dir(blocker / "run", "run"):
            pass
    check_writable(tmp_path / "new" / "model.pt")
    assert (tmp_path / "new").is_dir() and not any((tmp_path / "new").iterdir())


@pytest.mark.parametrize("below", ["model.pt", "sub/model.pt"])
def test_a_file_where_the_output_folder_should_be_is_named(tmp_path, below):
    """train.py checkpoint=FILE/model.pt said "cannot write FILE/model.pt: File exists": the reason is the
    one track.py's --out gives for a file in the way (Not a directory), and the file in the way is named."""
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(NotADirectoryError) as info:
        check_writable(blocker / below)
    assert str(info.value) == (f"[Errno {errno.ENOTDIR}] cannot write {blocker / below}: Not a directory "
                               f"({blocker} is a file)")
    with pytest.raises(NotADirectoryError, match=f"^.*cannot write the run into {blocker}/run: Not a directory$"):
        with claimed_output_dir(blocker / "run", "run"):  # track.py's --out
            pass


def test_a_run_that_fails_before_writing_leaves_the_earlier_run_as_it_was(tmp_path):
    run = tmp_path / "run"
    with claimed_output_dir(run, "run", replaces=("report.json",)):
        for name in ("report.json", "figure.png", "events.out.tfevents.1.host"):
            (run / name).write_text(name)
    earlier = {p.name: p.read_text() for p in run.iterdir()}
    with pytest.raises(ValueError):
        with claimed_output_dir(run, "run", replaces=("report.json",)):
            assert {p.name for p in run.iterdir()} == {RUN_CLAIM, "figure.png", ".report.json.replaced",
                                                       ".events.out.tfevents.1.host.replaced"}
            raise ValueError("a bad frame, found by the work")
    assert {p.name: p.read_text() for p in run.iterdir()} == earlier
    (run / RUN_CLAIM).unlink()  # a finished run of an older version: its files alone
    earlier.pop(RUN_CLAIM)
    with pytest.raises(KeyboardInterrupt):
        with claimed_output_dir(run, "run", replaces=("report.json",)):
            raise KeyboardInterrupt
    assert {p.name: p.read_text() for p in run.iterdir()} == earlier
    with pytest.raises(ValueError):  # once it wrote something, the earlier run's marker and events are gone
        with claimed_output_dir(run, "run", replaces=("report.json",)):
            (run / "figure.png").write_text("new")
            raise ValueError("late")
    assert {p.name for p in run.iterdir()} == {RUN_CLAIM, "figure.png"}


def test_a_failed_run_removes_the_empty_folders_it_created_and_no_other(tmp_path):
    """--out runs/a/b/c of a run that failed left runs/a/b behind (only c went)."""
    (tmp_path / "runs").mkdir()
    with pytest.raises(ValueError):
        with claimed_output_dir(tmp_path / "runs/a/b/c", "run"):
            raise ValueError("a bad frame, found by the work")
    assert [p.name for p in tmp_path.rglob("*")] == ["runs"]  # runs was there before: it stays
    with pytest.raises(OSError, match=r"cannot write the run into .*/x{300}: "):  # made runs/new, then failed
        with claimed_output_dir(tmp_path / "runs/new" / ("x" * 300), "run"):
            pass
    assert [p.name for p in tmp_path.rglob("*")] == ["runs"]
    with pytest.raises(KeyboardInterrupt):  # a folder that is not empty stays, and those above it
        with created_folders(tmp_path / "runs/a/b/c") as made:
            made.mkdir(parents=True)
            (tmp_path / "runs/a/notes.txt").write_text("the user's, written meanwhile")
            raise KeyboardInterrupt
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == ["runs", "runs/a",
                                                                                       "runs/a/notes.txt"]
    with created_folders(tmp_path / "ckpt/new") as made:  # a run that succeeds keeps them
        made.mkdir(parents=True)
    assert made.is_dir()


def test_files_a_killed_run_set_aside_go_at_the_next_claim(tmp_path):
    (tmp_path / RUN_CLAIM).write_text("{}")
    (tmp_path / ".report.json.replaced").write_text("old")  # set aside by a run that was killed
    with claimed_output_dir(tmp_path, "run", replaces=("report.json",)):
        (tmp_path / "report.json").write_text("new")
    assert {p.name for p in tmp_path.iterdir()} == {RUN_CLAIM, "report.json"}


def test_replaced_outputs_are_named_by_patterns(tmp_path):
    for name in ("report.json", "a.png", "b.png", "notes.txt"):
        (tmp_path / name).write_text(name)
    with claimed_output_dir(tmp_path, "run", replaces=("report.json", "*.png")):
        (tmp_path / "a.png").write_text("new")
    assert {p.name: p.read_text() for p in tmp_path.iterdir() if p.name != RUN_CLAIM} == {"a.png": "new",
                                                                                       "notes.txt": "notes.txt"}


def test_csv_columns_keep_the_rows_order_when_the_first_row_has_fewer_keys(tmp_path):
    lost = {"frame": 0, "time_s": 0.0, "lost": 1, "mask_area_px": 0, "step_ms": 2.5, "true_x": 1.0}
    tracked = {"frame": 1, "time_s": 0.5, "lost": 0, "mask_area_px": 9, "x": 1.5, "overlap": 0.75, "step_ms": 3.0,
               "true_x": 1.25}
    atomic_write_csv([lost, tracked], tmp_path / "estimates.csv")
    assert (tmp_path / "estimates.csv").read_text() == (
        "frame,time_s,lost,mask_area_px,x,overlap,step_ms,true_x\n"
        "0,0,1,0,,,2.5,1\n"
        "1,0.5,0,9,1.5,0.75,3,1.25\n")
    # a later row with two known keys swapped: its new key goes after both, not between them
    atomic_write_csv([{"a": 1, "b": 2}, {"b": 3, "a": 4, "c": 5}], tmp_path / "swapped.csv")
    assert (tmp_path / "swapped.csv").read_text() == "a,b,c\n1,2,\n4,3,5\n"


def test_a_file_that_cannot_be_set_aside_leaves_every_earlier_output_in_place(tmp_path, monkeypatch):
    run = tmp_path / "run"
    with claimed_output_dir(run, "run", replaces=("*.json", "*.png")):
        for name in ("a.json", "b.png", "c.png"):
            (run / name).write_text(name)
    replace, calls = os.replace, []

    def failing(src, dst):  # the second file set aside cannot be
        if str(dst).endswith(".replaced"):
            calls.append(src)
            if len(calls) == 2:
                raise PermissionError(13, "denied", str(src))
        replace(src, dst)

    monkeypatch.setattr(os, "replace", failing)
    with pytest.raises(PermissionError):
        with claimed_output_dir(run, "run", replaces=("*.json", "*.png")):
            pytest.fail("the block must not run")
    monkeypatch.undo()
    with claimed_output_dir(run, "run", replaces=()):  # the next claim deletes files set aside and left
        pass
    assert sorted(p.name for p in run.iterdir() if p.name != RUN_CLAIM) == ["a.json", "b.png", "c.png"]


def test_a_failed_rename_names_the_target_keeps_the_old_file_and_no_temp(tmp_path, monkeypatch):
    """A full disk at the rename said '[Errno 28] No space left on device', no file named; a folder in the way
    named our temporary file."""
    target = tmp_path / "report.json"
    target.write_text("old")
    (tmp_path / "frames").mkdir()

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    with pytest.raises(OSError, match=rf"^\[Errno {errno.EISDIR}\] cannot write {tmp_path / 'frames'}: "):
        atomic_write_text("new", tmp_path / "frames")
    monkeypatch.setattr(atomic_io.os, "replace", full)
    with pytest.raises(OSError, match=rf"^\[Errno {errno.ENOSPC}\] cannot write {target}: No space left on device$"):
        atomic_write_text("new", target)
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames", "report.json"]
    assert list((tmp_path / "frames").iterdir()) == []


def test_a_temp_file_another_write_deleted_before_it_was_locked_is_replaced(tmp_path, monkeypatch):
    """Two writes of one target: the second's clean-up may find the first's new temporary file before the first
    locks it, take it for a killed write's and delete it. The first write must still land (it lost its file with
    'cannot write ...: No such file or directory' at the rename)."""
    target = tmp_path / "report.json"
    made = []
    real_mkstemp = atomic_io.tempfile.mkstemp

    def mkstemp_then_cleaned_away(*args, **kwargs):
        fd, name = real_mkstemp(*args, **kwargs)
        made.append(name)
        if len(made) == 1:
            os.unlink(name)  # what the other write's _remove_stale_temps does to an unlocked temporary file
        return fd, name

    monkeypatch.setattr(atomic_io.tempfile, "mkstemp", mkstemp_then_cleaned_away)
    atomic_write_text("new", target)
    assert target.read_text() == "new"
    assert len(made) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json"]


def test_the_content_is_synced_before_the_rename_and_the_folder_after(tmp_path, disk_events):
    """Without fsync a power cut after the rename could leave the new name on 0 bytes (the data was
    still in the page cache): the file is synced before os.replace, its folder after."""
    events = disk_events
    target = tmp_path / "metrics.json"
    atomic_write_text("{}", target)
    assert [event[0] for event in events] == ["fsync", "replace", "fsync"]
    synced, renamed = Path(events[0][1]), events[1][2]
    assert synced.parent == tmp_path and synced != target and renamed == str(target) and events[2][1] == str(tmp_path)
    assert target.read_text() == "{}"
