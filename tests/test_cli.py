import pytest

from torch_atr.cli import run_main
from torch_atr.config import ConfigError
from torch_atr.io import OutputExistsError


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


def test_success_returns_and_bugs_keep_their_traceback():
    seen = []
    run_main(seen.append, ["--x"])
    assert seen == [["--x"]]

    def buggy(argv):
        raise KeyError("a bug")

    with pytest.raises(KeyError):
        run_main(buggy, [])
