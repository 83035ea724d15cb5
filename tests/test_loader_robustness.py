"""Robustness of torch_atr.vehicles.loader and catalog folders against mis-sized, broken or mis-specified inputs.

References are independent of the code under test: the trimesh primitives built here, in metres.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import trimesh

from torch_atr.vehicles import load_catalog_folder, load_vehicle, vehicle_from_mesh
from torch_atr.vehicles import loader
from torch_atr.vehicles.loader import MAX_EXTENT_M

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


def test_length_ignores_vertices_no_face_uses(tmp_path):
    """A PLY box 4 m long with one stray vertex 20 m out (trimesh's PLY reader keeps it; its OBJ
    reader would drop it): length 4.5 makes the box 4.5 m long, as the loaded mesh shows."""
    box = trimesh.creation.box(extents=[4.0, 1.8, 1.5])
    stray = trimesh.Trimesh(np.vstack([box.vertices, [[20.0, 0.0, 0.0]]]), box.faces, process=False)
    (tmp_path / "stray.ply").write_bytes(trimesh.exchange.ply.export_ply(stray, encoding="ascii"))
    assert len(trimesh.load(tmp_path / "stray.ply", process=False).vertices) == 9  # the stray vertex is read
    trimesh.creation.box(extents=[4.5, 1.8, 1.5]).export(tmp_path / "van.obj")
    (tmp_path / "catalog.yaml").write_text("vehicles:\n  - {file: stray.ply, class: car, length: 4.5}\n"
                                           "  - {file: van.obj, class: minivan, scale: 1.0}\n")
    car = {v.name: v for v in load_catalog_folder(tmp_path)}["stray"]
    np.testing.assert_allclose(car.mesh.extents, [4.5, 1.8 * 4.5 / 4.0, 1.5 * 4.5 / 4.0], rtol=1e-6)  # PLY: float32


@pytest.fixture
def trimmed(monkeypatch):
    """The largest extent (metres) of every mesh thick_bounds trims: its cost grows with the extent
    (a 1e6 m box exhausted 24 GB), so a mis-scaled mesh must be refused before it gets there."""
    extents, thick_bounds = [], loader.thick_bounds

    def spy(vertices, *args, **kwargs):
        extents.append(float(np.ptp(vertices, axis=0).max()))
        return thick_bounds(vertices, *args, **kwargs)

    monkeypatch.setattr(loader, "thick_bounds", spy)
    return extents


@pytest.mark.parametrize("extent, scale", [(1e6, 1.0), (4.5, 1e12), (MAX_EXTENT_M * 1.01, 1.0)])
def test_mis_scaled_mesh_fails_fast_naming_file_and_size(tmp_path, extent, scale, trimmed):
    path = tmp_path / "huge.obj"
    trimesh.creation.box(extents=[extent, extent / 2, extent / 4]).export(path)
    expected = rf"huge\.obj: {re.escape(f'{extent * scale:.3g}')} × .* m at scale {re.escape(f'{scale:g}')} is too big"
    with pytest.raises(ValueError, match=expected):
        load_vehicle(path, scale=scale)
    assert trimmed == []  # refused before the trimming


def test_largest_plausible_vehicle_loads(tmp_path):
    path = tmp_path / "big.obj"
    trimesh.creation.box(extents=[MAX_EXTENT_M, 5.0, 4.0]).export(path)
    np.testing.assert_allclose(load_vehicle(path).mesh.extents, [MAX_EXTENT_M, 5.0, 4.0], atol=1e-9)


def test_length_on_a_millimetre_file_never_trims_it_unscaled(tmp_path, trimmed):
    for name, size in (("car_mm", [4500.0, 1800.0, 1500.0]), ("suv", [5.0, 1.9, 1.7])):
        trimesh.creation.box(extents=size).export(tmp_path / f"{name}.obj")
    (tmp_path / "catalog.yaml").write_text("vehicles:\n  - {file: car_mm.obj, class: car, length: 4.5}\n"
                                           "  - {file: suv.obj, class: suv, length: 5.0}\n")
    car = {v.name: v for v in load_catalog_folder(tmp_path)}["car_mm"]
    assert sorted(trimmed) == pytest.approx([4.5, 5.0])  # trimmed in metres, never at 4500 file units
    np.testing.assert_allclose(car.mesh.extents, [4.5, 1.8, 1.5], atol=1e-9)


@pytest.mark.parametrize("suffix, bad", [("stl", 4), ("ply", 1), ("obj", 1)])  # STL repeats a vertex per face
def test_non_finite_vertex_is_an_error_not_dropped_faces(tmp_path, suffix, bad):
    box = trimesh.creation.box(extents=[4.5, 1.8, 1.5])
    vertices = box.vertices.copy()
    vertices[0] = np.nan  # a corner of 4 of the box's 12 triangles (trimesh would drop them)
    path = tmp_path / f"nan_box.{suffix}"
    trimesh.Trimesh(vertices, box.faces, process=False).export(path)
    with pytest.raises(ValueError, match=rf"nan_box\.{suffix} has {bad} non-finite \(NaN or infinite\) vertices"):
        load_vehicle(path)


def test_single_nan_triangle_obj_names_the_cause(tmp_path):
    path = tmp_path / "nan.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match=r"nan\.obj has 1 non-finite \(NaN or infinite\) vertices of 3"):
        load_vehicle(path)


@pytest.fixture
def car(tmp_path) -> Path:
    path = tmp_path / "car.obj"
    trimesh.creation.box(extents=[4.5, 1.8, 1.5]).export(path)
    return path


@pytest.mark.parametrize("kwargs, message", [
    (dict(up_axis="z", forward_axis="-z"), "the up axis 'z' and the forward axis '-z' must be perpendicular"),
    (dict(up_axis="Y"), "the up axis must be one of"),
    (dict(scale="0.01"), "scale: expected a finite number > 0; got '0.01'"),
    (dict(scale=True), "scale: expected a finite number > 0; got True"),
    (dict(min_thickness="0.05"), "min_thickness: expected a finite number >= 0; got '0.05'"),
    (dict(name=""), "name must be a non-empty string .*; got ''"),
    (dict(name="  "), "name must be a non-empty string .*; got '  '"),
])
def test_bad_argument_names_file_and_value(car, kwargs, message):
    with pytest.raises(ValueError, match=rf"car\.obj: {message}"):
        load_vehicle(car, **kwargs)


def test_numpy_scale_is_a_number(car):
    np.testing.assert_allclose(load_vehicle(car, scale=np.float32(2.0)).mesh.extents, [9.0, 3.6, 3.0], atol=1e-6)


def test_zero_extent_mesh_names_file_and_size(tmp_path):
    path = tmp_path / "point.obj"
    path.write_text("v 1 2 3\nv 1 2 3\nv 1 2 3\nf 1 2 3\n")
    with pytest.raises(ValueError, match=r"point\.obj: size 0 × 0 × 0 m: flat along x"):
        load_vehicle(path)
    plane = tmp_path / "plane.obj"  # 4 x 2 m, no height: it would cast a line, not a vehicle's silhouette
    plane.write_text("v 0 0 0\nv 4 0 0\nv 4 2 0\nv 0 2 0\nf 1 2 3\nf 1 3 4\n")
    with pytest.raises(ValueError, match=r"plane\.obj: size 4 × 2 × 0 m: flat along z .*a vehicle has a size"):
        load_vehicle(plane)


def test_a_loader_error_of_any_value_error_type_is_named_with_its_entry(tmp_path, monkeypatch):
    """An error whose type takes more than a message (UnicodeDecodeError, as a non-UTF-8 URDF once
    raised) is reported as a ValueError naming the entry, not a TypeError from re-raising its type."""
    from torch_atr.vehicles import catalog

    def undecodable(path, **kwargs):
        raise UnicodeDecodeError("utf-8", b"\xe9", 0, 1, "invalid continuation byte")

    monkeypatch.setattr(catalog, "load_vehicle", undecodable)
    (tmp_path / "catalog.yaml").write_text("vehicles:\n  - {file: a.urdf, class: car, scale: 1}\n"
                                           "  - {file: b.urdf, class: car, scale: 1}\n")
    with pytest.raises(ValueError, match=r"catalog\.yaml: vehicles\[0\] \(a\.urdf\): 'utf-8' codec can't decode byte "
                                         r"0xe9 in position 0: invalid continuation byte$"):
        load_catalog_folder(tmp_path)


def test_relative_obj_indices_count_back_from_their_face_line(tmp_path):
    """OBJ ``f -8 -7 -6``: the 8th, 7th and 6th vertices declared before that line (OBJ spec), in a
    file written one object at a time (its vertices, then its faces); trimesh alone counts back
    from the file's last vertex, giving every object's faces the last object's vertices."""
    blocks = []
    for size, centre in (((4.0, 2.0, 1.5), (0.0, 0.0, 0.75)), ((2.0, 1.8, 0.8), (-0.5, 0.0, 1.9))):  # body, cabin
        part = trimesh.creation.box(extents=size)
        lines = [f"v {x:g} {y:g} {z:g}" for x, y, z in part.vertices + centre]
        lines += ["f " + " ".join(str(i - len(part.vertices)) for i in face) for face in part.faces]
        blocks.append("\n".join(lines))
    path = tmp_path / "van.obj"
    path.write_text("o body\n" + blocks[0] + "\no cabin\n" + blocks[1] + "\n")
    # body x [-2, 2], y [-1, 1], z [0, 1.5]; cabin x [-1.5, 0.5], y [-0.9, 0.9], z [1.5, 2.3]
    np.testing.assert_allclose(load_vehicle(path).mesh.bounds, [[-2.0, -1.0, 0.0], [2.0, 1.0, 2.3]], atol=1e-12)


@pytest.mark.parametrize("index, encoding", [(8, "binary"), (99, "ascii"), (-1, "ascii")])
@pytest.mark.parametrize("size", ["scale: 1", "length: 4.5"])
def test_a_triangle_indexing_a_vertex_the_file_lacks_names_the_entry(tmp_path, index, encoding, size):
    """A PLY box (8 vertices, 0 to 7) with one more triangle using vertex ``index``: trimesh keeps
    it, so it raised IndexError through train.py (or, -1, silently took the last vertex)."""
    box = trimesh.creation.box(extents=[4.5, 1.8, 1.5])
    broken = trimesh.Trimesh(box.vertices, np.vstack([box.faces, [[0, 1, index]]]), process=False, validate=False)
    (tmp_path / "car.ply").write_bytes(trimesh.exchange.ply.export_ply(broken, encoding=encoding))
    box.export(tmp_path / "van.obj")
    (tmp_path / "catalog.yaml").write_text(f"vehicles:\n  - {{file: car.ply, class: car, {size}}}\n"
                                           "  - {file: van.obj, class: minivan, scale: 1}\n")
    with pytest.raises(ValueError, match=r"catalog\.yaml: vehicles\[0\] \(car\.ply\): mesh file .*car\.ply has 1 "
                                         r"triangles of 13 indexing a vertex it lacks \(it has 8 vertices\)$"):
        load_catalog_folder(tmp_path)


def _box_link(name: str, size: str) -> str:
    return f'<link name="{name}"><visual><geometry><box size="{size}"/></geometry></visual></link>'


def _joint(name: str, parent: str, child: str, kind: str = "fixed", limit: str = "") -> str:
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="0 0 1.5"/><axis xyz="0 0 1"/>{limit}</joint>')


@pytest.mark.parametrize("joints", ["", _joint("j", "hull", "turret")])
def test_two_links_of_one_name_are_refused_naming_the_link(tmp_path, joints):
    """A second link 'turret' (9 m box) replaced the first (2 m box) unseen; which one a URDF means is unknowable."""
    path = tmp_path / "tank.urdf"
    path.write_text(f'<robot name="t">{_box_link("hull", "7 3.5 1.5")}{_box_link("turret", "2 2 0.8")}'
                    f'{_box_link("turret", "9 9 9")}{joints}</robot>')
    with pytest.raises(ValueError, match=r"tank\.urdf: two links are named 'turret'; a URDF's link names must be "
                                         r"unique$"):
        load_vehicle(path)


def test_two_joints_of_one_name_are_refused_naming_the_joint(tmp_path):
    """Two revolute joints 'yaw' (limits [0, 1] and [0, 0.1]): the second one's limits held for both."""
    limit = '<limit lower="0" upper="{}"/>'
    path = tmp_path / "arm.urdf"
    path.write_text(f'<robot name="a">{_box_link("a", "4 2 1.5")}{_box_link("b", "1 1 1")}{_box_link("c", "1 1 1")}'
                    f'{_joint("yaw", "a", "b", "revolute", limit.format(1))}'
                    f'{_joint("yaw", "b", "c", "revolute", limit.format(0.1))}</robot>')
    with pytest.raises(ValueError, match=r"arm\.urdf: two joints are named 'yaw'; a URDF's joint names must be "
                                         r"unique$"):
        load_vehicle(path)


@pytest.mark.parametrize("joints, message", [
    (_joint("j1", "hull", "turret") + _joint("j2", "turret", "hull"),
     r"joints \['j1', 'j2'\] form a cycle through links \['turret', 'hull'\]"),
    (_joint("j1", "hull", "turret") + _joint("spin", "gun", "gun"), r"joints \['spin'\] form a cycle through links "
                                                                     r"\['gun'\]"),
    (_joint("j1", "hull", "turret") + _joint("j2", "turret", "gun") + _joint("j3", "gun", "turret"),
     r"link 'turret' is the child of joints 'j1' and 'j3'; a link has at most one parent joint"),
    (_joint("j1", "hull", "turret") + _joint("j2", "hull", "gun") + _joint("j3", "turret", "gun"),  # no cycle
     r"link 'gun' is the child of joints 'j2' and 'j3'; a link has at most one parent joint$"),
])
def test_joints_forming_a_cycle_are_refused_naming_them(tmp_path, joints, message):
    """A cycle made pytorch-kinematics recurse until 'maximum recursion depth exceeded'; a link with two
    parent joints (the last two examples: a cycle hanging off the root, and a gun on the hull and on the
    turret) has two poses, and was posed by one of them, silently."""
    path = tmp_path / "tank.urdf"
    path.write_text(f'<robot name="t">{_box_link("hull", "7 3.5 1.5")}{_box_link("turret", "2 2 0.8")}'
                    f'{_box_link("gun", "3 0.2 0.2")}{joints}</robot>')
    with pytest.raises(ValueError, match=rf"tank\.urdf: {message}"):
        load_vehicle(path)


def _corners_obj(path: Path, lo: float, hi: float) -> None:
    """An OBJ box with every coordinate lo or hi (written exactly as repr prints them)."""
    corners = [(x, y, z) for x in (lo, hi) for y in (lo, hi) for z in (lo, hi)]
    faces = trimesh.creation.box().faces + 1  # the unit box's corners are in the same order
    path.write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in corners)
                    + "".join(f"f {a} {b} {c}\n" for a, b, c in faces))


@pytest.mark.parametrize("lo, hi, extent", [(-1e308, 1e308, "inf"), (0.0, 4e-320, f"{4e-320:g}")])
def test_an_unusable_extent_for_a_length_names_the_extent_not_a_scale(tmp_path, lo, hi, extent):
    """An extent of 2e308 overflows float64 (length / inf made scale 0.0) and one of 4e-320 is denormal (4.5 / it
    made scale inf): the error said 'scale: expected a finite number > 0', a key the entry does not set."""
    _corners_obj(tmp_path / "odd.obj", lo, hi)
    trimesh.creation.box(extents=[4.5, 1.8, 1.5]).export(tmp_path / "van.obj")
    (tmp_path / "catalog.yaml").write_text("vehicles:\n  - {file: odd.obj, class: car, length: 4.5}\n"
                                           "  - {file: van.obj, class: minivan, scale: 1}\n")
    with pytest.raises(ValueError, match=rf"vehicles\[0\] \(odd\.obj\): .*odd\.obj: the extent along the forward axis "
                                         rf"'x' is {re.escape(extent)} file units, unusable for a length in metres"):
        load_catalog_folder(tmp_path)


@pytest.mark.parametrize("half, size", [(5e306, "length: 4.5"), (2.25e12, "scale: 1.0e-12")])
def test_a_file_in_huge_units_loads_at_its_size_in_metres(tmp_path, half, size):
    """A 4.5 m cube 1e307 file units across (given a length) or in picometres (given a scale): trimesh merged its
    vertices in file units on a 1e-8 grid held as int64, which overflowed, every vertex became one, and the
    error said 'size 0 × 0 × 0 m: flat along x'."""
    _corners_obj(tmp_path / "odd.obj", -half, half)
    trimesh.creation.box(extents=[4.5, 1.8, 1.5]).export(tmp_path / "van.obj")
    (tmp_path / "catalog.yaml").write_text(f"vehicles:\n  - {{file: odd.obj, class: car, {size}}}\n"
                                           "  - {file: van.obj, class: minivan, scale: 1}\n")
    cube = {v.name: v for v in load_catalog_folder(tmp_path)}["odd"]
    np.testing.assert_allclose(cube.mesh.extents, [4.5, 4.5, 4.5], rtol=1e-12)
    assert len(cube.mesh.vertices) == 8


def test_a_mesh_built_in_python_loads_as_its_file_does(tmp_path):
    """vehicle_from_mesh(mesh, path, ...) is load_vehicle's mesh-file path without the file: a box in
    centimetres, +Y up and -Z forward, written as an OBJ and loaded both ways, gives the same vehicle,
    of the box's size in metres (a 450 x 180 x 150 cm box: 4.5 m long, 1.8 m wide, 1.5 m high), centred
    on the ground; the mesh passed in is left as it was. A mesh that no file could hold is
    refused, naming the path given."""
    box = trimesh.creation.box(extents=(180.0, 150.0, 450.0))  # file x: width, y: height, z: length
    box.apply_translation((7.0, 75.0, -30.0))
    path = tmp_path / "box.obj"
    box.export(path)
    args = dict(up_axis="y", forward_axis="-z", scale=0.01, cls="car", min_thickness=0.0)
    from_file = load_vehicle(path, **args)
    mesh = loader.read_mesh(path)
    before = mesh.vertices.copy()
    built = vehicle_from_mesh(mesh, path, **args)
    assert np.array_equal(mesh.vertices, before)
    assert (built.name, built.cls, built.source) == ("box", "car", path)
    np.testing.assert_array_equal(built.mesh.vertices, from_file.mesh.vertices)
    np.testing.assert_array_equal(built.mesh.faces, from_file.mesh.faces)
    lo, hi = built.mesh.bounds
    np.testing.assert_allclose(hi - lo, [4.5, 1.8, 1.5], rtol=1e-12)
    np.testing.assert_allclose([*((hi + lo) / 2)[:2], lo[2]], 0.0, atol=1e-12)
    nan = trimesh.Trimesh(np.where(np.arange(len(box.vertices))[:, None] == 2, np.nan, box.vertices), box.faces,
                          process=False)
    with pytest.raises(ValueError, match=r"^the mesh of .*box\.obj has 1 non-finite \(NaN or infinite\) vertices of 8"):
        vehicle_from_mesh(nan, path)
    outside = trimesh.Trimesh(box.vertices, np.vstack([box.faces[:11], [[0, 1, 8]]]), process=False)
    with pytest.raises(ValueError, match=r"^the mesh of made in Python has 1 triangles of 12 indexing a vertex it"):
        vehicle_from_mesh(outside, "made in Python")
    with pytest.raises(ValueError, match=r"^the mesh of made in Python holds no triangles$"):
        vehicle_from_mesh(trimesh.Trimesh(box.vertices, np.zeros((0, 3), int), process=False), "made in Python")
    with pytest.raises(ValueError, match=r"^made in Python: expected a trimesh.Trimesh \(one mesh\); got Scene$"):
        vehicle_from_mesh(trimesh.Scene(box), "made in Python")
    with pytest.raises(ValueError, match=r"^made in Python: unknown vehicle class 'lorry'"):
        vehicle_from_mesh(box, "made in Python", cls="lorry")
