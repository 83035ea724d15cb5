"""Load one vehicle (URDF or any mesh file trimesh reads) into the body frame of METHOD.md.

Body frame: +X forward, +Y left, +Z up, metres; origin at the centre of the footprint on the
ground (x/y centre of the bounding box, z = 0 at the lowest point).

Thin protrusions. A plain mesh file is trimmed to the part of it that is at least
``min_thickness`` (5 cm) across (:func:`thick_bounds`): a whip antenna, a wire, a pole or a
stray sliver of a triangle sticking out of the vehicle is cut off where it leaves the body. Such parts are far thinner
than a template pixel (0.19 m) and than a camera pixel at the tracker's ranges (0.1 m at
1000 m), so they add nothing to a silhouette, but a 1.7 m antenna on a 1.5 m body would raise
the centre of the bounding box, on which every template window is centred, by 0.8 m (4 px).
A URDF is taken as written (its parts are meant, and a turned turret must not be clipped).

URDF: links carry box / cylinder / sphere / mesh visuals (``<origin xyz rpy>``); joints
(revolute, continuous, prismatic, fixed) are posed with pytorch-kinematics' forward kinematics.
Joint limits follow the URDF specification: revolute and prismatic joints need a ``<limit>``
whose missing ``lower`` / ``upper`` are 0; continuous joints are unbounded.
Two measured pitfalls of ``pk.build_chain_from_urdf`` are handled here: it raises on a valid
URDF with a single link and no joint (the lone link's visuals are used directly), and it
requires ``effort`` and ``velocity`` on every ``<limit>`` (missing ones are filled with 0).
It also keeps only the *first* visual of each link, so visuals are read from the XML here and
pytorch-kinematics only supplies the link poses.
"""

from __future__ import annotations

import dataclasses
import io
import logging
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Mapping
from urllib.parse import unquote

import numpy as np
import pytorch_kinematics as pk
import torch
import trimesh

from torch_atr.validate import MAX_MESH_BYTES, real
from torch_atr.vehicles.geometry import check_mesh

log = logging.getLogger(__name__)

CLASS_NAMES = ("tank", "apc", "pickup", "suv", "car", "minivan")
UNKNOWN = "unknown"  # class of a held-out vehicle outside CLASS_NAMES

_AXES = {
    "x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0),
    "-x": (-1.0, 0.0, 0.0), "-y": (0.0, -1.0, 0.0), "-z": (0.0, 0.0, -1.0),
}
_CYLINDER_SECTIONS = 16
MIN_THICKNESS_M = 0.05  # load_vehicle's default: thinner protrusions are trimmed from mesh files
_SLAB_M = 0.01  # slab thickness of thick_bounds
_PAIRS_PER_CHUNK = 1 << 20  # (face, slab) pairs thick_bounds holds at once (~50 MB)
MAX_EXTENT_M = 100.0  # a vehicle larger along any axis is mis-scaled (centimetres or millimetres read as metres)
MIN_EXTENT_M = 0.5  # a vehicle shorter along its longest axis is mis-scaled (metres read as centimetres)
_TEXT_MESHES = (".obj", ".off")  # text formats decoded here (_mesh_text), not by trimesh


def body_rotation(up_axis: str, forward_axis: str) -> np.ndarray:
    """Rotation (3, 3) taking file coordinates to the body frame.

    ``up_axis`` / ``forward_axis`` name the file axes ("x", "y", "z", "-x", "-y", "-z") that
    point up and forward; the body's +Y (left) is up × forward, so the map is a proper rotation.
    """
    for what, axis in (("up", up_axis), ("forward", forward_axis)):  # a manifest's keys are up and forward
        if axis not in _AXES:
            raise ValueError(f"the {what} axis must be one of {sorted(_AXES)}; got {axis!r}")
    up = np.array(_AXES[up_axis])
    fwd = np.array(_AXES[forward_axis])
    if abs(float(up @ fwd)) > 0.5:
        raise ValueError(f"the up axis {up_axis!r} and the forward axis {forward_axis!r} must be perpendicular")
    return np.stack([fwd, np.cross(up, fwd), up])  # rows: body X, Y, Z in file coordinates


@dataclass(frozen=True, eq=False)
class _Rig:
    """What a URDF vehicle needs to be re-posed: link-frame geometry, chain, body transform."""

    chain: pk.Chain | None  # None for a single link without joints
    root: str
    joint_names: tuple[str, ...]
    limits: Mapping[str, tuple[float, float]]
    parts: tuple[tuple[str, np.ndarray, np.ndarray], ...]  # (link, vertices (M, 3), faces (F, 3))
    rotation: np.ndarray  # (3, 3) file -> body, times scale
    offset: np.ndarray  # (3,) added after rotation: centres the rest pose

    def link_poses(self, values: Mapping[str, float]) -> dict[str, np.ndarray]:
        """Link name -> (4, 4) pose in the URDF root frame for joint ``values``."""
        if self.chain is None:
            return {self.root: np.eye(4)}
        th = torch.tensor([values[n] for n in self.chain.get_joint_parameter_names()], dtype=torch.float64)
        return {k: t.get_matrix()[0].numpy() for k, t in self.chain.forward_kinematics(th).items()}

    def file_vertices(self, values: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """All parts posed in the URDF root frame: vertices (M, 3), faces (F, 3)."""
        poses = self.link_poses(values)
        verts, faces, base = [], [], 0
        for link, v, f in self.parts:
            pose = poses[link]
            verts.append(v @ pose[:3, :3].T + pose[:3, 3])
            faces.append(f + base)
            base += len(v)
        return np.concatenate(verts), np.concatenate(faces)

    def mesh(self, values: Mapping[str, float]) -> trimesh.Trimesh:
        v, f = self.file_vertices(values)
        return trimesh.Trimesh(v @ self.rotation.T + self.offset, f, process=False)


@dataclass(frozen=True, eq=False)
class Vehicle:
    """A vehicle in the body frame (+X forward, +Y left, +Z up, metres, origin on the ground).

    ``name``, ``cls`` and ``mesh`` are what other modules use. ``joints`` holds the current
    joint values (radians / metres) of a URDF vehicle; :meth:`posed` re-poses it.
    """

    name: str
    cls: str
    mesh: trimesh.Trimesh
    source: Path
    joints: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))
    _rig: _Rig | None = field(default=None, repr=False)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Movable joints (kinematic-chain order); empty for a plain mesh or a rigid URDF."""
        return self._rig.joint_names if self._rig is not None else ()

    def posed(self, joints: Mapping[str, float]) -> Vehicle:
        """A new Vehicle with the given joints set (others keep their current values).

        The body-frame offset stays the one of the rest pose (every joint at 0, clipped into
        its limits), so the hull does not move when the turret turns.
        """
        if not joints:
            return self
        if self._rig is None:
            raise ValueError(f"{self.name} ({self.source}) has no joints; got {sorted(joints)}")
        values = dict(self.joints)
        values.update(_check_joints(self._rig, joints, self.source))
        return Vehicle(self.name, self.cls, self._rig.mesh(values), self.source, MappingProxyType(values), self._rig)


def _check_joints(rig: _Rig, joints: Mapping[str, float], source: Path) -> dict[str, float]:
    out = {}
    for k, v in joints.items():
        if k not in rig.limits:
            raise ValueError(f"{source}: unknown joint {k!r}; joints are {list(rig.joint_names)}")
        v = float(v)
        lo, hi = rig.limits[k]
        if not (math.isfinite(v) and lo - 1e-9 <= v <= hi + 1e-9):
            raise ValueError(f"{source}: joint {k!r} = {v} is outside its limits [{lo}, {hi}]")
        out[k] = v
    return out


def load_vehicle(
    path: str | Path,
    joints: Mapping[str, float] | None = None,
    *,
    up_axis: str = "z",
    forward_axis: str = "x",
    scale: float = 1.0,
    cls: str | None = None,
    name: str | None = None,
    min_thickness: float = MIN_THICKNESS_M,
) -> Vehicle:
    """Load a URDF or a mesh file (OBJ, GLB, STL, ...) as a :class:`Vehicle` in the body frame.

    Args:
        path: ``.urdf`` file, or any mesh file ``trimesh.load(p, force="mesh")`` reads.
        joints: joint values for a URDF (unset joints stay at their rest value 0, clipped into
            their limits); must be empty for a mesh file.
        up_axis, forward_axis: the file axes pointing up / forward ("x", "y", "z", "-x", ...).
        scale: file units -> metres.
        cls: one of CLASS_NAMES or "unknown" (the default when None).
        name: defaults to the file stem.
        min_thickness: a mesh file is cut down to :func:`thick_bounds` with this thickness,
            metres (module docstring); 0 keeps every part. Ignored for a URDF.

    A URDF ``<mesh filename>`` is read as a path relative to the URDF's folder (or absolute,
    with or without ``file://``); a ``file://`` or ``package://`` URI is percent-decoded
    (``%20`` is a space), a plain path is taken as written. ``package://pkg/rest`` has no ROS
    package index to consult:
    ``rest`` is looked up beside the URDF first, then one folder up (the ROS layout
    ``pkg/urdf/x.urdf`` with meshes under ``pkg/meshes/``).

    Raises:
        FileNotFoundError: the file, or a mesh a URDF references, is missing (message names it).
        ValueError: broken XML, two links or joints of one name, joints that do not form a tree (a cycle, a
            link with two parent joints), a missing or non-positive geometry size, unreadable or empty
            mesh, a mesh file over ``validate.MAX_MESH_BYTES`` (256 MiB), unknown class, bad axes, joints
            or joint limits, a size above ``MAX_EXTENT_M`` (100 m) along an axis once scaled (checked
            before any trimming), below ``MIN_EXTENT_M`` (0.5 m) along the longest or of zero along any,
            a scale or min_thickness that is not a number, an empty name.
    """
    path = Path(path)
    _check_class(path, cls)
    if path.is_dir():
        raise ValueError(f"{path}: is a folder; expected a URDF or mesh file")
    if not path.is_file():
        raise FileNotFoundError(f"vehicle file not found: {path}")
    cls, name, scale, min_thickness, rotation = _vehicle_args(path, cls, name, scale, min_thickness, up_axis,
                                                              forward_axis)
    if path.suffix.lower() == ".urdf":
        rig = _load_urdf(path, rotation)
        values = _rest_pose(rig.limits)
        values.update(_check_joints(rig, joints or {}, path))
        mesh = rig.mesh(values)
        _check_size(path, mesh.vertices, scale)
        return Vehicle(name, cls, mesh, path, MappingProxyType(values), rig)
    if joints:
        raise ValueError(f"{path} is a plain mesh and has no joints; got {sorted(joints)}")
    return _mesh_vehicle(read_mesh(path), path, cls, name, scale, min_thickness, rotation)


def vehicle_from_mesh(
    mesh: trimesh.Trimesh,
    path: str | Path,
    *,
    up_axis: str = "z",
    forward_axis: str = "x",
    scale: float = 1.0,
    cls: str | None = None,
    name: str | None = None,
    min_thickness: float = MIN_THICKNESS_M,
) -> Vehicle:
    """A mesh in a file's own frame and units (as :func:`read_mesh` gives it, perhaps with parts added)
    as a :class:`Vehicle`, exactly as :func:`load_vehicle` loads a mesh file: turned, scaled, trimmed and
    centred. ``path`` names it (in errors, and as the Vehicle's file); it is not read. Arguments and
    errors as :func:`load_vehicle`'s."""
    path = Path(path)
    _check_class(path, cls)
    args = _vehicle_args(path, cls, name, scale, min_thickness, up_axis, forward_axis)
    if not isinstance(mesh, trimesh.Trimesh):  # a Scene: trimesh.load(..., force="mesh") or scene.dump(concatenate=True)
        raise ValueError(f"{path}: expected a trimesh.Trimesh (one mesh); got {type(mesh).__name__}")
    return _mesh_vehicle(_check_mesh(mesh, f"the mesh of {path}").copy(), path, *args)


def _check_class(path: Path, cls: str | None) -> None:
    """ValueError naming the file unless ``cls`` is one of CLASS_NAMES, "unknown" or None."""
    if cls is not None and cls not in CLASS_NAMES + (UNKNOWN,):
        raise ValueError(f"{path}: unknown vehicle class {cls!r}; expected one of {CLASS_NAMES + (UNKNOWN,)}")


def _vehicle_args(path: Path, cls: str | None, name: str | None, scale, min_thickness, up_axis: str,
                  forward_axis: str) -> tuple[str, str, float, float, np.ndarray]:
    """:func:`load_vehicle`'s arguments checked, each error naming the file, and their defaults filled in:
    (cls, name, scale, min_thickness, the file-to-body rotation times the scale)."""
    scale = real(f"{path}: scale", scale, lo=0, lo_open=True)
    min_thickness = real(f"{path}: min_thickness", min_thickness, lo=0)
    if name is not None and not (isinstance(name, str) and name.strip()):
        raise ValueError(f"{path}: name must be a non-empty string (None: the file's stem); got {name!r}")
    rotation = _file_rotation(path, up_axis, forward_axis) * scale
    return UNKNOWN if cls is None else cls, path.stem if name is None else name, scale, min_thickness, rotation


def _mesh_vehicle(mesh: trimesh.Trimesh, path: Path, cls: str, name: str, scale: float, min_thickness: float,
                  rotation: np.ndarray) -> Vehicle:
    """The Vehicle of a mesh in its file's frame and units (modified in place), its arguments checked."""
    _check_size(path, mesh.vertices[np.unique(mesh.faces)] @ rotation.T, scale)  # before thick_bounds (its cost
    # grows with the extent) and before merging: trimesh merges vertices on a 1e-8 grid held as int64, so it merges
    # in metres, not file units (coordinates beyond ±9e10 overflowed the grid and every vertex became one)
    transform = np.eye(4)
    transform[:3, :3] = rotation
    mesh = mesh.apply_transform(transform).process()
    v, faces = mesh.vertices, np.asarray(mesh.faces)
    if min_thickness > 0:
        v, faces = _clip_to_box(v, faces, thick_bounds(v, faces, min_thickness))
    v = v + _centring_offset(v)
    return Vehicle(name, cls, trimesh.Trimesh(v, faces, process=False), path)


def forward_extent(path: str | Path, *, up_axis: str = "z", forward_axis: str = "x") -> float:
    """A vehicle file's extent along ``forward_axis``, file units, untrimmed (a URDF in its rest pose).

    :func:`load_vehicle` with ``scale = L / forward_extent(...)`` makes the vehicle L metres long
    (less any thin protrusion at its front, which is trimmed in metres). ValueError naming the file
    and the extent for one no such scale can be computed from: zero, beyond float64 (coordinates near
    ±1e308), or so small (denormal, 1e-320) that a length up to ``MAX_EXTENT_M`` over it is infinite.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"vehicle file not found: {path}")
    rotation = _file_rotation(path, up_axis, forward_axis)
    if path.suffix.lower() == ".urdf":
        rig = _load_urdf(path, rotation)
        forward = rig.mesh(_rest_pose(rig.limits)).vertices[:, 0]
    else:
        mesh = read_mesh(path)
        forward = mesh.vertices[np.unique(mesh.faces)] @ rotation[0]  # a vertex no face uses is no part of it
    with np.errstate(over="ignore"):  # an overflow is the inf refused below
        extent = float(np.ptp(forward))
    if not (extent > 0 and math.isfinite(extent) and math.isfinite(MAX_EXTENT_M / extent)):
        raise ValueError(f"{path}: the extent along the forward axis {forward_axis!r} is {extent:g} file units, "
                         f"unusable for a length in metres (length / extent must be a finite scale > 0); expected a "
                         f"finite extent of at least {MAX_EXTENT_M / np.finfo(np.float64).max:.3g}")
    return extent


def thick_bounds(vertices: np.ndarray, faces: np.ndarray, min_thickness: float, slab: float = _SLAB_M) -> np.ndarray:
    """The bounding box of the part of a mesh that is at least ``min_thickness`` across.

    Along each axis the mesh is cut into slabs ``slab`` thick. A slab is thin when the faces
    crossing it (their bounding boxes, united) span less than ``min_thickness`` along both
    other axes, as a wire does; the box runs from the first thick slab to the last along each
    axis. A whip antenna's slabs above the roof are thin; a gun barrel's and a mirror plate's
    are not (a plate is seen face on from some view). Conservative: two thin parts far apart
    in one slab make it thick.

    Args:
        vertices: (M, 3) float; faces: (F, 3) int; min_thickness, slab: metres.
    Returns:
        (2, 3) [low, high] corners, inside the mesh's bounding box (they may leave up to one
        slab of a trimmed wire); that box itself where an axis has no thick slab.
    """
    check_mesh(vertices, faces, ("vertices", "faces"))
    tri = vertices[faces]  # (F, 3, 3)
    lo, hi = tri.min(axis=1), tri.max(axis=1)  # (F, 3) each
    box = np.stack([vertices.min(axis=0), vertices.max(axis=0)])
    for a in range(3):
        others = [k for k in range(3) if k != a]
        s0 = np.floor((lo[:, a] - box[0, a]) / slab).astype(np.int64)
        count = np.floor((hi[:, a] - box[0, a]) / slab).astype(np.int64) - s0 + 1  # (F,) slabs per face
        slabs = int((s0 + count).max()) if len(faces) else 0
        low, high = np.full((slabs, 2), np.inf), np.full((slabs, 2), -np.inf)  # per slab, along the other axes
        ends = np.cumsum(count)
        start = 0
        while start < len(faces):  # (face, slab) pairs a chunk at a time: a 9 m triangle crosses 900 slabs
            done = ends[start - 1] if start else 0
            stop = max(start + 1, int(np.searchsorted(ends, done + _PAIRS_PER_CHUNK, side="right")))
            n = count[start:stop]
            face = np.repeat(np.arange(start, stop), n)
            index = s0[face] + np.arange(len(face)) - np.repeat(np.cumsum(n) - n, n)  # slab of each pair
            order = np.argsort(index, kind="stable")
            index, face = index[order], face[order]
            starts = np.flatnonzero(np.r_[True, index[1:] != index[:-1]])  # first pair of each occupied slab
            np.minimum.at(low, index[starts], np.minimum.reduceat(lo[face][:, others], starts))
            np.maximum.at(high, index[starts], np.maximum.reduceat(hi[face][:, others], starts))
            start = stop
        thick = np.flatnonzero(((high - low) >= min_thickness).any(axis=1))  # an empty slab spans −inf
        if len(thick):
            origin = box[0, a]
            box[0, a] = origin + thick.min() * slab
            box[1, a] = min(box[1, a], origin + (thick.max() + 1) * slab)
    return box


def _clip_to_box(vertices: np.ndarray, faces: np.ndarray, box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The part of a mesh inside an axis-aligned box (2, 3): faces cut at its planes, no caps."""
    for a in range(3):
        for side, normal in ((0, 1.0), (1, -1.0)):
            n = np.zeros(3)
            n[a] = normal
            if (normal * (vertices[:, a] - box[side, a])).min() < -1e-9:  # something lies beyond the plane
                origin = np.zeros(3)
                origin[a] = box[side, a]
                vertices, faces = trimesh.intersections.slice_faces_plane(vertices, faces, n, origin)[:2]
    if len(faces) == 0:
        raise ValueError("trimming thin protrusions left no faces")
    return vertices, faces


def _file_rotation(path: Path, up_axis: str, forward_axis: str) -> np.ndarray:
    """:func:`body_rotation`, its ValueError naming the file."""
    try:
        return body_rotation(up_axis, forward_axis)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def _check_size(path: Path, vertices: np.ndarray, scale: float) -> None:
    """ValueError naming the file and its size when body-frame ``vertices`` (M, 3), metres, are mis-scaled
    or flat (no size along some axis: a plane or a line casts no vehicle's silhouette)."""
    extents = np.ptp(vertices, axis=0)
    size = " × ".join(f"{e:.3g}" for e in extents)
    if not extents.min() > 0:
        raise ValueError(f"{path}: size {size} m: flat along {'xyz'[int(np.argmin(extents))]} (body frame: x forward, "
                         f"y left, z up); a vehicle has a size along every axis")
    if extents.max() > MAX_EXTENT_M:
        raise ValueError(f"{path}: {size} m at scale {scale:g} is too big for a vehicle (at most {MAX_EXTENT_M:g} m "
                         f"along each axis); check its scale or length (millimetres or centimetres read as metres?)")
    if extents.max() < MIN_EXTENT_M:  # a 4.9 cm car rendered no template pixel, and nothing said why
        raise ValueError(f"{path}: {size} m at scale {scale:g} is too small for a vehicle (at least {MIN_EXTENT_M:g} m "
                         f"along its longest axis); check its scale or length (metres read as centimetres?)")


def _rest_pose(limits: Mapping[str, tuple[float, float]]) -> dict[str, float]:
    """Every joint at 0, clipped into its limits."""
    return {n: min(max(0.0, lo), hi) for n, (lo, hi) in limits.items()}


def _centring_offset(v: np.ndarray) -> np.ndarray:
    """(3,) translation putting the bounding box's x/y centre at 0 and its lowest point at z = 0."""
    lo, hi = v.min(axis=0), v.max(axis=0)
    return np.array([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])


def _mesh_text(path: Path) -> tuple[str, str]:
    """A text mesh file's content, and a note for error messages.

    UTF-8, else Latin-1 (every byte is a Latin-1 character; OBJ and OFF numbers and keywords are
    ASCII in both, so only comments and names can come out garbled), with a warning. trimesh would
    guess the encoding with charset_normalizer, which is not a dependency. The note is "" or says
    the file was read as Latin-1.
    """
    data = path.read_bytes()
    try:
        return data.decode("utf-8"), ""
    except UnicodeDecodeError as exc:
        log.warning("%s is not UTF-8 (byte 0x%02x at byte offset %d); reading it as Latin-1, in which its "
                    "comments and names may come out garbled", path, data[exc.start], exc.start)
        return data.decode("latin-1"), " (not UTF-8 text: read as Latin-1)"


def _obj_absolute_indices(text: str) -> str:
    """OBJ text with its relative face indices made absolute.

    A face's ``-k`` is the k-th ``v`` (``vt``, ``vn``) declared before that face line (OBJ
    specification); trimesh counts it back from the file's last one instead (trimesh issue 2364),
    which tangles the faces of a file that declares vertices after its first relative face
    (objects written one block of ``v`` and ``f -3 -2 -1`` lines after another).
    """
    if not re.search(r"^[ \t]*f[ \t][^\n]*-", text, flags=re.MULTILINE):  # no relative index: nothing to do
        return text
    counts = {"v": 0, "vt": 0, "vn": 0}  # declared so far

    def absolute(kind: str, index: str) -> str:
        return str(counts[kind] + int(index) + 1) if index.startswith("-") and index[1:].isdigit() else index

    lines = text.splitlines(keepends=True)
    for i, line in enumerate(lines):
        words = line.split()
        if words and words[0] in counts:
            counts[words[0]] += 1
        elif words and words[0] == "f":  # corners v, v/vt, v//vn or v/vt/vn
            corners = ["/".join(absolute(kind, n) for kind, n in zip(counts, w.split("/"))) for w in words[1:]]
            lines[i] = " ".join(["f", *corners]) + "\n"
    return "".join(lines)


def read_mesh(path: str | Path) -> trimesh.Trimesh:
    """The mesh a file holds, in the file's own frame and units, as one unprocessed Trimesh (vertices not merged);
    ValueError naming the file when it cannot be read, holds no triangles, a triangle with a vertex
    index out of range, or non-finite vertices. It is read unprocessed: trimesh's processing drops the
    faces of a NaN vertex without a word, and :func:`load_vehicle` merges vertices in metres. OBJ and
    OFF text is decoded by :func:`_mesh_text` (and an OBJ's relative face indices resolved by
    :func:`_obj_absolute_indices`); other text formats (ASCII STL, PLY) trimesh decodes itself,
    guessing a non-UTF-8 encoding only when the optional ``charset_normalizer`` (``chardet`` in
    trimesh 4.0) is installed, and
    refused here (saying so) when it is not."""
    path = Path(path)
    note = ""
    size = path.stat().st_size if path.is_file() else 0
    if size > MAX_MESH_BYTES:  # read whole, as bytes, text and lines: ~15 bytes of memory a byte, before any check
        raise ValueError(f"{path}: {size / 2 ** 20:.0f} MiB is more than a mesh file may have "
                         f"({MAX_MESH_BYTES / 2 ** 20:.0f} MiB; a vehicle's mesh takes a few); decimate it first "
                         f"(trimesh's simplify_quadric_decimation, or Blender's Decimate)")
    try:
        if path.suffix.lower() in _TEXT_MESHES:
            text, note = _mesh_text(path)
            if path.suffix.lower() == ".obj":
                text = _obj_absolute_indices(text)
            mesh = trimesh.load(io.StringIO(text), file_type=path.suffix.lower()[1:], force="mesh", process=False,
                                resolver=trimesh.resolvers.FilePathResolver(path))  # mtllib beside the file
        else:
            mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for unreadable files
        if isinstance(exc, ImportError) and exc.name in ("charset_normalizer", "chardet"):  # trimesh's encoding guess
            raise ValueError(f"could not read mesh {path}: its text is not UTF-8; save it as UTF-8") from exc
        raise ValueError(f"could not read mesh {path}{note}: {exc}") from exc
    return _check_mesh(mesh, f"mesh file {path}", note)


def _check_mesh(mesh, what: str, note: str = "") -> trimesh.Trimesh:
    """``mesh`` if it is a Trimesh with triangles, each indexing vertices it has, all finite; else a
    ValueError that starts with ``what``."""
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{what} holds no triangles{note}")
    outside = int(((mesh.faces < 0) | (mesh.faces >= len(mesh.vertices))).any(axis=1).sum())
    if outside:  # trimesh keeps them (PLY, glTF): an IndexError later, or a negative one wraps round
        raise ValueError(f"{what} has {outside} triangles of {len(mesh.faces)} indexing a vertex it lacks "
                         f"(it has {len(mesh.vertices)} vertices)")
    bad = int((~np.isfinite(mesh.vertices).all(axis=1)).sum())
    if bad:
        raise ValueError(f"{what} has {bad} non-finite (NaN or infinite) vertices of {len(mesh.vertices)}")
    return mesh


def _floats(text: str | None, n: int, default: tuple[float, ...] | None, where: str) -> np.ndarray:
    """``n`` finite numbers parsed from ``text``, or ``default`` if ``text`` is None (an error if both are)."""
    if text is None:
        if default is None:
            raise ValueError(f"{where}: required attribute is missing")
        return np.array(default, dtype=np.float64)
    try:
        vals = [float(t) for t in text.split()]
    except ValueError as exc:
        raise ValueError(f"{where}: expected {n} numbers; got {text!r}") from exc
    if len(vals) != n or not all(math.isfinite(x) for x in vals):
        raise ValueError(f"{where}: expected {n} finite numbers; got {text!r}")
    return np.array(vals, dtype=np.float64)


def _origin(elem: ET.Element, where: str) -> np.ndarray:
    """(4, 4) transform of an element's ``<origin xyz rpy>`` (URDF rpy: fixed-axis X, Y, Z)."""
    o = elem.find("origin")
    xyz = _floats(None if o is None else o.get("xyz"), 3, (0.0, 0.0, 0.0), f"{where} origin xyz")
    rpy = _floats(None if o is None else o.get("rpy"), 3, (0.0, 0.0, 0.0), f"{where} origin rpy")
    t = trimesh.transformations.euler_matrix(*rpy, axes="sxyz")
    t[:3, 3] = xyz
    return t


def _positive(g: ET.Element, attr: str, n: int, where: str, default: tuple[float, ...] | None = None) -> np.ndarray:
    """Attribute ``attr`` of geometry ``g``: ``n`` positive numbers (required without a default)."""
    what = f"{where} <{g.tag}> {attr}"
    vals = _floats(g.get(attr), n, default, what)
    if not (vals > 0).all():
        raise ValueError(f"{what}: expected positive numbers; got {g.get(attr)!r}")
    return vals


def _mesh_path(urdf: Path, filename: str, where: str) -> Path:
    """The mesh file a URDF ``filename`` names (resolution rule: :func:`load_vehicle`)."""
    if filename.startswith("package://"):
        rest = unquote(filename[len("package://"):].partition("/")[2])
        candidates = [urdf.parent / rest, urdf.parent.parent / rest]
    else:
        p = Path(unquote(filename[len("file://"):]) if filename.startswith("file://") else filename)
        candidates = [p if p.is_absolute() else urdf.parent / p]
    for p in candidates:
        if p.is_file():
            return p
    raise FileNotFoundError(f"{where}: mesh file not found: {' or '.join(str(p) for p in candidates)}")


def _geometry(geom: ET.Element, urdf: Path, where: str) -> trimesh.Trimesh:
    kids = list(geom)
    if len(kids) != 1:
        raise ValueError(f"{where}: <geometry> must hold exactly one shape; got {[k.tag for k in kids]}")
    g = kids[0]
    if g.tag == "box":
        return trimesh.creation.box(extents=_positive(g, "size", 3, where))
    if g.tag == "cylinder":
        r, h = _positive(g, "radius", 1, where)[0], _positive(g, "length", 1, where)[0]
        return trimesh.creation.cylinder(radius=r, height=h, sections=_CYLINDER_SECTIONS)
    if g.tag == "sphere":
        return trimesh.creation.icosphere(subdivisions=2, radius=_positive(g, "radius", 1, where)[0])
    if g.tag == "mesh":
        if not g.get("filename"):
            raise ValueError(f"{where}: <mesh> without a filename")
        s = _positive(g, "scale", 3, where, default=(1.0, 1.0, 1.0))
        mesh = read_mesh(_mesh_path(urdf, g.get("filename"), where))
        return trimesh.Trimesh(mesh.vertices * s, mesh.faces, process=False)
    raise ValueError(f"{where}: unsupported geometry <{g.tag}>")


def _check_tree(path: Path, joints: list[ET.Element]) -> None:
    """ValueError naming the file and the joints when a link is the child of two joints or the joints form a
    cycle (pytorch-kinematics recursed round a cycle until Python's recursion limit); a URDF's joints form a tree.
    A joint without ``<parent>`` or ``<child>`` is left to pytorch-kinematics, whose error names it."""
    parent: dict[str | None, tuple[str | None, str | None]] = {}  # child link -> (joint, parent link)
    for j in joints:
        p, c = j.find("parent"), j.find("child")
        if p is None or c is None:
            continue
        if c.get("link") in parent:
            raise ValueError(f"{path}: link {c.get('link')!r} is the child of joints {parent[c.get('link')][0]!r} "
                             f"and {j.get('name')!r}; a link has at most one parent joint")
        parent[c.get("link")] = (j.get("name"), p.get("link"))
    done: set[str | None] = set()  # links whose chain up to a root is known to end
    for start in parent:
        trail: dict[str | None, None] = {}  # links walked up from start, in order
        link = start
        while link in parent and link not in done and link not in trail:
            trail[link] = None
            link = parent[link][1]
        if link in trail:
            cycle = list(trail)[list(trail).index(link):]
            joints = [parent[link][0] for link in cycle]
            raise ValueError(f"{path}: joints {joints} form a cycle through links {cycle}; a URDF's joints form a tree")
        done.update(trail)


def _load_urdf(path: Path, rotation: np.ndarray) -> _Rig:
    try:  # bytes: the parser honours the XML declaration's encoding (UTF-8 without one)
        root = ET.fromstring(path.read_bytes())
    except (ET.ParseError, LookupError) as exc:  # LookupError: an encoding Python does not know
        raise ValueError(f"{path}: invalid URDF XML: {exc}") from exc
    if root.tag != "robot":
        raise ValueError(f"{path}: expected a <robot> root element; got <{root.tag}>")
    links = root.findall("link")
    if not links or any(not l.get("name") for l in links):
        raise ValueError(f"{path}: a URDF needs named <link> elements")
    joints = root.findall("joint")
    for kind, elems in (("link", links), ("joint", joints)):  # a later namesake replaced the earlier one unseen
        seen: set[str | None] = set()
        for e in elems:
            if e.get("name") in seen:
                raise ValueError(f"{path}: two {kind}s are named {e.get('name')!r}; a URDF's {kind} names must be "
                                 f"unique")
            seen.add(e.get("name"))
    parts = []
    for link in links:
        for k, vis in enumerate(link.findall("visual")):
            where = f"{path}: link {link.get('name')!r} visual {k}"
            geom = vis.find("geometry")
            if geom is None:
                raise ValueError(f"{where}: missing <geometry>")
            mesh = _geometry(geom, path, where)
            t = _origin(vis, where)
            parts.append((link.get("name"), mesh.vertices @ t[:3, :3].T + t[:3, 3], np.asarray(mesh.faces)))
    if not parts:
        raise ValueError(f"{path}: no <visual> geometry in any link")

    limits: dict[str, tuple[float, float]] = {}
    for j in joints:
        where = f"{path}: joint {j.get('name')!r}"
        _origin(j, where)  # finite numbers, as a visual's: pytorch-kinematics takes NaN and poses every part at NaN
        if j.get("type") in ("revolute", "continuous", "prismatic"):
            axis = j.find("axis")
            if not _floats(None if axis is None else axis.get("xyz"), 3, (1.0, 0.0, 0.0), f"{where} axis xyz").any():
                raise ValueError(f"{where}: axis xyz is 0 0 0; a {j.get('type')} joint needs a direction")
        lim = j.find("limit")
        if lim is not None:  # pytorch-kinematics' parser requires both attributes
            lim.set("effort", lim.get("effort", "0"))
            lim.set("velocity", lim.get("velocity", "0"))
        if j.get("type") in ("revolute", "prismatic"):
            if lim is None:
                raise ValueError(f"{where}: a {j.get('type')} joint needs a <limit> (URDF specification)")
            lo = float(_floats(lim.get("lower"), 1, (0.0,), f"{where} limit lower")[0])  # URDF default 0
            hi = float(_floats(lim.get("upper"), 1, (0.0,), f"{where} limit upper")[0])
            if lo > hi:
                raise ValueError(f"{where}: limit lower {lo} is above upper {hi}")
            limits[j.get("name")] = (lo, hi)
        elif j.get("type") == "continuous":
            limits[j.get("name")] = (-math.inf, math.inf)
        elif j.get("type") not in ("fixed",):
            raise ValueError(f"{where}: unsupported joint type {j.get('type')!r}")

    if not joints:
        if len(links) != 1:
            raise ValueError(f"{path}: {len(links)} links but no joint connecting them")
        chain, names = None, ()
    else:
        _check_tree(path, joints)
        try:
            chain = pk.build_chain_from_urdf(ET.tostring(root, encoding="unicode")).to(dtype=torch.float64)
        except Exception as exc:  # the parser raises assorted types on inconsistent URDFs
            raise ValueError(f"{path}: pytorch-kinematics could not build the chain: {exc}") from exc
        names = tuple(chain.get_joint_parameter_names())
        missing = {l.get("name") for l in links} - set(chain.get_frame_names(exclude_fixed=False))
        if missing:
            raise ValueError(f"{path}: links {sorted(missing)} are not connected to the root")
    rig = _Rig(chain, links[0].get("name"), names, MappingProxyType(limits), tuple(parts), rotation, np.zeros(3))
    v, _ = rig.file_vertices(_rest_pose(limits))
    return dataclasses.replace(rig, offset=_centring_offset(v @ rotation.T))
