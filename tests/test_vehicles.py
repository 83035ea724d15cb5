"""Tests for torch_atr.vehicles: loading, body frame, articulation, catalog, held-out meshes.

References are independent of the code under test: published dimensions (specs), hand-built
rotation matrices, scipy's convex hull volumes, shoelace areas, meshes built with trimesh in a
known orientation, and the byte content of the shipped files.
"""

from __future__ import annotations

import dataclasses
import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import trimesh
from matplotlib.path import Path as MplPath
from scipy.spatial import ConvexHull

from torch_atr.vehicles import CLASS_NAMES, Vehicle, load_catalog, load_heldout_meshes, load_vehicle
from torch_atr.vehicles.build import _clip, build_catalog
from torch_atr.vehicles.catalog import CATALOG_DIR, MESHES_ENV, default_meshes_root, read_manifest
from torch_atr.vehicles.geometry import fillet, frustum_xy, prism_xz, signed_area, sweep, triangulate, volume
from torch_atr.vehicles.loader import body_rotation, thick_bounds
from torch_atr.vehicles.specs import TEST, TRAIN, Road

SPECS = {s.name: s for s in TRAIN + TEST}
TOL = 0.05  # published dimensions, relative


@pytest.fixture(scope="module")
def catalog() -> dict[str, list[Vehicle]]:
    return {split: load_catalog(split) for split in ("train", "test")}


@pytest.fixture(scope="module")
def by_name(catalog) -> dict[str, Vehicle]:
    return {v.name: v for vs in catalog.values() for v in vs}


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


# ------------------------------------------------------------------------------------------
# Catalog composition
# ------------------------------------------------------------------------------------------
def test_split_sizes_and_classes(catalog):
    train, test = catalog["train"], catalog["test"]
    assert len(train) == 36
    assert {c: sum(v.cls == c for v in train) for c in CLASS_NAMES} == {c: 6 for c in CLASS_NAMES}
    assert len(test) == 8
    counts = {c: sum(v.cls == c for v in test) for c in CLASS_NAMES}
    assert counts == {"tank": 3, "apc": 3, "pickup": 1, "suv": 1, "car": 0, "minivan": 0}
    assert {v.name for v in train}.isdisjoint(v.name for v in test)
    assert len({v.name for v in train}) == 36


def test_catalog_order_is_stable(catalog):
    for split, vehicles in catalog.items():
        keys = [(CLASS_NAMES.index(v.cls), v.name) for v in vehicles]
        assert keys == sorted(keys)
        assert [v.name for v in load_catalog(split)] == [v.name for v in vehicles]


def test_test_split_mirrors_sensiac():
    titles = " ".join(s.title for s in TEST)
    for target in ("T-72", "ZSU-23-4", "2S3", "BTR-70", "BRDM-2", "BMP-2", "F-150", "Isuzu"):
        assert target in titles
    train_titles = [s.title for s in TRAIN]
    assert not any(t in title for title in train_titles for t in ("T-72", "ZSU", "2S3", "BTR-70", "BRDM", "BMP", "F-150", "Isuzu"))


def test_unknown_split_raises():
    with pytest.raises(ValueError, match="'val'"):
        load_catalog("val")


# ------------------------------------------------------------------------------------------
# Published dimensions and the body frame
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(SPECS))
def test_extents_match_published(by_name, name):
    # Length and width are built straight from the spec (the x / y placements use them), so they
    # mostly check the assembly; height (deck + turret or roof) and anything that could stick
    # out (cupolas, extras, guns, wheels) are what this really tests.
    # A road vehicle's published width leaves out its door mirrors; the mesh has them.
    spec, v = SPECS[name], by_name[name]
    length = spec.gun_length if getattr(spec, "gun_length", None) else spec.length
    width = spec.width
    if isinstance(spec, Road):
        width = max(width, (spec.cab[0] if spec.cab else width) + 2 * spec.mirror)
    lo, hi = v.mesh.bounds
    ext = hi - lo
    np.testing.assert_allclose(ext, [length, width, spec.height], rtol=TOL, err_msg=name)
    assert lo[2] == pytest.approx(0.0, abs=1e-9)  # on the ground
    np.testing.assert_allclose((lo + hi)[:2] / 2, 0.0, atol=1e-9)  # footprint centred


@pytest.mark.parametrize("name", sorted(n for n, s in SPECS.items() if isinstance(s, Road)))
def test_wheelbase_and_track_from_urdf(name):
    """Wheel cylinders on the ground in the URDF XML sit at the published wheelbase and track."""
    spec = SPECS[name]
    split = "train" if spec in TRAIN else "test"
    root = ET.parse(CATALOG_DIR / split / name / f"{name}.urdf").getroot()
    centres = []
    for vis in root.iter("visual"):
        cyl = vis.find("geometry/cylinder")
        if cyl is not None and float(cyl.get("radius")) == pytest.approx(spec.wheel_d / 2):
            centre = [float(t) for t in vis.find("origin").get("xyz").split()]
            if centre[2] == pytest.approx(spec.wheel_d / 2):  # not a spare wheel
                centres.append(centre)
    c = np.array(centres)
    assert len(c) == 4
    assert np.ptp(c[:, 0]) == pytest.approx(spec.wheelbase, abs=1e-3)
    assert np.ptp(c[:, 1]) == pytest.approx(spec.track, abs=1e-3)
    assert np.all(c[:, 0] <= spec.length / 2) and np.all(c[:, 0] >= -spec.length / 2)


def _max_height(v: Vehicle, lo: float, hi: float) -> float:
    x = v.mesh.vertices
    sel = (x[:, 0] >= lo) & (x[:, 0] <= hi)
    return float(x[sel, 2].max())


@pytest.mark.parametrize("name", sorted(n for n, s in SPECS.items() if getattr(s, "turret", None) is None))
def test_front_is_plus_x_without_turret(by_name, name):
    """Bonnet / glacis at the front: the nose end is lower than the tail end (5 % of length)."""
    v = by_name[name]
    half = v.mesh.extents[0] / 2
    band = 0.05 * 2 * half
    assert _max_height(v, half - band, half) < _max_height(v, -half, -half + band) - 0.05


def _gun_vertices(v: Vehicle) -> np.ndarray:
    """Indices of vertices that move with gun_pitch (the gun link)."""
    moved = np.linalg.norm(v.posed({"gun_pitch": 0.1}).mesh.vertices - v.mesh.vertices, axis=1) > 1e-6
    return np.flatnonzero(moved)


ARTICULATED = sorted(n for n, s in SPECS.items() if getattr(s, "turret", None) is not None)
OVERHANG = sorted(n for n, s in SPECS.items() if getattr(s, "gun_length", None))


@pytest.mark.parametrize("name", ARTICULATED)
def test_gun_points_forward_and_pitch_raises_it(by_name, name):
    v = by_name[name]
    assert v.joint_names == ("turret_yaw", "gun_pitch")
    gun = _gun_vertices(v)
    muzzle = gun[np.argmax(v.mesh.vertices[gun, 0])]
    p = v.mesh.vertices[muzzle]
    assert p[0] > 0.0  # the gun points to +X
    up, down = v.posed({"gun_pitch": 0.15}), v.posed({"gun_pitch": -0.05})
    assert up.mesh.vertices[muzzle, 2] > p[2] + 0.1
    assert down.mesh.vertices[muzzle, 2] < p[2]
    if name in OVERHANG:  # the muzzle is the frontmost point
        assert p[0] == pytest.approx(v.mesh.bounds[1, 0], abs=1e-9)


@pytest.mark.parametrize("name", ARTICULATED)
def test_turret_yaw_is_a_rigid_left_turn(by_name, name):
    """turret_yaw = pi/2 rotates turret and gun rigidly by +90 deg about a vertical axis; hull stays."""
    v = by_name[name]
    turned = v.posed({"turret_yaw": math.pi / 2})
    a, b = v.mesh.vertices, turned.mesh.vertices
    moved = np.linalg.norm(b - a, axis=1) > 1e-6
    assert moved.sum() > 0 and (~moved).sum() > 0
    pa, pb = a[moved], b[moved]
    np.testing.assert_allclose(pb - pb[0], (pa - pa[0]) @ _rot_z(math.pi / 2).T, atol=1e-6)
    gun = _gun_vertices(v)
    muzzle = gun[np.argmax(a[gun, 0])]
    assert b[muzzle, 1] > a[muzzle, 1] + 0.3  # swung to the left (+Y)
    assert b[muzzle, 0] < a[muzzle, 0]


@pytest.mark.parametrize("name", OVERHANG)
def test_turret_yaw_moves_the_muzzle_extreme_from_x_to_y(by_name, name):
    spec, v = SPECS[name], by_name[name]
    turned = v.posed({"turret_yaw": math.pi / 2}).mesh
    lo, hi = turned.bounds
    assert hi[1] > spec.width / 2 + 0.5  # the gun now sticks out to the left
    assert hi[1] > -lo[1] + 0.5
    assert hi[0] - lo[0] == pytest.approx(spec.length, rel=TOL)  # what remains along X is the hull


def test_posed_keeps_other_joints_and_validates(by_name):
    v = by_name["t_72"].posed({"gun_pitch": 0.1})
    w = v.posed({"turret_yaw": 1.0})
    assert dict(w.joints) == {"turret_yaw": 1.0, "gun_pitch": 0.1}
    with pytest.raises(ValueError, match="unknown joint 'hull_roll'"):
        v.posed({"hull_roll": 0.1})
    with pytest.raises(ValueError, match="gun_pitch"):
        v.posed({"gun_pitch": 1.2})  # T-72 elevates to +14 deg only
    with pytest.raises(ValueError, match=r"toyota_camry\.urdf: unknown joint 'turret_yaw'"):
        by_name["toyota_camry"].posed({"turret_yaw": 0.1})
    assert by_name["toyota_camry"].posed({}) is by_name["toyota_camry"]


def test_catalog_meshes_are_closed_and_not_degenerate(catalog):
    for v in catalog["train"] + catalog["test"]:
        m = v.mesh
        assert m.is_watertight and m.is_winding_consistent, v.name
        assert m.area_faces.min() > 1e-6, v.name
        assert m.volume > 0, v.name


def test_shipped_part_files_are_closed_and_small():
    objs = sorted(CATALOG_DIR.rglob("*.obj"))
    assert len(objs) >= 44
    for p in objs:
        m = trimesh.load(p, force="mesh", process=False)
        assert m.is_watertight and m.is_winding_consistent and m.volume > 0, p
    total = sum(p.stat().st_size for p in CATALOG_DIR.rglob("*") if p.is_file())
    assert total < 2 * 1024 * 1024
    assert max(p.stat().st_size for p in CATALOG_DIR.rglob("*") if p.is_file()) < 16 * 1024


def test_catalog_is_reproducible(tmp_path):
    build_catalog(tmp_path)
    shipped = {p.relative_to(CATALOG_DIR): p.read_bytes() for p in CATALOG_DIR.rglob("*") if p.is_file()}
    built = {p.relative_to(tmp_path): p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    assert sorted(built) == sorted(shipped)
    for rel, data in built.items():
        assert data == shipped[rel], rel


# ------------------------------------------------------------------------------------------
# URDF loading: single link, <limit> without effort/velocity, rpy convention, joints
# ------------------------------------------------------------------------------------------
def test_single_link_urdf_uses_every_visual(tmp_path):
    # pytorch-kinematics raises on this (single link, no joint) and keeps only a link's first visual.
    (tmp_path / "car.urdf").write_text(
        '<robot name="car"><link name="body">'
        '<visual><origin xyz="0 0 0.5"/><geometry><box size="4 2 1"/></geometry></visual>'
        '<visual><origin xyz="2.5 0 0.5" rpy="0 1.5707963267948966 0"/>'
        '<geometry><cylinder radius="0.2" length="1"/></geometry></visual>'
        "</link></robot>"
    )
    v = load_vehicle(tmp_path / "car.urdf", cls="car")
    assert v.joint_names == () and v.cls == "car" and v.name == "car"
    # Box spans x in [-2, 2], the cylinder (axis along x) [2, 3]: 5 m long, centred.
    np.testing.assert_allclose(v.mesh.extents, [5.0, 2.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(v.mesh.bounds[:, 0], [-2.5, 2.5], atol=1e-6)


ARM = """<robot name="arm">
  <link name="base"><visual><geometry><box size="2 2 1"/></geometry></visual></link>
  <link name="top"><visual><origin xyz="1 0 0"/><geometry><box size="2 0.2 0.2"/></geometry></visual></link>
  <joint name="yaw" type="revolute">
    <parent link="base"/><child link="top"/>
    <origin xyz="0.5 0 1" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-1.0" upper="2.0"/>
  </joint>
</robot>"""


def test_limit_without_effort_and_velocity_loads_and_poses(tmp_path):
    (tmp_path / "arm.urdf").write_text(ARM)
    rest = load_vehicle(tmp_path / "arm.urdf")
    assert rest.joint_names == ("yaw",) and rest.cls == "unknown"
    angle = 0.7
    posed = load_vehicle(tmp_path / "arm.urdf", {"yaw": angle})
    # Closed form: the top box's vertices rotate about the joint axis through (0.5, 0, 1).
    top = trimesh.creation.box(extents=(2, 0.2, 0.2)).vertices + [1.0, 0.0, 0.0]
    expected = top @ _rot_z(angle).T + [0.5, 0.0, 1.0]
    # Rest pose (yaw 0): base x, y, z in [-1, 1] x [-1, 1] x [-0.5, 0.5], top [0.5, 2.5] x
    # [-0.1, 0.1] x [0.9, 1.1]; centring the box [-1, 2.5] x [-1, 1] x [-0.5, 1.1] shifts by:
    offset = np.array([-0.75, 0.0, 0.5])
    base = trimesh.creation.box(extents=(2, 2, 1)).vertices + offset
    np.testing.assert_allclose(rest.mesh.vertices[:8], base, atol=1e-12)
    np.testing.assert_allclose(posed.mesh.vertices[8:], expected + offset, atol=1e-9)
    np.testing.assert_allclose(posed.mesh.vertices[:8], base, atol=1e-12)  # the base stays
    with pytest.raises(ValueError, match="outside its limits"):
        rest.posed({"yaw": 2.5})


def _arm(tmp_path: Path, joint_type: str, limit: str) -> Path:
    path = tmp_path / "arm.urdf"
    text = ARM.replace('type="revolute"', f'type="{joint_type}"')
    path.write_text(text.replace('<limit lower="-1.0" upper="2.0"/>', limit))
    return path


@pytest.mark.parametrize("joint_type", ["revolute", "prismatic"])
def test_missing_lower_or_upper_is_zero(tmp_path, joint_type):
    """URDF specification: <limit> lower / upper default to 0 (not unbounded)."""
    v = load_vehicle(_arm(tmp_path, joint_type, '<limit upper="0.5"/>'))
    assert dict(v.joints) == {"yaw": 0.0}
    v.posed({"yaw": 0.0})
    with pytest.raises(ValueError, match=r"arm\.urdf: joint 'yaw' = -0\.1 is outside its limits \[0\.0, 0\.5\]"):
        v.posed({"yaw": -0.1})
    v = load_vehicle(_arm(tmp_path, joint_type, '<limit lower="-0.5"/>'))
    with pytest.raises(ValueError, match=r"outside its limits \[-0\.5, 0\.0\]"):
        v.posed({"yaw": 0.1})
    with pytest.raises(ValueError, match=rf"arm\.urdf: joint 'yaw': a {joint_type} joint needs a <limit>"):
        load_vehicle(_arm(tmp_path, joint_type, ""))


def test_continuous_joint_is_unbounded(tmp_path):
    v = load_vehicle(_arm(tmp_path, "continuous", ""), {"yaw": 10.0})
    top = trimesh.creation.box(extents=(2, 0.2, 0.2)).vertices + [1.0, 0.0, 0.0]
    expected = top @ _rot_z(10.0).T + [0.5, 0.0, 1.0] + [-0.75, 0.0, 0.5]  # rest-pose centring (test above)
    np.testing.assert_allclose(v.mesh.vertices[8:], expected, atol=1e-9)


def test_lower_above_upper_raises(tmp_path):
    with pytest.raises(ValueError, match=r"arm\.urdf: joint 'yaw': limit lower 1\.0 is above upper -1\.0"):
        load_vehicle(_arm(tmp_path, "revolute", '<limit lower="1" upper="-1"/>'))


def test_unsupported_joint_type(tmp_path):
    with pytest.raises(ValueError, match=r"arm\.urdf: joint 'yaw': unsupported joint type 'floating'"):
        load_vehicle(_arm(tmp_path, "floating", ""))


@pytest.mark.parametrize("old, new, message", [
    ('<axis xyz="0 0 1"/>', '<axis xyz="0 0 0"/>',
     r"joint 'yaw': axis xyz is 0 0 0; a revolute joint needs a direction"),
    ('<origin xyz="0.5 0 1" rpy="0 0 0"/>', '<origin xyz="0.5 0 1" rpy="0 nan 0"/>',
     r"joint 'yaw' origin rpy: expected 3 finite numbers; got '0 nan 0'"),
])
def test_a_joint_without_a_finite_origin_or_a_direction_is_named(tmp_path, old, new, message):
    """pytorch-kinematics poses every part at NaN for these (reported as 'size nan: flat along x')."""
    path = tmp_path / "arm.urdf"
    path.write_text(ARM.replace(old, new))
    with pytest.raises(ValueError, match=rf"arm\.urdf: {message}"):
        load_vehicle(path)
    fixed = ARM.replace('type="revolute"', 'type="fixed"')  # a fixed joint has no axis: 0 0 0 is fine
    path.write_text(fixed.replace('<axis xyz="0 0 1"/>', '<axis xyz="0 0 0"/>'))
    np.testing.assert_allclose(load_vehicle(path).mesh.extents, [3.5, 2.0, 1.6], atol=1e-9)  # test above: the box


BOX_LINK = '<link name="{}"><visual><geometry><box size="1 1 1"/></geometry></visual></link>'
FIXED = '<joint name="{}" type="fixed"><parent link="{}"/><child link="{}"/></joint>'


def test_links_without_joints_raise(tmp_path):
    (tmp_path / "two.urdf").write_text(f'<robot name="r">{BOX_LINK.format("a")}{BOX_LINK.format("b")}</robot>')
    with pytest.raises(ValueError, match=r"two\.urdf: 2 links but no joint"):
        load_vehicle(tmp_path / "two.urdf")
    links = "".join(BOX_LINK.format(n) for n in "abc")
    (tmp_path / "loose.urdf").write_text(f'<robot name="r">{links}{FIXED.format("j", "a", "b")}</robot>')
    with pytest.raises(ValueError, match=r"loose\.urdf: links \['c'\] are not connected to the root"):
        load_vehicle(tmp_path / "loose.urdf")


def test_visual_rpy_is_fixed_axis_xyz(tmp_path):
    r, p, y = 0.3, -0.4, 1.1
    (tmp_path / "box.urdf").write_text(
        f'<robot name="b"><link name="l"><visual><origin xyz="0 0 0" rpy="{r} {p} {y}"/>'
        '<geometry><box size="3 1 0.5"/></geometry></visual></link></robot>'
    )
    v = load_vehicle(tmp_path / "box.urdf")
    raw = trimesh.creation.box(extents=(3, 1, 0.5)).vertices @ (_rot_z(y) @ _rot_y(p) @ _rot_x(r)).T
    np.testing.assert_allclose(v.mesh.vertices - v.mesh.vertices[0], raw - raw[0], atol=1e-9)


def test_urdf_mesh_visual_is_resolved_beside_the_urdf(tmp_path):
    (tmp_path / "parts").mkdir()
    trimesh.creation.box(extents=(1, 1, 1)).export(tmp_path / "parts" / "cube.stl")
    (tmp_path / "m.urdf").write_text(
        '<robot name="m"><link name="l"><visual><geometry>'
        '<mesh filename="parts/cube.stl" scale="4 2 1.5"/></geometry></visual></link></robot>'
    )
    np.testing.assert_allclose(load_vehicle(tmp_path / "m.urdf").mesh.extents, [4, 2, 1.5], atol=1e-6)


def test_package_uri_beside_the_urdf_then_one_folder_up(tmp_path):
    """package://pkg/rest: ``rest`` beside the URDF wins, else one folder up (pkg/urdf/, pkg/meshes/)."""
    (tmp_path / "pkg" / "urdf").mkdir(parents=True)
    (tmp_path / "pkg" / "meshes").mkdir()
    urdf = tmp_path / "pkg" / "urdf" / "v.urdf"
    urdf.write_text('<robot name="v"><link name="l"><visual><geometry>'
                    '<mesh filename="package://pkg/meshes/cube.stl"/></geometry></visual></link></robot>')
    with pytest.raises(FileNotFoundError, match=r"v\.urdf.*urdf/meshes/cube\.stl or .*pkg/meshes/cube\.stl"):
        load_vehicle(urdf)
    trimesh.creation.box(extents=(3, 2, 1)).export(tmp_path / "pkg" / "meshes" / "cube.stl")
    np.testing.assert_allclose(load_vehicle(urdf).mesh.extents, [3, 2, 1], atol=1e-6)
    (tmp_path / "pkg" / "urdf" / "meshes").mkdir()
    trimesh.creation.box(extents=(5, 2, 1)).export(tmp_path / "pkg" / "urdf" / "meshes" / "cube.stl")
    np.testing.assert_allclose(load_vehicle(urdf).mesh.extents, [5, 2, 1], atol=1e-6)


@pytest.mark.parametrize("uri", ["package://pkg/my%20parts/cube%231.stl", "file://{folder}/my%20parts/cube%231.stl"])
def test_uri_mesh_names_are_percent_decoded(tmp_path, uri):
    """A URI's ``%20`` is a space and ``%23`` a '#' (RFC 3986, as ROS's resource retriever reads them); a plain
    path with a literal '%' is read as written."""
    (tmp_path / "my parts").mkdir()
    trimesh.creation.box(extents=(3, 2, 1)).export(tmp_path / "my parts" / "cube#1.stl")
    mesh = f'<mesh filename="{uri.format(folder=tmp_path)}"/>'
    (tmp_path / "v.urdf").write_text(f'<robot name="v"><link name="l"><visual><geometry>{mesh}</geometry></visual>'
                                     '</link></robot>')
    np.testing.assert_allclose(load_vehicle(tmp_path / "v.urdf").mesh.extents, [3, 2, 1], atol=1e-6)
    (tmp_path / "a%20b").mkdir()
    trimesh.creation.box(extents=(4, 2, 1)).export(tmp_path / "a%20b" / "cube.stl")
    (tmp_path / "w.urdf").write_text('<robot name="w"><link name="l"><visual><geometry>'
                                     '<mesh filename="a%20b/cube.stl"/></geometry></visual></link></robot>')
    np.testing.assert_allclose(load_vehicle(tmp_path / "w.urdf").mesh.extents, [4, 2, 1], atol=1e-6)


# ------------------------------------------------------------------------------------------
# Mesh files: axes and scale
# ------------------------------------------------------------------------------------------
def _marked_box(forward: np.ndarray, left: np.ndarray, up: np.ndarray, scale: float) -> trimesh.Trimesh:
    """A 4 x 2 x 1.5 m body with a nose block at front-top and a fin on the left, in file axes."""
    parts = [((4.0, 2.0, 1.5), (0.0, 0.0, 0.75)), ((0.5, 0.4, 0.4), (2.0, 0.0, 1.5)), ((1.0, 0.6, 0.2), (0.0, 1.0, 0.3))]
    basis = np.stack([forward, left, up], axis=1) / scale  # body -> file coordinates
    meshes = []
    for size, centre in parts:
        m = trimesh.creation.box(extents=size)
        m.vertices = (m.vertices + centre) @ basis.T
        meshes.append(m)
    return trimesh.util.concatenate(meshes)


AXIS_VEC = {"x": [1, 0, 0], "y": [0, 1, 0], "z": [0, 0, 1], "-x": [-1, 0, 0], "-y": [0, -1, 0], "-z": [0, 0, -1]}


@pytest.mark.parametrize(
    "up,forward,scale,ext",
    [("z", "x", 1.0, "obj"), ("y", "-z", 0.01, "obj"), ("y", "x", 0.0254, "stl"), ("-x", "y", 1.0, "glb"), ("z", "-y", 0.001, "ply")],
)
def test_mesh_file_axes_and_scale(tmp_path, up, forward, scale, ext):
    u, f = np.array(AXIS_VEC[up], float), np.array(AXIS_VEC[forward], float)
    left = np.cross(u, f)
    _marked_box(f, left, u, scale).export(tmp_path / f"v.{ext}")
    v = load_vehicle(tmp_path / f"v.{ext}", up_axis=up, forward_axis=forward, scale=scale, cls="apc")
    lo, hi = v.mesh.bounds
    np.testing.assert_allclose(hi - lo, [4.25, 2.3, 1.7], atol=1e-4)  # nose and fin included
    assert lo[2] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose((lo + hi)[:2] / 2, 0.0, atol=1e-6)
    x = v.mesh.vertices
    assert x[np.argmax(x[:, 0]), 2] > 1.2  # the nose block is at the front, on top
    assert x[np.argmax(x[:, 1]), 2] < 0.5  # the low fin is on the left (+Y)


def _with_antenna_and_mirror() -> trimesh.Trimesh:
    """A 4 x 1.8 x 1.5 m box body on the ground, a 1.2 m whip antenna (2 cm thick) on its roof and a
    mirror plate (2 cm thick, 0.2 m wide and 0.15 m high) sticking 0.25 m out of its left side."""
    body = trimesh.creation.box(extents=(4.0, 1.8, 1.5)).apply_translation((0.0, 0.0, 0.75))
    whip = trimesh.creation.cylinder(radius=0.01, height=1.2, sections=8).apply_translation((-1.5, 0.5, 1.5 + 0.6))
    mirror = trimesh.creation.box(extents=(0.02, 0.35, 0.15)).apply_translation((1.0, 0.9 + 0.075, 1.0))
    return trimesh.util.concatenate([body, whip, mirror])


def test_thin_protrusions_are_trimmed_from_mesh_files(tmp_path):
    _with_antenna_and_mirror().export(tmp_path / "v.obj")
    v = load_vehicle(tmp_path / "v.obj")
    # The whip goes, to within one 1 cm slab (it would raise the box centre by 0.6 m); the mirror plate stays.
    np.testing.assert_allclose(v.mesh.extents, [4.0, 1.8 + 0.25, 1.5], atol=0.0101)
    assert len(v.mesh.faces) > 12 + 12  # body and mirror boxes, and the whip's stub
    kept = load_vehicle(tmp_path / "v.obj", min_thickness=0.0)
    np.testing.assert_allclose(kept.mesh.extents, [4.0, 2.05, 2.7], atol=1e-6)
    # The same whip 10 cm thick is a mast, not a wire: it stays.
    assert load_vehicle(tmp_path / "v.obj", min_thickness=0.01).mesh.extents[2] == pytest.approx(2.7, abs=1e-6)
    with pytest.raises(ValueError, match="min_thickness"):
        load_vehicle(tmp_path / "v.obj", min_thickness=-1.0)


def test_thick_bounds_leave_the_catalog_untouched(catalog):
    """No catalog vehicle has a thin protrusion: the trimmed box is the whole box (so URDFs, taken as
    written, and mesh files are centred by one rule)."""
    for v in catalog["train"] + catalog["test"]:
        box = thick_bounds(v.mesh.vertices, np.asarray(v.mesh.faces), 0.05)
        np.testing.assert_allclose(box, v.mesh.bounds, atol=1e-9, err_msg=v.name)


def test_thick_bounds_refuse_vertices_or_faces_of_the_wrong_shape_or_kind():
    """Float faces and (M, 2) vertices raised numpy's IndexError from deep inside."""
    mesh = trimesh.creation.box((1.0, 2.0, 3.0))
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    with pytest.raises(ValueError, match=r"Expected faces to be an integer array of shape \(F, 3\); got shape "
                                         r"\(12, 3\), dtype float64"):
        thick_bounds(v, f.astype(np.float64), 0.05)
    with pytest.raises(ValueError, match=r"Expected vertices to be a float array of shape \(M, 3\); got shape "
                                         r"\(8, 2\)"):
        thick_bounds(v[:, :2], f, 0.05)


def test_thick_bounds_against_a_slab_by_slab_loop_whatever_the_chunk(monkeypatch):
    """thick_bounds against its definition done slab by slab (the faces crossing a slab, their boxes'
    span along the other two axes), with (face, slab) pairs taken a handful at a time: it held one
    entry per pair at once, 565 MB for a 1 MB OBJ of a 9 m cylinder's long triangles."""
    from torch_atr.vehicles import loader

    mesh = _with_antenna_and_mirror()
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    tri = v[f]
    lo, hi, box = tri.min(axis=1), tri.max(axis=1), np.stack([v.min(axis=0), v.max(axis=0)])
    want = box.copy()
    for a in range(3):
        others = [k for k in range(3) if k != a]
        first = np.floor((lo[:, a] - box[0, a]) / 0.01).astype(int)
        last = np.floor((hi[:, a] - box[0, a]) / 0.01).astype(int)
        thick = [s for s in range(last.max() + 1) if any(
            hi[(first <= s) & (last >= s), k].max() - lo[(first <= s) & (last >= s), k].min() >= 0.05 for k in others
            if ((first <= s) & (last >= s)).any())]
        want[0, a], want[1, a] = box[0, a] + min(thick) * 0.01, min(box[1, a], box[0, a] + (max(thick) + 1) * 0.01)
    for chunk in (1 << 20, 7):
        monkeypatch.setattr(loader, "_PAIRS_PER_CHUNK", chunk)
        np.testing.assert_allclose(thick_bounds(v, f, 0.05), want, rtol=0, atol=1e-12)
    assert want[1, 2] < box[1, 2] - 1.0  # the whip is trimmed: the case has a thin part


def test_body_rotation_is_proper():
    for up in AXIS_VEC:
        for fw in AXIS_VEC:
            if abs(np.dot(AXIS_VEC[up], AXIS_VEC[fw])) > 0:
                with pytest.raises(ValueError, match="perpendicular"):
                    body_rotation(up, fw)
                continue
            r = body_rotation(up, fw)
            np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
            assert np.linalg.det(r) == pytest.approx(1.0)
            np.testing.assert_allclose(r @ np.array(AXIS_VEC[fw], float), [1, 0, 0])
            np.testing.assert_allclose(r @ np.array(AXIS_VEC[up], float), [0, 0, 1])
    with pytest.raises(ValueError, match="the up axis must be one of"):
        body_rotation("w", "x")


# ------------------------------------------------------------------------------------------
# Bad input names the file
# ------------------------------------------------------------------------------------------
def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.urdf"):
        load_vehicle(tmp_path / "nope.urdf")


def test_a_mesh_scaled_to_a_toy_is_refused_naming_its_size(tmp_path):
    """A 4.9 m car read at the centimetre scale came in as 4.9 cm and rendered no template pixel, without a word."""
    trimesh.creation.box(extents=(4.9, 1.8, 1.5)).export(tmp_path / "car.obj")
    assert load_vehicle(tmp_path / "car.obj", scale=0.15).mesh.extents[0] == pytest.approx(0.735)
    with pytest.raises(ValueError, match=r"car\.obj: 0\.049 × 0\.018 × 0\.015 m at scale 0\.01 is too small for a "
                                         r"vehicle \(at least 0\.5 m along its longest axis\); check its scale"):
        load_vehicle(tmp_path / "car.obj", scale=0.01)


def test_a_mesh_file_too_big_to_read_is_refused_before_it_is_read(tmp_path, monkeypatch):
    """A mesh file is read whole as bytes, text and lines (~15 bytes of memory a byte) before any
    check: a 1 GB scan needed ~15 GB. Its size is checked first."""
    from torch_atr.vehicles import loader

    trimesh.creation.box(extents=(4.0, 1.8, 1.5)).export(tmp_path / "scan.obj")
    size = (tmp_path / "scan.obj").stat().st_size
    monkeypatch.setattr(loader, "MAX_MESH_BYTES", size - 1)
    monkeypatch.setattr(loader, "_mesh_text", lambda path: pytest.fail("the file was read"))
    with pytest.raises(ValueError, match=r"scan\.obj: 0 MiB is more than a mesh file may have .* decimate it first"):
        load_vehicle(tmp_path / "scan.obj")
    monkeypatch.setattr(loader, "MAX_MESH_BYTES", size)
    monkeypatch.undo()
    assert load_vehicle(tmp_path / "scan.obj").mesh.extents[0] == pytest.approx(4.0)


def test_missing_referenced_mesh(tmp_path):
    (tmp_path / "v.urdf").write_text(
        '<robot name="v"><link name="l"><visual><geometry><mesh filename="gone.obj"/></geometry></visual></link></robot>'
    )
    with pytest.raises(FileNotFoundError, match=r"v\.urdf.*gone\.obj"):
        load_vehicle(tmp_path / "v.urdf")


def test_broken_xml(tmp_path):
    (tmp_path / "broken.urdf").write_text('<robot name="v"><link name="l"></robot>')
    with pytest.raises(ValueError, match="broken.urdf"):
        load_vehicle(tmp_path / "broken.urdf")


@pytest.mark.parametrize(
    "geometry,message",
    [
        ('<cylinder length="1"/>', "<cylinder> radius: required attribute is missing"),
        ('<cylinder radius="1"/>', "<cylinder> length: required attribute is missing"),
        ("<box/>", "<box> size: required attribute is missing"),
        ("<sphere/>", "<sphere> radius: required attribute is missing"),
        ('<box size="1 0 1"/>', "<box> size: expected positive numbers; got '1 0 1'"),
        ('<cylinder radius="-0.2" length="1"/>', "<cylinder> radius: expected positive numbers"),
        ('<cylinder radius="0.2" length="0"/>', "<cylinder> length: expected positive numbers"),
        ('<sphere radius="0"/>', "<sphere> radius: expected positive numbers"),
        ('<mesh filename="c.stl" scale="1 -1 1"/>', "<mesh> scale: expected positive numbers"),
        ('<box size="1 1"/>', "<box> size: expected 3 finite numbers"),
    ],
)
def test_bad_geometry_attributes_name_file_and_element(tmp_path, geometry, message):
    trimesh.creation.box().export(tmp_path / "c.stl")
    (tmp_path / "g.urdf").write_text(
        f'<robot name="g"><link name="body"><visual><geometry>{geometry}</geometry></visual></link></robot>'
    )
    with pytest.raises(ValueError, match=r"g\.urdf: link 'body' visual 0 .*" + re.escape(message)):
        load_vehicle(tmp_path / "g.urdf")


def test_unknown_class(tmp_path):
    trimesh.creation.box().export(tmp_path / "b.obj")
    with pytest.raises(ValueError, match=r"b\.obj.*'truck'"):
        load_vehicle(tmp_path / "b.obj", cls="truck")


def test_empty_and_unreadable_meshes(tmp_path):
    (tmp_path / "empty.obj").write_text("# nothing here\n")
    with pytest.raises(ValueError, match="empty.obj"):
        load_vehicle(tmp_path / "empty.obj")
    (tmp_path / "v.urdf").write_text("<robot name='v'><link name='l'/></robot>")
    with pytest.raises(ValueError, match="v.urdf"):
        load_vehicle(tmp_path / "v.urdf")


def test_bad_options(tmp_path):
    trimesh.creation.box().export(tmp_path / "b.obj")
    with pytest.raises(ValueError, match="scale"):
        load_vehicle(tmp_path / "b.obj", scale=0.0)
    with pytest.raises(ValueError, match="perpendicular"):
        load_vehicle(tmp_path / "b.obj", up_axis="x", forward_axis="-x")
    with pytest.raises(ValueError, match="no joints"):
        load_vehicle(tmp_path / "b.obj", {"turret_yaw": 0.0})
    with pytest.raises(ValueError, match=r"b\.obj\) has no joints"):
        load_vehicle(tmp_path / "b.obj").posed({"turret_yaw": 0.0})


# ------------------------------------------------------------------------------------------
# Geometry primitives
# ------------------------------------------------------------------------------------------
def test_triangulate_non_convex_polygon():
    poly = np.array([(0, 0), (4, 0), (4, 1), (2.5, 1), (2, 2.5), (1.5, 1), (0, 1)], float)  # a cab on a body
    tri = triangulate(poly)
    assert tri.shape == (len(poly) - 2, 3)
    areas = [signed_area(poly[t]) for t in tri]
    assert min(areas) > 0
    assert sum(areas) == pytest.approx(signed_area(poly))


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_triangulate_star_polygons_cover_each_point_once(seed):
    """Every sample point inside the polygon (matplotlib) lies in exactly one triangle, outside in none."""
    rng = np.random.default_rng(seed)
    n = 12
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    poly = rng.uniform(0.2, 1.0, (n, 1)) * np.stack([np.cos(ang), np.sin(ang)], 1)  # star-shaped about 0
    tri = triangulate(poly)
    assert tri.shape == (n - 2, 3)
    pts = rng.uniform(-1.0, 1.0, (4000, 2))
    a, b, c = (poly[tri[:, k]][:, None, :] for k in range(3))  # (n - 2, 1, 2)

    def left_of(p, q):  # (n - 2, P): pts strictly left of the edge p -> q
        return (q[..., 0] - p[..., 0]) * (pts[:, 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (pts[:, 0] - p[..., 0]) > 0

    count = (left_of(a, b) & left_of(b, c) & left_of(c, a)).sum(axis=0)  # (P,)
    inside = MplPath(poly).contains_points(pts)
    assert inside.sum() > 500 and (~inside).sum() > 500
    np.testing.assert_array_equal(count, inside.astype(int))


def test_triangulate_rejects_clockwise_and_non_simple():
    square = np.array([(0, 0), (1, 0), (1, 1), (0, 1)], float)
    with pytest.raises(ValueError, match="counter-clockwise"):
        triangulate(square[::-1])
    crossed = np.array([(0, 0), (3, 0), (3, 3), (2, 3), (2, -1), (1, -1), (1, 3), (0, 3)], float)
    assert signed_area(crossed) > 0  # passes the winding check, then finds no ear
    with pytest.raises(ValueError, match="not simple"):
        triangulate(crossed)
    with pytest.raises(ValueError, match=r"shape \(n>=3, 2\)"):
        triangulate(square[:2])


@pytest.mark.parametrize("above", [True, False])
def test_clip_trapezoid(above):
    """Trapezoid base [0, 4] at z = 0, top [1, 3] at z = 2, cut at z = 1: the cut runs x in [0.5, 3.5]."""
    trapezoid = [(0.0, 0.0), (4.0, 0.0), (3.0, 2.0), (1.0, 2.0)]
    out = _clip(trapezoid, 1.0, above=above)
    if above:
        expected, area = {(3.5, 1.0), (3.0, 2.0), (1.0, 2.0), (0.5, 1.0)}, (3.0 + 2.0) / 2
    else:
        expected, area = {(0.0, 0.0), (4.0, 0.0), (3.5, 1.0), (0.5, 1.0)}, (4.0 + 3.0) / 2
    assert {(round(x, 12), round(z, 12)) for x, z in out} == expected
    assert signed_area(np.array(out)) == pytest.approx(area)  # counter-clockwise kept
    assert _clip(trapezoid, 3.0, above=above) == ([] if above else trapezoid)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_loft_volumes_match_convex_hull(seed):
    rng = np.random.default_rng(seed)
    n = 7
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    floor = np.stack([2 * np.cos(ang), 1.2 * np.sin(ang)], 1)
    v, f = frustum_xy(floor, 0.0, floor * 0.6 + [0.3, 0.0], 1.3)  # convex: hull volume is exact
    assert volume(v, f) == pytest.approx(ConvexHull(v).volume, rel=1e-9)
    m = trimesh.Trimesh(v, f, process=False)
    assert m.is_watertight and m.is_winding_consistent
    profile = np.stack([3 * np.cos(ang), 1 + np.sin(ang)], 1)
    v, f = prism_xz(profile, 0.8, y0=0.5)
    assert volume(v, f) == pytest.approx(ConvexHull(v).volume, rel=1e-9)
    assert v[:, 1].min() == pytest.approx(-0.3) and v[:, 1].max() == pytest.approx(1.3)


@pytest.mark.parametrize("seed", [0, 1])
def test_sweep_volume_matches_convex_hull(seed):
    """Scaled copies of one convex ring along x (sizes concave in x, centres on a line): the side quads
    are planar trapezoids and the swept solid is the rings' convex hull."""
    rng = np.random.default_rng(seed)
    ang = np.sort(rng.uniform(0, 2 * np.pi, 9))
    ring = np.stack([np.cos(ang), 0.6 * np.sin(ang)], 1)
    sizes = ((0.0, 0.5), (0.7, 1.0), (2.0, 0.9), (2.5, 0.3))  # (x, scale)
    rings = [np.c_[np.full(9, x), ring * s + [0.0, 0.2 * x]] for x, s in sizes]
    v, f = sweep(rings)
    m = trimesh.Trimesh(v, f, process=False)
    assert m.is_watertight and m.is_winding_consistent
    assert volume(v, f) == pytest.approx(ConvexHull(np.concatenate(rings)).volume, rel=1e-9)
    assert volume(*sweep(rings[::-1])) > 0  # either direction comes out oriented outwards
    with pytest.raises(ValueError, match=r"shape \(S>=2, n>=3, 3\)"):
        sweep(rings[:1])


def test_signed_area_refuses_points_that_are_not_2d():
    """Points (n, 3) gave the area of their x, y shadow without a word."""
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    assert signed_area(square) == 2.0 and signed_area(square[::-1]) == -2.0
    with pytest.raises(ValueError, match=r"Expected poly to have shape \(n, 2\); got \(4, 3\)"):
        signed_area(np.c_[square, np.ones(4)])
    with pytest.raises(ValueError, match=r"Expected poly to have shape \(n, 2\); got \(8,\)"):
        signed_area(square.ravel())


def test_volume_refuses_vertices_or_faces_of_the_wrong_shape_or_kind():
    """Float faces failed inside numpy's indexing; faces (F, 4) were read as triangles of their first three."""
    v = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    assert volume(v, f) == pytest.approx(1 / 6, rel=1e-12)
    with pytest.raises(ValueError, match=r"Expected faces to be an integer array of shape \(F, 3\); got shape "
                                         r"\(4, 3\), dtype float64"):
        volume(v, f.astype(np.float64))
    with pytest.raises(ValueError, match=r"Expected faces .*; got shape \(4, 4\), dtype int64"):
        volume(v, np.c_[f, f[:, :1]])
    with pytest.raises(ValueError, match=r"Expected verts to be a float array of shape \(M, 3\); got shape \(4, 2\)"):
        volume(v[:, :2], f)


def test_fillet_arcs_are_tangent_circles_of_the_radius():
    pts = [(0.0, 0.0), (2.0, 0.0), (2.0, 1.0), (4.0, 3.0)]
    out = np.array(fillet(pts, [0.3, 0.0], arc=5))
    assert len(out) == 2 + 5 + 1  # end points, one arc, one sharp corner
    arc = out[1:6]
    np.testing.assert_allclose(np.linalg.norm(arc - [1.7, 0.3], axis=1), 0.3, atol=1e-12)  # centre (1.7, 0.3)
    np.testing.assert_allclose(arc[[0, -1]], [[1.7, 0.0], [2.0, 0.3]], atol=1e-12)  # tangent points
    np.testing.assert_allclose(out[6], (2.0, 1.0))  # radius 0 keeps the corner
    # A radius too large for the segments shrinks to fit 0.45 of the shorter one.
    tight = np.array(fillet([(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)], 5.0))
    np.testing.assert_allclose(tight[[1, -2]], [[0.55, 0.0], [1.0, 0.45]], atol=1e-12)


# ------------------------------------------------------------------------------------------
# Held-out meshes
# ------------------------------------------------------------------------------------------
FOLDER_CLASS = {"tank": "tank", "apc": "apc", "pickup": "pickup", "suv": "suv", "sedan": "car", "van": "minivan",
                "military_utility": "unknown", "truck": "unknown"}
PLAUSIBLE_LENGTH = {"tank": (4.0, 12.0), "apc": (4.0, 9.0), "pickup": (4.5, 6.5), "suv": (3.5, 5.5),
                    "car": (3.0, 5.5), "minivan": (4.0, 7.0), "unknown": (3.0, 12.0)}
MESHES_ROOT = default_meshes_root()
needs_meshes = pytest.mark.skipif(not MESHES_ROOT.is_dir(), reason=f"no held-out meshes at {MESHES_ROOT}")


@needs_meshes
def test_manifest_covers_every_model_with_the_folder_class():
    entries = read_manifest()
    files = {str(p.relative_to(MESHES_ROOT)) for p in MESHES_ROOT.glob("*/*") if p.suffix in (".obj", ".glb")}
    assert {e.path for e in entries} == files
    assert len({Path(e.path).stem for e in entries}) == len(entries)
    for e in entries:
        assert e.cls == FOLDER_CLASS[e.path.split("/")[0]], e.path
        assert e.note


def _check_heldout(vehicles):
    for v in vehicles:
        lo, hi = v.mesh.bounds
        assert lo[2] == pytest.approx(0.0, abs=1e-9), v.name
        np.testing.assert_allclose((lo + hi)[:2] / 2, 0.0, atol=1e-6)
        low, high = PLAUSIBLE_LENGTH[v.cls]
        assert low <= hi[0] - lo[0] <= high, (v.name, hi[0] - lo[0])
        assert hi[0] - lo[0] > hi[1] - lo[1], v.name  # long axis forward


FAST_SUBSET = ("tank/iron_tanktics_warfare_tank.glb", "sedan/quaternius_normalcar2.obj", "van/gazebo_ambulance.obj",
               "apc/chrono_M113_chassis.obj")


@needs_meshes
def test_heldout_subset_loads_in_body_frame():
    entries = [e for e in read_manifest() if e.path in FAST_SUBSET]
    assert len(entries) == len(FAST_SUBSET)
    vehicles = load_heldout_meshes(entries=entries)
    _check_heldout(vehicles)
    m113 = vehicles[[e.path for e in entries].index("apc/chrono_M113_chassis.obj")]
    # M113: the long sloped glacis is at the front, the rear plate is vertical.
    assert _max_height(m113, 2.2, 2.7) < _max_height(m113, -2.7, -2.2) - 0.3


@needs_meshes
def test_heldout_antenna_no_longer_sets_the_box():
    """The Chrono G-class carries a 1.7 m whip antenna (SOURCES.md: z-extent 3.1 m)."""
    entries = [e for e in read_manifest() if e.path == "suv/chrono_gclass_gd250_chassis.obj"]
    (kept,) = load_heldout_meshes(entries=entries, min_thickness=0.0)
    (trimmed,) = load_heldout_meshes(entries=entries)
    assert kept.mesh.extents[2] == pytest.approx(3.12, abs=0.01)
    assert trimmed.mesh.extents[2] == pytest.approx(1.5, abs=0.02)  # the body without wheels
    np.testing.assert_allclose(trimmed.mesh.extents[:2], kept.mesh.extents[:2], atol=1e-6)


@needs_meshes
def test_heldout_root_from_environment(tmp_path, monkeypatch):
    entry = next(e for e in read_manifest() if e.path == "van/gazebo_ambulance.obj")
    (tmp_path / "van").mkdir()
    (tmp_path / entry.path).write_bytes((MESHES_ROOT / entry.path).read_bytes())
    monkeypatch.setenv(MESHES_ENV, str(tmp_path))
    (v,) = load_heldout_meshes(entries=[entry])
    assert v.source == tmp_path / entry.path and v.cls == "minivan"
    monkeypatch.setenv(MESHES_ENV, str(tmp_path / "missing"))
    with pytest.raises(FileNotFoundError, match="missing"):
        load_heldout_meshes()


@pytest.mark.slow
@needs_meshes
def test_all_heldout_meshes_load_in_body_frame():
    vehicles = load_heldout_meshes()
    assert len(vehicles) == len(read_manifest())
    _check_heldout(vehicles)


def test_load_catalog_vehicle_by_name_either_split():
    from torch_atr.vehicles import load_catalog_vehicle

    assert load_catalog_vehicle("BTR-70").name == "btr_70"
    assert load_catalog_vehicle("m1a2_abrams").cls == "tank"
    with pytest.raises(ValueError, match="Unknown catalog vehicle 'tiger'.*t_72"):
        load_catalog_vehicle("tiger")


def test_spec_gun_validation():
    btr = SPECS["btr_80"]
    turret = dataclasses.replace(btr.turret, gun=dataclasses.replace(btr.turret.gun, length=None))
    with pytest.raises(ValueError, match="btr_80: a wheeled vehicle has no gun_length to reach; give turret.gun.length"):
        dataclasses.replace(btr, turret=turret)
    with pytest.raises(ValueError, match="m113: gun_length 6.0 needs a turret with a gun; there is none"):
        dataclasses.replace(SPECS["m113"], turret=None, gun_length=6.0)
    with pytest.raises(ValueError, match="t_72: give exactly one of gun_length and turret.gun.length"):
        dataclasses.replace(SPECS["t_72"], gun_length=None)
    for name in ("btr_80", "toyota_camry"):
        with pytest.raises(ValueError, match=rf"{name}: wheels \(track 3\.0, tyre"):
            dataclasses.replace(SPECS[name], track=3.0)


@pytest.mark.parametrize("size", ["scale: null", "length: null", "length: null, scale: null", "length: ~"])
def test_a_catalog_entry_with_a_null_length_or_scale_has_no_size(tmp_path, size):
    """A null ``length`` or ``scale`` does not size the vehicle: the manifest reader refuses the entry
    (naming it), as it does one with neither key, instead of passing on an entry with no size at all."""
    from torch_atr.vehicles.catalog import read_catalog_manifest

    (tmp_path / "catalog.yaml").write_text("vehicles:\n  - {file: a.obj, class: car, scale: 1}\n"
                                           f"  - {{file: b.obj, class: car, {size}}}\n")
    with pytest.raises(ValueError, match=r"catalog.yaml: vehicles\[1\] \(b.obj\): give exactly one of 'length'"):
        read_catalog_manifest(tmp_path)
    (tmp_path / "catalog.yaml").write_text("vehicles:\n  - {file: a.obj, class: car, scale: 1}\n"
                                           "  - {file: b.obj, class: car, length: 4.5, scale: null}\n")
    assert read_catalog_manifest(tmp_path)[1].length == 4.5


def test_a_repeated_catalog_name_names_both_entries(tmp_path):
    """Like every manifest error, a repeated name names the entries (index and file) that share it."""
    from torch_atr.vehicles.catalog import read_catalog_manifest

    (tmp_path / "catalog.yaml").write_text("vehicles:\n  - {file: a.obj, class: car, scale: 1}\n"
                                           "  - {file: b.obj, class: car, scale: 1}\n"
                                           "  - {file: sub/a.obj, class: suv, scale: 1}\n")
    with pytest.raises(ValueError, match=r"catalog.yaml: vehicles\[2\] \(sub/a.obj\): vehicle names must be unique "
                                         r"\(set 'name'\); 'a' is vehicles\[0\] \(a.obj\)'s too$"):
        read_catalog_manifest(tmp_path)
