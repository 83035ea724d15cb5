import dataclasses
import math
import os
import re
from pathlib import Path

import pytest
import torch

from torch_atr.config import ConfigError, ModelConfig, TemplateConfig, load_config
from torch_atr.training import TrainConfig, ViewGridConfig

REPO = Path(__file__).resolve().parents[1]


def test_yaml_then_overrides_then_types(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("name: a\ntemplate:\n  size_px: 32\nmodel:\n  pixel_rank: null\n")
    cfg = load_config(TrainConfig, path, ["template.window_m=10", "model.ridge=1e-3", "name=b"])
    assert cfg.name == "b" and cfg.template == TemplateConfig(size_px=32, window_m=10.0)
    assert cfg.model == ModelConfig(pixel_rank=None, ridge=1e-3, width_steps=50)  # 50: the shipped default
    assert isinstance(cfg.template.window_m, float)


def test_the_defaults_are_the_shipped_config(tmp_path):
    """TrainConfig() is configs/default.yaml (the file is the reference), so a config file that
    leaves keys out, whole sections or single keys of one, gets the shipped values for them."""
    shipped = load_config(TrainConfig, REPO / "configs/default.yaml")
    assert TrainConfig() == shipped
    assert (shipped.model.width_steps, shipped.model.width_lr) == (50, 0.05)  # the keys once left at 0 and 0.02
    path = tmp_path / "c.yaml"
    path.write_text("name: onlyname\n")
    assert load_config(TrainConfig, path) == dataclasses.replace(shipped, name="onlyname")
    path.write_text("model:\n  ridge: 1.0e-3\n")
    assert load_config(TrainConfig, path).model == dataclasses.replace(shipped.model, ridge=1e-3)
    assert load_config(TrainConfig, None, ["model.ridge=1e-3"]).model == dataclasses.replace(shipped.model, ridge=1e-3)


def test_a_section_keeps_its_own_defaults_for_the_keys_not_given(tmp_path):
    """The tracker's segmentation section defaults to the feedback segmentation, not to
    SegmentationConfig()'s frozen background: one key given, in an override or a YAML section,
    one or two levels down, must leave the section's other defaults as they were."""
    from torch_atr.segmentation import SegmentationConfig
    from torch_atr.tracking import TrackerConfig
    from torch_atr.tracking.filter import tracker_segmentation
    from torch_atr.tracking.job import TrackConfig

    feedback = tracker_segmentation()
    assert feedback != SegmentationConfig()  # else this test could not fail
    expected = dataclasses.replace(feedback, var_threshold=16.0)
    assert load_config(TrackerConfig, None, ["segmentation.var_threshold=16"]).segmentation == expected
    path = tmp_path / "t.yaml"
    path.write_text("tracker:\n  segmentation:\n    var_threshold: 16\n")
    job = load_config(TrackConfig, path, ["tracker.filter.particles=10"])
    assert job.tracker.segmentation == expected
    assert job.tracker.filter.particles == 10 and job.tracker.filter.sigma == TrackerConfig().filter.sigma
    with pytest.raises(ConfigError, match="segmentation.var_threshold=-1"):
        load_config(TrackerConfig, None, ["segmentation.var_threshold=-1"])


@pytest.mark.parametrize("text, match", [
    ("nme: a\n", "unknown config key.*nme"),
    ("template:\n  sizepx: 3\n", "template.sizepx"),
    ("template:\n  size_px: 3.5\n", "template.size_px: expected an integer"),
    ("tensorboard: 1\n", "tensorboard: expected true/false"),
    ("template: 5\n", "template: expected a mapping"),
    ("- a\n", "top level must be a mapping"),
    ("a: [\n", "not valid YAML"),
    ("template:\n  size_px: 4\n", r"size_px must be in \[8, 512\]; got 4"),
    ("template:\n  size_px: 100000\n", r"size_px must be in \[8, 512\]; got 100000"),
    ("template:\n  tau_px: .inf\n", "template.tau_px: expected a finite number; got inf"),
    ("template:\n  tau_px: .nan\n", "template.tau_px: expected a finite number; got nan"),
    ("template:\n  tau_px: 1e400\n", "template.tau_px: expected a finite number; got inf"),
    ("template:\n  window_m: 1e-300\n", r"window_m must be in \[0.1, 1000\] metres; got 1e-300"),
    ("model:\n  ridge: 1e300\n", r"model.ridge must be in \[0, 1000\]; got 1e\+300"),
    ("model:\n  init_width: 100\n", r"model.init_width must be in \[0.001, 4\]"),
    ("views:\n  azimuth_step_deg: 1e-9\n", "give 360000000000 x 5 = 1800000000000 views; expected at most 10000"),
    ("views:\n  azimuth_step_deg: 2.2250738585e-313\n", "give more views than a float counts; expected at most 10000"),
    ("views:\n  elevation_step_deg: 2.2250738585e-313\n", "give more views than a float counts"),  # were OverflowError
    # Held-out views half a step above the top elevation, at 105°: train.py stopped after rendering, naming no key.
    ("views:\n  elevation_step_deg: 70\n  elevation_max_deg: 70\n", r"views: elevation_step_deg=70 and "
     r"elevation_max_deg=70 put the held-out views half a step above the top elevation 70°, at 105°, beyond "
     r"the zenith"),
    ("views:\n  azimuth_step_deg: 7\n", r"views.azimuth_step_deg=7 must divide 360 \(e.g. 6 or 8\): 360/7 = 51.43 "
                                          r"azimuths would leave a step of 10° where they wrap"),
    ("seed: 1\nname: a\nseed: 2\n", r"key 'seed' repeated \(first on line 1\).*line 3"),
    ("template:\n  size_px: 32\n  size_px: 64\n", "key 'size_px' repeated"),
    ("name: ../../..\n", "name must be a plain folder name.*got '../../..'"),
    ("name: /abs\n", "name must be a plain folder name"),
    ("name: a/b\n", "name must be a plain folder name"),
    ("name: ''\n", "name must be a plain folder name"),
    ("checkpoint: ''\n", "checkpoint must be a path"),
])
def test_bad_files_name_file_and_key(tmp_path, text, match):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=match) as info:
        load_config(TrainConfig, path)
    assert str(path) in str(info.value)


def test_bad_override_and_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="key=value"):
        load_config(TrainConfig, None, ["template.size_px"])
    with pytest.raises(ConfigError, match="model.pixel_rank"):
        load_config(TrainConfig, None, ["model.pixel_rank=0"])
    with pytest.raises(ConfigError, match="not found.*nope.yaml"):
        load_config(TrainConfig, tmp_path / "nope.yaml")
    # unique (train.py's and track.py's user input): a key set twice to two values is refused
    with pytest.raises(ConfigError, match=r"overrides 'model.ridge=0.1' and ' model.ridge =0.2' both set "
                                          r"model.ridge; give one"):
        load_config(TrainConfig, None, ["model.ridge=0.1", "name=x", " model.ridge =0.2"], unique=True)
    assert load_config(TrainConfig, None, ["name=x", "name=x"], unique=True).name == "x"  # the same value: no clash
    assert load_config(TrainConfig, None, ["model.ridge=0.1", "model.ridge=0.2"]).model.ridge == 0.2  # code's layers


def test_a_mapping_for_a_section_sets_its_keys_and_keeps_the_others(tmp_path):
    """model={ridge: 0.001} is model.ridge=0.001: the file's other model keys stay (the mapping
    replaced the section, so pixel_rank and width_steps fell back to the defaults), and a key it sets
    twice to two values is refused like any other."""
    path = tmp_path / "tiny.yaml"
    path.write_text("model:\n  pixel_rank: 8\n  width_steps: 0\n")
    cfg = load_config(TrainConfig, path, ["model={ridge: 0.001}", "seed=3"])
    assert (cfg.model.ridge, cfg.model.pixel_rank, cfg.model.width_steps) == (0.001, 8, 0)
    nested = load_config(TrainConfig, path, ["model={ridge: 0.002, pixel_rank: 4}"])
    assert (nested.model.ridge, nested.model.pixel_rank, nested.model.width_steps) == (0.002, 4, 0)
    assert load_config(TrainConfig, path, ["model={}"]).model.pixel_rank == 8  # nothing set
    with pytest.raises(ConfigError, match=r"both set model.ridge; give one"):
        load_config(TrainConfig, path, ["model.ridge=0.1", "model={ridge: 0.2}"], unique=True)
    with pytest.raises(ConfigError,
                       match=r"^override model={colour: 1}: unknown config key\(s\) model\.colour; known: "):
        load_config(TrainConfig, path, ["model={colour: 1}"])


def test_a_bad_override_is_reported_as_an_override_not_against_the_file(tmp_path):
    path = tmp_path / "good.yaml"
    path.write_text("name: a\n")
    cases = {
        "template.tau_px=.inf": "override template.tau_px=.inf: template.tau_px: expected a finite number; got inf",
        "model.ridg=1": r"override model.ridg=1: unknown config key\(s\) model.ridg",
        "name=../x": "override name=../x: name must be a plain folder name",
        "template.size_px={a: 1, a: 2}": "override 'template.size_px={a: 1, a: 2}': not a YAML value: .*repeated",
        "name.x=1": "override 'name.x=1': name is not a section",
    }
    for item, message in cases.items():
        with pytest.raises(ConfigError, match=message) as info:
            load_config(TrainConfig, path, ["seed=3", item])
        assert str(path) not in str(info.value)
    # Of several overrides, the one whose key the message names is blamed.
    with pytest.raises(ConfigError, match=r"^override model.ridge=1e9: model.ridge must be in"):
        load_config(TrainConfig, path, ["seed=3", "model.ridge=1e9", "name=b"])
    # A key that ends another's name is not blamed for it (frames / init.speed_frames).
    from torch_atr.tracking.job import TrackConfig

    with pytest.raises(ConfigError, match=r"^override tracker.init.speed_frames=-1: init.speed_frames must be"):
        load_config(TrackConfig, None, ["frames=3", "tracker.init.speed_frames=-1"])
    # An unknown section is blamed on the override that opened it, not on a key the list of known ones names.
    with pytest.raises(ConfigError, match=r"^override filter.sigma=0.1: unknown config key\(s\) filter; known: .*"
                                          r"\(did you mean tracker.filter\?\)$"):
        load_config(TrackConfig, None, ["out=x", "filter.sigma=0.1"])
    # A key given without its sections is found at any depth below (tracker.filter.particles).
    with pytest.raises(ConfigError, match=r"^override particles=9: .*\(did you mean tracker.filter.particles\?\)$"):
        load_config(TrackConfig, None, ["particles=9"])
    with pytest.raises(ConfigError, match=r"\(did you mean tracker.adapt.every or tracker.redetect.every\?\)$"):
        load_config(TrackConfig, None, ["every=3"])
    # A misspelt key gets the nearest of its section's.
    with pytest.raises(ConfigError, match=r"partciles; .*\(did you mean tracker.filter.particles\?\)$"):
        load_config(TrackConfig, None, ["tracker.filter.partciles=9"])
    with pytest.raises(ConfigError, match=r"\(did you mean tracker.init.speed_frames or tracker.init.speed_mps or "
                                          r"tracker.init.speed_std_mps\?\)$"):  # every key it begins
        load_config(TrackConfig, None, ["tracker.init.speed=9"])
    with pytest.raises(ConfigError, match=r"^override tracker.filtr.sigma=0.1: unknown config key\(s\) tracker.filtr;"):
        load_config(TrackConfig, None, ["tracker.filter.particles=9", "tracker.filtr.sigma=0.1"])
    # A range check's message lists every key of its section; only the override that fails is blamed.
    with pytest.raises(ConfigError, match=r"^override tracker.filter.sigma=-1: filter: bad value\(s\) sigma=-1.0 "):
        load_config(TrackConfig, None, ["tracker.filter.particles=9", "tracker.filter.sigma=-1"])
    # Two overrides that clash, each fine on its own, are both blamed (the keys the message names).
    from torch_atr.data.synthetic import SceneConfig

    with pytest.raises(ConfigError, match=r"^overrides circle_diameter_m=1000, range_m=400: "):
        load_config(SceneConfig, None, ["seed=1", "circle_diameter_m=1000", "range_m=400"])
    with pytest.raises(ConfigError, match=r"^override seed=99999999999999999999: seed must be in \[0, 2\*\*64 - 1\]"):
        load_config(TrackConfig, None, ["seed=99999999999999999999"])
    # A file that is bad on its own is blamed even when overrides follow.
    path.write_text("seed: x\n")
    with pytest.raises(ConfigError, match=rf"^{path}: seed: expected an integer"):
        load_config(TrainConfig, path, ["name=b"])


def test_config_text_must_be_utf8_and_small(tmp_path):
    path = tmp_path / "latin1.yaml"
    path.write_bytes("name: caf\xe9\n".encode("latin-1"))
    with pytest.raises(ConfigError, match=rf"{path}, line 1: not UTF-8 text \(byte 0xe9 at byte offset 9\)"):
        load_config(TrainConfig, path)
    path.write_bytes(b"# " + b"x" * 2 ** 20 + b"\n")
    with pytest.raises(ConfigError, match=rf"{path}: larger than 1048576 bytes"):
        load_config(TrainConfig, path)


def test_yaml_merge_keys_may_repeat_a_merged_key():
    from torch_atr.config import parse_yaml

    text = "base: &b\n  size_px: 32\n  tau_px: 3.0\ntemplate:\n  <<: *b\n  size_px: 16\n"
    assert parse_yaml(text)["template"] == {"size_px": 16, "tau_px": 3.0}


def test_view_grid_matches_chapter_6_1():
    theta, phi = ViewGridConfig().grid()
    assert len(theta) == 150  # 30 azimuths x 5 elevations
    assert sorted(set(round(float(t) * 180 / 3.141592653589793) for t in theta)) == list(range(0, 360, 12))
    assert sorted(set(round(float(p) * 180 / 3.141592653589793) for p in phi)) == [0, 10, 20, 30, 40]
    th, ph = ViewGridConfig().held_out()
    assert set(round(float(t) * 180 / 3.141592653589793) for t in th) == set(range(6, 360, 12))
    assert set(round(float(p) * 180 / 3.141592653589793) for p in ph) == {5, 15, 25, 35, 45}
    vt, vp = ViewGridConfig().validation()
    assert len(vt) == 300
    seen = {(round(float(a), 6), round(float(b), 6)) for a, b in zip(vt, vp)}
    assert not seen & {(round(float(a), 6), round(float(b), 6)) for a, b in zip(th, ph)}


@pytest.mark.parametrize("step, suggested", [(13, "12 or 15"), (100, "90 or 120"), (170, "120 or 180"),
                                             (0.7, "0.6 or 0.8")])
def test_an_azimuth_step_must_divide_360(step, suggested):
    """A step that does not divide 360 would leave an odd gap where the azimuths wrap; the message
    names the key and value and the nearest steps either side that divide 360 (by hand)."""
    with pytest.raises(ConfigError, match=rf"^override views.azimuth_step_deg={step}: views.azimuth_step_deg={step} "
                                          rf"must divide 360 \(e.g. {suggested}\)"):
        load_config(TrainConfig, None, [f"views.azimuth_step_deg={step}"])


@pytest.mark.parametrize("step, azimuths", [(7.5, 48), (0.3, 1200), (360 / 7, 7), (180, 2)])
def test_a_step_that_divides_360_gives_evenly_spaced_azimuths(step, azimuths):
    theta, _ = ViewGridConfig(azimuth_step_deg=step, elevation_max_deg=0).grid()
    assert len(theta) == azimuths
    gaps = torch.diff(theta, append=theta[:1] + 2 * math.pi)  # the last one across the wrap
    assert torch.allclose(gaps, torch.full_like(gaps, 2 * math.pi / azimuths))


def test_a_text_key_takes_its_value_as_written():
    """Paths and names are not YAML: '#' starts no comment, ': ' makes no mapping, 2024 stays text."""
    from torch_atr.tracking.job import TrackConfig

    cfg = load_config(TrackConfig, None, ["out=runs/a #b", "sequence=video:t/run: day1.mp4", "device=cpu"])
    assert (cfg.out, cfg.sequence) == ("runs/a #b", "video:t/run: day1.mp4")
    assert load_config(TrackConfig, None, ["out=2024"]).out == "2024"
    train = load_config(TrainConfig, None, ["name=2024", "checkpoint=null", "log_dir='my runs '"])
    assert (train.name, train.checkpoint, train.log_dir) == ("2024", None, "my runs ")  # quoted: YAML
    assert load_config(TrainConfig, None, ["checkpoint=~/m.pt"]).checkpoint == os.path.expanduser("~/m.pt")  # not null
    assert load_config(TrackConfig, None, ["seed=2024"]).seed == 2024  # other keys stay YAML


def test_paths_from_config_files_expand_the_home_folder(tmp_path, monkeypatch):
    """A config file's ~ is the user's home, as the shell makes it on the command line (not a folder named ~)."""
    from torch_atr.tracking.job import TrackConfig
    from torch_atr.training import TrainConfig

    monkeypatch.setenv("HOME", str(tmp_path))
    train = load_config(TrainConfig, None, ["checkpoint=~/m.pt", "log_dir=~/runs", "catalog=~/mine"])
    home = tuple(str(tmp_path / p) for p in ("m.pt", "runs", "mine"))
    assert (train.checkpoint, train.log_dir, train.catalog) == home
    assert load_config(TrainConfig, None, []).catalog == "train"
    track = load_config(TrackConfig, None, ["out=~/run", "checkpoint=~/m.pt"])
    assert (track.out, track.checkpoint) == (str(tmp_path / "run"), str(tmp_path / "m.pt"))


def test_a_config_path_with_an_unknown_users_home_is_not_found(tmp_path, monkeypatch):
    """~nobody_here/c.yaml names a user without a home; a shell leaves it as written, so it is a file that
    is not found (Path.expanduser raised a bare RuntimeError, 'Could not determine home directory'), and ~
    alone is the home folder (HOME)."""
    monkeypatch.setenv("HOME", str(tmp_path))
    (tmp_path / "c.yaml").write_text("name: mine\n")
    assert load_config(TrainConfig, "~/c.yaml").name == "mine"
    assert os.path.expanduser("~nobody_here_9f3/c.yaml") == "~nobody_here_9f3/c.yaml"  # the scenario
    with pytest.raises(ConfigError, match=r"^config file not found: ~nobody_here_9f3/c\.yaml$"):
        load_config(TrainConfig, "~nobody_here_9f3/c.yaml")


@pytest.mark.parametrize("cls_name, key", [("TrackConfig", "out"), ("TrackConfig", "checkpoint"),
                                           ("TrainConfig", "catalog")])
def test_a_blank_path_in_a_config_file_names_the_file(tmp_path, cls_name, key):
    """A blank out, checkpoint (track.py) or catalog (train.py) is Path('') = '.', the current folder. The
    entry points refused it after load_config, so a file's was named without the file, and TrackConfig(out='')
    from Python passed; the configs refuse it, as TrainConfig does a blank checkpoint or log_dir."""
    from torch_atr.tracking.job import TrackConfig

    cls = {"TrackConfig": TrackConfig, "TrainConfig": TrainConfig}[cls_name]
    path = tmp_path / "c.yaml"
    path.write_text(f"{key}: ' '\n")
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(path))}: {key} must be .*; got ' '$"):
        load_config(cls, path)
    with pytest.raises(ConfigError, match=rf"^{key} must be .*; got ''$"):
        cls(**{key: ""})


def test_type_errors_say_what_was_expected_in_words():
    from torch_atr.config import check_type, parse_yaml

    with pytest.raises(ConfigError, match=r"^name: expected text or null; got 2024 \(quote it for text\)$"):
        check_type("name", 2024, str | None)  # a catalog's name: 2024 (YAML reads a number)
    with pytest.raises(ConfigError, match=r"^length: expected a number or null; got '5'$"):
        check_type("length", "5", float | None)  # quoted: text, as the README says
    with pytest.raises(ConfigError, match=r"^ridge: expected a number; got '1e-3'$"):
        check_type("ridge", "1e-3", float)  # quoted, an exponent is text too
    # unquoted, an exponent without a dot is a number (YAML 1.2; 1.1 reads it as text), in a file or an override
    assert parse_yaml("a: 1e-3\nb: -2.5E+2\nc: '1e-3'\nd: 1.5e3\ne: 7\n") == {"a": 0.001, "b": -250.0, "c": "1e-3",
                                                                                 "d": 1500.0, "e": 7}


def test_a_fixed_length_tuple_checks_its_length_and_each_items_type():
    """tuple[float, float] checked every item against float alone and never the length: [1.0, 2.0, 3.0]
    passed, and tuple[int, str] refused [1, "a"]. tuple[X, ...] stays any length of X."""
    from torch_atr.config import check_type

    with pytest.raises(ConfigError, match=r"^box: expected a list of 2 \(a number, a number\); "
                                          r"got \[1\.0, 2\.0, 3\.0\]$"):
        check_type("box", [1.0, 2.0, 3.0], tuple[float, float])
    with pytest.raises(ConfigError, match=r"^box: expected a list of 2 or null; got \[1\.0\]$"):
        check_type("box", [1.0], tuple[float, float] | None)
    with pytest.raises(ConfigError, match=r"^pair\[1\]: expected a string; got 2"):
        check_type("pair", [1, 2], tuple[int, str])
    assert check_type("pair", [1, "a"], tuple[int, str]) == (1, "a")
    assert check_type("box", [1, 2.5], tuple[float, float]) == (1.0, 2.5)
    assert check_type("ranges", [1, 2.5, 3], tuple[float, ...]) == (1.0, 2.5, 3.0)
    assert check_type("ranges", [], tuple[float, ...]) == ()


def test_numbers_are_read_as_yaml_1_2_reads_them_not_as_octal_or_base_60(tmp_path):
    """YAML 1.1 reads 010 as octal 8 and 1:30 as base-60 90, without a word; a config means 10, and
    1:30 is no number: its key refuses it, in a file and in an override."""
    assert load_config(TrainConfig, None, ["views.azimuth_step_deg=010", "seed=0_12"]).views.azimuth_step_deg == 10
    assert load_config(TrainConfig, None, ["seed=012"]).seed == 12
    assert load_config(TrainConfig, None, ["seed=09"]).seed == 9  # not octal in YAML 1.1: was text
    assert load_config(TrainConfig, None, ["seed=0_9"]).seed == 9
    assert load_config(TrainConfig, None, ["seed=0x10"]).seed == 16  # hexadecimal, as YAML 1.2 has it too
    with pytest.raises(ConfigError, match=r"^override seed=1:30: seed: expected an integer; got '1:30'$"):
        load_config(TrainConfig, None, ["seed=1:30"])
    with pytest.raises(ConfigError, match=r"^override model.ridge=1:30.5: model.ridge: expected a number; "
                                          r"got '1:30.5'"):
        load_config(TrainConfig, None, ["model.ridge=1:30.5"])
    path = tmp_path / "c.yaml"
    path.write_text("seed: 010\nname: '1'\ntemplate:\n  size_px: 1:04\n")
    with pytest.raises(ConfigError, match=rf"^{path}: template.size_px: expected an integer; got '1:04'$"):
        load_config(TrainConfig, path)
    path.write_text("seed: 010\n")
    assert load_config(TrainConfig, path).seed == 10


def test_a_number_yaml_cannot_convert_is_named_with_its_file_or_override(tmp_path):
    """An integer of 5000 digits (int's 4300-digit limit), one too long to print (hexadecimal), a
    tagged ``!!int abc`` or lists nested thousands deep raised a bare ValueError, IndexError or
    RecursionError naming neither the file nor the override."""
    big = "1" * 5000
    for override in (f"seed={big}", f"seed=0{big}", f"model.ridge={big}", f"model={{ridge: {big}}}",
                     "seed=0x" + "f" * 5000, "seed=" + "[" * 3000 + "]" * 3000):
        quoted = repr(override)  # over 240 characters: its first 40, '…' and its length
        with pytest.raises(ConfigError, match=rf"^override {re.escape(quoted[:40])}… \({len(quoted)} characters\): "
                                              rf"not a YAML value: "):
            load_config(TrainConfig, None, [override])
    path = tmp_path / "c.yaml"
    for text, why in ((f"seed: {big}\n", "is not a number"), ("seed: 0x" + "f" * 5000 + "\n", "more than 900 digits"),
                      ("seed: !!int abc\n", "'abc' is not a number"), ("seed: !!int ''\n", "'' is not a number"),
                      ("seed: !!float abc\n", "'abc' is not a number"), ("seed: " + "[" * 3000 + "\n", "nested")):
        path.write_text(text)
        with pytest.raises(ConfigError, match=rf"^{re.escape(str(path))}: not valid YAML: .*{re.escape(why)}"):
            load_config(TrainConfig, path)
    path.write_text("seed: !!int 12\nmodel:\n  ridge: !!float 0.5\n")
    assert (load_config(TrainConfig, path).seed, load_config(TrainConfig, path).model.ridge) == (12, 0.5)


def test_an_override_error_quotes_a_huge_value_shortened():
    """seed= and 100 000 digits, or 50 000 letters for a number's key, made a message as long: each
    value, key or override over 240 characters is now quoted by its first 40, '…' and its length."""
    cases = [
        (["seed=" + "1" * 100_000], "override 'seed=" + "1" * 34 + "… (100007 characters): not a YAML value: '"
         + "1" * 39 + "… (100002 characters) is not a number (Exceeds the limit (4300 digits)"),
        (["seed=" + "a" * 50_000], "override seed=" + "a" * 35 + "… (50005 characters): seed: expected an integer; "
         "got '" + "a" * 39 + "… (50002 characters)"),
        (["seed=" + "9" * 900], "override seed=" + "9" * 35 + "… (905 characters): seed must be in [0, 2**64 - 1]; "
         "got " + "9" * 40 + "… (900 characters)"),
        (["model.pixel_rank=" + "9" * 800], "override model.pixel_rank=" + "9" * 23 + "… (817 characters): "
         "model.pixel_rank must be in [1, 262144] or null; got " + "9" * 40 + "… (800 characters)"),
        (["x" * 50_000 + "=1"], "override " + "x" * 40 + "… (50002 characters): unknown config key(s) " + "x" * 40
         + "… (50000 characters); known: catalog,"),
        (["b" * 50_000], "override '" + "b" * 39 + "… (50002 characters) is not of the form key=value"),
        (["y" * 300 + "=1", "y" * 300 + "=2"], "overrides '" + "y" * 39 + "… (304 characters) and '" + "y" * 39
         + "… (304 characters) both set " + "y" * 40 + "… (300 characters); give one"),
    ]
    for overrides, start in cases:
        with pytest.raises(ConfigError) as info:
            load_config(TrainConfig, None, overrides, unique=True)
        assert str(info.value).startswith(start)
        assert len(str(info.value)) < 500 and "\n" not in str(info.value)
    # up to 240 characters a value or an override is quoted whole, as it was up to 200
    exact = [("seed=abc", "override seed=abc: seed: expected an integer; got 'abc'"),
             ("seed=" + "a" * 198, "override seed=" + "a" * 198 + ": seed: expected an integer; "
              "got '" + "a" * 198 + "'"),
             ("seed=" + "a" * 238, "override seed=" + "a" * 35 + "… (243 characters): seed: expected an integer; "
              "got '" + "a" * 238 + "'"),
             ("seed=" + "a" * 239, "override seed=" + "a" * 35 + "… (244 characters): seed: expected an integer; "
              "got '" + "a" * 39 + "… (241 characters)")]
    for override, message in exact:
        with pytest.raises(ConfigError) as info:
            load_config(TrainConfig, None, [override])
        assert str(info.value) == message



@pytest.mark.parametrize("section, key, value", [("filter", "method", "x" * 50_000),
                                                 ("segmentation", "history", -10 ** 5000),
                                                 ("scene", "frames", -10 ** 5000)],
                         ids=["filter", "segmentation", "scene"])
def test_bad_values_of_a_section_are_quoted_shortened(section, key, value):
    """A huge bad value makes a short message: a 50 000-character method, and integers of 5001 digits,
    which repr refuses (it raised ValueError 'Exceeds the limit (4300 digits)' from the message)."""
    from torch_atr.data.synthetic import SceneConfig
    from torch_atr.segmentation import SegmentationConfig
    from torch_atr.tracking.filter import FilterConfig
    cls = {"filter": FilterConfig, "segmentation": SegmentationConfig, "scene": SceneConfig}[section]
    with pytest.raises(ConfigError, match=f"^{section}: bad value.s. {key}=") as info:
        cls(**{key: value})
    assert len(str(info.value)) < 1000
