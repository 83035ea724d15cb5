"""The benchmark scripts' command lines: a bad argument is one line, ``bench_x.py: error: ...``,
exit status 2, before any work and without writing anything; an existing output is refused up
front unless it is ours and ``--overwrite`` is given. Each test stops at the argument checks
(or runs a few frames), so they take seconds."""

import importlib
import json
import logging
from pathlib import Path

import pytest

from torch_atr.cli import run_main
from torch_atr.data.synthetic import SyntheticSequence
from torch_atr.tracking import Tracker

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
FAKE_MATPLOTLIB_PNG = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + b"\x00" * 17 + b"\x00\x00\x00:tEXtSoftware\x00Matplotlib"


def script(name: str):
    """The module of ``benchmarks/<name>.py`` (its folder on sys.path while importing, as when run)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(BENCHMARKS))
        return importlib.import_module(name)


def error_line(capsys, name: str, argv: list[str]) -> str:
    """The one line ``name`` prints for ``argv`` through run_main (exit status 2), without its prefix."""
    with pytest.raises(SystemExit) as exit_info:
        run_main(script(name).main, argv, prog=f"{name}.py")
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"{name}.py: error: "), err
    return err[len(f"{name}.py: error: "):].rstrip("\n")


@pytest.mark.parametrize("name, argv, expected", [
    ("bench_render", ["--vehicles", "0"], "--vehicles: expected a finite number >= 1; got 0"),
    ("bench_render", ["--size", "-4"], "--size -4 --window 12: template.size_px"),
    ("bench_render", ["--mesh", "/nonexistent.obj"], "vehicle file not found: /nonexistent.obj"),
    ("bench_render", ["--threads", "0"], "--threads: expected a finite number >= 1"),
    ("bench_segmentation", ["--frames", "0"], "--frames: expected a finite number >= 1; got 0"),
    ("bench_segmentation", ["--vehicles", "t99"], "--vehicles t99 --ranges 1000: Unknown vehicle 't99'"),
    ("bench_segmentation", ["--ranges", "10"], "--ranges 10: scene: bad value(s) range_m"),
    ("bench_heldout", ["--grid", "0"], "--grid: expected a finite number >= 1; got 0"),
    ("bench_heldout", ["--min-thickness", "-1"], "--min-thickness: expected a finite number >= 0"),
    ("bench_heldout", ["--running-gear", "/nonexistent.yaml"], "--running-gear /nonexistent.yaml: no such file"),
    ("bench_reconstruct", ["--vehicles", "1"], "--vehicles: expected a finite number >= 2"),
    ("bench_reconstruct", ["--rank", "0"], "--rank must be in [1, --size squared = 4096]; got 0"),
    ("bench_track", ["--set", "filter.foo=1"], "override filter.foo=1: unknown config key(s) filter.foo"),
    ("bench_track", ["--set", "filter.likelihood_px=7"], "filter.likelihood_px=7 must divide"),
    ("bench_track", ["--device", "meta"], "device 'meta' is not available here"),
    ("bench_track", ["--checkpoint", "/nonexistent.pt"], "checkpoint not found: /nonexistent.pt"),
    ("bench_track", ["--frames", "5"], "--frames 5 must exceed --skip (5)"),
    ("bench_track", ["--segmentation-gaps", "2000"], "--segmentation-gaps must be at most 1000 ms"),
    ("bench_tracking", ["--frames", "30"], "--settle 60 leaves none of the --frames 30"),
    ("bench_track", ["--frames", "10", "--reference-frames", "11"], "--reference-frames 11 is more than the --frames"),
    ("bench_tracking", ["--particles", "0"], "--particles: expected a finite number >= 1"),
    ("bench_tracking", ["--device", "meta"], "device 'meta' is not available here"),
    ("bench_tracking", ["--inits", "foo"], "--inits foo: override init.mode=foo"),
    ("bench_tracking", ["--set", "filter.particles=50"], "--set filter.particles=50 sets 50 where --particles gave"),
    ("bench_tracking", ["--set", "filter={particles: 50}"], "sets 50 where --particles gave 1000; give --particles"),
    ("bench_tracking", ["--set", "init.mode=truth"], "sets 'truth' where --inits gave 'blind'; give --inits instead"),
    ("bench_train", ["foo=1"], "train.py: override foo=1: unknown config key(s) foo"),
])
def test_bad_argument_is_one_line(capsys, name, argv, expected):
    assert expected in error_line(capsys, name, argv)


@pytest.fixture
def no_work(monkeypatch):
    """Any frame made or run started fails the test: what it checks must come before them."""
    def fail(*args, **kwargs):
        pytest.fail("a frame was made or a run started before every argument was checked")
    monkeypatch.setattr(SyntheticSequence, "_read_frame", fail)
    monkeypatch.setattr(Tracker, "run", fail)


@pytest.mark.parametrize("argv, expected", [
    (["--vehicles", "isuzu_rodeo", "t99"], "--vehicles t99 --ranges 1000: Unknown vehicle 't99'"),
    (["--methods", "I", "V"], "--methods V: override filter.method=V"),
    (["--set", "filter.foo=1"], "override filter.foo=1: unknown config key(s)"),
])
def test_tracking_checks_every_run_before_the_first(capsys, tmp_path, argv, expected, no_work):
    """The SUV was tracked, then t99 failed and nothing was written; now nothing runs."""
    out = tmp_path / "out.json"
    assert expected in error_line(capsys, "bench_tracking", [*argv, "--json", str(out)])
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["bench_tracking", "bench_track", "bench_segmentation", "bench_heldout"])
def test_existing_json_is_refused_before_the_run(capsys, tmp_path, name, no_work):
    ours, theirs = tmp_path / "ours.json", tmp_path / "theirs.json"
    ours.write_text(json.dumps({"benchmark": name, "runs": []}))
    theirs.write_text(json.dumps({"runs": []}))
    fast = ["--vehicles", "t_72", "--ranges", "1000"] if name == "bench_segmentation" else []
    assert "pass --overwrite to replace it" in error_line(capsys, name, [*fast, "--json", str(ours)])
    message = error_line(capsys, name, [*fast, "--json", str(theirs), "--overwrite"])
    assert f"is not a {name} JSON; refusing to replace it (even with --overwrite)" in message
    assert json.loads(ours.read_text()) == {"benchmark": name, "runs": []}
    assert json.loads(theirs.read_text()) == {"runs": []}


def test_output_under_a_missing_folder_is_refused_and_not_created(capsys, tmp_path, no_work):
    out = tmp_path / "missing" / "out.json"
    message = error_line(capsys, "bench_tracking", ["--json", str(out)])
    assert message == f"cannot write {out}: the folder {out.parent} does not exist"
    assert not out.parent.exists()


def test_heldout_figure_is_checked_up_front(capsys, tmp_path):
    figure = tmp_path / "figure.png"
    figure.write_bytes(FAKE_MATPLOTLIB_PNG)
    assert "pass --overwrite to replace it" in error_line(capsys, "bench_heldout", ["--figure", str(figure)])
    other = tmp_path / "photo.png"
    other.write_bytes(b"\x89PNG\r\n\x1a\n")
    assert "is not a matplotlib PNG" in error_line(capsys, "bench_heldout", ["--figure", str(other), "--overwrite"])
    assert "--figure must be a .png file" in error_line(capsys, "bench_heldout", ["--figure", str(tmp_path / "f.jpg")])
    message = error_line(capsys, "bench_heldout", ["--figure", str(tmp_path / "f.png"), "--catalog-dir", str(tmp_path)])
    assert f"--catalog-dir {tmp_path} lacks 36 of the checkpoint's training vehicles" in message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["figure.png", "photo.png"]
    assert figure.read_bytes() == FAKE_MATPLOTLIB_PNG


def test_real_figures_are_recognised_as_matplotlib_pngs(tmp_path):
    """The check --figure's --overwrite relies on, on figures matplotlib writes and on the shipped
    ones in docs/ (the fake PNG above only mirrors what the check looks for)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    fig.savefig(tmp_path / "real.png")
    plt.close(fig)
    is_ours = script("benchlib")._is_matplotlib_png
    shipped = sorted((Path(__file__).resolve().parents[1] / "docs").glob("*.png"))
    assert shipped and all(is_ours(p) for p in [tmp_path / "real.png", *shipped])
    (tmp_path / "photo.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 64)
    assert not is_ours(tmp_path / "photo.png")


def test_json_of_ours_is_replaced_only_with_overwrite(tmp_path):
    benchlib = script("benchlib")
    out = tmp_path / "out.json"
    benchlib.write_json({"runs": [1]}, out, "bench_x")
    assert json.loads(out.read_text()) == {"benchmark": "bench_x", "runs": [1]}
    with pytest.raises(FileExistsError, match="pass --overwrite"):
        benchlib.json_output(out, False, "bench_x")
    assert benchlib.json_output(out, True, "bench_x") == out
    with pytest.raises(FileExistsError, match="is not a bench_y JSON"):
        benchlib.json_output(out, True, "bench_y")
    # a NaN (a run without an estimate, say) is written null: strict JSON, still ours to replace
    benchlib.write_json({"runs": [{"x": float("nan"), "y": [float("inf"), 1.5]}]}, out, "bench_x")
    assert json.loads(out.read_text(), parse_constant=pytest.fail)["runs"] == [{"x": None, "y": [None, 1.5]}]
    assert benchlib.json_output(out, True, "bench_x") == out


def test_tracking_runs_from_elsewhere_with_labels_of_its_settle(tmp_path, monkeypatch, caplog):
    """The shipped checkpoint is found from another folder; the settled columns say --settle."""
    monkeypatch.chdir(tmp_path)
    caplog.set_level(logging.INFO, logger="bench_tracking")
    out = tmp_path / "out.json"
    argv = ["--vehicles", "t_72", "--methods", "I", "--inits", "truth", "--frames", "3", "--settle", "1",
            "--particles", "20", "--json", str(out)]
    script("bench_tracking").main(argv)
    header = caplog.records[0].getMessage()
    assert "horiz1" in header and "asp1" in header and "rec1" in header and "60" not in header
    data = json.loads(out.read_text())
    assert data["benchmark"] == "bench_tracking" and len(data["runs"]) == 1


def test_track_help_has_the_whole_description_and_every_option(capsys):
    with pytest.raises(SystemExit) as exit_info:
        script("bench_track").main(["--help"])
    assert exit_info.value.code == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "against particle count, a per-particle reference of Table 5.1 written here, and where the time goes." in out
    for text in ("the particle counts of the batched filter's runs", "particles of the reference, the speed-up",
                 "where the batched filter's particles live", "the trained model (default: the shipped one)",
                 "replace an earlier --json of this benchmark"):
        assert text in out
