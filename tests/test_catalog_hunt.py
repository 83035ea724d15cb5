"""Catalog builder hunt: geometry primitives against closed forms, degenerate inputs, spec validation
and the build's atomicity (torch_atr/vehicles/{geometry,build,specs,catalog}.py)."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest
import trimesh

from torch_atr.vehicles.geometry import fillet, prism_xz, sweep


# ------------------------------------------------------------------------------------------
# Geometry: closed forms and degenerate solids
# ------------------------------------------------------------------------------------------
def test_swept_rectangle_and_polygon_match_the_prism_formulas():
    """A constant cross-section swept along a straight line is a prism: volume = section area x length,
    surface = perimeter x length + 2 x section area (closed forms, regular n-gon of circumradius r)."""
    rect = np.array([(-1.0, -0.5), (1.0, -0.5), (1.0, 0.5), (-1.0, 0.5)])  # 2 x 1
    m = trimesh.Trimesh(*sweep([np.c_[np.full(4, s), rect] for s in (0.0, 1.0, 2.5)]), process=False)
    assert m.is_watertight and m.is_winding_consistent
    assert m.volume == pytest.approx(2.0 * 2.5, rel=1e-12)
    assert m.area == pytest.approx(6.0 * 2.5 + 2 * 2.0, rel=1e-12)
    n, r, length = 24, 0.7, 3.0
    a = 2 * np.pi * np.arange(n) / n
    ring = np.c_[r * np.cos(a), r * np.sin(a)]
    m = trimesh.Trimesh(*sweep([np.c_[ring, np.full(n, z)] for z in np.linspace(0.0, length, 5)]), process=False)
    section = n / 2 * r * r * math.sin(2 * math.pi / n)
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0
    assert m.volume == pytest.approx(section * length, rel=1e-12)
    assert m.area == pytest.approx(2 * n * r * math.sin(math.pi / n) * length + 2 * section, rel=1e-12)
    v, f = prism_xz([(0.0, 0.0), (0.0, 1.0), (2.0, 1.0), (2.0, 0.0)], 0.5, y0=3.0)  # clockwise profile
    m = trimesh.Trimesh(v, f, process=False)
    assert m.volume == pytest.approx(2.0, rel=1e-12) and m.is_winding_consistent
    np.testing.assert_allclose(m.bounds, [[0.0, 2.5, 0.0], [2.0, 3.5, 1.0]])


def test_solids_without_volume_are_refused():
    """A zero-length sweep or a zero / negative / miscounted prism width built a flat 'solid' (volume 0,
    every face doubled) or a mirrored one without a word; each is now a ValueError saying why."""
    rect = np.array([(-1.0, -0.5), (1.0, -0.5), (1.0, 0.5), (-1.0, 0.5)])
    with pytest.raises(ValueError, match="sweep: the solid encloses no volume"):
        sweep([np.c_[np.zeros(4), rect]] * 3)
    square = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
    for width in (0.0, -0.5, [0.5, 0.5, 0.0, 0.5], float("nan")):
        with pytest.raises(ValueError, match="positive half_width"):
            prism_xz(square, width)
    with pytest.raises(ValueError, match=r"one half_width or 4 \(one per profile point\); got shape \(2,\)"):
        prism_xz(square, [0.5, 0.6])


def test_fillet_arc_points_lie_on_the_tangent_circle():
    """A 90-degree corner at (2, 0) between (0, 0) and (2, 2), radius 0.5: the fillet centre is (1.5, 0.5)
    (hand-worked), every arc point is 0.5 from it and the arc runs between the tangent points (1.5, 0) and
    (2, 0.5); a 60-degree corner's centre lies r / sin(30 deg) = 2 r along the bisector."""
    out = np.array(fillet([(0.0, 0.0), (2.0, 0.0), (2.0, 2.0)], 0.5, arc=7))
    np.testing.assert_allclose(np.linalg.norm(out[1:-1] - [1.5, 0.5], axis=1), 0.5, atol=1e-12)
    np.testing.assert_allclose(out[[1, -2]], [[1.5, 0.0], [2.0, 0.5]], atol=1e-12)
    corner = np.array([3.0, 0.0])
    far = corner + 3.0 * np.array([math.cos(math.radians(120)), math.sin(math.radians(120))])
    out = np.array(fillet([(0.0, 0.0), tuple(corner), tuple(far)], 0.4, arc=4))
    centre = corner + 2 * 0.4 * np.array([math.cos(math.radians(150)), math.sin(math.radians(150))])
    np.testing.assert_allclose(np.linalg.norm(out[1:-1] - centre, axis=1), 0.4, atol=1e-12)


@pytest.mark.parametrize("points, radius, arc, message", [
    ([(0.0, 0.0), (0.0, 0.0), (1.0, 1.0)], 0.3, 3, r"points 0 and 1 coincide at \(0.0, 0.0\)"),
    ([(0.0, 0.0), (1.0, 0.0), (0.0, 0.0)], 0.3, 3, r"corner 1 at \(1.0, 0.0\) turns straight back"),
    ([(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (2.0, 1.0)], [0.1, 0.2, 0.3], 3, r"one radius or 2 \(one per interior"),
    ([(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)], -0.2, 3, "radii >= 0; got -0.2"),
    ([(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)], 0.2, 1, "arc >= 2 points per arc; got 1"),
    ([(0.0, 0.0)], 0.2, 3, r"shape \(m>=2, 2\)"),
    ([], 0.2, 3, r"shape \(m>=2, 2\)"),
])
def test_fillet_refuses_degenerate_input(points, radius, arc, message):
    """A repeated point or a corner turning straight back returned NaN points (0 / 0) that went on into the
    OBJ as 'nan'; a wrong radius count raised numpy's broadcast error; a negative radius was read as 0,
    arc = 1 kept only the first tangent point (a cut corner, not an arc), one point came back twice and
    none raised an IndexError. Each is now a ValueError saying what is wrong."""
    with pytest.raises(ValueError, match=message):
        fillet(points, radius, arc=arc)


# ------------------------------------------------------------------------------------------
# The build
# ------------------------------------------------------------------------------------------
def _tree(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_a_failing_build_leaves_the_old_catalog(tmp_path, monkeypatch):
    """build_catalog emptied each split folder first and then generated vehicle by vehicle, so a spec that
    failed to build (or a write that failed) half way left a catalog with vehicles missing. Now
    everything is generated first and each split folder is replaced only once it is complete."""
    from torch_atr.vehicles import build
    from torch_atr.vehicles.specs import SPLITS

    first = build.build_catalog(tmp_path)
    before = _tree(tmp_path)
    assert len(first) == len(before) and set(before) == {str(p.relative_to(tmp_path)) for p in first}
    late = SPLITS["train"][20].name  # generated after earlier vehicles of the split were written
    real = build.vehicle_files

    def failing(spec):
        if spec.name == late:
            raise ValueError(f"{late}: broken")
        return real(spec)

    monkeypatch.setattr(build, "vehicle_files", failing)
    with pytest.raises(ValueError, match="broken"):
        build.build_catalog(tmp_path)
    assert _tree(tmp_path) == before
    monkeypatch.setattr(build, "vehicle_files", real)
    real_write = build.atomic_write_text
    count = {"n": 0}

    def failing_write(text, path):
        count["n"] += 1
        if count["n"] == 50:  # a full disk in the middle of the train split
            raise OSError(28, "No space left on device")
        real_write(text, path)

    monkeypatch.setattr(build, "atomic_write_text", failing_write)
    with pytest.raises(OSError, match="No space"):
        build.build_catalog(tmp_path)
    assert _tree(tmp_path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["test", "train"]  # no staging folder left
    monkeypatch.setattr(build, "atomic_write_text", real_write)
    (tmp_path / "train" / "gone_vehicle").mkdir()
    (tmp_path / "train" / "gone_vehicle" / "gone_vehicle.urdf").write_text("<robot/>")
    build.build_catalog(tmp_path)  # a vehicle no longer in the specs disappears
    assert _tree(tmp_path) == before


# ------------------------------------------------------------------------------------------
# Spec validation
# ------------------------------------------------------------------------------------------
def _spec(name):
    from torch_atr.vehicles.specs import TEST, TRAIN

    return next(s for s in TRAIN + TEST if s.name == name)


@pytest.mark.parametrize("name, field, value, kind", [
    ("toyota_camry", "length", 0.0, "positive"),
    ("toyota_camry", "width", -1.0, "positive"),
    ("toyota_camry", "height", float("nan"), "positive"),
    ("toyota_camry", "wheel_d", 0.0, "positive"),
    ("toyota_camry", "wheelbase", -1.0, "positive"),
    ("toyota_camry", "clearance", -0.1, "positive"),
    ("toyota_camry", "tyre_w", 0.0, "positive"),
    ("toyota_camry", "mirror", -0.1, "non-negative"),
    ("toyota_camry", "rails", -0.1, "non-negative"),
    ("t_72", "wheel_d", 0.0, "positive"),
    ("t_72", "track_w", 0.0, "positive"),
    ("t_72", "belly", -0.1, "positive"),
    ("t_72", "contact", "4.28", "positive"),
    ("btr_80", "tyre_w", 0.0, "positive"),
    ("btr_80", "side_slope", -0.1, "non-negative"),
])
def test_a_bad_dimension_names_the_vehicle_and_the_field(name, field, value, kind):
    """Only length, width and height were checked (one message for the three); a zero wheel, a negative
    clearance or mirror, a text number were accepted and built into a broken or flat mesh."""
    with pytest.raises(ValueError, match=rf"^{name}: {field} must be a {kind} number \(metres\); got {value!r}$"):
        dataclasses.replace(_spec(name), **{field: value})


@pytest.mark.parametrize("path, value", [("width", 0.0), ("height", -1.0), ("slope", -0.1), ("gun.diameter", 0.0),
                                         ("gun.length", -1.0)])
def test_a_bad_turret_dimension_names_the_vehicle_and_the_field(path, value):
    bmp = _spec("bmp_2")
    turret = bmp.turret
    if path.startswith("gun."):
        turret = dataclasses.replace(turret, gun=dataclasses.replace(turret.gun, **{path[4:]: value}))
    else:
        turret = dataclasses.replace(turret, **{path: value})
    message = rf"^bmp_2: turret\.{re.escape(path)} must be a (non-negative|positive) number"
    with pytest.raises(ValueError, match=message):
        dataclasses.replace(bmp, turret=turret)


def test_an_unknown_option_or_a_bad_name_names_the_vehicle():
    """An unknown keyword raised the dataclass's TypeError ("Road.__init__() got an unexpected keyword
    argument"), which names neither the vehicle nor the options; a name with spaces or capitals gave a
    catalog folder that load_catalog_vehicle's normalised key can never find."""
    from torch_atr.vehicles.specs import Road

    camry = _spec("toyota_camry")
    kw = {f.name: getattr(camry, f.name) for f in dataclasses.fields(Road)}
    with pytest.raises(ValueError, match=r"^toyota_camry: unknown Road option\(s\) \['colour'\]; the options are "
                                         r"\['name', 'title'"):
        Road(**kw, colour="red")
    for bad in ("my camry", "Camry", "camry-2", ""):
        with pytest.raises(ValueError, match="a vehicle name must be lower-case letters, digits and underscores"):
            dataclasses.replace(camry, name=bad)
