"""Mesh files whose text is not UTF-8: read as Latin-1 (OBJ, OFF) or refused naming the file,
never with trimesh's "No module named 'charset_normalizer'"."""

import logging
import sys

import numpy as np
import pytest
import trimesh

from torch_atr.vehicles import load_catalog_folder, load_vehicle
from torch_atr.vehicles.catalog import default_meshes_root

PICKUP = default_meshes_root() / "pickup" / "gazebo_pickup.obj"
AXES = dict(up_axis="y", forward_axis="-z", cls="pickup")
COMMENT = "# Modell für Größe\n"  # ü, ö and ß: one byte each in Latin-1, not UTF-8

needs_pickup = pytest.mark.skipif(not PICKUP.is_file(), reason=f"no held-out mesh at {PICKUP}")


@needs_pickup
@pytest.mark.parametrize("encoding, warned", [
    ("latin-1", "is not UTF-8 (byte 0xfc at byte offset 10); reading it as Latin-1, in which its comments and names "
                "may come out garbled"),  # 0xfc: the ü of "# Modell f" (10 bytes)
    ("utf-8", None)])
def test_a_commented_copy_loads_the_same_mesh_as_the_original(tmp_path, caplog, encoding, warned):
    copy = tmp_path / f"pickup_{encoding}.obj"
    copy.write_bytes(COMMENT.encode(encoding) + PICKUP.read_bytes())
    with caplog.at_level(logging.WARNING, logger="torch_atr.vehicles.loader"):
        vehicle = load_vehicle(copy, **AXES)
    reference = load_vehicle(PICKUP, **AXES)  # the original file, UTF-8 (ASCII)
    np.testing.assert_array_equal(vehicle.mesh.vertices, reference.mesh.vertices)
    np.testing.assert_array_equal(vehicle.mesh.faces, reference.mesh.faces)
    assert [r.getMessage() for r in caplog.records] == ([f"{copy} {warned}"] if warned else [])


def test_random_bytes_are_refused_naming_the_file(tmp_path):
    path = tmp_path / "noise.obj"
    path.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    with pytest.raises(ValueError, match=r"noise\.obj holds no triangles \(not UTF-8 text: read as Latin-1\)") as info:
        load_vehicle(path)
    assert "charset" not in str(info.value)


def test_a_non_utf8_text_format_not_read_here_is_refused_naming_the_file(tmp_path, monkeypatch):
    """An ASCII STL named in Latin-1: trimesh decodes STL itself, guessing the encoding only with
    the optional charset_normalizer (chardet in trimesh 4.0; absent here; installed with requests, say), so
    without it the file is refused, with a message that says what to do rather than which package trimesh lacked."""
    for guesser in ("charset_normalizer", "chardet"):
        monkeypatch.setitem(sys.modules, guesser, None)  # as on a machine without it
    path = tmp_path / "box.stl"
    text = trimesh.exchange.stl.export_stl_ascii(trimesh.creation.box())
    path.write_bytes(text.replace("solid", "solid Kühler", 1).encode("latin-1"))
    with pytest.raises(ValueError, match=r"could not read mesh .*box\.stl: its text is not UTF-8; save it as UTF-8$"):
        load_vehicle(path)


LATIN1_URDF = ('<?xml version="1.0" encoding="ISO-8859-1"?>\n<robot name="Kübelwagen"><!-- Größe in Metern -->'
               '<link name="Karosserie"><visual><geometry><box size="3.7 1.6 1.1"/></geometry></visual></link></robot>')


def test_a_urdf_declared_latin1_loads_as_its_declaration_says(tmp_path):
    """XML names its encoding in its declaration; the URDF loads like the same robot in UTF-8."""
    path = tmp_path / "kuebel.urdf"
    path.write_bytes(LATIN1_URDF.encode("latin-1"))
    np.testing.assert_allclose(load_vehicle(path).mesh.extents, [3.7, 1.6, 1.1], atol=1e-9)


@pytest.mark.parametrize("text, message", [
    (LATIN1_URDF.replace(' encoding="ISO-8859-1"', ""), r"invalid URDF XML: not well-formed \(invalid token\)"),
    (LATIN1_URDF.replace("ISO-8859-1", "klingon"), "invalid URDF XML: unknown encoding: klingon")])
def test_a_urdf_in_another_encoding_than_declared_names_the_catalog_entry(tmp_path, text, message):
    """Latin-1 bytes without a declaration (XML's default is UTF-8), or an encoding Python does not
    know: a one-line error naming the manifest entry and the file, as for any other broken URDF."""
    (tmp_path / "kuebel.urdf").write_bytes(text.encode("latin-1"))
    trimesh.creation.box(extents=(4.5, 1.8, 1.5)).export(tmp_path / "car.obj")
    (tmp_path / "catalog.yaml").write_text("vehicles:\n  - {file: kuebel.urdf, class: car, scale: 1}\n"
                                           "  - {file: car.obj, class: car, scale: 1}\n")
    with pytest.raises(ValueError, match=rf"catalog.yaml: vehicles\[0\] \(kuebel.urdf\): .*kuebel.urdf: {message}"):
        load_catalog_folder(tmp_path)
