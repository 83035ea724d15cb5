"""Catalog builder hunt: geometry primitives against closed forms, degenerate inputs, spec validation
and the build's atomicity (torch_atr/vehicles/{geometry,build,specs,catalog}.py)."""

from __future__ import annotations

import dataclasses
import itertools
import math
import re

import numpy as np
import pytest
import trimesh

from torch_atr.vehicles.geometry import fillet, prism_xz, sweep
from torch_atr.vehicles.specs import TEST, TRAIN


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


def _build_fails_on_a_full_disk_leaving(root, before, monkeypatch, build, fails) -> None:
    """build_catalog(root) with ``fails(path)`` choosing the writes that hit a full disk: it raises, and
    leaves the tree ``before`` and no staging folder. The real writer is put back afterwards."""
    real_write = build.atomic_write_text

    def failing_write(text, path):
        if fails(path):
            raise OSError(28, "No space left on device")
        real_write(text, path)

    monkeypatch.setattr(build, "atomic_write_text", failing_write)
    with pytest.raises(OSError, match="No space"):
        build.build_catalog(root)
    monkeypatch.setattr(build, "atomic_write_text", real_write)
    assert _tree(root) == before
    assert sorted(p.name for p in root.iterdir()) == ["test", "train"]  # no staging folder left


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
    writes = itertools.count(1)
    _build_fails_on_a_full_disk_leaving(tmp_path, before, monkeypatch, build,
                                        lambda path: next(writes) == 50)  # in the middle of the train split
    (tmp_path / "train" / "gone_vehicle").mkdir()
    (tmp_path / "train" / "gone_vehicle" / "gone_vehicle.urdf").write_text("<robot/>")
    build.build_catalog(tmp_path)  # a vehicle no longer in the specs disappears
    assert _tree(tmp_path) == before


def test_a_write_failing_in_a_later_split_leaves_the_earlier_split_as_it_was(tmp_path, monkeypatch):
    """Each split replaced its folder as soon as it was written, so a full disk in the test split left the
    train split already replaced: a catalog of two builds. Every split is now written before any is replaced.
    Reference: the folder tree before the build, with a file the new build would not write."""
    from torch_atr.vehicles import build
    from torch_atr.vehicles.specs import SPLITS

    assert list(SPLITS)[-1] == "test"  # the scenario: test is written after train
    build.build_catalog(tmp_path)
    (tmp_path / "train" / "older_vehicle").mkdir()
    (tmp_path / "train" / "older_vehicle" / "older_vehicle.urdf").write_text("<robot/>")
    before = _tree(tmp_path)
    _build_fails_on_a_full_disk_leaving(tmp_path, before, monkeypatch, build,
                                        lambda path: path.parent.parent.name == ".test.building")


def test_a_failing_swap_in_a_later_split_puts_the_earlier_split_back(tmp_path, monkeypatch):
    """When the test split's folder could not be replaced (a rename refused after the train split's had
    been), only the test split was put back: the catalog was the new train split beside the old test split,
    with '.train.old' left on disk. Reference: the folder tree before the build, with a file the new build
    would not write."""
    from pathlib import Path

    from torch_atr.vehicles import build

    build.build_catalog(tmp_path)
    (tmp_path / "train" / "older_vehicle").mkdir()
    (tmp_path / "train" / "older_vehicle" / "older_vehicle.urdf").write_text("<robot/>")
    before = _tree(tmp_path)
    real_rename = Path.rename

    def rename(self, target):
        if self.name == ".test.building":
            raise PermissionError(13, "Permission denied")
        return real_rename(self, target)

    monkeypatch.setattr(Path, "rename", rename)
    with pytest.raises(PermissionError):
        build.build_catalog(tmp_path)
    monkeypatch.setattr(Path, "rename", real_rename)
    assert _tree(tmp_path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["test", "train"]


# ------------------------------------------------------------------------------------------
# Spec validation
# ------------------------------------------------------------------------------------------
def _spec(name):
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
    """A zero turret width or gun diameter was accepted and built into a broken mesh or failed deep in the
    builder (ZeroDivisionError), naming neither the vehicle nor the field."""
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


def _turret(spec, **kw):
    return dataclasses.replace(spec, turret=dataclasses.replace(spec.turret, **kw))


def _gun(spec, **kw):
    return _turret(spec, gun=dataclasses.replace(spec.turret.gun, **kw))


@pytest.mark.parametrize("name, change, message", [
    ("toyota_camry", {"front": 0.1}, r"the wheels \(wheel_d 0.67, front 0.1, wheelbase 2.825\) stick out of the "
                                     r"length 4.88"),
    ("toyota_camry", {"wheel_d": 1.5}, r"wheel_d 1.5 reaches above the belt line"),
    ("toyota_camry", {"clearance": 0.9}, r"clearance 0.9 must be below the axles \(wheel_d / 2 = 0.335\)"),
    ("toyota_camry", {"rails": 2.0}, r"rails 2.0 are taller than the glasshouse"),
    ("toyota_hilux", {"bed": 6.0}, r"bed 6.0 leaves no cab behind the front wheels"),
    ("t_72", {"deck": 3.0}, r"heights must satisfy belly < nose < deck <= height; got belly 0.45, nose 0.95, deck 3.0"),
    ("t_72", {"road_wheels": 1}, r"road_wheels must be an integer >= 2; got 1"),
    ("t_72", {"contact": 8.0}, r"contact 8.0 must be shorter than the length 6.95"),
    ("t_72", {"wheel_d": 2.0}, r"wheel_d 2.0 puts the track's top run \(wheel_d \+ 0.18 m\) above the deck 1.4"),
    ("t_72", {"track_w": 2.0}, r"two tracks of track_w 2.0 leave no hull between them in width 3.59"),
    ("t_72", {"glacis": 8.0}, r"glacis 8.0, lower_glacis 0.55 and rear_slope 0.15 do not fit in the length 6.95"),
    ("t_72", {"gun_length": float("nan")}, r"gun_length nan must exceed the hull length"),
    ("btr_80", {"axles": (-1.0, 9.0)}, r"axles \(-1.0, 9.0\) must be one or more positions"),
    ("btr_80", {"axles": ()}, r"axles \(\) must be one or more positions"),
    ("btr_80", {"wheel_d": 3.0}, r"wheel_d 3.0 must be above the belly 0.475 and reach no higher than 0.1 m below "
                                 r"the deck 2.0"),
    ("brdm_2", {"wheel_d": 0.321}, r"wheel_d 0.321 must be above the belly 0.43"),
    ("btr_80", {"side_slope": 2.0}, r"side_slope 2.0 or the wheels .* leave no hull in width 2.95"),
])
def test_a_spec_that_does_not_fit_together_names_the_vehicle_and_the_fields(name, change, message):
    """Each of these was accepted and built a wrong vehicle (wheels outside the body, a contact patch longer
    than the hull, a deck above the height) or failed inside the builder without naming the vehicle
    (ZeroDivisionError for one road wheel, IndexError for a wheel above the deck or a bed longer than
    the pickup, the triangulator's 'degenerate triangle' for a glacis longer than the hull)."""
    with pytest.raises(ValueError, match=rf"^{name}: {message}"):
        dataclasses.replace(_spec(name), **change)


def _extra(spec, on):
    from torch_atr.vehicles.specs import Extra

    size = (0.0, 1.0, 1.0) if on == "hull" else (1.0, 1.0, 1.0)
    return dataclasses.replace(spec, extras=(Extra(on, "box", size, (1.0, 0.0, 1.0)),))


@pytest.mark.parametrize("name, make, message", [
    ("t_72", lambda s: _turret(s, slope=2.0), r"turret.slope 2.0 must be below turret.front 1.3"),
    ("t_72", lambda s: _turret(s, taper=1.5), r"turret.taper 1.5 must be below turret.rear 1.2"),
    ("t_72", lambda s: _turret(s, ring=9.0), r"the turret \(ring 9.0, .*\) is not on the hull"),
    ("t_72", lambda s: _turret(s, width=5.0), r"the turret \(.*width 5.0.*\) is not on the hull"),
    ("t_72", lambda s: _turret(s, height=1.5), r"the turret \(.*height 1.5 above the deck 1.4\) is not on the hull"),
    ("t_72", lambda s: _gun(s, elevation=(14.0, -6.0)), r"turret.gun.elevation \(14.0, -6.0\) must be"),
    ("t_72", lambda s: _gun(s, elevation=(5.0, 14.0)), r"turret.gun.elevation \(5.0, 14.0\) must be"),
    ("t_72", lambda s: _gun(s, barrels=()), r"turret.gun needs barrels"),
    ("t_72", lambda s: _extra(s, "hull"), r"extras\[0\].size must be positive numbers; got \(0.0, 1.0, 1.0\)"),
    ("toyota_camry", lambda s: _extra(s, "turret"), r"extras\[0\] is on the turret, which the vehicle does not have"),
    ("t_72", lambda s: dataclasses.replace(s, extras=(dataclasses.replace(s.extras[0], xyz=(float("nan"), 0.0, 1.0)),)),
     r"extras\[0\].xyz must be finite numbers; got \(nan, 0.0, 1.0\)"),
    ("t_72", lambda s: _gun(s, barrels=((float("inf"), 0.0),)), r"turret.gun.barrels must be finite numbers"),
    ("t_72", lambda s: _gun(s, trunnion=(0.5, float("nan"))), r"turret.gun.trunnion must be finite numbers"),
    ("t_72", lambda s: _gun(s, mantlet=("0.5", 0.8, 0.4)), r"turret.gun.mantlet must be finite numbers"),
    ("t_72", lambda s: _gun(s, elevation=(-6.0, "14")), r"turret.gun.elevation must be finite numbers"),
])
def test_a_turret_gun_or_extra_that_does_not_fit_names_the_vehicle(name, make, message):
    """A turret off the hull or wider than it, a turret slope past its front, a gun whose rest pose is outside its
    elevation limits were accepted and built wrong; an extra on a turret the vehicle lacks failed in the builder
    with a bare error, naming neither the vehicle nor the extra. A NaN or infinite extra centre or barrel
    position was built into the URDF as 'nan' without a word; a text mantlet or elevation raised a bare
    TypeError."""
    with pytest.raises(ValueError, match=rf"^{name}: {message}"):
        make(_spec(name))


@pytest.mark.parametrize("change, message", [
    ({"roof": (0.7, 0.4)}, r"0 < windshield < roof\[0\] < roof\[1\] <= tail <= 1; got windshield 0.34, "
                           r"roof \(0.7, 0.4\)"),
    ({"windshield": 0.6}, r"0 < windshield < roof\[0\]"),
    ({"tail": 0.5}, r"roof\[1\] <= tail"),
    ({"nose": 0.9}, r"0 < nose <= belt < 1 and 0 < deck < 1; got nose 0.9"),
    ({"roof_w": 0.0}, r"Shape.roof_w must be in \(0, 1\]; got 0.0"),
    ({"deck": float("nan")}, r"Shape: expected numbers"),
])
def test_a_shape_out_of_order_is_refused(change, message):
    """A roof that ends before it starts, a windshield behind the roof or a bonnet above the belt line built
    a self-crossing side profile without a word."""
    from torch_atr.vehicles.specs import SEDAN

    with pytest.raises(ValueError, match=message):
        dataclasses.replace(SEDAN, **change)


def test_a_spec_the_builder_cannot_build_is_named():
    """What validation lets through but the builder cannot build (a LAV-25 whose belly is so high that the
    rear plate folds back on itself) failed with the triangulator's 'polygon is not simple', naming
    neither the vehicle nor its spec."""
    from torch_atr.vehicles.build import vehicle_files

    lav = dataclasses.replace(_spec("lav_25"), belly=0.75)
    with pytest.raises(ValueError, match=r"^lav_25: cannot build the Wheeled from its spec: polygon is not simple"):
        vehicle_files(lav)


# ------------------------------------------------------------------------------------------
# The held-out manifest
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("field, value, message", [
    ("scale", "0", r"scale must be a positive number \(file units -> metres\); got 0"),
    ("scale", "-1.0", r"scale must be a positive number .*; got -1.0"),
    ("scale", ".nan", r"scale must be a positive number .*; got nan"),
    ("scale", ".inf", r"scale must be a positive number .*; got inf"),
    ("scale", "true", r"scale must be a positive number .*; got True"),
    ("cls", "truck", r"cls 'truck' is not one of \('tank', .*'unknown'\)"),
    ("up", "q", r"the up axis must be one of .*; got 'q'"),
    ("forward", "z", r"the up axis 'z' and the forward axis 'z' must be perpendicular"),
    ("path", "null", r"path must be non-empty text; got None"),
    ("note", "12", r"note must be text; got 12"),
])
def test_a_bad_heldout_manifest_entry_names_the_entry_and_the_key(tmp_path, field, value, message):
    """read_manifest took a scale of 0, -1, NaN, infinity or true (read as 1.0), a class such as 'truck',
    axes such as 'q' or up = forward, a null path (as the text 'None'); the bad value surfaced only when
    the mesh was loaded, naming the mesh file rather than the manifest entry, or never (a scale of true).
    Now the manifest, the entry and the key are named when the manifest is read."""
    from torch_atr.vehicles.catalog import read_manifest

    good = {"path": "car/a.obj", "cls": "car", "up": "z", "forward": "x", "scale": "1.0", "note": "why"}

    def manifest(entry):
        (tmp_path / "m.yaml").write_text("meshes:\n  - {" + ", ".join(f"{k}: {v}" for k, v in entry.items()) + "}\n")
        return tmp_path / "m.yaml"

    with pytest.raises(ValueError, match=rf"m.yaml: meshes\[0\] \((car/a.obj|None)\): ({message})"):
        read_manifest(manifest({**good, field: value}))
    assert read_manifest(manifest(good))[0].cls == "car"


# ------------------------------------------------------------------------------------------
# References for what was found right
# ------------------------------------------------------------------------------------------
def test_section_cap_is_the_superellipse_between_its_limits():
    """_section's cap half-width at height fraction v is w (1 - v^e)^(1/e) for a constant tumblehome:
    e = 2 is the quarter ellipse sqrt(1 - v^2) (closed form), a large e tends to the box (w at every v)."""
    from torch_atr.vehicles.build import _CAP_V, _section

    v = np.array(_CAP_V)
    for e, expected in ((2.0, np.sqrt(1 - v ** 2)), (400.0, np.ones_like(v))):
        sec = np.array(_section(0.0, 1.0, 2.0, 1.0, 1.0, e, 0.05))  # belt at z = 1, top at z = 2, half-width 1
        cap = sec[2:2 + len(v)]
        np.testing.assert_allclose(cap[:, 1], 1.0 + v, atol=1e-12)
        np.testing.assert_allclose(cap[:, 0], expected, atol=1e-6)
    sec = np.array(_section(0.0, 1.0, 2.0, 1.0, 1.0, 2.0, 0.05))
    assert len(sec) == 13 and tuple(sec[6]) == (0.0, 2.0)
    np.testing.assert_allclose(sec[::-1] * [-1, 1], sec, atol=1e-12)  # mirror-symmetric about y = 0


def test_catalog_hulls_are_mirror_symmetric_and_wheels_share_the_ground():
    """Every hull.obj is symmetric under y -> -y (vertex sets equal to 0.1 mm); its lowest point is the
    tracks' ground line, a wheeled hull's belly or a road body's sill (1.6 x clearance, docs/recognition.md);
    every wheel (a y-axis cylinder of wheel_d on the hull link) touches z = 0, or for a tracked vehicle
    stands 7 cm up inside its track."""
    import xml.etree.ElementTree as ET

    from scipy.spatial import cKDTree

    from torch_atr.vehicles.catalog import CATALOG_DIR
    from torch_atr.vehicles.specs import SPLITS, Tracked, Wheeled

    for split, specs in SPLITS.items():
        for spec in specs:
            folder = CATALOG_DIR / split / spec.name
            hull = trimesh.load(folder / "hull.obj", force="mesh", process=False)
            d, _ = cKDTree(hull.vertices).query(hull.vertices * [1, -1, 1])
            assert d.max() < 1e-4, spec.name
            lowest = (0.0 if isinstance(spec, Tracked) else spec.belly if isinstance(spec, Wheeled)
                      else 1.6 * spec.clearance)
            assert hull.bounds[0, 2] == pytest.approx(lowest, abs=1e-4), spec.name
            link = next(k for k in ET.parse(folder / f"{spec.name}.urdf").getroot().iter("link")
                        if k.get("name") == "hull")
            bottoms = []
            for vis in link.iter("visual"):
                cyl, origin = vis.find("geometry/cylinder"), vis.find("origin")
                if cyl is not None and origin.get("rpy").startswith("1.5708") \
                        and float(cyl.get("radius")) == pytest.approx(spec.wheel_d / 2):
                    bottoms.append(float(origin.get("xyz").split()[2]) - float(cyl.get("radius")))
            assert bottoms and np.allclose(bottoms, 0.07 if isinstance(spec, Tracked) else 0.0, atol=1e-4), spec.name


KNOWN_OFF = {"cv90": "the 40 mm gun (ring 3.2 - trunnion 0.9 - barrel 2.4) reaches 0.10 m past the hull front although "
                     "gun_length None means 'gun within the hull': 6.57 m for the published 6.47 m; fixing it changes "
                     "the catalog the shipped checkpoint was trained on"}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.xfail(reason=KNOWN_OFF[n], strict=True))
                                  if n in KNOWN_OFF else n for n in sorted(s.name for s in TRAIN + TEST)])
def test_built_extents_match_the_published_figures_to_half_a_percent(name):
    """The loaded rest pose's length (a tank's with its gun forward), width (a road vehicle's with its door
    mirrors, which published widths leave out) and height match the spec's published figures to 0.5 %
    (test_vehicles allows 5 %). The largest accepted deviation is the Qashqai's roof, 6 mm (0.4 %) under
    1.59 m where the fillet rounds the highest corner of a falling roof."""
    from torch_atr.vehicles import load_catalog_vehicle
    from torch_atr.vehicles.specs import Road

    spec = _spec(name)
    lo, hi = load_catalog_vehicle(name).mesh.bounds
    length = getattr(spec, "gun_length", None) or spec.length
    width = spec.width
    if isinstance(spec, Road):
        width = max(width, (spec.cab[0] if spec.cab else width) + 2 * spec.mirror)
    np.testing.assert_allclose(hi - lo, [length, width, spec.height], rtol=0.005, err_msg=name)
