"""Closed polyhedral parts for the catalog builder, with explicit (deterministic) topology.

Every part is a *loft* (two rings of ``n`` corresponding vertices joined by side quads and
closed by two caps triangulated by ear clipping) or a *sweep* (a sequence of such rings,
capped by fans), oriented outwards. No convex hull or boolean operation is involved, so the
same numbers always give the same vertices and faces. :func:`fillet` rounds the corners of
the side profiles the builder sweeps.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

Part = tuple[np.ndarray, np.ndarray]  # vertices (M, 3) float64, faces (F, 3) int64

_EPS = 1e-12


def _cross2(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))


def signed_area(poly: np.ndarray) -> float:
    """Shoelace area of a polygon ``poly: (n, 2)``; positive when counter-clockwise."""
    poly = np.asarray(poly)
    if poly.ndim != 2 or poly.shape[1] != 2:
        raise ValueError(f"Expected poly to have shape (n, 2); got {poly.shape}")
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def triangulate(poly: np.ndarray) -> np.ndarray:
    """Ear-clipping triangulation of a simple counter-clockwise polygon.

    Args:
        poly: (n, 2) vertices, n >= 3, counter-clockwise, no repeated points.

    Returns:
        (n - 2, 3) int64 vertex indices, each triangle counter-clockwise with positive area.
    """
    poly = np.asarray(poly, dtype=np.float64)
    if poly.ndim != 2 or poly.shape[1] != 2 or len(poly) < 3:
        raise ValueError(f"Expected poly to have shape (n>=3, 2); got {poly.shape}")
    if signed_area(poly) <= 0:
        raise ValueError("Expected a counter-clockwise polygon with positive area")
    idx = list(range(len(poly)))
    tris = []
    while len(idx) > 3:
        for k in range(len(idx)):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            a, b, c = poly[i0], poly[i1], poly[i2]
            if _cross2(a, b, c) <= _EPS:  # reflex or collinear corner: not an ear
                continue
            others = (poly[m] for m in idx if m not in (i0, i1, i2))
            if any(_cross2(a, b, p) >= 0 and _cross2(b, c, p) >= 0 and _cross2(c, a, p) >= 0 for p in others):
                continue
            tris.append((i0, i1, i2))
            idx.pop(k)
            break
        else:
            raise ValueError("polygon is not simple: no ear left to clip")
    if _cross2(*(poly[i] for i in idx)) <= _EPS:
        raise ValueError("polygon triangulation left a degenerate triangle (collinear points?)")
    tris.append(tuple(idx))
    return np.asarray(tris, dtype=np.int64)


def loft(ring0: np.ndarray, ring1: np.ndarray, cap: np.ndarray) -> Part:
    """Close the band between two rings of corresponding vertices into a solid.

    Args:
        ring0, ring1: (n, 3) vertices; vertex i of one ring is joined to vertex i of the other.
        cap: (n, 2) 2-D polygon (either winding) whose triangulation closes both ends.

    Returns:
        (vertices (2n, 3), faces (4n - 4, 3)) oriented with outward normals (positive volume).

    Raises ValueError for a solid without volume (coinciding rings).
    """
    ring0, ring1, cap = (np.asarray(a, dtype=np.float64) for a in (ring0, ring1, cap))
    n = len(cap)
    if ring0.shape != (n, 3) or ring1.shape != (n, 3):
        raise ValueError(f"Expected ring0, ring1 of shape ({n}, 3); got {ring0.shape}, {ring1.shape}")
    if signed_area(cap) < 0:
        ring0, ring1, cap = ring0[::-1], ring1[::-1], cap[::-1]
    tri = triangulate(cap)
    i = np.arange(n)
    j = (i + 1) % n
    sides = np.concatenate([np.stack([i, j, n + j], 1), np.stack([i, n + j, n + i], 1)])
    faces = np.concatenate([tri[:, ::-1], sides, tri + n])
    verts = np.concatenate([ring0, ring1])
    return _outwards(verts, faces, "loft")


def check_mesh(verts, faces, names: tuple[str, str] = ("verts", "faces")) -> None:
    """ValueError naming the argument (``names``) unless ``verts`` is a float array (M, 3) and
    ``faces`` an integer array (F, 3)."""
    for name, a, kinds, want in ((names[0], verts, "f", "a float array of shape (M, 3)"),
                                 (names[1], faces, "iu", "an integer array of shape (F, 3)")):
        if not (isinstance(a, np.ndarray) and a.ndim == 2 and a.shape[1] == 3 and a.dtype.kind in kinds):
            got = f"shape {a.shape}, dtype {a.dtype}" if isinstance(a, np.ndarray) else type(a).__name__
            raise ValueError(f"Expected {name} to be {want}; got {got}")


def volume(verts: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume of a closed triangle mesh (divergence theorem); verts (M, 3) float, faces (F, 3)
    integer indices into verts."""
    check_mesh(verts, faces)
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _outwards(verts: np.ndarray, faces: np.ndarray, what: str) -> Part:
    """Flip ``faces`` if needed so that the closed mesh has a positive volume; a mesh that encloses
    no volume (rings that coincide, a zero width, non-finite vertices) is a ValueError naming ``what``."""
    v = volume(verts, faces)
    if not (math.isfinite(v) and abs(v) > _EPS):
        raise ValueError(f"{what}: the solid encloses no volume ({v} m^3): coinciding rings, a zero width "
                         f"or a non-finite vertex")
    return verts, np.ascontiguousarray(faces if v > 0 else faces[:, ::-1])


def prism_xz(profile: Sequence[tuple[float, float]], half_width: float | Sequence[float], y0: float = 0.0) -> Part:
    """Extrude a side profile (x, z) across the width, symmetric about ``y = y0``.

    Args:
        profile: n points (x, z) of a simple polygon (either winding).
        half_width: a scalar, or n per-vertex half-widths (a tumblehome: vertices on a roof
            line narrower than those on a belt line keep every face planar when each edge
            joins vertices of equal half-width or is parallel to another edge).
        y0: y of the symmetry plane.

    Raises ValueError for a half-width that is not positive or a count of them other than 1 or n.
    """
    p = np.asarray(profile, dtype=np.float64)
    w = np.asarray(half_width, dtype=np.float64)
    if w.ndim > 1 or w.size not in (1, len(p)):
        raise ValueError(f"Expected one half_width or {len(p)} (one per profile point); got shape {w.shape}")
    if not np.all(w > 0):
        raise ValueError(f"Expected positive half_width(s); got {w.tolist()}")
    w = np.broadcast_to(w, (len(p),))
    left = np.stack([p[:, 0], y0 + w, p[:, 1]], 1)
    right = np.stack([p[:, 0], y0 - w, p[:, 1]], 1)
    return loft(right, left, p)


def frustum_xy(bottom: Sequence[tuple[float, float]], z0: float, top: Sequence[tuple[float, float]], z1: float) -> Part:
    """Join a convex floor polygon (x, y) at ``z0`` to a convex roof polygon at ``z1``.

    ``bottom`` and ``top`` have the same number of corresponding vertices.
    """
    b = np.asarray(bottom, dtype=np.float64)
    t = np.asarray(top, dtype=np.float64)
    if b.shape != t.shape:
        raise ValueError(f"Expected bottom and top of equal shape (n, 2); got {b.shape}, {t.shape}")
    ring0 = np.concatenate([b, np.full((len(b), 1), z0)], 1)
    ring1 = np.concatenate([t, np.full((len(t), 1), z1)], 1)
    return loft(ring0, ring1, b)


def sweep(rings: Sequence[Sequence[Sequence[float]]] | np.ndarray) -> Part:
    """Join a sequence of rings of corresponding vertices into a closed solid.

    Consecutive rings are joined by quads (vertex i of one ring to vertex i of the next); each
    end ring is closed by a fan from its centroid, so the end rings must be planar polygons
    that are star-shaped about their centroid (convex ones are).

    Args:
        rings: (S, n, 3) vertices, S >= 2 rings of n >= 3 vertices, either winding.

    Returns:
        (vertices (S·n + 2, 3), faces (2·n·S, 3)) oriented with outward normals (positive volume).

    Raises ValueError for a solid without volume (all rings in one place: a zero-length sweep).
    """
    rings = np.asarray(rings, dtype=np.float64)
    if rings.ndim != 3 or rings.shape[0] < 2 or rings.shape[1] < 3 or rings.shape[2] != 3:
        raise ValueError(f"Expected rings of shape (S>=2, n>=3, 3); got {rings.shape}")
    S, n, _ = rings.shape
    i = np.arange(n)
    j = (i + 1) % n
    a = (np.arange(S - 1) * n)[:, None]  # (S-1, 1) first vertex of each ring but the last
    sides = np.concatenate([np.stack([a + i, a + j, a + n + j], -1), np.stack([a + i, a + n + j, a + n + i], -1)])
    c0, c1 = S * n, S * n + 1  # the two centroids
    caps = [np.stack([np.full(n, c0), j, i], 1), np.stack([np.full(n, c1), (S - 1) * n + i, (S - 1) * n + j], 1)]
    faces = np.concatenate([sides.reshape(-1, 3), *caps])
    verts = np.concatenate([rings.reshape(-1, 3), rings[0].mean(axis=0, keepdims=True),
                            rings[-1].mean(axis=0, keepdims=True)])
    return _outwards(verts, faces, "sweep")


def fillet(points: Sequence[tuple[float, float]], radius: float | Sequence[float], arc: int = 3
           ) -> list[tuple[float, float]]:
    """Round the interior corners of an open polyline by circular arcs.

    Each interior corner becomes ``arc`` points on the arc tangent to both of its segments, from
    the tangent point on the incoming segment to the one on the outgoing segment. Where a
    segment is too short for the radius, the radius shrinks until each tangent point is 0.45 of
    the shorter segment from the corner (so two arcs on one segment never overlap). End points
    and straight corners are kept.

    Args:
        points: (m, 2) points (x, y) of the polyline, m >= 2, consecutive points distinct.
        radius: one radius for every corner, or m - 2 radii (0 keeps a corner sharp), each >= 0.
        arc: points per arc, >= 2.
    Returns:
        the rounded polyline's points.

    Raises ValueError for the wrong number of radii, a negative radius, ``arc`` < 2, a repeated
    point or a corner that turns straight back (no tangent circle).
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) < 2 or not np.all(np.isfinite(p)):
        raise ValueError(f"Expected points of shape (m>=2, 2), finite; got shape {p.shape}")
    r_in = np.asarray(radius, dtype=np.float64)
    if r_in.ndim > 1 or r_in.size not in (1, len(p) - 2):
        raise ValueError(f"Expected one radius or {len(p) - 2} (one per interior corner); got shape {r_in.shape}")
    if not np.all(r_in >= 0):  # NaN fails too
        raise ValueError(f"Expected radii >= 0; got {r_in.tolist()}")
    if int(arc) != arc or arc < 2:
        raise ValueError(f"Expected arc >= 2 points per arc; got {arc!r}")
    lengths = np.linalg.norm(np.diff(p, axis=0), axis=1)  # (m - 1,)
    if not np.all(lengths > 0):
        k = int(np.argmin(lengths))
        raise ValueError(f"points {k} and {k + 1} coincide at {tuple(p[k].tolist())}: a segment of length 0")
    radii = np.broadcast_to(r_in, (len(p) - 2,))
    out = [tuple(p[0])]
    for k, radius in enumerate(radii, start=1):
        d0, d1 = p[k - 1] - p[k], p[k + 1] - p[k]
        l0, l1 = lengths[k - 1], lengths[k]
        u0, u1 = d0 / l0, d1 / l1
        half = 0.5 * np.arccos(np.clip(u0 @ u1, -1.0, 1.0))  # half the corner's interior angle
        if half < 1e-6 and radius > 0:
            raise ValueError(f"corner {k} at {tuple(p[k].tolist())} turns straight back: no arc is tangent to both "
                             f"of its segments")
        if abs(np.pi / 2 - half) < 1e-6 or radius <= 0:  # a straight or a sharp corner
            out.append(tuple(p[k]))
            continue
        r = min(radius, 0.45 * min(l0, l1) * np.tan(half))
        t = r / np.tan(half)  # corner -> tangent points
        centre = p[k] + (u0 + u1) / np.linalg.norm(u0 + u1) * (r / np.sin(half))
        a0, a1 = p[k] + u0 * t - centre, p[k] + u1 * t - centre
        ang0, ang1 = np.arctan2(a0[1], a0[0]), np.arctan2(a1[1], a1[0])
        sweep_angle = (ang1 - ang0 + np.pi) % (2 * np.pi) - np.pi  # the short way round
        for f in np.linspace(0.0, 1.0, arc):
            ang = ang0 + f * sweep_angle
            out.append((centre[0] + r * np.cos(ang), centre[1] + r * np.sin(ang)))
    out.append(tuple(p[-1]))
    return out


def ellipse(cx: float, cy: float, rx: float, ry: float, n: int) -> np.ndarray:
    """(n, 2) counter-clockwise points of an axis-aligned ellipse, the first at +x."""
    a = 2 * np.pi * np.arange(n) / n
    return np.stack([cx + rx * np.cos(a), cy + ry * np.sin(a)], 1)


def fmt(v: float) -> str:
    """Fixed 4-decimal text without a negative zero (byte-stable output)."""
    return f"{round(float(v), 4) + 0.0:.4f}"


def obj_text(parts: Sequence[tuple[str, Part]], header: str) -> str:
    """Wavefront OBJ text of named parts (``o`` groups), 1-based indices, 0.1 mm resolution."""
    lines = [f"# {header}"]
    base = 1
    for name, (verts, faces) in parts:
        lines.append(f"o {name}")
        lines += ["v " + " ".join(fmt(c) for c in v) for v in verts]
        lines += ["f " + " ".join(str(base + int(i)) for i in f) for f in faces]
        base += len(verts)
    return "\n".join(lines) + "\n"
