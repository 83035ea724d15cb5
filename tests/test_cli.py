import re
import subprocess
import sys
from pathlib import Path

import pytest

from torch_atr.cli import run_main
from torch_atr.config import ConfigError
from torch_atr.io import OutputExistsError

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("error", [ConfigError("cfg.yaml: seed:\n  expected an integer"), FileNotFoundError("x.arf"),
                                   OutputExistsError("runs/a exists; pass --overwrite"), ValueError("bad spec")])
def test_user_errors_become_one_line_and_status_2(capsys, error):
    def main(argv):
        raise error

    with pytest.raises(SystemExit) as info:
        run_main(main, [], prog="track.py")
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err == f"track.py: error: {' '.join(str(error).split())}\n"


@pytest.mark.parametrize("error, message", [
    (PermissionError(13, "Permission denied", "runs/x/metrics.json"), "runs/x/metrics.json: Permission denied"),
    (OSError(18, "Invalid cross-device link", "a.tmp", None, "b"), "a.tmp -> b: Invalid cross-device link"),
    (OSError(13, "cannot write runs/x/metrics.json: Permission denied"),  # our io's, the file named already
     "cannot write runs/x/metrics.json: Permission denied"),
    (IsADirectoryError(21, "Is a directory", b"configs"), "configs: Is a directory"),
])
def test_os_errors_read_without_their_errno(capsys, error, message):
    """The line read "[Errno 13] Permission denied: 'runs/x/metrics.json'"."""
    def main(argv):
        raise error

    with pytest.raises(SystemExit):
        run_main(main, [], prog="track.py")
    assert capsys.readouterr().err == f"track.py: error: {message}\n"


def test_an_unwritable_run_folder_is_one_plain_line(tmp_path):
    (tmp_path / "file").write_text("not a folder")
    result = subprocess.run([sys.executable, str(REPO / "train.py"), f"log_dir={tmp_path / 'file'}"],
                            capture_output=True, text=True, cwd=tmp_path)
    assert result.returncode == 2
    assert result.stderr == f"train.py: error: cannot write the run into {tmp_path}/file/default: Not a directory\n"


def test_success_returns_and_bugs_keep_their_traceback():
    seen = []
    run_main(seen.append, ["--x"])
    assert seen == [["--x"]]

    def buggy(argv):
        raise KeyError("a bug")

    with pytest.raises(KeyError):
        run_main(buggy, [])


def test_ctrl_c_is_one_line_and_status_130(capsys):
    def main(argv):
        raise KeyboardInterrupt

    with pytest.raises(SystemExit) as info:
        run_main(main, [], prog="train.py")
    assert info.value.code == 130 and capsys.readouterr().err == "\ntrain.py: interrupted\n"


def test_console_log_lines_stay_clear_of_progress_bars():
    """A record logged while a tqdm bar is drawn gets a line of its own (the bar is redrawn
    below it), where a plain stream handler appends it to the bar's text."""
    code = ("import logging\n"
            "from tqdm import tqdm\n"
            "from torch_atr.cli import console_logging\n"
            "console_logging()\n"
            "with tqdm(total=4, desc='frames', mininterval=0) as bar:\n"
            "    bar.update(2)\n"
            "    logging.getLogger('track').info('halfway')\n"
            "    bar.update(2)\n")
    err = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stderr
    lines = [segment.split("\r")[-1] for segment in err.split("\n") if "halfway" in segment]
    assert len(lines) == 1 and re.fullmatch(r"\d\d:\d\d:\d\d track: halfway", lines[0]), err


@pytest.mark.parametrize("error, line", [("KeyboardInterrupt", "demo.py: interrupted"),
                                         ("ValueError('bad vehicle')", "demo.py: error: bad vehicle")])
def test_the_last_line_is_the_message_not_a_progress_bar_closed_after_it(error, line):
    """A bar iterated in a list comprehension (train.py's rendering) lives in a frame of the
    traceback: it was closed, and drawn again, once run_main had printed its line, so a Ctrl-C
    while rendering ended with the bar ('views:  30%|███ | 3/10'), as if the run went on."""
    code = ("from tqdm import tqdm\n"
            "from torch_atr.cli import run_main\n"
            "def render(i):\n"
            f"    if i == 3: raise {error}\n"
            "def main(argv):\n"
            "    return [render(i) for i in tqdm(range(10), desc='views', mininterval=0)]\n"
            "run_main(main, [], prog='demo.py')\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode in (2, 130)
    assert result.stderr.endswith(f"\n{line}\n") and "views:  30%" in result.stderr, result.stderr


def test_a_bar_in_the_frames_of_the_error_a_user_error_arose_from_closes_before_the_line():
    """A user error raised ``from None`` over the one a bar's frame raised: that frame is in the
    first error's traceback alone."""
    code = ("from tqdm import tqdm\n"
            "from torch_atr.cli import run_main\n"
            "def render(i):\n"
            "    if i == 3: raise KeyError(i)\n"
            "def main(argv):\n"
            "    try:\n"
            "        return [render(i) for i in tqdm(range(10), desc='views', mininterval=0)]\n"
            "    except KeyError:\n"
            "        raise ValueError('vehicle 3 has no mesh') from None\n"
            "run_main(main, [], prog='demo.py')\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 2
    assert result.stderr.endswith("\ndemo.py: error: vehicle 3 has no mesh\n") and "30%" in result.stderr, result.stderr


@pytest.mark.parametrize("script, argv, message", [
    ("track.py", ["--bogus"], "unrecognized arguments: --bogus"),
    ("track.py", ["--particles"], "argument --particles: expected one argument"),
    ("train.py", ["--bogus"], "unrecognized arguments: --bogus"),
    ("-m torch_atr.experiments", ["sensiac-like"], "the following arguments are required: --out")])
def test_a_bad_argument_is_one_line_and_status_2(script, argv, message):
    """argparse printed its five-line usage block above the error line; run_main's user errors are one line."""
    prog = "python -m torch_atr.experiments" if script.startswith("-m") else script
    result = subprocess.run([sys.executable, *script.split(), *argv], capture_output=True, text=True, cwd=REPO)
    assert result.returncode == 2
    assert result.stderr == f"{prog}: error: {message} ({prog} --help: the options)\n"
