"""train.py end to end: a reduced run by default, the full default config under -m slow."""

import json
import math
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import train
from torch_atr.config import ConfigError
from torch_atr.io import OutputExistsError
from torch_atr.model import GenerativeShapeModel
from torch_atr.model.generative import load_checkpoint
from torch_atr.render import render_templates
from torch_atr.shape import iou
from torch_atr.training import trained_catalog, training_templates
from torch_atr.vehicles import load_catalog, load_catalog_folder, load_catalog_vehicle
from torch_atr.vehicles.catalog import CATALOG_DIR
from torch_atr.vehicles.loader import body_rotation

REPO = Path(__file__).resolve().parents[1]


TINY = ("template.size_px=16", "template.tau_px=2", "views.azimuth_step_deg=60", "views.elevation_step_deg=40",
        "model.pixel_rank=8", "model.width_steps=0", "evaluate_test_split=false", "tensorboard=false")


def _run(tmp_path, *overrides, flags=(), checkpoint="model.pt", name="test"):
    ckpt = tmp_path / checkpoint  # an absolute path stays itself
    report = train.main(["--config", str(REPO / "configs/default.yaml"), *flags, f"checkpoint={ckpt}",
                         f"log_dir={tmp_path / 'runs'}", f"name={name}", *overrides])
    return ckpt, report


def test_reduced_training_writes_a_loadable_checkpoint_and_logs(tmp_path):
    ckpt, report = _run(tmp_path, "template.size_px=32", "views.azimuth_step_deg=30", "views.elevation_step_deg=20",
                        "model.pixel_rank=48", "model.width_steps=3", "evaluate_test_split=false")
    raw = torch.load(ckpt, weights_only=True)
    assert raw["extra"]["config"]["template"]["size_px"] == 32
    model = GenerativeShapeModel.from_checkpoint(ckpt)
    assert len(model.vehicle_names) == 36 and model.core.pixel_rank == 48
    assert report["identity_self_match"]["all"]
    assert report["train_iou"]["all"] > 0.9
    assert json.loads((tmp_path / "runs/test/report.json").read_text())["views"] == 12 * 3
    assert list((tmp_path / "runs/test").glob("events.out.tfevents.*"))
    # Independent reference: the renderer, at views between the training ones.
    vehicles = {v.name: v for v in load_catalog("train")}
    theta = torch.tensor([math.radians(15.0), math.radians(200.0)])
    phi = torch.tensor([math.radians(10.0), math.radians(30.0)])
    for k in (0, 20):
        truth = render_templates(vehicles[model.vehicle_names[k]], theta, phi, model.template)
        recon = model.silhouette(model.alphas[k].expand(2), theta, phi)
        assert iou(recon, truth).mean() > 0.7  # 32 px, 30° steps: coarse but still the right shape

    # Re-runs: outputs are replaced only with --overwrite, and a file that is not ours never.
    report_path = tmp_path / "runs/test/report.json"
    assert json.loads(report_path.read_text())["format"] == "torch_atr.train_report" == report["format"]
    before = ckpt.read_bytes(), report_path.read_text()
    with pytest.raises(OutputExistsError, match=r"runs/test already holds a run \(report.json\); pass --overwrite"):
        _run(tmp_path, *TINY)
    report_path.unlink()  # our run folder without its report: a run killed midway, replaced only with --overwrite
    with pytest.raises(OutputExistsError, match=r"runs/test already holds an interrupted run \(no report.json\)"):
        _run(tmp_path, *TINY, checkpoint="other.pt")
    (tmp_path / "runs/test/.torch_atr_run").unlink()  # without our claim: another tool's folder, never replaced
    with pytest.raises(OutputExistsError, match="runs/test is not empty and holds no report.json of ours"):
        _run(tmp_path, *TINY, flags=["--overwrite"])
    report_path.write_text(before[1])
    with pytest.raises(OutputExistsError, match=rf"{ckpt} exists; pass --overwrite"):
        _run(tmp_path, *TINY, name="other")
    notes = tmp_path / "my_notes.txt"
    notes.write_text("precious")
    with pytest.raises(OutputExistsError, match=rf"{notes} exists and is not a checkpoint; refusing .*even with "):
        _run(tmp_path, *TINY, checkpoint=notes, name="other", flags=["--overwrite"])
    assert notes.read_text() == "precious" and (ckpt.read_bytes(), report_path.read_text()) == before
    stale = tmp_path / "runs/test/model.pt"  # the replaced run's checkpoint, where this run writes none
    stale.write_bytes(ckpt.read_bytes())
    _, second = _run(tmp_path, *TINY, flags=["--overwrite"])
    assert json.loads(report_path.read_text())["views"] == second["views"] == 6 * 2
    assert not list((tmp_path / "runs/test").glob("events.out.tfevents.*"))  # the replaced run's logs went with it
    assert not stale.exists()  # nor its model beside this run's report
    assert GenerativeShapeModel.from_checkpoint(ckpt).core.pixel_rank == 8


def test_the_checkpoint_goes_into_the_named_run_folder(tmp_path):
    runs = tmp_path / "runs"
    train.main(["--config", str(REPO / "configs/default.yaml"), f"log_dir={runs}", "name=solo", *TINY])
    ckpt = runs / "solo" / "model.pt"
    assert ckpt.is_file() and not (runs / "default").exists()
    assert torch.load(ckpt, weights_only=True)["extra"]["config"]["checkpoint"] == str(ckpt)


@pytest.mark.parametrize("checkpoint", ["runs/test/report.json", "runs/test/view_sweeps.png",
                                        "runs/test/.torch_atr_run", "runs/test/events.out.tfevents.1", "runs/test",
                                        "runs"])
def test_a_checkpoint_the_run_would_write_over_is_refused_before_anything_is_written(tmp_path, checkpoint):
    """A checkpoint at the run's own report.json was replaced by the report without a word."""
    with pytest.raises(ConfigError, match=rf"^checkpoint={re.escape(str(tmp_path / checkpoint))} is "):
        _run(tmp_path, *TINY, checkpoint=checkpoint)
    assert not (tmp_path / "runs").exists()


def test_user_errors_print_one_line_and_exit_2(tmp_path):
    result = subprocess.run([sys.executable, str(REPO / "train.py"), "model.ridg=1", f"log_dir={tmp_path}"],
                            capture_output=True, text=True, cwd=tmp_path)
    assert result.returncode == 2
    assert result.stderr.startswith("train.py: error: override model.ridg=1: unknown config key(s) model.ridg;")
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert "configs/default.yaml" not in result.stderr


REDUCED = ("template.size_px=32", "views.azimuth_step_deg=30", "views.elevation_step_deg=20", "model.pixel_rank=16",
           "model.width_steps=0", "evaluate_test_split=false")


def _own_catalog(folder: Path) -> None:
    """Three shipped URDFs, and a Camry exported as an OBJ in centimetres with y up and -z forward."""
    for name in ("m1a2_abrams", "vw_golf", "toyota_hilux"):
        shutil.copytree(CATALOG_DIR / "train" / name, folder / name)
    camry = load_catalog_vehicle("toyota_camry").mesh.copy()
    camry.vertices = 100.0 * camry.vertices @ body_rotation("y", "-z")  # body -> file: the inverse rotation, in cm
    camry.export(folder / "camry_cm.obj")
    (folder / "catalog.yaml").write_text(
        "vehicles:\n"
        "  - {file: m1a2_abrams/m1a2_abrams.urdf, class: tank, scale: 1.0}\n"
        "  - {file: vw_golf/vw_golf.urdf, class: car, length: 4.255}\n"
        "  - {file: toyota_hilux/toyota_hilux.urdf, class: pickup, scale: 1.0}\n"
        "  - {file: camry_cm.obj, class: car, up: y, forward: -z, length: 4.88, name: camry}\n")


def test_training_on_a_catalog_folder(tmp_path, caplog):
    folder = tmp_path / "mine"
    _own_catalog(folder)
    vehicles = load_catalog_folder(folder)
    assert [(v.name, v.cls) for v in vehicles] == [("m1a2_abrams", "tank"), ("toyota_hilux", "pickup"),
                                                   ("camry", "car"), ("vw_golf", "car")]
    # Independent reference: the shipped URDF the OBJ was exported from, in metres and the body frame.
    shipped = load_catalog_vehicle("toyota_camry").mesh
    np.testing.assert_allclose(vehicles[2].mesh.bounds, shipped.bounds, atol=1e-6)
    ckpt, report = _run(tmp_path, f"catalog={folder}", *REDUCED)
    raw = torch.load(ckpt, weights_only=True)
    assert raw["extra"]["config"]["catalog"] == str(folder)
    model = GenerativeShapeModel.from_checkpoint(ckpt)
    assert model.vehicle_names == [v.name for v in vehicles] and report["identity_self_match"]["all"]
    classes = [model.class_names[c] for c in model.classify(model.alphas).tolist()]
    assert classes == [v.cls for v in vehicles]
    # Method IV re-renders the catalog the checkpoint records, not the shipped split (which lacks
    # "camry"): against the shipped Camry URDF the OBJ came from, rendered at the model's views.
    model, extra = load_checkpoint(ckpt)
    templates = training_templates(model, trained_catalog(extra))
    theta, phi = model.rbf.centres_theta, model.rbf.centres_phi
    truth = render_templates(load_catalog_vehicle("toyota_camry"), theta, phi, model.template)
    assert templates.shape[:2] == (4, len(theta)) and iou(templates[2] > 0, truth).min() > 0.98
    assert "Method IV" not in caplog.text
    # A catalog edited since training is named (Method IV would compare a 9 m Camry's templates).
    manifest = folder / "catalog.yaml"
    manifest.write_text(manifest.read_text().replace("length: 4.88", "length: 9.0"))
    training_templates(model, trained_catalog(extra))
    assert re.search(r"Method IV: has catalog .*mine changed since training\? Its camry \(0\.\d\d\) differ",
                     caplog.text)
    folder.rename(tmp_path / "moved")
    with pytest.raises(FileNotFoundError, match="Method IV re-renders the training vehicles from the catalog the "
                                                 f"checkpoint names: catalog manifest not found: {manifest} \\("):
        training_templates(model, trained_catalog(extra))


def test_a_catalog_given_as_its_manifest_file(tmp_path):
    """catalog=PATH/catalog.yaml is the folder's catalog (it was 'not found: PATH/catalog.yaml/catalog.yaml')."""
    folder = tmp_path / "mine"
    _own_catalog(folder)
    vehicles = load_catalog_folder(folder / "catalog.yaml")
    assert [(v.name, v.cls) for v in vehicles] == [("m1a2_abrams", "tank"), ("toyota_hilux", "pickup"),
                                                   ("camry", "car"), ("vw_golf", "car")]
    np.testing.assert_allclose(vehicles[2].mesh.bounds, load_catalog_vehicle("toyota_camry").mesh.bounds, atol=1e-6)
    (folder / "catalog.yaml").rename(folder / "other.yaml")  # any manifest file, its folder holding the files
    assert [v.name for v in load_catalog_folder(folder / "other.yaml")] == [v.name for v in vehicles]
    with pytest.raises(FileNotFoundError, match=f"catalog manifest not found: {folder / 'catalog.yaml'} \\(a catalog"):
        load_catalog_folder(folder)


def test_catalog_manifest_errors_name_the_entry(tmp_path):
    folder = tmp_path / "mine"
    _own_catalog(folder)
    manifest = folder / "catalog.yaml"
    good = manifest.read_text()
    for line, message in [
        ("  - {file: camry_cm.obj, class: sedan, length: 4.88, name: c2}",
         r"vehicles\[4\] \(camry_cm.obj\): class 'sedan'"),
        ("  - {file: gone.obj, class: car, scale: 1.0}", r"vehicles\[4\] \(gone.obj\): vehicle file not found"),
        ("  - {file: camry_cm.obj, class: car, length: 4.88, scale: 0.01}", r"vehicles\[4\].*exactly one of 'length'"),
        ("  - {file: camry_cm.obj, class: car, scale: -1}", r"vehicles\[4\].*scale must be a positive number"),
        ("  - {file: camry_cm.obj, class: car, scale: 0.01, colour: red}", r"vehicles\[4\].*unknown keys \['colour'\]"),
        ("  - {file: camry_cm.obj, class: car, scale: 0.01, up: y, forward: y}",
         r"vehicles\[4\].*: the up axis 'y' and the forward axis 'y' must be perpendicular"),
        ("  - {file: vw_golf/vw_golf.urdf, class: car, scale: 1.0}", r"names must be unique.*vw_golf"),
        ("  - {file: camry_cm.obj, class: car, scale: 1, scale: 2}", r"YAML: key 'scale' repeated \(first on line 6"),
        ("  - {file: camry_cm.obj, class: car, scale: 0.01, name: ''}", r"vehicles\[4\].*name must not be empty"),
        ("  - {file: camry_cm.obj, class: car, scale: 0.01, up: null}", r"vehicles\[4\].*up: expected a string"),
        ("  - {file: ., class: car, scale: 0.01}", r"vehicles\[4\] \(.\):.*is a folder"),
        ("vehicles: []", r"key 'vehicles' repeated"),
        ("  - {file: camry_cm.obj, class: car", r"catalog.yaml: not valid YAML: "),
    ]:
        manifest.write_text(good + line + "\n")
        with pytest.raises((ValueError, FileNotFoundError), match=message):
            load_catalog_folder(folder)
    manifest.write_bytes(good.encode() + b"  - {file: camry\xff.obj, class: car, scale: 1}\n")
    with pytest.raises(ValueError, match=r"catalog.yaml, line 6: not UTF-8"):
        load_catalog_folder(folder)
    manifest.write_text("vehicles:\n  - {file: camry_cm.obj, class: car, scale: 0.01}\n")
    with pytest.raises(ValueError, match="catalog.yaml: lists one vehicle; an identity manifold needs at least 2"):
        load_catalog_folder(folder)
    # YAML 1.1 reads 1e-2 (no dot) as a string: still the number (a model in centimetres).
    manifest.write_text(good.replace("length: 4.88, name: camry", "scale: 1e-2, name: camry"))
    assert load_catalog_folder(folder)[2].mesh.bounds == pytest.approx(load_catalog_vehicle("toyota_camry").mesh.bounds,
                                                                      abs=1e-6)
    manifest.unlink()
    with pytest.raises(FileNotFoundError, match="catalog.yaml"):
        _run(tmp_path, f"catalog={folder}", *REDUCED)
    # Named first, before the outputs: here a checkpoint of ours is in the way.
    shutil.copy(REPO / "checkpoints" / "default.pt", tmp_path / "model.pt")
    with pytest.raises(FileNotFoundError, match="catalog.yaml"):
        _run(tmp_path, f"catalog={folder}", *REDUCED)


def test_a_vehicle_of_the_wrong_size_is_named_before_training(tmp_path):
    folder = tmp_path / "mine"
    _own_catalog(folder)
    manifest = folder / "catalog.yaml"
    good = manifest.read_text()
    for scale, message in [("1.0e-5", r"vehicles\[3\] \(camry_cm.obj\): .*camry_cm.obj: 0.00488 × 0.00208 × "
                                      r"0.00145 m at scale 1e-05 is too small for a vehicle \(at least 0.5 m"),  # at loading
                           ("0.00105", r"'camry' \(0.512 × 0.2 × 0.152 m\) covers no template pixel in \d+ of 12"),
                           ("0.03", r"'camry' \(14.6 × 6.24 × 4.34 m\) reaches the edge of the 12 m template window"),
                           ("1.0", r"vehicles\[3\] \(camry_cm.obj\): .*camry_cm.obj: 488 × 208 × 145 m at scale 1 is "
                                   r"too big for a vehicle \(at most 100 m")]:  # centimetres read as metres: at loading
        manifest.write_text(good.replace("length: 4.88, name: camry", f"scale: {scale}, name: camry"))
        with pytest.raises(ValueError, match=message):
            train.main(["--config", str(REPO / "configs/default.yaml"), f"catalog={folder}",
                        f"log_dir={tmp_path / 'logs/a'}", f"checkpoint={tmp_path / 'ckpt/new/model.pt'}", *TINY])
        # Nothing written for a run that never trained, nor any of the folders it made (it left logs/a, ckpt/new).
        assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]


def test_bad_config_key_and_type_are_named(tmp_path):
    with pytest.raises(ConfigError, match="model.ridg"):
        _run(tmp_path, "model.ridg=1")
    with pytest.raises(ConfigError, match="template.size_px"):
        _run(tmp_path, "template.size_px=big")
    with pytest.raises(ConfigError, match="model.ridg"):  # a flag between the overrides
        train.main([f"log_dir={tmp_path}", "--overwrite", "model.ridg=1"])
    with pytest.raises(ConfigError, match="'model.ridge=0.1' and 'model.ridge=0.2' both set model.ridge"):
        _run(tmp_path, "model.ridge=0.1", "model.ridge=0.2")


@pytest.mark.slow
def test_default_training_meets_the_quality_bars(tmp_path):
    _, report = _run(tmp_path)
    assert report["train_iou"]["all"] >= 0.95 and min(report["train_iou"].values()) >= 0.9
    assert report["held_out_iou"]["all"] >= 0.93  # half-step views
    assert report["identity_self_match"]["all"]
    assert report["test_split_correct"] >= 7  # of the 8 SENSIAC-like vehicles on their class


def test_non_finite_measures_are_named():
    from torch_atr.training import non_finite_keys

    report = {"views": 150, "train_iou": {"tank": 0.9, "car": math.nan}, "test_split": [{"mse": 0.1},
                                                                                        {"mse": math.inf}],
              "note": "nan", "ok": True}
    assert non_finite_keys(report) == ["train_iou.car", "test_split[1].mse"]
    assert non_finite_keys({"a": [1.0, 2]}) == []


def test_the_kernel_widths_histogram_is_tagged_with_their_unit(tmp_path):
    """Every TensorBoard tag names its unit (the tracker's: error/aspect_rad); the widths' was
    rbf/kernel_widths. They are chord lengths on the unit view sphere (rbf.mean_nearest_chord): no unit
    but that, so the tag says chord. The reference: the histogram's count is the checkpoint's centres."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    ckpt, _ = _run(tmp_path, *(o for o in TINY if not o.startswith("tensorboard=")))  # the config's: on
    events = EventAccumulator(str(tmp_path / "runs/test"), size_guidance={"histograms": 0}).Reload()
    assert [tag for tag in events.Tags()["histograms"] if tag.startswith("rbf/")] == ["rbf/kernel_widths_chord"]
    widths = events.Histograms("rbf/kernel_widths_chord")[0].histogram_value
    assert widths.num == GenerativeShapeModel.from_checkpoint(ckpt).rbf.num_centres
