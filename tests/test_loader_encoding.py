"""Mesh files whose text is not UTF-8: read as Latin-1 (OBJ, OFF) or refused naming the file,
never with trimesh's "No module named 'charset_normalizer'"."""

import logging
import sys

import numpy as np
import pytest
import trimesh

from torch_atr.vehicles import load_vehicle
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
    the optional charset_normalizer (absent here; installed with requests, say), so without it the
    file is refused, with a message that says what to do rather than which package trimesh lacked."""
    monkeypatch.setitem(sys.modules, "charset_normalizer", None)  # as on a machine without it
    path = tmp_path / "box.stl"
    text = trimesh.exchange.stl.export_stl_ascii(trimesh.creation.box())
    path.write_bytes(text.replace("solid", "solid Kühler", 1).encode("latin-1"))
    with pytest.raises(ValueError, match=r"could not read mesh .*box\.stl: its text is not UTF-8; save it as UTF-8$"):
        load_vehicle(path)
