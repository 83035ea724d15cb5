"""Generate the catalog (URDF + part OBJ files) from the spec table in ``specs.py``.

    python -m torch_atr.vehicles.build [--out DIR]

writes ``DIR/{train,test}/<name>/<name>.urdf`` with ``hull.obj`` (and ``turret.obj``) beside
it; DIR defaults to the package's ``catalog`` folder, whose files are committed. The output
is a pure function of the specs (fixed topology, 0.1 mm text), so rebuilding reproduces the
shipped files byte for byte.

Road vehicles are swept through rounded cross-sections along a filleted side profile
(:func:`_road_body`), with wheels, door mirrors and, per spec, roof rails, a tailgate spare
wheel, a pickup bed or a van's box body. Military hulls are prisms of their side profile over
track runs or wheels, with faceted or domed turrets. Nothing thinner than 5 cm sticks out (no
whip antennas): such parts are below a template pixel and would only move the bounding-box
centre that templates are centred on (:func:`torch_atr.vehicles.loader.thick_bounds`).

Frames: each URDF's root link ``hull`` is already the body frame at the rest pose (+X
forward, +Y left, +Z up; the bounding box, gun forward, is centred on x = y = 0 and the tracks
or tyres touch z = 0). Articulated vehicles have a ``turret`` link on the continuous joint
``turret_yaw`` (axis +Z, so +pi/2 swings the gun to the left, +Y) and a ``gun`` link on the
revolute joint ``gun_pitch`` (axis -Y, so a positive angle raises the muzzle).
"""

from __future__ import annotations

import argparse
import logging
import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from torch_atr.io import atomic_write_text
from torch_atr.vehicles.catalog import CATALOG_DIR
from torch_atr.vehicles.geometry import Part, ellipse, fillet, fmt, frustum_xy, obj_text, prism_xz, sweep
from torch_atr.vehicles.specs import SPLITS, Extra, Road, Spec, Tracked, Turret, Wheeled

log = logging.getLogger(__name__)

_AXIS_RPY = {"x": (0.0, math.pi / 2, 0.0), "y": (math.pi / 2, 0.0, 0.0), "z": (0.0, 0.0, 0.0)}
_GUN_EFFORT, _GUN_VELOCITY = 1.0e4, 0.7  # N m, rad/s: nominal, URDF requires them
_DOME_U = (0.0, 0.45, 0.75, 0.92, 1.0)  # height fractions of a round turret's rings


@dataclass
class _Link:
    """One URDF link being assembled: lofted parts (written to ``<name>.obj``) and primitives."""

    name: str
    lofts: list[tuple[str, Part]] = field(default_factory=list)
    visuals: list[str] = field(default_factory=list)

    def box(self, size: Sequence[float], xyz: Sequence[float]) -> None:
        self.visuals.append(_visual(xyz, (0.0, 0.0, 0.0), f'<box size="{_v(size)}"/>'))

    def cylinder(self, radius: float, length: float, xyz: Sequence[float], axis: str) -> None:
        self.visuals.append(_visual(xyz, _AXIS_RPY[axis], f'<cylinder radius="{fmt(radius)}" length="{fmt(length)}"/>'))


def _v(values: Sequence[float]) -> str:
    return " ".join(fmt(x) for x in values)


def _visual(xyz: Sequence[float], rpy: Sequence[float], geometry: str) -> str:
    return (f'    <visual>\n      <origin xyz="{_v(xyz)}" rpy="{_v(rpy)}"/>\n'
            f"      <geometry>{geometry}</geometry>\n    </visual>")


def _clean(points: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """Drop repeated (< 1 mm apart) and collinear points of a closed polygon."""
    pts = [p for i, p in enumerate(points) if math.dist(p, points[i - 1]) > 1e-3]
    out = []
    for i, p in enumerate(pts):
        a, c = pts[i - 1], pts[(i + 1) % len(pts)]
        if abs((p[0] - a[0]) * (c[1] - a[1]) - (p[1] - a[1]) * (c[0] - a[0])) > 1e-6:
            out.append(p)
    return out


def _clip(points: Sequence[tuple[float, float]], z: float, above: bool) -> list[tuple[float, float]]:
    """The part of a polygon (x, z) above (or below) the line z = const (Sutherland-Hodgman)."""
    inside: Callable[[tuple[float, float]], bool] = (lambda p: p[1] >= z) if above else (lambda p: p[1] <= z)
    out = []
    for i, q in enumerate(points):
        p = points[i - 1]
        if inside(p) != inside(q):
            t = (z - p[1]) / (q[1] - p[1])
            out.append((p[0] + t * (q[0] - p[0]), z))
        if inside(q):
            out.append(q)
    return _clean(out)


def _extras(links: dict[str, _Link], extras: Sequence[Extra], hull_x: Callable[[float], float]) -> None:
    """Add spec extras to their links (hull positions are given as s, converted by ``hull_x``)."""
    for e in extras:
        xyz = (hull_x(e.xyz[0]), e.xyz[1], e.xyz[2]) if e.link == "hull" else e.xyz
        if e.shape == "box":
            links[e.link].box(e.size, xyz)
        else:
            links[e.link].cylinder(e.size[0], e.size[1], xyz, e.axis)


def _turret(t: Turret, length: float) -> tuple[_Link, _Link]:
    """Turret link (frame: axis on the deck) and gun link (frame: trunnion; barrel ``length``)."""
    turret, gun = _Link("turret"), _Link("gun")
    hw = t.width / 2
    if t.round:
        floor = [tuple(p) for p in ellipse((t.front - t.rear) / 2, 0.0, (t.front + t.rear) / 2, hw, 12)]
    else:
        n, c1, c2 = t.nose * hw, max((1 - t.nose) * hw * 0.8, 0.05), 0.25 * hw
        floor = [(t.front, -n), (t.front, n), (t.front - c1, hw), (-t.rear + c2, hw), (-t.rear, 0.7 * hw),
                 (-t.rear, -0.7 * hw), (-t.rear + c2, -hw), (t.front - c1, -hw)]
    # Roof: the front edge set back by `slope`, the sides and rear drawn in by `taper`.
    roof = [(px * (1 - t.slope / t.front) if px > 0 else px * (1 - t.taper / t.rear), py * (1 - t.taper / hw))
            for px, py in floor]
    if t.round:  # a cast dome: rings drawn in towards the roof along a quarter circle of the height
        f, r = np.array(floor), np.array(roof)
        rings = [np.c_[f + (r - f) * (1 - math.sqrt(1 - u * u)), np.full(len(f), z)]
                 for u, z in zip(_DOME_U, (-0.03, *(u * t.height for u in _DOME_U[1:])))]
        turret.lofts.append(("turret", sweep(rings)))
    else:
        turret.lofts.append(("turret", frustum_xy(floor, -0.03, roof, t.height)))

    g = t.gun
    gun.box(g.mantlet, (0.0, 0.0, 0.0))
    for by, bz in g.barrels:
        gun.cylinder(g.diameter / 2, length + 0.4, ((length - 0.4) / 2, by, bz), "x")
        if g.evacuator:
            gun.cylinder(0.8 * g.diameter, 0.6, (g.evacuator * length, by, bz), "x")
        if g.brake:
            gun.cylinder(0.8 * g.diameter, 0.45, (length - 0.225, by, bz), "x")
    return turret, gun


def _military(spec: Tracked | Wheeled, hull: _Link, x: Callable[[float], float]) -> tuple[list[_Link], str]:
    """Add turret, gun, joints and extras to a military hull; returns (links, joints XML)."""
    links = {"hull": hull}
    joints = ""
    t = spec.turret
    if t is not None:
        trunnion_x = x(t.ring) + t.gun.trunnion[0]
        if t.gun.length is not None:
            length = t.gun.length
        else:  # the muzzle reaches the published length with the gun forward
            length = x(-(spec.gun_length - spec.length)) - trunnion_x
        links["turret"], links["gun"] = _turret(t, length)
        lo, hi = (math.radians(a) for a in t.gun.elevation)
        joints = (
            f'  <joint name="turret_yaw" type="continuous">\n    <parent link="hull"/>\n'
            f'    <child link="turret"/>\n'
            f'    <origin xyz="{_v((x(t.ring), t.offset, spec.deck))}" rpy="0 0 0"/>\n    <axis xyz="0 0 1"/>\n'
            f"  </joint>\n"
            f'  <joint name="gun_pitch" type="revolute">\n    <parent link="turret"/>\n    <child link="gun"/>\n'
            f'    <origin xyz="{_v((t.gun.trunnion[0], 0.0, t.gun.trunnion[1]))}" rpy="0 0 0"/>\n'
            f'    <axis xyz="0 -1 0"/>\n'
            f'    <limit lower="{fmt(lo)}" upper="{fmt(hi)}" effort="{_GUN_EFFORT:g}" velocity="{_GUN_VELOCITY:g}"/>\n'
            f"  </joint>\n"
        )
    _extras(links, spec.extras, x)
    return list(links.values()), joints


def _hull_profile(spec: Tracked | Wheeled, rear_low: float, rear_mid: float) -> list[tuple[float, float]]:
    """Side profile (s, z) of a military hull: nose, lower glacis, belly, rear plate, roof, glacis."""
    L = spec.length
    return [(0.0, spec.nose), (spec.lower_glacis, spec.belly), (L - 0.35, spec.belly), (L, rear_low),
            (L, rear_mid), (L - spec.rear_slope, spec.deck), (spec.glacis, spec.deck)]


def _body_x(length: float, overhang: float = 0.0) -> Callable[[float], float]:
    """s (behind the front) -> body x, the bounding box (``overhang`` of gun ahead of it) centred."""
    return lambda s: (length - overhang) / 2 - s


def _wheels(hull: _Link, spec: Wheeled | Road, axles: Sequence[float], x: Callable[[float], float]) -> None:
    """A pair of tyres (cylinders on the ground, axis Y) at each axle position s."""
    for s in axles:
        for side in (1, -1):
            hull.cylinder(spec.wheel_d / 2, spec.tyre_w, (x(s), side * spec.track / 2, spec.wheel_d / 2), "y")


def _tracked(spec: Tracked) -> tuple[list[_Link], str]:
    """Hull between and over two track runs, road wheels, optional skirts, turret and gun."""
    L, W = spec.length, spec.width
    x = _body_x(L, spec.gun_length - L if spec.gun_length is not None else 0.0)
    hull = _Link("hull")
    z_top = spec.wheel_d + 0.15  # top run of the track
    z_fender = z_top + 0.03
    y_track = W / 2 - 0.06 - spec.track_w / 2  # track centre line

    profile = [(x(s), z) for s, z in _hull_profile(spec, spec.belly + 0.3, (spec.belly + spec.deck) / 2)]
    hull.lofts.append(("lower_hull", prism_xz(profile, y_track - spec.track_w / 2 - 0.03)))
    upper = _clip(profile, z_fender, above=True)
    hull.lofts.append(("upper_hull", prism_xz(upper, W / 2)))

    a, b = (L - spec.contact) / 2, (L + spec.contact) / 2  # first and last road-wheel centres
    run = [(a, 0.0), (b, 0.0), (min(L - 0.08, b + 0.7), 0.6 * z_top), (min(L - 0.25, b + 0.5), z_top),
           (max(0.25, a - 0.5), z_top), (max(0.1, a - 0.7), 0.6 * z_top)]
    run_xz = [(x(s), z) for s, z in run]
    skirt_front, skirt_rear = max(px for px, _ in upper) - 0.1, x(L - 0.15)
    skirt_z = (0.55 * spec.wheel_d, z_fender + 0.05)
    for side, label in ((1, "left"), (-1, "right")):
        hull.lofts.append((f"track_{label}", prism_xz(run_xz, spec.track_w / 2, side * y_track)))
        for i in range(spec.road_wheels):
            s = a + i * (b - a) / (spec.road_wheels - 1)
            hull.cylinder(spec.wheel_d / 2, spec.track_w + 0.1, (x(s), side * y_track, spec.wheel_d / 2 + 0.07), "y")
        if spec.skirts:
            hull.box((skirt_front - skirt_rear, 0.06, skirt_z[1] - skirt_z[0]),
                     ((skirt_front + skirt_rear) / 2, side * (W / 2 - 0.03), sum(skirt_z) / 2))
    return _military(spec, hull, x)


def _wheeled(spec: Wheeled) -> tuple[list[_Link], str]:
    """Narrow lower hull between the wheels, wide upper hull with sloped sides over them."""
    L, W = spec.length, spec.width
    x = _body_x(L)
    hull = _Link("hull")
    z_w = spec.wheel_d + 0.05  # widest level, just above the tyres
    profile = [(x(s), z) for s, z in _hull_profile(spec, spec.belly + 0.4, z_w)]
    lower = _clip(profile, z_w + 0.05, above=False)
    hull.lofts.append(("lower_hull", prism_xz(lower, spec.track / 2 - spec.tyre_w / 2 - 0.05)))
    upper = _clip(profile, z_w, above=True)
    # Sloped sides: the half-width falls linearly with height, so each cap stays planar.
    widths = [W / 2 - spec.side_slope * (z - z_w) / (spec.deck - z_w) for _, z in upper]
    hull.lofts.append(("upper_hull", prism_xz(upper, widths)))
    _wheels(hull, spec, spec.axles, x)
    return _military(spec, hull, x)


_CAP_V = (0.0, 0.45, 0.75, 0.92)  # height fractions (belt -> top) of the cap points of a road-body section
_SPARE_W = 0.25  # depth of a tailgate spare wheel, metres
# Sill (rocker panel) height / published ground clearance, estimated from side views: about 0.22 m for
# a car, 0.3 m for a crossover, 0.37 m for a full-size SUV, 0.4-0.45 m under a pickup's cab.
_SILL_PER_CLEARANCE = 1.6


def _section(z0: float, belt: float, top: float, wb: float, wr: float, e: float, c: float) -> list[tuple[float, float]]:
    """Cross-section (y, z) of a road body, 13 points: a flat bottom at ``z0`` with its corners
    chamfered by ``c``, vertical sides up to the ``belt``, and a cap up to ``top`` whose
    half-width is the tumblehome line (``wb`` at the belt, ``wr`` at the top) times the
    superellipse (1 - v^e)^(1/e) of the height fraction v: e = 2 gives a round roof, e = 8 a
    flat one with tight shoulders."""
    right = [(wb - c, z0), (wb, z0 + c)]
    right += [((wb + (wr - wb) * v) * (1 - v ** e) ** (1 / e), belt + v * (top - belt)) for v in _CAP_V]
    return right + [(0.0, top)] + [(-y, z) for y, z in reversed(right)]


def _road_body(spec: Road, length: float, width: float, height: float) -> tuple[Part, Callable[[float], tuple]]:
    """Body (or a box van's cab) of a road vehicle, swept along s through rounded sections.

    The side profile (bumpers, bonnet, windshield, roof, tailgate or boot, from the spec's
    Shape fractions of ``length`` and ``height``) has its corners filleted; at each station the
    section (:func:`_section`) spans the profile's bottom and top, the glasshouse tapers to the
    roof (``roof_w``) and the plan view rounds off at the bumper corners. ``Shape.round`` sets
    the fillets, the shoulders (superellipse exponent 8 -> 2) and the plan corners.
    Returns the part in (s, y, z) coordinates and a function s -> (belt, top, half-width of the
    roof line) at that station, for the parts placed on the body.
    """
    sh, rnd = spec.shape, spec.shape.round
    H = height - spec.rails
    z0, zn, zb, zd = spec.clearance, sh.nose * H, sh.belt * H, sh.deck * H
    f = 0.05 + 0.07 * rnd  # the bonnet's leading edge is chamfered by f
    top = [(0.0, zn - f), (f, zn), (sh.windshield * length, zb), (sh.roof[0] * length, H),
           (sh.roof[1] * length, H * (1.0 - sh.drop))]
    s_tail = sh.tail * length
    if s_tail < length - 0.15:  # a separate boot (three-box sedan)
        top += [(s_tail, zb), (length - 0.1, zd), (length, zd - 0.15)]
    elif s_tail < length - 0.02:
        top += [(s_tail, zb), (length, zb)]
    else:
        top += [(length, zb)]
    # The roof's corners (windshield header, roof end) round with Shape.round; the bonnet edge and the
    # cowl stay tight: a blunt, high bonnet is what sets an SUV's nose apart from a car's.
    r = 0.04 + 0.3 * rnd
    top = fillet(top, [0.05, 0.05, r, r] + [0.1] * (len(top) - 6))
    sill = _SILL_PER_CLEARANCE * z0  # the body's lower edge between the wheels, above the lowest point
    bottom = [(0.0, sill + 0.08), (0.3, sill), (length - 0.3, sill), (length, sill + 0.12)]
    top_s, top_z = np.array(top).T
    bot_s, bot_z = np.array(bottom).T
    rc = 0.12 + 0.3 * rnd  # plan-view corner radius
    e, c, crown = 2.0 + 6.0 * (1.0 - rnd), 0.04 + 0.06 * rnd, 0.03 + 0.07 * rnd

    def station(s: float) -> tuple[float, float, float, float, float]:
        """(bottom, belt, top, body half-width, roof-line half-width) at s."""
        t, b = float(np.interp(s, top_s, top_z)), float(np.interp(s, bot_s, bot_z))
        belt = max(min(zb, t - crown), b + c + 0.02)
        t = max(t, belt + 0.01)
        d = min(s, length - s)
        wb = width / 2 - (rc - math.sqrt(max(rc * rc - (rc - d) ** 2, 0.0)) if d < rc else 0.0)
        frac = min(max((t - zb) / (H - zb), 0.0), 1.0)
        return b, belt, t, wb, wb * (1.0 - (1.0 - sh.roof_w) * frac)

    stations = sorted({round(float(v), 3) for v in (*top_s, *bot_s, rc / 3, rc * 2 / 3, length - rc / 3,
                                                      length - rc * 2 / 3) if 0.0 <= v <= length})
    stations = [v for k, v in enumerate(stations) if k == 0 or v - stations[k - 1] >= 0.03]
    stations[-1] = length
    rings = []
    for s in stations:
        b, belt, t, wb, wr = station(s)
        rings.append([(s, y, z) for y, z in _section(b, belt, t, wb, wr, e, c)])

    def at(s: float) -> tuple[float, float, float]:
        _, belt, t, wb, wr = station(s)
        return belt, t, (wb + (wr - wb) * _CAP_V[-1]) * (1 - _CAP_V[-1] ** e) ** (1 / e)

    return sweep(rings), at


def _road(spec: Road) -> tuple[list[_Link], str]:
    """Swept body (:func:`_road_body`), wheels, door mirrors, and the optional roof rails, tailgate
    spare wheel, pickup bed or van box."""
    L, W, H, sh = spec.length, spec.width, spec.height, spec.shape
    x = _body_x(L)
    hull = _Link("hull")
    rear = spec.bed or spec.box
    body = L - rear - 0.03 if rear else L - (_SPARE_W if spec.spare else 0.0)  # the cab ends where a bed or box starts
    cab_w, cab_h = spec.cab if spec.cab is not None else (W, H)
    (verts, faces), at = _road_body(spec, body, cab_w, cab_h)
    verts = verts.copy()
    verts[:, 0] = [x(s) for s in verts[:, 0]]  # s -> x mirrors the part: flip the faces to keep them outwards
    hull.lofts.append(("body", (verts, np.ascontiguousarray(faces[:, ::-1]))))
    _wheels(hull, spec, (spec.front, spec.front + spec.wheelbase), x)
    z0, zb = spec.clearance, sh.belt * (cab_h - spec.rails)
    if spec.mirror > 0:  # door mirrors just behind the windshield base
        s_m = sh.windshield * body + 0.15
        for side in (1, -1):
            hull.box((0.1, spec.mirror + 0.06, 0.16), (x(s_m), side * (cab_w / 2 + spec.mirror / 2 - 0.03), zb + 0.12))
    if spec.rails > 0:  # two rails along the roof, their tops at the published height
        s0, s1 = sh.roof[0] * body + 0.1, sh.roof[1] * body - 0.1
        belt, roof, y_edge = at((s0 + s1) / 2)
        z_cap = belt + _CAP_V[-1] * (roof - belt)  # the roof's edge, where the rails stand
        for side in (1, -1):
            hull.box((s1 - s0, 0.05, cab_h - z_cap), (x((s0 + s1) / 2), side * (y_edge - 0.05), (cab_h + z_cap) / 2))
    if spec.spare:
        hull.cylinder(spec.wheel_d / 2, _SPARE_W + 0.02, (x(body + _SPARE_W / 2 - 0.01), 0.0,
                                                           zb - spec.wheel_d / 2 + 0.15), "x")
    if spec.bed:
        s0, floor, rail = body + 0.03, spec.wheel_d + 0.08, zb
        mid, length = x((s0 + L) / 2), L - s0
        hull.box((length - 0.1, W - 0.12, 0.06), (mid, 0.0, floor - 0.03))  # floor
        hull.box((length, 0.9, floor - z0 - 0.1), (mid, 0.0, (floor + z0 + 0.1) / 2))  # frame under the bed
        bottom = z0 + 0.3
        for side in (1, -1):
            hull.box((length, 0.06, rail - bottom), (mid, side * (W / 2 - 0.03), (rail + bottom) / 2))  # sides
        hull.box((0.06, W - 0.12, rail - bottom - 0.05), (x(L - 0.03), 0.0, (rail + bottom + 0.05) / 2))  # tailgate
    if spec.box:
        s0, floor = body + 0.03, spec.wheel_d + 0.1
        hull.box((L - s0, W, H - floor), (x((s0 + L) / 2), 0.0, (H + floor) / 2))
        hull.box((L - s0, 0.9, floor - z0 - 0.1), (x((s0 + L) / 2), 0.0, (floor + z0 + 0.1) / 2))  # frame
    _extras({"hull": hull}, spec.extras, x)
    return [hull], ""


def vehicle_files(spec: Spec) -> dict[str, str]:
    """File name -> text of one vehicle: ``<name>.urdf`` and one OBJ per link with lofted parts."""
    builder = {Tracked: _tracked, Wheeled: _wheeled, Road: _road}[type(spec)]
    try:
        links, joints = builder(spec)
    except (ValueError, ArithmeticError, IndexError) as exc:  # a spec that passed validation but cannot be built
        raise ValueError(f"{spec.name}: cannot build the {type(spec).__name__} from its spec: {exc}") from exc
    header = f"{spec.title}: generated by `python -m torch_atr.vehicles.build` from specs.py; do not edit."
    files: dict[str, str] = {}
    body = []
    for link in links:
        visuals = list(link.visuals)
        if link.lofts:
            files[f"{link.name}.obj"] = obj_text(link.lofts, header)
            visuals.insert(0, f'    <visual>\n      <geometry><mesh filename="{link.name}.obj"/></geometry>\n    </visual>')
        body.append(f'  <link name="{link.name}">\n' + "\n".join(visuals) + "\n  </link>\n")
    files[f"{spec.name}.urdf"] = (
        f'<?xml version="1.0"?>\n<!-- {header} -->\n<robot name="{spec.name}">\n' + "".join(body) + joints + "</robot>\n"
    )
    return files


def build_catalog(out_dir: str | Path = CATALOG_DIR) -> list[Path]:
    """Write every split's vehicles under ``out_dir/<split>/<name>/``; returns the files written.

    Every vehicle is generated before anything is written, and every split is written in full into
    a staging folder beside it before any of them replaces its old split folder, so vehicles
    removed from the specs disappear and a spec that fails to build, a write that fails, or a split
    folder that cannot be replaced leaves the old catalog as it was.
    """
    out_dir = Path(out_dir)
    texts = {split: {spec.name: vehicle_files(spec) for spec in specs} for split, specs in SPLITS.items()}
    folders = {split: (out_dir / split, out_dir / f".{split}.building", out_dir / f".{split}.old") for split in texts}
    swapped = []  # (final, old) of the splits whose folder is (being) replaced, the old one moved to ``old``
    try:  # every split written before any replaces its folder (a full disk in test left a new train split)
        for split, vehicles in texts.items():
            staging = folders[split][1]
            shutil.rmtree(staging, ignore_errors=True)  # left by a killed build
            for name, files in vehicles.items():
                for fname, text in files.items():
                    atomic_write_text(text, staging / name / fname)
        for final, staging, old in folders.values():
            shutil.rmtree(old, ignore_errors=True)
            if final.exists():
                final.rename(old)
            swapped.append((final, old))
            staging.rename(final)
    except BaseException:
        for final, old in swapped:  # a replaced split goes back too, not only the one that failed
            shutil.rmtree(final, ignore_errors=True)
            if old.exists():
                old.rename(final)
        for _, staging, _ in folders.values():
            shutil.rmtree(staging, ignore_errors=True)
        raise
    for _, _, old in folders.values():
        shutil.rmtree(old, ignore_errors=True)
    return [folders[split][0] / name / fname for split, vehicles in texts.items() for name, files in vehicles.items()
            for fname in files]


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Generate the vehicle catalog from specs.py.")
    parser.add_argument("--out", type=Path, default=CATALOG_DIR, help="output folder (default: the package catalog)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    files = build_catalog(args.out)
    size = sum(p.stat().st_size for p in files)
    log.info("wrote %d files (%.1f KB) under %s", len(files), size / 1024, args.out)


if __name__ == "__main__":
    main()
