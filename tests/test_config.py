import pytest

from torch_atr.config import ConfigError, ModelConfig, TemplateConfig, load_config
from torch_atr.training import TrainConfig, ViewGridConfig


def test_yaml_then_overrides_then_types(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("name: a\ntemplate:\n  size_px: 32\nmodel:\n  pixel_rank: null\n")
    cfg = load_config(TrainConfig, path, ["template.window_m=10", "model.ridge=1e-3", "name=b"])
    assert cfg.name == "b" and cfg.template == TemplateConfig(size_px=32, window_m=10.0)
    assert cfg.model == ModelConfig(pixel_rank=None, ridge=1e-3)
    assert isinstance(cfg.template.window_m, float)


@pytest.mark.parametrize("text, match", [
    ("nme: a\n", "unknown config key.*nme"),
    ("template:\n  sizepx: 3\n", "template.sizepx"),
    ("template:\n  size_px: 3.5\n", "template.size_px: expected an integer"),
    ("tensorboard: 1\n", "tensorboard: expected true/false"),
    ("template: 5\n", "template: expected a mapping"),
    ("- a\n", "top level must be a mapping"),
    ("a: [\n", "not valid YAML"),
    ("template:\n  size_px: 4\n", "size_px must be >= 8"),
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
