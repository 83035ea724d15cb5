"""track.py end to end on a short simulated sequence: outputs, one-line user errors, no overwriting."""

import csv
import json
import logging
import math
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import track

REPO = Path(__file__).resolve().parents[1]
SHORT = "synthetic:vehicle=bmp_2,range=1000,frames=12,seed=3"


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("track") / "run"
    said = []  # track.py's summary lines
    handler, logger = logging.Handler(logging.INFO), logging.getLogger("track")
    handler.emit = lambda record: said.append(record.getMessage())
    level = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    try:
        metrics = track.main(["--sequence", SHORT, "--particles", "200", "--init", "truth", "--out", str(out),
                              "--tensorboard", "--video", "tracker.filter.resample=residual"])
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
    return out, metrics, said


def test_outputs_are_written_and_consistent(run):
    out, metrics, said = run
    names = {p.name for p in out.iterdir()}
    assert {"estimates.csv", "metrics.json", "config.yaml", "alpha_over_time.png", "errors_over_time.png",
            "view_trajectory.png", "frames.png", "overlay.mp4"} <= names
    assert any(n.startswith("events.out.tfevents") for n in names)
    wrote = next(line for line in said if line.startswith(f"wrote {out}: "))  # the summary names every output
    assert all(name in wrote for name in names if not name.startswith(("events.", ".torch_atr")))
    assert "TensorBoard events" in wrote
    rows = list(csv.DictReader((out / "estimates.csv").open()))
    assert len(rows) == 12 and {"x", "z", "theta", "alpha", "class", "nearest_1", "true_x", "ess"} <= set(rows[0])
    assert list(rows[0])[:3] == ["frame", "time_s", "lost"]  # the README's order
    saved = json.loads((out / "metrics.json").read_text())
    assert saved["frames"] == 12 and saved["format"] == "torch_atr.track_metrics"
    assert saved["settled"] is None  # 12 frames: none after the first 60
    # The summary agrees with the table it summarises.
    err = sum(abs(float(r["x"]) - float(r["true_x"])) for r in rows) / 12
    assert saved["horizontal_error_m"] == pytest.approx(err, rel=1e-4)
    assert saved["recognition_accuracy"] == pytest.approx(sum(r["class"] == "apc" for r in rows) / 12)
    # The per-frame errors, recomputed from the table's own estimate and truth columns (6 digits).
    def wrapped(d):
        d = abs(d) % (2 * math.pi)
        return min(d, 2 * math.pi - d)

    by_hand = {"error_horizontal_m": [abs(float(r["x"]) - float(r["true_x"])) for r in rows],
               "error_range_m": [abs(float(r["z"]) - float(r["true_z"])) for r in rows],
               "error_aspect_rad": [wrapped(float(r["theta"]) - float(r["true_theta"])) for r in rows],
               "error_aspect_up_to_mirror_rad": [min(wrapped(float(r["theta"]) - float(r["true_theta"])),
                                                     wrapped(float(r["theta"]) - math.pi + float(r["true_theta"])))
                                                 for r in rows]}
    tolerance = {"error_horizontal_m": 2e-4, "error_range_m": 2e-3, "error_aspect_rad": 2e-5,
                 "error_aspect_up_to_mirror_rad": 2e-5}  # the CSV's 6 significant digits of x, z (~950 m), θ
    for name, expected in by_hand.items():
        assert [float(r[name]) for r in rows] == pytest.approx(expected, abs=tolerance[name]), name
    assert [float(r["recognised"]) for r in rows] == [float(r["class"] == r["true_class"]) for r in rows]
    for key in ("horizontal_error_m", "range_error_m", "aspect_error_rad", "recognition_accuracy", "best_matches",
                "overlap_ratio", "frames_per_second", "frames"):
        assert saved[key] is not None and key in metrics
    assert "resample: residual" in (out / "config.yaml").read_text()
    # TensorBoard's scalars, each with its unit, are the table's columns.
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(out)).Reload()
    tags = set(events.Tags()["scalars"])
    assert {"estimate/x_m", "estimate/alpha_rad", "estimate/lost", "recognition/p_apc", "recognition/correct",
            "error/horizontal_m", "error/aspect_rad", "error/aspect_up_to_mirror_rad"} <= tags
    logged = [e.value for e in events.Scalars("estimate/x_m")]
    assert logged == pytest.approx([float(r["x"]) for r in rows], rel=1e-5)
    correct = [e.value for e in events.Scalars("recognition/correct")]
    assert correct == [float(r["class"] == r["true_class"]) for r in rows]
    for name, expected in by_hand.items():  # error_range_m: error/range_m
        logged = [e.value for e in events.Scalars(name.replace("error_", "error/", 1))]
        assert logged == pytest.approx(expected, abs=tolerance[name]), name


def test_an_existing_run_is_kept_unless_overwrite(run, tmp_path):
    out, *_ = run
    with pytest.raises(OSError, match="--overwrite"):
        track.main(["--sequence", SHORT, "--out", str(out), "--frames", "2"])
    foreign = tmp_path / "notes"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(OSError, match="not empty"):
        track.main(["--sequence", SHORT, "--out", str(foreign), "--overwrite", "--frames", "2"])
    assert (foreign / "notes.txt").read_text() == "mine"
    # A bad input is named first, not the run folder it would have gone to.
    with pytest.raises(OSError, match="nope.mp4"):
        track.main(["--sequence", f"video:{tmp_path / 'nope.mp4'}", "--out", str(out)])
    # --overwrite replaces the whole run: no video or TensorBoard events of the old one stay behind.
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    (copy / "notes.png").write_bytes(b"the user's own")  # any other file of the folder stays
    track.main(["--sequence", SHORT, "--particles", "50", "--out", str(copy), "--overwrite", "--frames", "2"])
    names = {p.name for p in copy.iterdir()}
    assert "overlay.mp4" not in names and not any(n.startswith("events.out") for n in names)
    assert (copy / "notes.png").read_bytes() == b"the user's own"
    assert json.loads((copy / "metrics.json").read_text())["frames"] == 2 and "frames.png" in names
    # A run that fails, on a value the tracker refuses or on a sequence midway, leaves the earlier run as it was.
    from torch_atr.data import open_sequence
    from torch_atr.data.folder import save_sequence

    unknown = save_sequence(open_sequence(SHORT), tmp_path / "no_truth", progress=False)
    (unknown / "truth.csv").unlink()
    earlier = {p.name: p.read_bytes() for p in copy.iterdir()}
    with pytest.raises(ValueError, match="likelihood_px=7"):
        track.main(["--sequence", SHORT, "--out", str(copy), "--overwrite", "tracker.filter.likelihood_px=7"])
    with pytest.raises(ValueError, match="needs ground truth"):
        track.main(["--sequence", str(unknown), "--init", "truth", "--out", str(copy), "--overwrite", "--video"])
    assert {p.name: p.read_bytes() for p in copy.iterdir()} == earlier  # the video's temporary file went too
    # A run without truth draws no error figure: the replaced run's does not stay behind.
    track.main(["--sequence", str(unknown), "--particles", "50", "--out", str(copy), "--overwrite", "--frames", "2"])
    assert "errors_over_time.png" in earlier and "errors_over_time.png" not in {p.name for p in copy.iterdir()}
    # An unusable folder is found before the frames are tracked.
    with pytest.raises(OSError, match=f"cannot write the tracking run into {foreign / 'notes.txt' / 'sub'}"):
        track.main(["--sequence", SHORT, "--out", str(foreign / "notes.txt" / "sub")])


def test_a_run_whose_figures_fail_does_not_look_finished(tmp_path, monkeypatch):
    """metrics.json marks a finished run: it was written before the figures, so a run that failed (or
    was killed) drawing them looked finished."""
    from torch_atr.io import check_output_dir
    from torch_atr.tracking.job import is_track_run

    def no_space(figures, folder):
        raise OSError(28, f"cannot write {folder / 'frames.png'}: No space left on device")

    monkeypatch.setattr(track.viz, "save_figures", no_space)
    out = tmp_path / "run"
    with pytest.raises(OSError, match="No space left"):
        track.main(["--sequence", SHORT, "--particles", "50", "--frames", "2", "--out", str(out)])
    assert (out / "estimates.csv").is_file() and not (out / "metrics.json").exists()
    with pytest.raises(OSError, match=r"holds an interrupted tracking run \(no metrics.json\)"):
        check_output_dir(out, False, "metrics.json", is_track_run, "tracking run")


def test_config_yaml_reproduces_the_run_from_any_folder(tmp_path, monkeypatch):
    """config.yaml kept the relative --sequence and --checkpoint: from another folder it named nothing."""
    import yaml

    from torch_atr.data import open_sequence
    from torch_atr.data.folder import save_sequence

    data = tmp_path / "data"
    save_sequence(open_sequence(SHORT), data / "clip", progress=False)
    shutil.copy(REPO / "checkpoints" / "default.pt", data / "model.pt")
    monkeypatch.chdir(data)
    first = track.main(["--sequence", "clip", "--checkpoint", "model.pt", "--particles", "50", "--frames", "2",
                        "--out", "run"])
    saved = yaml.safe_load((data / "run" / "config.yaml").read_text())
    assert (saved["sequence"], saved["checkpoint"]) == (str(data / "clip"), str(data / "model.pt"))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    again = track.main(["--config", str(data / "run" / "config.yaml"), "--out", "again"])
    assert again["horizontal_error_m"] == first["horizontal_error_m"] and again["frames"] == 2


def test_absolute_spec_makes_the_files_a_spec_reads_absolute(tmp_path, monkeypatch):
    from torch_atr.tracking.job import absolute_spec

    monkeypatch.chdir(tmp_path)
    (tmp_path / "tank.obj").write_text("")
    assert absolute_spec("clips/a") == str(tmp_path / "clips/a")
    assert absolute_spec("folder:clips/a") == f"folder:{tmp_path / 'clips/a'}"
    assert absolute_spec("video:shots/*.png, calib=cam.json,fps=30") == (f"video:{tmp_path / 'shots/*.png'},"
                                                                         f"calib={tmp_path / 'cam.json'},fps=30")
    assert absolute_spec("sensiac:~/arf/a.arf,layout=trailer40") == (f"sensiac:{Path.home() / 'arf/a.arf'},"
                                                                     f"layout=trailer40")
    (tmp_path / "store").mkdir()
    (tmp_path / "store" / "abc123.mp4").write_text("")
    (tmp_path / "clip.mp4").symlink_to(tmp_path / "store" / "abc123.mp4")
    assert absolute_spec("video:clip.mp4") == f"video:{tmp_path / 'clip.mp4'}"  # a link keeps its name
    assert absolute_spec(SHORT) == SHORT  # a catalog name, not a path
    assert absolute_spec("synthetic:vehicle=tank.obj,range=900") == (f"synthetic:vehicle={tmp_path / 'tank.obj'},"
                                                                     f"range=900")
    assert absolute_spec("mine:relative/x") == "mine:relative/x"  # another scheme's spec: as given
    long_name = "synthetic:vehicle=" + "t" * 300  # too long for a file name: a name (stat raised OSError)
    assert absolute_spec(long_name) == long_name


def test_the_summary_names_what_the_truth_allows():
    full = {"horizontal_error_m": 0.371, "range_error_m": 28.46, "aspect_error_rad": 0.259,
            "recognition_accuracy": 1.0, "frames_to_convergence": 1, "frames_to_convergence_up_to_mirror": 1,
            "first_frame": 0, "frames": 300}
    assert track.truth_summary(full) == ("horizontal 0.37 m, range 28.5 m, aspect 0.26 rad; recognition 1.0; "
                                         "converged at frame 1")  # the README's quick start
    mirror = {**full, "frames_to_convergence": 126, "frames_to_convergence_up_to_mirror": 7}  # a start on π − θ
    assert track.truth_summary(mirror).endswith("converged at frame 126 (at frame 7 up to the mirror θ ↔ π − θ)")
    assert track.truth_summary({**mirror, "frames_to_convergence": None}).endswith(
        "never converged (at frame 7 up to the mirror θ ↔ π − θ)")
    positions = {**full, "aspect_error_rad": None, "recognition_accuracy": None, "frames_to_convergence": None,
                 "frames_to_convergence_up_to_mirror": None}
    assert track.truth_summary(positions) == "horizontal 0.37 m, range 28.5 m"  # truth.csv of x, y, z only
    classes = dict.fromkeys(full) | {"recognition_accuracy": 142 / 150, "first_frame": 0, "frames": 150}
    assert track.truth_summary(classes) == "recognition 0.947; never converged"  # not 0.9466666666666667
    short = classes | {"first_frame": 2, "frames": 7}  # 9 frames: no 10 in a row to converge in
    assert track.truth_summary(short) == "recognition 0.947; too short to converge (10 frames in a row)"
    assert track.truth_summary(dict.fromkeys(full)) == ""


@pytest.mark.parametrize("args, message", [
    (["tracker.filter.method=V"], "method='V'"),
    (["--particles", "0"], "particles=0"),
    (["tracker.filter.likelihood_px=7"], "likelihood_px=7 must divide the model's template size 64 (e.g. 64, 32, 16)"),
    (["--sequence", "synthetic:vehicle=nope"], "nope"),
    (["--checkpoint", "missing.pt"], "missing.pt"),
    (["--device", "tpu"], "device 'tpu' is not available"),
    (["tracker.filter.sigma=0.03", "--overwrite", "tracker.filter.method=V"], "method='V'"),  # a flag between
    (["--frames", "3", "frames=5"], "--frames 3 and override 'frames=5' both set frames; give one"),
    (["--particles", "10", "tracker.filter.particles=20"],
     "--particles 10 and override 'tracker.filter.particles=20' both set tracker.filter.particles; give one"),
    # A flag's value is named as the flag was given, not as the override it stands for.
    (["--frames", "0"], "track.py: error: --frames 0: frames must be null or in [1, 1e7]; got 0"),
    (["--particles", "1e9"], "track.py: error: --particles 1e9: tracker.filter.particles: expected an integer"),
    (["--particles", "[1"], "track.py: error: --particles '[1': not a YAML value"),
    (["--tensorboard", "tensorboard=false"], "--tensorboard and override 'tensorboard=false' both set tensorboard"),
    (["--frames", "9" * 300], f"track.py: error: --frames {'9' * 31}… (309 characters): frames must be null or "
                              "in [1, 1e7]; got 9999"),
])
def test_user_errors_are_one_line(tmp_path, args, message):
    proc = subprocess.run([sys.executable, str(REPO / "track.py"), "--out", str(tmp_path / "x"), *args],
                          capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("track.py: error:") and message in lines[0], proc.stderr


def test_an_uncalibrated_video_tracks_view_and_identity(tmp_path):
    """video: without calib= has no camera: track.py falls back to the blob tracker (no 3D)."""
    import cv2

    from torch_atr.data import open_sequence

    seq = open_sequence(SHORT)
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (640, 512), isColor=False)
    for i in range(len(seq)):
        writer.write((seq.frame(i) // 64).clip(0, 255).astype("uint8"))
    writer.release()
    out = tmp_path / "run"
    metrics = track.main(["--sequence", f"video:{path}", "--particles", "100", "--out", str(out)])
    rows = list(csv.DictReader((out / "estimates.csv").open()))
    assert len(rows) == 12 and "x" not in rows[0] and {"theta", "phi", "alpha", "class"} <= set(rows[0])
    assert metrics["horizontal_error_m"] is None and metrics["frames"] == 12
    # With truth but no camera (a saved sequence without its camera.json), TensorBoard gets the
    # aspect error and no position errors.
    from torch_atr.data.folder import save_sequence

    folder = save_sequence(seq, tmp_path / "saved", progress=False)
    (folder / "camera.json").unlink()
    metrics = track.main(["--sequence", str(folder), "--particles", "100", "--out", str(tmp_path / "tb"),
                          "--tensorboard", "--frames", "4"])
    assert metrics["aspect_error_rad"] is not None and any((tmp_path / "tb").glob("events.out.tfevents.*"))


def test_the_tensorboard_command_it_names_works_for_a_folder_with_spaces(tmp_path, caplog):
    """The summary's 'tensorboard --logdir FOLDER' left a folder with spaces unquoted: pasted into a
    shell, it named 'runs' and two other words."""
    import shlex

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out = tmp_path / "my runs é" / "run 1"
    caplog.set_level(logging.INFO, logger="track")
    track.main(["--sequence", SHORT, "--particles", "50", "--frames", "1", "--out", str(out), "--tensorboard"])
    wrote = next(r.getMessage() for r in caplog.records if r.getMessage().startswith(f"wrote {out}: "))
    command = shlex.split(wrote.split("TensorBoard events (", 1)[1].rsplit(")", 1)[0])
    assert command == ["tensorboard", "--logdir", str(out.parent)]
    rows = list(csv.DictReader((out / "estimates.csv").open()))
    events = EventAccumulator(str(out)).Reload()
    assert [(e.step, e.value) for e in events.Scalars("estimate/x_m")] == [(0, pytest.approx(float(rows[0]["x"])))]


def test_an_overlay_video_into_a_folder_named_in_bytes_that_are_not_utf8(tmp_path):
    """cv2.VideoWriter crashed the process (SIGSEGV) on a Latin-1 folder name, after every other
    output was written; the video is now written under an ASCII name and copied into place. Its
    frames are counted by OpenCV reading a copy."""
    import os

    import cv2

    try:
        out = os.fsdecode(os.path.join(os.fsencode(tmp_path), b"r\xe9sultat"))
        os.mkdir(out)
        os.rmdir(out)
    except OSError:
        pytest.skip("this file system refuses names that are not UTF-8")
    child = subprocess.run([sys.executable, "track.py", "--sequence", "synthetic:vehicle=bmp_2,range=1000,frames=3",
                            "--particles", "50", "--init", "truth", "--video", "--out", out],
                           capture_output=True, text=True, cwd=REPO, errors="surrogateescape")
    assert child.returncode == 0, child.stderr[-2000:]
    shutil.copyfile(os.path.join(out, "overlay.mp4"), tmp_path / "copy.mp4")
    video = cv2.VideoCapture(str(tmp_path / "copy.mp4"))
    count = 0
    while video.read()[0]:
        count += 1
    assert count == 3
