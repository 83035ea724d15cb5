"""benchmarks/running_gear.py and the cited Chrono running gear (benchmarks/chrono_running_gear.yaml).

References: a wheel's centre after the manifest transform against the closed-form rotation of
METHOD.md's body frame (up = file y, forward = file -z: body (x, y, z) = (-z_f, -x_f, y_f)) and the
centring worked out by hand; a track band's volume against the closed-form area of a stadium of two
regular polygons; the cited data against physical consistency it must have whatever the body
(every tyre of a vehicle on one ground plane, that plane below the body, wheels within the body's
length, left and right mirrored)."""

import importlib
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from torch_atr.config import ConfigError
from torch_atr.vehicles.catalog import HeldoutEntry, default_meshes_root, read_manifest
from torch_atr.vehicles.loader import read_mesh

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
CHRONO_GEAR = BENCHMARKS / "chrono_running_gear.yaml"
MESHES_ROOT = default_meshes_root()
needs_meshes = pytest.mark.skipif(not MESHES_ROOT.is_dir(), reason=f"no held-out meshes at {MESHES_ROOT}")


def module():
    """``benchmarks/running_gear.py`` (its folder on sys.path while importing, as when the benchmark runs)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(BENCHMARKS))
        return importlib.import_module("running_gear")


def cube_obj(path: Path) -> None:
    """The unit cube [0, 1]^3 as an OBJ file."""
    box = trimesh.creation.box(extents=(1, 1, 1))
    v = box.vertices + 0.5
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in v) + "".join(f"f {a} {b} {c}\n"
                                                                           for a, b, c in box.faces + 1))


def test_wheel_centre_lands_where_the_manifest_transform_puts_it(tmp_path):
    rg = module()
    cube_obj(tmp_path / "body.obj")
    entry = HeldoutEntry("body.obj", "car", "y", "-z", 1.0, "test")
    centre, radius, width = (0.5, 3.0, -2.0), 0.3, 0.4
    gear = rg.RunningGear((rg.Wheel(centre, radius, width),), ())
    mesh = rg.load_with_running_gear(tmp_path, entry, gear, min_thickness=0.05).mesh
    # By hand: body (x, y, z) = (-z_f, -x_f, y_f). The cube goes to [-1, 0] x [-1, 0] x [0, 1]; the wheel
    # (file x in [0.2, 0.8], y in [2.8, 3.2], z in [-2.3, -1.7]) to x in [1.7, 2.3], y in [-0.8, -0.2],
    # z in [2.8, 3.2]. Centring: x by -(−1 + 2.3) / 2 = -0.65, y by +0.5, z by 0 (the cube's floor).
    # So the wheel centre (2.0, -0.5, 3.0) lands at (1.35, 0.0, 3.0), the cube at x <= -0.65.
    wheel = mesh.vertices[mesh.vertices[:, 0] > 0.0]
    np.testing.assert_allclose((wheel.min(axis=0) + wheel.max(axis=0)) / 2, (1.35, 0.0, 3.0), atol=1e-9)
    np.testing.assert_allclose(wheel.max(axis=0) - wheel.min(axis=0), (2 * radius, 2 * radius, width), atol=1e-9)
    cube = mesh.vertices[mesh.vertices[:, 0] <= 0.0]
    np.testing.assert_allclose(cube.min(axis=0), (-1.65, -0.5, 0.0), atol=1e-9)
    np.testing.assert_allclose(cube.max(axis=0), (-0.65, 0.5, 1.0), atol=1e-9)


def test_track_band_is_the_hull_of_its_circles():
    rg = module()
    r, d, width, n = 0.3, 2.0, 0.38, rg.SECTIONS
    v, f = rg.track_part(rg.Track(1.0, width, ((0.0, -0.2, r), (-d, -0.2, r))))
    # A regular n-gon of circumradius r (n a multiple of 4: corners at its top and bottom) is (n / 2) r^2 sin(2 pi / n);
    # the hull of two of them d apart adds the 2 r x d rectangle between them.
    area = n / 2 * r**2 * math.sin(2 * math.pi / n) + 2 * r * d
    assert trimesh.Trimesh(v, f).volume == pytest.approx(area * width, rel=1e-9)
    np.testing.assert_allclose(v.min(axis=0), (-d - r, 1.0 - width / 2, -0.2 - r), atol=1e-12)
    np.testing.assert_allclose(v.max(axis=0), (r, 1.0 + width / 2, -0.2 + r), atol=1e-12)


def chrono_gear():
    return module().read_running_gear(CHRONO_GEAR, read_manifest())


def test_chrono_gear_names_the_eight_bodies_at_scale_one():
    gear = chrono_gear()
    scales = {e.path: e.scale for e in read_manifest()}
    assert sorted(gear) == sorted([
        "apc/chrono_M113_chassis.obj", "sedan/chrono_audi_chassis.obj", "sedan/chrono_sedan_chassis_vis.obj",
        "suv/chrono_gclass_gd250_chassis.obj", "suv/chrono_jeep_cherokee.obj", "suv/chrono_nissan_patrol_chassis.obj",
        "van/chrono_uaz_bus_chassis.obj", "van/chrono_vw_microbus_chassis.obj"])
    assert all(scales[p] == 1.0 for p in gear)


def ground(gear) -> list[float]:
    """z of the lowest point of each wheel and of each track band."""
    return [w.centre[2] - w.radius for w in gear.wheels] + [min(z - r for _, z, r in t.circles) for t in gear.tracks]


def test_chrono_tyres_of_a_vehicle_stand_on_one_ground_plane():
    for path, gear in chrono_gear().items():
        if gear.tracks:  # tracked: the two bands on one plane, each on at least 3 road wheels there
            lows = [min(z - r for _, z, r in t.circles) for t in gear.tracks]
            assert max(lows) - min(lows) < 0.01, path
            for t in gear.tracks:
                assert sum(z - r < min(lows) + 0.05 for _, z, r in t.circles) >= 3, path
        else:  # wheeled: every tyre's bottom within a few cm (Chrono's design positions, unloaded tyres)
            bottoms = [w.centre[2] - w.radius for w in gear.wheels]
            assert len(bottoms) == 4 and max(bottoms) - min(bottoms) < 0.05, (path, bottoms)


def test_chrono_wheeled_vehicles_are_mirror_symmetric():
    for path, gear in chrono_gear().items():
        if not gear.tracks:
            wheels = {(w.centre, w.radius, w.width) for w in gear.wheels}
            assert {((x, -y, z), r, wd) for (x, y, z), r, wd in wheels} == wheels, path


@needs_meshes
def test_chrono_running_gear_sits_under_its_body():
    for path, gear in chrono_gear().items():
        body = read_mesh(MESHES_ROOT / path).vertices  # the file frame, as the gear is given
        assert max(ground(gear)) < body[:, 2].min(), path  # the ground is below the whole body
        xs = [w.centre[0] for w in gear.wheels]
        assert body[:, 0].min() < min(xs) and max(xs) < body[:, 0].max(), path  # wheels within its length
        ys = [abs(w.centre[1]) for w in gear.wheels]
        assert max(ys) < np.abs(body[:, 1]).max(), path  # wheel centres within its width


@pytest.mark.parametrize("text, key, message", [
    ("[]", "", "expected a mapping with the single key 'bodies'"),
    ("bodies: {nope.obj: {wheels: [], tracks: []}}", "bodies.nope.obj", "not a path of the held-out manifest"),
    ("bodies: {a.obj: {wheels: []}}", "bodies.a.obj", "expected exactly the keys ['tracks', 'wheels']"),
    ("bodies: {a.obj: {wheels: [], tracks: []}}", "bodies.a.obj", "no wheels and no tracks"),
    ("bodies: {a.obj: {wheels: {}, tracks: []}}", "bodies.a.obj.wheels", "expected a list"),
    ("bodies: {a.obj: {wheels: [{centre: [0, 1], radius: 0.3, width: 0.2}], tracks: []}}",
     "bodies.a.obj.wheels[0].centre", "expected a list of 3 numbers"),
    ("bodies: {a.obj: {wheels: [{centre: [0, 1, 0], radius: -0.3, width: 0.2}], tracks: []}}",
     "bodies.a.obj.wheels[0].radius", "expected a finite number in (0, 100]; got -0.3"),
    ("bodies: {a.obj: {wheels: [{centre: [0, 1, 0], radius: 0.3}], tracks: []}}",
     "bodies.a.obj.wheels[0]", "expected a mapping with exactly the keys ['centre', 'radius', 'width']"),
    ("bodies: {a.obj: {wheels: [], tracks: [{y: 1, width: 0.4, circles: [[0, 0, 0.3]]}]}}",
     "bodies.a.obj.tracks[0].circles", "a track runs round at least 2 circles"),
    ("bodies: {a.obj: {wheels: [], tracks: [{y: 1, width: 0.4, circles: [[0, 0, 0.3], [1, 0, 0]]}]}}",
     "bodies.a.obj.tracks[0].circles[1][2] (radius)", "expected a finite number in (0, 100]; got 0"),
    ("bodies: {a.obj: {wheels: [], tracks: [{y: .nan, width: 0.4, circles: [[0, 0, 0.3], [1, 0, 0.3]]}]}}",
     "bodies.a.obj.tracks[0].y", "expected a finite number"),
    ("bodies: {b.obj: {wheels: [{centre: [0, 1, 0], radius: 0.3, width: 0.2}], tracks: []}}",
     "bodies.b.obj", "the manifest scales this mesh by 0.01"),
    ("bodies: {a.obj: {wheels: [{centre: [0, 1, 0], radius: 1.0e+300, width: 0.2}], tracks: []}}",
     "bodies.a.obj.wheels[0].radius", "expected a finite number in (0, 100]; got 1e+300"),
    ("bodies: {a.obj: {wheels: [{centre: [0, -1.0e+200, 0], radius: 0.3, width: 0.2}], tracks: []}}",
     "bodies.a.obj.wheels[0].centre[1]", "expected a finite number in [-100, 100]; got -1e+200"),
    ("bodies: {a.obj: {wheels: [], tracks: [{y: 1, width: 0.4, circles: [[0, 0, 0.3], [1.0e+300, 0, 0.3]]}]}}",
     "bodies.a.obj.tracks[0].circles[1][0]", "expected a finite number in [-100, 100]"),
])
def test_bad_running_gear_is_refused_naming_file_and_key(tmp_path, text, key, message):
    rg = module()
    path = tmp_path / "gear.yaml"
    path.write_text(text)
    entries = [HeldoutEntry("a.obj", "car", "z", "x", 1.0, ""), HeldoutEntry("b.obj", "car", "z", "x", 0.01, "")]
    with pytest.raises(ConfigError) as info:
        rg.read_running_gear(path, entries)
    assert str(info.value).startswith(f"{path}: {key}".rstrip(": ")), str(info.value)
    assert message in str(info.value), str(info.value)


def test_a_vehicle_too_big_with_its_running_gear_names_the_mesh(tmp_path):
    """A wheel of radius 0.5 m centred 99.8 m ahead of the unit cube's back makes a vehicle 100.3 m long, over the
    loader's 100 m. The loader's message named the temporary OBJ (gone by the time it is read), not the mesh."""
    rg = module()
    cube_obj(tmp_path / "body.obj")
    entry = HeldoutEntry("body.obj", "car", "z", "x", 1.0, "test")
    gear = rg.RunningGear((rg.Wheel((99.8, 0.5, 0.5), 0.5, 0.4),), ())
    with pytest.raises(ValueError) as info:
        rg.load_with_running_gear(tmp_path, entry, gear, min_thickness=0.05)
    message = str(info.value)
    assert message.startswith(f"{tmp_path / 'body.obj'} with its running gear: 100 × 1 × 1 m"), message
    assert "too big for a vehicle" in message


def test_missing_running_gear_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match="--running-gear .*nope.yaml: no such file"):
        module().read_running_gear(tmp_path / "nope.yaml", [])
