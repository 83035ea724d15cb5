"""Robustness of torch_atr.vehicles.loader and catalog folders against mis-sized, broken or mis-specified inputs.

References are independent of the code under test: the trimesh primitives built here, in metres.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from torch_atr.vehicles import load_catalog_folder

HULL = (7.0, 3.5, 2.2)  # metres
GUN = (5.0, 0.15, 0.15)  # metres; 0.015 file units thick once the tank is normalised to 1 unit
GUN_X = 4.0  # the gun's centre: it reaches GUN_X + GUN[0] / 2 = 6.5 m, 3 m past the hull's front


def _tank_unit(path: Path) -> float:
    """Write a hull with a gun, normalised to 1 file unit per 10 m; returns its true length, metres."""
    hull = trimesh.creation.box(extents=HULL)
    gun = trimesh.creation.box(extents=GUN)
    gun.apply_translation([GUN_X, 0.0, HULL[2] / 2])
    tank = trimesh.util.concatenate([hull, gun])
    tank.apply_scale(0.1)
    tank.export(path)
    return GUN_X + GUN[0] / 2 + HULL[0] / 2


def test_length_is_measured_before_trimming(tmp_path):
    true_length = _tank_unit(tmp_path / "tank_unit.obj")
    assert true_length == pytest.approx(10.0)
    trimesh.creation.box(extents=[4.5, 1.8, 1.5]).export(tmp_path / "car.obj")
    (tmp_path / "catalog.yaml").write_text("vehicles:\n  - {file: tank_unit.obj, class: tank, length: 10.0}\n"
                                           "  - {file: car.obj, class: car, scale: 1.0}\n")
    tank = {v.name: v for v in load_catalog_folder(tmp_path)}["tank_unit"]
    # scale 10 / 1.0 unit: the primitives come back at their size in metres, gun kept (0.15 m > 5 cm)
    np.testing.assert_allclose(tank.mesh.extents, [true_length, HULL[1], HULL[2] + GUN[2] / 2], atol=1e-9)
