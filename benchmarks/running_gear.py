"""Running gear for held-out vehicle bodies that have none: wheels and track bands added in a mesh file's own frame.

Eight held-out meshes are Project Chrono vehicle bodies without wheels or tracks; a body sits
0.3-0.45 m lower than the vehicle. ``python benchmarks/bench_heldout.py --running-gear FILE``
measures them as vehicles instead: the running gear that ``FILE`` gives for a manifest entry is
added to that entry's mesh in the file's own frame, before the manifest's up / forward / scale
transform, and the result goes through :func:`torch_atr.vehicles.loader.vehicle_from_mesh` as the bare mesh
does (trimming of thin protrusions, centring). ``benchmarks/chrono_running_gear.yaml`` holds
Chrono's own numbers for the eight, each cited there.

File format (YAML; lengths in metres in the file frame, so only entries of scale 1 take running gear)::

    bodies:
      <manifest path>:
        wheels:   # cylinders about the file's y axis
          - {centre: [x, y, z], radius: r, width: w}
        tracks:   # bands across y round the convex hull, in the x-z plane, of circles (x, z, radius)
          - {y: y, width: w, circles: [[x, z, r], ...]}
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from torch_atr.config import ConfigError, read_yaml
from torch_atr.validate import InputError, real, show, vector
from torch_atr.vehicles.catalog import HeldoutEntry
from torch_atr.vehicles.geometry import Part, ellipse, prism_xz
from torch_atr.vehicles.loader import MAX_EXTENT_M, Vehicle, read_mesh, vehicle_from_mesh

SECTIONS = 32  # polygon corners of a wheel or of a circle round which a track runs (a multiple of 4: the
# polygon reaches the circle's top, bottom, front and back)


@dataclass(frozen=True)
class Wheel:
    """A cylinder about the file's y axis: centre (3,), radius and width, file units."""

    centre: tuple[float, float, float]
    radius: float
    width: float


@dataclass(frozen=True)
class Track:
    """A band ``width`` wide centred at ``y``, round the convex hull of ``circles`` ((x, z, radius), x-z plane)."""

    y: float
    width: float
    circles: tuple[tuple[float, float, float], ...]


@dataclass(frozen=True)
class RunningGear:
    """The wheels and track bands added to one body."""

    wheels: tuple[Wheel, ...]
    tracks: tuple[Track, ...]


def read_running_gear(path: str | Path, entries: list[HeldoutEntry]) -> dict[str, RunningGear]:
    """Manifest path -> running gear, from a YAML file (module docstring); ConfigError naming the file and key.

    Every body must be a manifest entry of ``entries`` with scale 1 (the file's lengths are metres in
    the mesh's frame) and must get at least one wheel or track.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"--running-gear {path}: no such file")
    data = read_yaml(path)
    if not isinstance(data, dict) or set(data) != {"bodies"} or not isinstance(data["bodies"], dict):
        raise ConfigError(f"{path}: expected a mapping with the single key 'bodies' holding a mapping "
                          f"(manifest path -> running gear)")
    scales = {e.path: e.scale for e in entries}
    out = {}
    for body, gear in data["bodies"].items():
        where = f"{path}: bodies.{body}"
        if body not in scales:
            raise ConfigError(f"{where}: not a path of the held-out manifest")
        if scales[body] != 1.0:
            raise ConfigError(f"{where}: the manifest scales this mesh by {scales[body]:g}; running gear is given "
                              f"in metres in the mesh's frame, so only a mesh of scale 1 takes it")
        if not isinstance(gear, dict) or set(gear) != {"wheels", "tracks"}:
            got = sorted(gear) if isinstance(gear, dict) else show(gear)
            raise ConfigError(f"{where}: expected exactly the keys ['tracks', 'wheels']; got {got}")
        try:
            wheels = _items(f"{where}.wheels", gear["wheels"])
            tracks = _items(f"{where}.tracks", gear["tracks"])
            wheels = tuple(_wheel(f"{where}.wheels[{i}]", w) for i, w in enumerate(wheels))
            tracks = tuple(_track(f"{where}.tracks[{i}]", t) for i, t in enumerate(tracks))
        except InputError as exc:
            raise ConfigError(str(exc)) from None
        if not wheels and not tracks:
            raise ConfigError(f"{where}: no wheels and no tracks: nothing to add")
        out[str(body)] = RunningGear(wheels, tracks)
    return out


def _items(where: str, value: Any) -> list:
    """``value`` if it is a list; InputError starting with ``where`` otherwise."""
    if not isinstance(value, list):
        raise InputError(f"{where}: expected a list; got {show(value)}")
    return value


def _keys(where: str, value: Any, keys: set[str]) -> dict:
    """``value`` if it is a mapping with exactly ``keys``; InputError starting with ``where`` otherwise."""
    if not isinstance(value, dict) or set(value) != keys:
        got = sorted(value) if isinstance(value, dict) else show(value)
        raise InputError(f"{where}: expected a mapping with exactly the keys {sorted(keys)}; got {got}")
    return value


def _length(where: str, value: Any, positive: bool = False) -> float:
    """A coordinate within ±MAX_EXTENT_M, or a size in (0, MAX_EXTENT_M] when ``positive``; InputError naming
    ``where`` otherwise (a larger one made a vehicle the loader refuses, naming only a temporary file, or
    overflowed the prism's volume)."""
    return real(where, value, lo=0 if positive else -MAX_EXTENT_M, hi=MAX_EXTENT_M, lo_open=positive)


def _wheel(where: str, value: Any) -> Wheel:
    w = _keys(where, value, {"centre", "radius", "width"})
    centre = tuple(_length(f"{where}.centre[{i}]", x) for i, x in enumerate(vector(f"{where}.centre", w["centre"], 3)))
    radius = _length(f"{where}.radius", w["radius"], positive=True)
    return Wheel(centre, radius, _length(f"{where}.width", w["width"], positive=True))


def _track(where: str, value: Any) -> Track:
    t = _keys(where, value, {"y", "width", "circles"})
    circles = _items(f"{where}.circles", t["circles"])
    if len(circles) < 2:
        raise InputError(f"{where}.circles: a track runs round at least 2 circles; got {len(circles)}")
    parsed = []
    for i, c in enumerate(circles):
        x, z, r = vector(f"{where}.circles[{i}]", c, 3)
        parsed.append((_length(f"{where}.circles[{i}][0]", x), _length(f"{where}.circles[{i}][1]", z),
                       _length(f"{where}.circles[{i}][2] (radius)", r, positive=True)))
    return Track(_length(f"{where}.y", t["y"]), _length(f"{where}.width", t["width"], positive=True), tuple(parsed))


def wheel_part(wheel: Wheel) -> Part:
    """A closed cylinder of ``SECTIONS`` sides about the y axis: vertices (2 * SECTIONS, 3), faces."""
    x, y, z = wheel.centre
    return prism_xz(ellipse(x, z, wheel.radius, wheel.radius, SECTIONS), wheel.width / 2, y0=y)


def track_part(track: Track) -> Part:
    """The band of a track: the convex hull (x-z plane) of its circles' ``SECTIONS``-gons, extruded across y."""
    points = np.concatenate([ellipse(x, z, r, r, SECTIONS) for x, z, r in track.circles])  # (n * SECTIONS, 2)
    hull = points[ConvexHull(points).vertices]  # counter-clockwise
    return prism_xz(hull, track.width / 2, y0=track.y)


def gear_mesh(gear: RunningGear) -> trimesh.Trimesh:
    """Every wheel and track band of ``gear`` as one mesh, in the file frame."""
    parts = [wheel_part(w) for w in gear.wheels] + [track_part(t) for t in gear.tracks]
    return trimesh.util.concatenate([trimesh.Trimesh(v, f, process=False) for v, f in parts])


def load_with_running_gear(root: str | Path, entry: HeldoutEntry, gear: RunningGear, min_thickness: float) -> Vehicle:
    """``entry``'s mesh with ``gear`` added in the file frame, loaded as :func:`load_vehicle` loads a mesh file:
    the body read as the loader reads it, the running gear appended, and the union turned, scaled,
    trimmed and centred with the entry's up, forward and scale (``vehicle_from_mesh``)."""
    source = Path(root) / entry.path
    body = read_mesh(source)
    gear_part = gear_mesh(gear)
    union = trimesh.Trimesh(np.concatenate([body.vertices, gear_part.vertices]),
                            np.concatenate([body.faces, gear_part.faces + len(body.vertices)]), process=False)
    return vehicle_from_mesh(union, f"{source} with its running gear", up_axis=entry.up, forward_axis=entry.forward,
                             scale=entry.scale, cls=entry.cls, name=source.stem, min_thickness=min_thickness)
