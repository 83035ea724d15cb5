"""Checkpoints from untrusted sources: checksum, checks before allocation, no unsafe hints, no overwriting."""

import copy
import logging
import os
import re
import struct
import zipfile

import pytest
import torch

from torch_atr.cli import error_text
from torch_atr.config import ModelConfig, TemplateConfig
from torch_atr.io import OutputExistsError
from torch_atr.model import GenerativeShapeModel, load_checkpoint
from torch_atr.model.generative import is_checkpoint, state_shapes
from torch_atr.validate import InputError


@pytest.fixture(scope="module")
def model():
    g = torch.Generator().manual_seed(0)
    templates = torch.rand(3, 6, 8, 8, generator=g) * 2 - 1  # (K, V, H, W)
    theta = torch.linspace(0, 5, 6)
    phi = torch.linspace(0, 0.6, 6)
    return GenerativeShapeModel.fit(templates, theta, phi, ["a", "b", "c"], [0, 0, 1], ["car", "tank"],
                                    TemplateConfig(size_px=8, window_m=4.0, tau_px=2.0),
                                    ModelConfig(pixel_rank=5, ridge=1e-3))


@pytest.fixture
def saved(model, tmp_path):
    path = tmp_path / "model.pt"
    model.save(path, extra={"note": "x", "views": torch.arange(3)})
    return path


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU")
def test_a_model_saved_from_a_gpu_holds_cpu_tensors(model, tmp_path):
    """torch.load puts a tensor back on the device it was saved from, and a machine without that
    device refuses it (which load_checkpoint reported as a corrupt file): a checkpoint holds CPU tensors."""
    path = tmp_path / "gpu.pt"
    copy.deepcopy(model).to("cuda").save(path, extra={"views": [torch.arange(3, device="cuda")]})
    raw = torch.load(path, weights_only=True)
    assert {t.device.type for t in [*raw["state_dict"].values(), *raw["extra"]["views"]]} == {"cpu"}
    assert GenerativeShapeModel.from_checkpoint(path).core.core.device.type == "cpu"


def _v1(path):
    """The checkpoint at ``path`` as a version-1 payload (no checksum), to edit freely."""
    raw = torch.load(path, weights_only=True)
    del raw["sha256"]
    return {**raw, "format_version": 1}


def _stored_data(path):
    """(offset, size) of the largest tensor storage (``*/data/N``) in the zip at ``path``, from its local header."""
    with zipfile.ZipFile(path) as archive:
        entry = max((e for e in archive.infolist() if "/data/" in e.filename), key=lambda e: e.file_size)
    with open(path, "rb") as fh:
        fh.seek(entry.header_offset)
        header = fh.read(30)
    name_len, extra_len = struct.unpack("<HH", header[26:30])
    return entry.header_offset + 30 + name_len + extra_len, entry.file_size


@pytest.mark.parametrize("rank", [None, 5])
def test_state_shapes_are_those_of_the_modules(model, rank):
    args = {**model.model_args, "pixel_rank": rank}
    built = GenerativeShapeModel.from_model_args(args).state_dict()
    assert {k: tuple(v.shape) for k, v in built.items()} == state_shapes(args)


def test_a_flipped_byte_inside_a_tensor_is_caught_by_the_checksum(model, saved):
    offset, size = _stored_data(saved)
    data = bytearray(saved.read_bytes())
    data[offset + size // 2] ^= 0x40
    saved.write_bytes(bytes(data))
    raw = torch.load(saved, weights_only=True)  # PyTorch itself reads it without complaint ...
    assert not all(torch.equal(raw["state_dict"][k], v) for k, v in model.state_dict().items())
    with pytest.raises(InputError, match=rf"^{saved}: content checksum mismatch .*corrupt or was edited"):
        load_checkpoint(saved)  # ... the checksum does not


def test_edited_content_with_the_old_checksum_is_refused(saved):
    raw = torch.load(saved, weights_only=True)
    raw["state_dict"]["identity.alphas"][1] += 1e-6
    torch.save(raw, saved)
    with pytest.raises(InputError, match="content checksum mismatch"):
        load_checkpoint(saved)
    raw = torch.load(saved, weights_only=True)
    raw["extra"]["note"] = "y"
    torch.save(raw, saved)
    with pytest.raises(InputError, match="content checksum mismatch"):
        load_checkpoint(saved)


def test_checksum_survives_a_load_save_round_trip(model, saved, tmp_path):
    loaded, extra = load_checkpoint(saved)
    again = tmp_path / "again.pt"
    loaded.save(again, extra=extra)
    assert torch.load(again, weights_only=True)["sha256"] == torch.load(saved, weights_only=True)["sha256"]


def test_a_model_that_would_not_load_is_not_saved(saved, tmp_path):
    half = load_checkpoint(saved)[0].half()
    path = tmp_path / "half.pt"
    with pytest.raises(InputError, match=re.escape(f"{path} (not written, as it would not load): state_dict[") + ".*"
                                         "float16; expected the model's one float dtype, float32 or float64"):
        half.save(path)
    assert not path.exists()


def test_version_1_files_load_with_a_warning(model, saved, caplog):
    torch.save(_v1(saved), saved)
    with caplog.at_level(logging.WARNING):
        loaded, extra = load_checkpoint(saved)
    assert "format_version 1 carries no checksum" in caplog.text
    assert extra["note"] == "x"
    for k, v in model.state_dict().items():
        assert torch.equal(loaded.state_dict()[k], v)


def _edit_state(raw, key, value):
    return {**raw, "state_dict": {**raw["state_dict"], key: value}}


@pytest.mark.parametrize("edit, message", [
    (lambda r: _edit_state(r, "core.core", r["state_dict"]["core.core"].clone().fill_(float("nan"))),
     r"state_dict\['core.core'\] holds 150 NaN or infinite value\(s\)"),
    (lambda r: _edit_state(r, "identity.alphas", torch.tensor([0.0, float("inf"), 1.0])),
     r"state_dict\['identity.alphas'\] holds 1 NaN"),
    (lambda r: _edit_state(r, "identity.order", torch.tensor([0, 0, 2])),
     r"identity.order'\] is not a permutation of 0..2: \[0, 0, 2\]"),
    (lambda r: _edit_state(r, "identity.order", torch.tensor([0, 1, 2], dtype=torch.int32)),
     r"identity.order'\] has dtype torch.int32; expected torch.int64"),
    (lambda r: _edit_state(r, "core.core", r["state_dict"]["core.core"].half()),
     r"core.core'\] has dtype torch.float16; expected the model's one float dtype"),
    (lambda r: _edit_state(r, "identity.knots", r["state_dict"]["identity.knots"].double()),
     r"identity.knots'\] has dtype torch.float64; expected the model's one float dtype, float32 or float64 "
     r"\(torch.float32 here\)"),
    (lambda r: _edit_state(r, "rbf.log_width", [1.0] * 6), r"rbf.log_width'\] is a list; expected a dense tensor"),
    (lambda r: _edit_state(r, "rbf.log_width", torch.full((6,), -200.0)),
     r"rbf.log_width'\] holds values in \[-200, -200\]; expected them within \[-20, 20\]"),
    (lambda r: _edit_state(r, "core.core", r["state_dict"]["core.core"] * 1e30),
     r"core.core'\] holds values in .*; expected them within \[-1e\+06, 1e\+06\]"),
    (lambda r: _edit_state(r, "identity.knots", r["state_dict"]["identity.knots"].flip(0)),
     r"identity.knots'\] is not strictly increasing"),
    # The αₖ are the spline's sites from 0 to 2π: swapped, re-ordered or shifted ones put vehicles where the
    # spline does not reproduce them (these loaded).
    (lambda r: _edit_state(r, "identity.alphas", r["state_dict"]["identity.alphas"][[1, 0, 2]]),
     r"identity.alphas'\] along identity.order, \[2.09.*\], are not the identity spline's data sites from 0 to 2π"),
    (lambda r: _edit_state(r, "identity.order", torch.tensor([0, 2, 1])), r"are not the identity spline's data sites"),
    (lambda r: _edit_state(_edit_state(r, "identity.knots", r["state_dict"]["identity.knots"] + 1.0),
                           "identity.alphas", r["state_dict"]["identity.alphas"] + 1.0),
     r"are not the identity spline's data sites from 0 to 2π, identity.knots\[3:7\] = \[1.0, "),
    (lambda r: _edit_state(r, "extra_buffer", torch.zeros(2)), "state_dict does not match model_args: unexpected "
                                                               "'extra_buffer'"),
    (lambda r: {**r, "model_args": {**r["model_args"], "template": {"size_px": 100000}}},
     r"model_args\['template'\]: template.size_px must be in \[8, 512\]; got 100000"),
    (lambda r: {**r, "model_args": {**r["model_args"], "num_centres": 10 ** 9}},
     r"model_args\['num_centres'\]: expected an integer in \[1, 10000\]"),
    (lambda r: {**r, "model_args": {**r["model_args"], "num_vehicles": 10 ** 6}},
     r"model_args\['num_vehicles'\]: expected an integer in \[2, 1000\]"),
    (lambda r: {**r, "model_args": {**r["model_args"], "pixel_rank": 65}},
     r"model_args\['pixel_rank'\]: expected an integer in \[1, 64\]; got 65"),
    (lambda r: {**r, "model_args": {**r["model_args"], "pixel_rank": 5.0}}, r"pixel_rank'\]: expected an integer"),
    (lambda r: {**r, "model_args": {**r["model_args"], "vehicle_classes": [0, 0, 2]}},
     r"vehicle_classes'\]\[2\]: expected an integer in \[0, 1\]; got 2"),
    (lambda r: {**r, "model_args": {**r["model_args"], "gpu": True}}, r"model_args: unknown key\(s\) 'gpu'"),
    # A class named twice was two classes that class_names.index told apart wrongly (recognition, truth starts).
    (lambda r: {**r, "model_args": {**r["model_args"], "class_names": ["car", "car"]}},
     r"model_args\['class_names'\]: expected distinct names; \['car'\] repeat\(s\)"),
    (lambda r: {**r, "model_args": {**r["model_args"], "vehicle_names": ["a", "b", "a"]}},
     r"model_args\['vehicle_names'\]: expected distinct names; \['a'\] repeat\(s\)"),
    (lambda r: {**r, "format_version": True}, "format_version True is not a version number"),
    (lambda r: {**r, "format_version": 1.0}, "format_version 1.0 is not a version number"),
    (lambda r: {**r, "surprise": 1}, r"unknown checkpoint key\(s\) 'surprise'"),
])
def test_bad_content_is_refused_with_file_and_key(saved, edit, message):
    torch.save(edit(_v1(saved)), saved)
    with pytest.raises(InputError, match=rf"^{saved}: .*{message}"):
        load_checkpoint(saved)


def test_model_args_are_checked_against_the_state_before_the_model_is_built(saved, monkeypatch):
    raw = _v1(saved)
    torch.save({**raw, "model_args": {**raw["model_args"], "num_centres": 9000,
                                      "template": {"size_px": 512, "window_m": 4.0, "tau_px": 2.0}}}, saved)

    def no_allocation(*args, **kwargs):
        raise AssertionError("from_model_args was called before model_args were checked against the state")

    monkeypatch.setattr(GenerativeShapeModel, "from_model_args", no_allocation)
    with pytest.raises(InputError, match=r"rbf.centres_theta has shape \(6,\); model_args call for \(9000,\)"):
        load_checkpoint(saved)


def test_a_malicious_pickle_is_refused_without_suggesting_weights_only_false(tmp_path):
    class Payload:
        def __reduce__(self):
            return (os.system, ("echo pwned",))

    path = tmp_path / "evil.pt"
    torch.save({"format": "torch_atr.generative", "x": Payload()}, path)
    with pytest.raises(InputError) as info:
        load_checkpoint(path)
    message = str(info.value)
    assert message.startswith(f"{path}: refused to load: it holds something other than tensors and plain data")
    assert "system" in message and "weights_only" not in message
    assert not is_checkpoint(path)


def test_a_compressed_archive_is_refused_before_unpickling(saved, tmp_path):
    packed = tmp_path / "packed.pt"
    with zipfile.ZipFile(saved) as src, zipfile.ZipFile(packed, "w", zipfile.ZIP_DEFLATED) as dst:
        for entry in src.infolist():
            dst.writestr(entry.filename, src.read(entry))
    with pytest.raises(InputError, match=rf"^{packed}: archive entry .* is compressed"):
        load_checkpoint(packed)


def test_text_and_folders_are_not_checkpoints(tmp_path):
    notes = tmp_path / "notes.pt"
    notes.write_text("my notes\n")
    with pytest.raises(InputError, match=rf"^{notes}: not a readable checkpoint .*not a zip archive"):
        load_checkpoint(notes)
    with pytest.raises(InputError, match="expected a checkpoint file"):
        load_checkpoint(tmp_path)
    assert not is_checkpoint(notes) and not is_checkpoint(tmp_path) and not is_checkpoint(tmp_path / "none.pt")


def test_a_checkpoint_we_may_not_read_is_not_called_corrupt(saved, monkeypatch):
    """A file the user may not read was reported as "not a readable checkpoint (corrupt, truncated or another kind
    of file)"; the reason is the permission, said as a config file's is."""
    saved.chmod(0)
    if os.access(saved, os.R_OK):  # root reads it anyway: the open fails as it would for another user
        def refuse(*args, **kwargs):
            raise PermissionError(13, "Permission denied", str(saved))

        monkeypatch.setattr(zipfile, "ZipFile", refuse)
    with pytest.raises(PermissionError) as info:
        load_checkpoint(saved)
    assert error_text(info.value) == f"{saved}: cannot read it: Permission denied"


def test_a_device_this_machine_lacks_is_named_not_blamed_on_the_file(saved):
    """map_location naming a missing device: a ValueError about the device, not "corrupt"."""
    missing = ["tpu", "cuda:x", "meta"] + ([] if torch.cuda.is_available() else ["cuda", 0])  # 0: was 'corrupt'
    for device in missing:
        with pytest.raises(ValueError, match=rf"^device '{device}' is not available here") as info:
            load_checkpoint(saved, map_location=device)
        assert not isinstance(info.value, InputError)
    for device in ("cpu", "cpu:0", torch.device("cpu")):  # torch.load itself refuses "cpu:0"
        assert load_checkpoint(saved, map_location=device)[0].alphas.device.type == "cpu"
    if not torch.backends.mps.is_available():  # PyTorch's reason was 7000 characters, its backend list
        with pytest.raises(ValueError, match=r"^device 'mps' is not available here \(PyTorch [^:]*: [^\n]*\); try cpu$"
                           ) as info:
            load_checkpoint(saved, map_location="mps")
        assert len(str(info.value)) < 300  # PyTorch's one sentence, whatever its wording


def test_save_replaces_a_checkpoint_but_never_another_file(model, saved, tmp_path):
    assert is_checkpoint(saved)
    model.save(saved, extra={"note": "second"})
    assert load_checkpoint(saved)[1] == {"note": "second"}
    notes = tmp_path / "my_notes.txt"
    notes.write_text("do not lose me")
    with pytest.raises(OutputExistsError, match=rf"^{notes} exists and is not a checkpoint; refusing to replace it"):
        model.save(notes)
    assert notes.read_text() == "do not lose me"
