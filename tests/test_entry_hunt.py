"""The entry points' handling of hostile but realistic input: one line naming what is wrong, an exit
status of 2, nothing made or replaced that the user did not ask for. Each case stops before any work."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import SHIPPED_CHECKPOINT

import torch_atr.experiments.__main__ as experiments
from torch_atr.config import ConfigError

REPO = Path(__file__).resolve().parents[1]


def entry_point(*args: str, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``python args...`` run from ``cwd`` (a script of the repository, or ``-m``), its output as text;
    ``env``: variables set over the current environment."""
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=cwd, timeout=120,
                          env=None if env is None else {**os.environ, **env})


class Reached(Exception):
    """The experiment's work began: everything before it was accepted."""


@pytest.fixture
def no_work(monkeypatch):
    """The experiments' runners replaced by one that records its config and stops."""
    import torch_atr.experiments.visible as visible

    seen = []

    def stop(cfg, *args, **kwargs):
        seen.append(cfg)
        raise Reached

    for module, name in ((experiments, "run_all"), (experiments, "run_studies"), (visible, "run_visible")):
        monkeypatch.setattr(module, name, stop)
    return seen


@pytest.mark.parametrize("experiment", ["sensiac-like", "unseen", "studies", "visible"])
@pytest.mark.parametrize("override, key, flag", [("filter.particles=5", "filter.particles", "--particles"),
                                                 ("filter={particles: 5}", "filter.particles", "--particles"),
                                                 ("filter.method=IV", "filter.method", "--methods"),
                                                 ("init.mode=truth", "init.mode", "--init")])
def test_a_tracker_override_may_not_set_what_the_experiment_sets_and_reports(tmp_path, no_work, experiment,
                                                                            override, key, flag):
    """The experiment lays its particles, method and start under the user's overrides, so
    filter.method=IV ran every column of Table 6.1 with Method IV (labelled I-IV), and
    filter.particles=5 ran the studies' 250, 4000 and 16 000 particles with 5, as their rows did not say."""
    with pytest.raises(ConfigError, match=rf"^override '?{override}'?: .*{key}.*{flag}"):
        experiments.main([experiment, "--out", str(tmp_path / "out"), "--quick", override])
    assert not (tmp_path / "out").exists()


def test_a_tracker_key_given_twice_with_two_values_is_refused(tmp_path, no_work):
    """As track.py refuses it: the later won without a word."""
    with pytest.raises(ConfigError, match=r"^overrides 'filter.sigma=0.1' and 'filter.sigma=0.2' both set "
                                          r"filter.sigma; give one$"):
        experiments.main(["sensiac-like", "--out", str(tmp_path / "out"), "filter.sigma=0.1", "filter.sigma=0.2"])


@pytest.mark.parametrize("option, values, key, expected", [
    ("--vehicles", ("t_72", "bmp_2"), "vehicles", ("t_72", "bmp_2")),
    ("--ranges", ("1000", "2500"), "ranges_m", (1000.0, 2500.0)),
    ("--methods", ("I", "IV"), "methods", ("I", "IV")),
    ("--scene", ("night=false", "occluder_width_m=3"), "scene", ("night=false", "occluder_width_m=3"))])
def test_a_list_option_given_twice_takes_both(tmp_path, no_work, option, values, key, expected):
    """``--vehicles t_72 --vehicles bmp_2`` ran bmp_2 alone (argparse keeps the last), without a word."""
    with pytest.raises(Reached):
        experiments.main(["sensiac-like", "--out", str(tmp_path / "out"), *(a for v in values for a in (option, v))])
    assert getattr(no_work[0], key) == expected


def test_a_scene_key_given_twice_with_two_values_is_refused(tmp_path, no_work):
    """``--scene night=true ... --scene night=false`` ran the later alone, without a word."""
    with pytest.raises(ConfigError, match=r"^scene overrides 'night=true' and 'night=false' both set night; give one$"):
        experiments.main(["sensiac-like", "--out", str(tmp_path / "out"), "--scene", "night=true",
                          "turret_sweep_deg=60", "--scene", "night=false"])


@pytest.mark.parametrize("experiment", ["sensiac-like", "unseen", "studies", "visible"])
@pytest.mark.parametrize("content", [b"", b"hello\n", b"PK\x03\x04 truncated"])
def test_a_checkpoint_that_is_not_one_is_named_before_the_report_folder_is_made(tmp_path, no_work, experiment,
                                                                                content):
    """A text file given as --checkpoint was read by the first sequence's worker, once OUT/sequences
    had been made: the line named it, and an empty report folder stayed behind."""
    (tmp_path / "model.pt").write_bytes(content)
    with pytest.raises(ValueError, match=r"model.pt: not a readable checkpoint"):
        experiments.main([experiment, "--out", str(tmp_path / "out"), "--quick", "--checkpoint",
                          str(tmp_path / "model.pt")])
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("experiment", ["sensiac-like", "unseen", "studies", "visible"])
def test_a_checkpoint_that_is_a_folder_is_named_as_track_py_names_it(tmp_path, no_work, experiment):
    """``--checkpoint DIR`` said "checkpoint not found: DIR" where track.py says what is wrong with it."""
    from torch_atr.model.generative import load_checkpoint

    folder = tmp_path / "models"
    folder.mkdir()
    with pytest.raises(ValueError) as tracks:
        load_checkpoint(folder)
    with pytest.raises(ValueError) as info:
        experiments.main([experiment, "--out", str(tmp_path / "out"), "--quick", "--checkpoint", str(folder)])
    assert str(info.value) == str(tracks.value) == f"{folder}: expected a checkpoint file; it is a folder or a device"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("key", ["out", "checkpoint", "sequence", "device"])
def test_a_nul_byte_in_a_text_value_is_named_with_its_key(tmp_path, key):
    """No path, spec or device holds a NUL byte; Python refused one as "embedded null byte", naming neither
    file nor key, or the line printed it as nothing: "checkpoint not found: a b"."""
    (tmp_path / "nul.yaml").write_text(f'{key}: "a\\0b"\n')
    result = entry_point(str(REPO / "track.py"), "--config", "nul.yaml", cwd=tmp_path)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr == f"track.py: error: nul.yaml: {key}: expected text without a NUL byte; got 'a\\x00b'\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nul.yaml"]


def test_a_nul_byte_in_text_that_may_be_null_says_why(tmp_path):
    """train.py's checkpoint is text or null: the line says what is wrong with the text."""
    (tmp_path / "nul.yaml").write_text('checkpoint: "a\\0b"\n')
    result = entry_point(str(REPO / "train.py"), "--config", "nul.yaml", cwd=tmp_path)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr == "train.py: error: nul.yaml: checkpoint: expected text without a NUL byte; got 'a\\x00b'\n"


@pytest.mark.parametrize("args, key", [(["--out", ""], "out"), (["out= "], "out"),
                                       (["--checkpoint", ""], "checkpoint")])
def test_an_empty_path_is_refused_not_read_as_the_current_folder(tmp_path, args, key):
    """``--out ''`` wrote the run's files straight into the current folder when it was empty (Path('')
    is '.'), and named '.' when it was not; ``--checkpoint ''`` read '.: expected a checkpoint file'."""
    result = entry_point(str(REPO / "track.py"), *args, "--frames", "1", "--particles", "5", cwd=tmp_path)
    assert result.returncode == 2 and result.stdout == ""
    given, value = ("override out= ", " ") if args == ["out= "] else (f"{args[0]} ''", "")  # as given (load_config)
    assert result.stderr.endswith(f"track.py: error: {given}: {key} must be a path; got '{value}'\n")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("written, read", [("yes", "True"), ("off", "False"), ("2024", "2024"), ("1.5", "1.5"),
                                           ("2024-01-01", r"datetime.date\(2024, 1, 1\)"), ("1e3", "1000.0")])
@pytest.mark.parametrize("key", ["name", "checkpoint"])  # text; text or null
def test_a_text_key_given_what_yaml_reads_as_another_type_says_to_quote_it(tmp_path, written, read, key):
    """YAML 1.1 reads ``name: yes`` as true and ``name: 2024-01-01`` as a date: the line read
    "name: expected a string; got True" for what the user wrote as text."""
    from torch_atr.config import load_config
    from torch_atr.training import TrainConfig

    (tmp_path / "c.yaml").write_text(f"{key}: {written}\n")
    with pytest.raises(ConfigError, match=rf"c.yaml: {key}: expected .*; got {read} \(quote it for text\)$"):
        load_config(TrainConfig, tmp_path / "c.yaml")


@pytest.mark.parametrize("override, meant", [("partciles=10", "tracker.filter.particles"),
                                             ("tracker.partciles=10", "tracker.filter.particles"),
                                             ("sigam=0.03", "tracker.filter.sigma"),
                                             ("resample_es=0.5", "tracker.filter.resample_ess")])
def test_a_misspelt_key_of_a_section_below_is_suggested(override, meant):
    """``particles=10`` was suggested tracker.filter.particles, but ``partciles=10`` nothing."""
    from torch_atr.config import load_config
    from torch_atr.tracking.job import TrackConfig

    with pytest.raises(ConfigError, match=rf"unknown config key.*\(did you mean {meant}\?\)$"):
        load_config(TrackConfig, None, [override])


def test_a_tracker_override_written_as_track_py_takes_it_says_how_to_write_it(tmp_path, no_work):
    """track.py's keys start with tracker.; the experiments' are the tracker's own. The line read
    "unknown config key(s) tracker; known: adapt, filter, ..." and suggested nothing."""
    with pytest.raises(ConfigError, match=r"^override 'tracker.filter.sigma=0.1': .*; give 'filter.sigma=0.1'$"):
        experiments.main(["sensiac-like", "--out", str(tmp_path / "out"), "tracker.filter.sigma=0.1"])


@pytest.mark.parametrize("experiment", ["sensiac-like", "unseen", "studies", "visible", "all"])
@pytest.mark.parametrize("seed", [2 ** 64, 10 ** 40, -1])
def test_a_seed_torch_cannot_take_is_named_before_any_work(tmp_path, no_work, experiment, seed):
    """torch's generators take seeds in [0, 2**64 - 1]: --seed 18446744073709551616 was accepted, and the
    visible experiment stopped in its calibration, once OUT/sequences was made, on PyTorch's "Overflow
    when unpacking long long" (no option named); the others in their workers."""
    with pytest.raises(ConfigError, match=rf"^--seed must be in \[0, 2\*\*64 - 1\]; got {seed}$"):
        experiments.main([experiment, "--out", str(tmp_path / "out"), "--quick", "--seed", str(seed)])
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("script", ["track.py", "train.py"])
def test_an_empty_config_path_is_named_as_such(tmp_path, script):
    """``--config ''`` read ".: expected a file; it is a folder or a device" (Path('') is '.')."""
    result = entry_point(str(REPO / script), "--config", "", cwd=tmp_path)
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr == f"{script}: error: the config file must be a path; got ''\n"


@pytest.mark.parametrize("override", ["catalog=", "catalog= "])
def test_an_empty_catalog_is_refused_not_read_as_the_current_folder(tmp_path, override):
    """``catalog=`` read the current folder's catalog.yaml (Path('') is '.'), or named 'catalog.yaml'
    as missing; checkpoint= and log_dir= were refused already."""
    result = entry_point(str(REPO / "train.py"), override, cwd=tmp_path)
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr == (f"train.py: error: override {override}: catalog must be 'train' or a catalog folder (or "
                             f"its catalog.yaml); got '{override[8:]}'\n")


@pytest.mark.parametrize("experiment", ["sensiac-like", "unseen", "studies", "visible", "all"])
@pytest.mark.parametrize("out", ["", " "])
def test_an_empty_report_folder_is_refused_not_read_as_the_current_folder(tmp_path, monkeypatch, no_work,
                                                                          experiment, out):
    """``--out ''`` is '.': the experiment's report went into the current folder when it was empty."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=rf"^--out must be a folder path; got '{out}'$"):
        experiments.main([experiment, "--out", out, "--quick"])
    assert list(tmp_path.iterdir()) == []


def test_an_override_setting_several_bad_keys_of_a_section_is_named_once():
    """A mapping override stands for each of its keys: one at fault through two keys was named twice,
    'overrides tracker={...}, tracker={...}: ...'."""
    from torch_atr.config import load_config
    from torch_atr.tracking.job import TrackConfig

    item = "tracker={filter: {particles: 0, sigma: -1}}"
    with pytest.raises(ConfigError, match=rf"^override {re.escape(item)}: filter: bad value\(s\) particles=0, "):
        load_config(TrackConfig, None, [item])


@pytest.mark.parametrize("script", ["track.py", "train.py"])
def test_a_config_path_starting_with_a_tilde_is_read_from_the_home_folder(tmp_path, script):
    """``--config=~/c.yaml`` reaches the program with its ~ (a shell expands it after a space, not after
    '='): the line read "config file not found: ~/c.yaml", where the paths inside a config file and
    track.py's --out=~/run are expanded."""
    home = tmp_path / "home"
    home.mkdir()
    (home / "c.yaml").write_text("nope: 1\n")
    result = entry_point(str(REPO / script), "--config=~/c.yaml", cwd=tmp_path, env={"HOME": str(home)})
    assert result.returncode == 2
    assert result.stderr.startswith(f"{script}: error: {home / 'c.yaml'}: unknown config key(s) nope;"), result.stderr


@pytest.mark.parametrize("experiment", ["sensiac-like", "unseen", "studies", "visible", "all"])
def test_a_report_folder_or_checkpoint_starting_with_a_tilde_is_in_the_home_folder(tmp_path, monkeypatch,
                                                                                  experiment):
    """``--out=~/exp`` made a folder named '~' in the current folder (and --checkpoint=~/m.pt was not
    found), where track.py expands both."""
    import torch_atr.experiments.visible as visible

    home = tmp_path / "home"
    home.mkdir()
    (home / "m.pt").write_bytes(SHIPPED_CHECKPOINT.read_bytes())
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(tmp_path)
    seen = []

    def stop(*args, **kwargs):
        seen.append(args)
        raise Reached

    monkeypatch.setattr(experiments, "run_all", stop)
    monkeypatch.setattr(experiments, "run_studies", stop)
    monkeypatch.setattr(visible, "run_visible", stop)
    with pytest.raises(Reached):
        experiments.main([experiment, "--out=~/exp", "--quick", "--checkpoint=~/m.pt"])
    # run_all(cfg, out, ...); run_studies(out, configs, ...); run_visible(cfg, out, ...)
    out, cfg = sorted(seen[0][:2], key=lambda arg: not isinstance(arg, Path))
    assert str(out).startswith(str(home / "exp"))
    assert all(c.checkpoint == str(home / "m.pt") for c in (cfg.values() if isinstance(cfg, dict) else [cfg]))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["home"]


@pytest.mark.parametrize("experiment", ["sensiac-like", "unseen", "studies"])
def test_a_run_that_fails_before_any_sequence_leaves_no_empty_report_folder(tmp_path, monkeypatch, experiment):
    """--ray without Ray installed failed once OUT/sequences (studies: OUT/baseline/sequences) was made:
    the line was right, and the empty folders stayed, read as an unfinished run of that experiment."""
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray: ImportError, installed or not
    (tmp_path / "kept").mkdir()
    with pytest.raises(ConfigError, match="--ray needs Ray"):
        experiments.main([experiment, "--out", str(tmp_path / "kept" / "out"), "--quick", "--ray", "local"])
    assert [p.name for p in tmp_path.iterdir()] == ["kept"] and not any((tmp_path / "kept").iterdir())


@pytest.mark.parametrize("experiment", ["sensiac-like", "unseen", "visible"])
def test_a_method_listed_twice_is_tracked_once(tmp_path, no_work, experiment):
    """``--methods I IV I`` tracked every sequence with Method I twice and tabled 'I/IV/I' (vehicles
    and ranges listed twice were one job already)."""
    with pytest.raises(Reached):
        experiments.main([experiment, "--out", str(tmp_path / "out"), "--quick", "--methods", "I", "IV",
                          "--methods", "I"])
    assert no_work[0].methods == ("I", "IV")


@pytest.mark.parametrize("text, key, nested", [
    ("tracker.filter.particles: 10\n", "tracker.filter.particles", "tracker: then filter: then particles:"),
    ("tracker:\n  filter.particles: 10\n", "filter.particles", "filter: then particles:")])
def test_a_dotted_key_in_a_file_says_to_nest_it(tmp_path, text, key, nested):
    """A file's keys are names, not paths: 'filter.particles: 10' under tracker read "unknown config key(s)
    tracker.filter.particles; ... (did you mean tracker.filter.particles?)", suggesting what was written."""
    from torch_atr.config import load_config
    from torch_atr.tracking.job import TrackConfig

    (tmp_path / "c.yaml").write_text(text)
    with pytest.raises(ConfigError, match=rf"c.yaml: unknown config key\(s\) tracker.filter.particles; known: .*"
                                          rf"\(a file nests its sections: write {key} as {nested}, each indented "
                                          rf"below the one before\)$") as info:
        load_config(TrackConfig, tmp_path / "c.yaml")
    assert "did you mean" not in str(info.value)


def test_workers_and_ray_are_one_or_the_other(tmp_path, no_work, capsys):
    """The usage reads [--workers N | --ray ADDRESS]: given both, --workers was dropped without a word."""
    with pytest.raises(SystemExit) as info:
        experiments.main(["sensiac-like", "--out", str(tmp_path / "out"), "--workers", "4", "--ray", "local"])
    assert info.value.code == 2
    assert "argument --ray: not allowed with argument --workers" in capsys.readouterr().err
