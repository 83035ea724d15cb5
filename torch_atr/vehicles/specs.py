"""Published dimensions of the catalog vehicles and the few shape numbers that build them.

``python -m torch_atr.vehicles.build`` turns each spec into a URDF plus part meshes. Overall
length / width / height, wheelbase or axle positions, and (tanks) hull length and length with
the gun forward are the published figures for the stated model and body; the ``source`` field
says whose. They were compiled from reference knowledge of manufacturers' data sheets and the
usual tabulations of them (Jane's, Wikipedia infoboxes), without a live look-up, so expect
+-1-2 % against a particular brochure. Everything else (deck heights, turret sizes, glacis
runs, shape fractions, rounding, door-mirror reach) is estimated from side-view drawings and
photographs; it shapes the silhouette, not the headline dimensions that tests check.

Each class spans the real range of its kind, not one archetype (docs/recognition.md):
- tanks, one of each kind: a light tank, Second World War medium and heavy tanks, Cold War and
  current main battle tanks and a self-propelled howitzer (SENSIAC's tank class holds a
  howitzer and an anti-aircraft gun);
- APCs half tracked, half wheeled, from 4 x 4 to 8 x 8;
- SUVs from 4.2 m, 1.6 m high subcompact crossovers to 5.1 m, 2 m high body-on-frame SUVs;
- cars from a 3.5 m city car to 4.9 m saloons;
- vans from minivans to one-box, high-roof and cutaway box vans.

Conventions for the numbers below (metres, degrees):
- ``s`` positions are measured backwards from the front of the hull / body;
- turret coordinates: x ahead of the turret axis, y to the left, z above the deck;
- gun coordinates: x ahead of the trunnion along the barrel, y left, z up.

The SENSIAC-like TEST split (T-72, ZSU-23-4, 2S3, BTR-70, BRDM-2, BMP-2, Ford F-150, Isuzu
Rodeo) is held out from TRAIN: no name appears in both.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
from dataclasses import dataclass

from torch_atr.vehicles.loader import CLASS_NAMES


_NAME = re.compile(r"[a-z0-9_]+")  # a folder and file name that load_catalog_vehicle's normalised key can match


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _named_options(cls):
    """Make an unknown keyword of a vehicle spec a ValueError naming the vehicle and the option (the
    dataclass's own TypeError names neither the vehicle nor the options there are)."""
    init = cls.__init__
    names = [f.name for f in dataclasses.fields(cls)]

    @functools.wraps(init)
    def __init__(self, *args, **kwargs):
        unknown = sorted(set(kwargs) - set(names))
        if unknown:
            vehicle = kwargs.get("name", args[0] if args else "?")
            raise ValueError(f"{vehicle}: unknown {cls.__name__} option(s) {unknown}; the options are {names}")
        init(self, *args, **kwargs)

    cls.__init__ = __init__
    return cls


@dataclass(frozen=True)
class Extra:
    """A box or cylinder added to a link (cupola, sight, radar, launcher, fuel drum, shield).

    ``xyz`` is the centre in the link's spec coordinates: hull (s, y, z above ground), turret
    (x, y, z above deck), gun (x, y, z). Box ``size`` = (sx, sy, sz); cylinder ``size`` =
    (radius, length) with the axis along ``axis``.
    """

    link: str  # "hull" | "turret" | "gun"
    shape: str  # "box" | "cylinder"
    size: tuple[float, ...]
    xyz: tuple[float, float, float]
    axis: str = "z"

    def __post_init__(self) -> None:
        if self.link not in ("hull", "turret", "gun") or self.shape not in ("box", "cylinder"):
            raise ValueError(f"Extra: bad link/shape {self.link!r}/{self.shape!r}")
        if len(self.size) != (3 if self.shape == "box" else 2) or self.axis not in ("x", "y", "z"):
            raise ValueError(f"Extra: bad size {self.size} or axis {self.axis!r} for a {self.shape}")


@dataclass(frozen=True)
class Gun:
    """Barrel(s) on the ``gun_pitch`` joint (axis -Y, so positive pitch raises the muzzle)."""

    diameter: float  # barrel outer diameter
    trunnion: tuple[float, float]  # (x ahead of the turret axis, z above the deck)
    length: float | None = None  # trunnion -> muzzle; None: reach the spec's gun_length
    elevation: tuple[float, float] = (-10.0, 20.0)  # (lowest, highest), degrees
    barrels: tuple[tuple[float, float], ...] = ((0.0, 0.0),)  # (y, z) of parallel barrels
    mantlet: tuple[float, float, float] = (0.5, 0.8, 0.4)  # box (sx, sy, sz) at the trunnion
    evacuator: float = 0.0  # bore evacuator at this fraction of the barrel (0: none)
    brake: bool = False  # muzzle brake


@dataclass(frozen=True)
class Turret:
    """A faceted (or round) turret on the ``turret_yaw`` joint (axis +Z, counter-clockwise)."""

    ring: float  # turret axis behind the hull front (s)
    front: float  # axis -> front of the turret floor
    rear: float  # axis -> rear of the turret floor (bustle)
    width: float
    height: float  # roof above the deck
    gun: Gun
    nose: float = 0.6  # front-face half-width / half-width (small: wedge), <= 0.9
    slope: float = 0.3  # the roof's front edge is this far behind the floor's
    taper: float = 0.1  # roof inset at the sides and rear
    round: bool = False  # elliptical plan (dome / cone) instead of faceted
    offset: float = 0.0  # y of the turret axis


@_named_options
@dataclass(frozen=True)
class Tracked:
    """Tank, tracked APC / IFV / SPG: hull between and over two track runs, optional turret."""

    name: str
    title: str
    cls: str
    source: str
    length: float  # hull length
    width: float
    height: float
    gun_length: float | None  # overall length with the gun forward; None: gun within the hull
    deck: float  # hull roof height
    nose: float  # height of the glacis' front edge
    glacis: float  # horizontal run of the upper glacis (nose -> deck)
    road_wheels: int
    wheel_d: float  # road-wheel diameter
    track_w: float  # track width
    contact: float  # track ground-contact length
    lower_glacis: float = 0.55  # horizontal run nose -> belly
    belly: float = 0.45  # ground clearance
    rear_slope: float = 0.15  # horizontal run of the rear plate
    skirts: bool = True  # side skirts over the upper track run
    turret: Turret | None = None
    extras: tuple[Extra, ...] = ()

    def __post_init__(self) -> None:
        _check_common(self)
        if self.turret is None and self.gun_length is not None:
            raise ValueError(f"{self.name}: gun_length {self.gun_length} needs a turret with a gun; there is none")
        if self.gun_length is not None and not (_number(self.gun_length) and self.gun_length > self.length):
            raise ValueError(f"{self.name}: gun_length {self.gun_length} must exceed the hull length")
        if (self.gun_length is None) == (self.turret is not None and self.turret.gun.length is None):
            raise ValueError(f"{self.name}: give exactly one of gun_length and turret.gun.length")
        _check_layout(self)


@_named_options
@dataclass(frozen=True)
class Wheeled:
    """Wheeled APC / scout car: narrow lower hull between the wheels, wide upper hull over them."""

    name: str
    title: str
    cls: str
    source: str
    length: float
    width: float
    height: float
    axles: tuple[float, ...]  # axle positions s
    wheel_d: float
    tyre_w: float
    track: float  # tyre centre to tyre centre across the vehicle
    deck: float  # hull roof height
    nose: float  # height where the lower and upper glacis meet
    glacis: float  # horizontal run nose -> roof
    lower_glacis: float  # horizontal run nose -> belly
    belly: float = 0.45
    rear_slope: float = 0.4  # horizontal run of the rear plate above the wheels
    side_slope: float = 0.25  # the roof is this much narrower on each side than the widest level
    turret: Turret | None = None
    extras: tuple[Extra, ...] = ()

    def __post_init__(self) -> None:
        _check_common(self)
        if self.turret is not None and self.turret.gun.length is None:
            raise ValueError(f"{self.name}: a wheeled vehicle has no gun_length to reach; give turret.gun.length")
        _check_layout(self)


@dataclass(frozen=True)
class Shape:
    """Side-profile fractions of a road vehicle.

    Heights are fractions of the overall height; positions are fractions of the body length
    behind the front (the whole length, or for a pickup the part in front of the bed).
    """

    nose: float  # bonnet front edge height
    belt: float  # belt line: bonnet rear, window sills
    windshield: float  # windshield base
    roof: tuple[float, float]  # roof start, roof end
    tail: float  # rear-glass base (sedan: start of the boot)
    deck: float  # boot lid / tail top height
    roof_w: float = 0.84  # half-width of the tumblehome line at the roof / body half-width
    round: float = 0.6  # 0: boxy (a Defender) .. 1: rounded (a modern hatchback); see build._road_body
    drop: float = 0.0  # the roof falls by this fraction of the height from its start to its end

    def __post_init__(self) -> None:
        values = (self.nose, self.belt, self.windshield, *self.roof, self.tail, self.deck, self.roof_w, self.round,
                  self.drop)
        if len(self.roof) != 2 or not all(_number(v) for v in values):
            raise ValueError(f"Shape: expected numbers and a (start, end) roof; got {self}")
        if not (0.0 <= self.round <= 1.0 and 0.0 <= self.drop < 1.0 - self.belt):
            raise ValueError(f"Shape.round must be in [0, 1] and Shape.drop in [0, 1 - belt); got {self.round}, "
                             f"{self.drop}")
        if not 0.0 < self.nose <= self.belt < 1.0 or not 0.0 < self.deck < 1.0:
            raise ValueError(f"Shape: heights must satisfy 0 < nose <= belt < 1 and 0 < deck < 1; got nose "
                             f"{self.nose}, belt {self.belt}, deck {self.deck}")
        if not 0.0 < self.windshield < self.roof[0] < self.roof[1] <= self.tail <= 1.0:
            raise ValueError(f"Shape: positions must satisfy 0 < windshield < roof[0] < roof[1] <= tail <= 1; got "
                             f"windshield {self.windshield}, roof {self.roof}, tail {self.tail}")
        if not 0.0 < self.roof_w <= 1.0:
            raise ValueError(f"Shape.roof_w must be in (0, 1]; got {self.roof_w}")


# Body styles (adjusted per vehicle with dataclasses.replace where it differs).
SEDAN = Shape(nose=0.52, belt=0.68, windshield=0.34, roof=(0.47, 0.68), tail=0.83, deck=0.72, roof_w=0.78, round=0.85)
HATCH = Shape(nose=0.50, belt=0.64, windshield=0.30, roof=(0.45, 0.88), tail=0.975, deck=0.64, roof_w=0.80, round=0.85,
              drop=0.04)
SUV = Shape(nose=0.55, belt=0.60, windshield=0.32, roof=(0.45, 0.965), tail=0.99, deck=0.60, roof_w=0.86, round=0.5)
# A compact crossover: car-like rounding on an SUV's ride height, the roof falling to a raked tailgate.
CROSSOVER = Shape(nose=0.55, belt=0.62, windshield=0.31, roof=(0.46, 0.9), tail=0.985, deck=0.62, roof_w=0.8,
                  round=0.85, drop=0.05)
MINIVAN = Shape(nose=0.48, belt=0.54, windshield=0.21, roof=(0.40, 0.965), tail=0.99, deck=0.54, roof_w=0.86,
                round=0.8)
ONE_BOX = Shape(nose=0.50, belt=0.52, windshield=0.11, roof=(0.25, 0.985), tail=0.995, deck=0.52, roof_w=0.9,
                round=0.45)
# Cab-over van (forward control): no bonnet, a near-vertical front up to the windshield.
CAB_OVER = Shape(nose=0.42, belt=0.50, windshield=0.04, roof=(0.16, 0.99), tail=0.995, deck=0.50, roof_w=0.9,
                 round=0.3)
CREW_CAB = Shape(nose=0.58, belt=0.66, windshield=0.40, roof=(0.55, 0.97), tail=1.0, deck=0.66, roof_w=0.86, round=0.4)
EXT_CAB = Shape(nose=0.58, belt=0.66, windshield=0.46, roof=(0.62, 0.97), tail=1.0, deck=0.66, roof_w=0.86, round=0.4)
REG_CAB = Shape(nose=0.58, belt=0.66, windshield=0.52, roof=(0.71, 0.97), tail=1.0, deck=0.66, roof_w=0.86, round=0.4)


@_named_options
@dataclass(frozen=True)
class Road:
    """Pickup, SUV, car or minivan: a lower body, a greenhouse, four wheels (and a bed)."""

    name: str
    title: str
    cls: str
    source: str
    length: float
    width: float
    height: float
    wheelbase: float
    front: float  # front overhang: front axle s
    wheel_d: float
    track: float
    shape: Shape
    bed: float = 0.0  # pickup bed length (0: none)
    clearance: float = 0.18
    tyre_w: float = 0.24
    mirror: float = 0.12  # reach of each door mirror beyond the body side (not in the published width)
    rails: float = 0.0  # roof-rail height (0: none); the published height includes them
    spare: bool = False  # a spare wheel on the tailgate; the published length includes it
    box: float = 0.0  # box van: length of the closed box body behind the cab (0: none)
    cab: tuple[float, float] | None = None  # box van: (width, height) of the cab; the box is width x height
    extras: tuple[Extra, ...] = ()

    def __post_init__(self) -> None:
        _check_common(self)
        if self.front + self.wheelbase >= self.length:
            raise ValueError(f"{self.name}: front overhang + wheelbase must be shorter than the length")
        if not self.front >= self.wheel_d / 2 or not self.front + self.wheelbase + self.wheel_d / 2 <= self.length:
            raise ValueError(f"{self.name}: the wheels (wheel_d {self.wheel_d}, front {self.front}, wheelbase "
                             f"{self.wheelbase}) stick out of the length {self.length}")
        if (self.bed > 0) != (self.cls == "pickup"):
            raise ValueError(f"{self.name}: exactly the pickups have a bed")
        if (self.box > 0) != (self.cab is not None) or (self.box > 0 and self.cls != "minivan"):
            raise ValueError(f"{self.name}: a box body (box > 0) needs a cab size, and only vans have one")
        if self.cab is not None and not (0 < self.cab[0] <= self.width and 0 < self.cab[1] < self.height):
            raise ValueError(f"{self.name}: the cab {self.cab} must be no wider and lower than the box")
        _check_layout(self)


Spec = Tracked | Wheeled | Road


# Fields in metres that must be positive, and those that may also be 0, per spec type.
_POSITIVE = {
    "Tracked": ("length", "width", "height", "deck", "nose", "wheel_d", "track_w", "contact", "belly"),
    "Wheeled": ("length", "width", "height", "wheel_d", "tyre_w", "track", "deck", "nose", "belly"),
    "Road": ("length", "width", "height", "wheelbase", "front", "wheel_d", "track", "clearance", "tyre_w"),
}
_NON_NEGATIVE = {
    "Tracked": ("glacis", "lower_glacis", "rear_slope"),
    "Wheeled": ("glacis", "lower_glacis", "rear_slope", "side_slope"),
    "Road": ("bed", "mirror", "rails", "box"),
}
_TURRET_POSITIVE = ("ring", "front", "rear", "width", "height")
_TURRET_NON_NEGATIVE = ("slope", "taper")


def _check_numbers(name: str, obj, positive: tuple[str, ...], non_negative: tuple[str, ...], prefix: str = "") -> None:
    """ValueError naming the vehicle and the field for a field of ``obj`` that is not a finite number > 0
    (``positive``) or >= 0 (``non_negative``)."""
    for f in (*positive, *non_negative):
        value, zero_ok = getattr(obj, f), f in non_negative
        if not (_number(value) and (value >= 0 if zero_ok else value > 0)):
            what = "a non-negative" if zero_ok else "a positive"
            raise ValueError(f"{name}: {prefix}{f} must be {what} number (metres); got {value!r}")


def _check_common(spec) -> None:
    if not (isinstance(spec.name, str) and _NAME.fullmatch(spec.name)):
        raise ValueError(f"{spec.name!r}: a vehicle name must be lower-case letters, digits and underscores (it "
                         f"names the catalog folder and files)")
    if spec.cls not in CLASS_NAMES:
        raise ValueError(f"{spec.name}: class {spec.cls!r} is not one of {CLASS_NAMES}")
    kind = type(spec).__name__
    _check_numbers(spec.name, spec, _POSITIVE[kind], _NON_NEGATIVE[kind])
    if isinstance(spec, (Wheeled, Road)) and spec.track / 2 + spec.tyre_w / 2 > spec.width / 2 + 1e-9:
        raise ValueError(f"{spec.name}: wheels (track {spec.track}, tyre {spec.tyre_w}) "
                         f"stick out of width {spec.width}")
    turret = getattr(spec, "turret", None)
    if turret is not None:
        _check_numbers(spec.name, turret, _TURRET_POSITIVE, _TURRET_NON_NEGATIVE, "turret.")
        if not 0 < turret.nose <= 0.9:
            raise ValueError(f"{spec.name}: turret.nose must be in (0, 0.9]; got {turret.nose}")
        gun = turret.gun
        if not (_number(gun.diameter) and gun.diameter > 0):
            raise ValueError(f"{spec.name}: turret.gun.diameter must be a positive number (metres); "
                             f"got {gun.diameter!r}")
        if gun.length is not None and not (_number(gun.length) and gun.length > 0):
            raise ValueError(f"{spec.name}: turret.gun.length must be a positive number (metres) or None; "
                             f"got {gun.length!r}")
        for f, values in (("trunnion", gun.trunnion), ("elevation", gun.elevation), ("mantlet", gun.mantlet),
                          ("barrels", [v for b in gun.barrels for v in b])):
            if not all(_number(v) for v in values):  # a NaN barrel position was written into the URDF as 'nan'
                raise ValueError(f"{spec.name}: turret.gun.{f} must be finite numbers; got {getattr(gun, f)!r}")


def _check_layout(spec) -> None:
    """Relations between a vehicle's numbers that the builder needs (ValueError naming the vehicle and
    the fields): wheels, tracks and turret inside the body, heights in order, extras on links it has."""
    n = spec.name
    if isinstance(spec, Road):
        if not spec.rails < (1.0 - spec.shape.belt) * spec.height:
            raise ValueError(f"{n}: rails {spec.rails} are taller than the glasshouse ((1 - shape.belt) x height = "
                             f"{(1.0 - spec.shape.belt) * spec.height:.3f} m)")
        H = (spec.cab[1] if spec.cab is not None else spec.height) - spec.rails
        if not spec.wheel_d < spec.shape.belt * H:
            raise ValueError(f"{n}: wheel_d {spec.wheel_d} reaches above the belt line (shape.belt x height = "
                             f"{spec.shape.belt * H:.3f} m)")
        if not spec.clearance < spec.wheel_d / 2:
            raise ValueError(f"{n}: clearance {spec.clearance} must be below the axles (wheel_d / 2 = "
                             f"{spec.wheel_d / 2})")
        rear = spec.bed or spec.box
        if rear and not spec.length - rear - 0.03 > spec.front + spec.wheel_d / 2:
            raise ValueError(f"{n}: {'bed' if spec.bed else 'box'} {rear} leaves no cab behind the front wheels "
                             f"(length {spec.length}, front {spec.front})")
    else:
        if not spec.belly < spec.nose < spec.deck <= spec.height:
            raise ValueError(f"{n}: heights must satisfy belly < nose < deck <= height; got belly {spec.belly}, "
                             f"nose {spec.nose}, deck {spec.deck}, height {spec.height}")
        if not (spec.lower_glacis < spec.length - 0.35 and spec.glacis + spec.rear_slope < spec.length):
            raise ValueError(f"{n}: glacis {spec.glacis}, lower_glacis {spec.lower_glacis} and rear_slope "
                             f"{spec.rear_slope} do not fit in the length {spec.length}")
    if isinstance(spec, Tracked):
        if not (isinstance(spec.road_wheels, int) and spec.road_wheels >= 2):
            raise ValueError(f"{n}: road_wheels must be an integer >= 2; got {spec.road_wheels!r}")
        if not spec.contact < spec.length:
            raise ValueError(f"{n}: contact {spec.contact} must be shorter than the length {spec.length}")
        if not spec.wheel_d + 0.18 < spec.deck:
            raise ValueError(f"{n}: wheel_d {spec.wheel_d} puts the track's top run (wheel_d + 0.18 m) above the "
                             f"deck {spec.deck}")
        if not spec.track_w < spec.width / 2 - 0.09:
            raise ValueError(f"{n}: two tracks of track_w {spec.track_w} leave no hull between them in width "
                             f"{spec.width}")
    if isinstance(spec, Wheeled):
        if not spec.axles or not all(_number(s) and spec.wheel_d / 2 <= s <= spec.length - spec.wheel_d / 2
                                     for s in spec.axles):
            raise ValueError(f"{n}: axles {spec.axles} must be one or more positions that keep the wheels "
                             f"(wheel_d {spec.wheel_d}) inside the length {spec.length}")
        if not spec.belly < spec.wheel_d < spec.deck - 0.1:
            raise ValueError(f"{n}: wheel_d {spec.wheel_d} must be above the belly {spec.belly} and reach no higher "
                             f"than 0.1 m below the deck {spec.deck}")
        if not (spec.side_slope < spec.width / 2 and spec.track / 2 - spec.tyre_w / 2 > 0.05):
            raise ValueError(f"{n}: side_slope {spec.side_slope} or the wheels (track {spec.track}, tyre_w "
                             f"{spec.tyre_w}) leave no hull in width {spec.width}")
    turret = getattr(spec, "turret", None)
    if turret is not None:
        t, g = turret, turret.gun
        if not t.slope < t.front:
            raise ValueError(f"{n}: turret.slope {t.slope} must be below turret.front {t.front}")
        if not (t.taper < t.rear and t.taper < t.width / 2):
            raise ValueError(f"{n}: turret.taper {t.taper} must be below turret.rear {t.rear} and half turret.width "
                             f"{t.width}")
        if not (t.ring - t.front >= 0 and t.ring + t.rear <= spec.length
                and abs(t.offset) + t.width / 2 <= spec.width / 2 and spec.deck + t.height <= spec.height + 1e-9):
            raise ValueError(f"{n}: the turret (ring {t.ring}, front {t.front}, rear {t.rear}, width {t.width}, "
                             f"offset {t.offset}, height {t.height} above the deck {spec.deck}) is not on the hull "
                             f"(length {spec.length}, width {spec.width}, height {spec.height})")
        lo, hi = g.elevation
        if not lo <= 0.0 <= hi or lo == hi:
            raise ValueError(f"{n}: turret.gun.elevation {g.elevation} must be (lowest <= 0 <= highest), not equal")
        if not g.barrels or not all(m > 0 for m in g.mantlet) or not 0.0 <= g.evacuator < 1.0:
            raise ValueError(f"{n}: turret.gun needs barrels, a positive mantlet and evacuator in [0, 1); got "
                             f"{g.barrels}, {g.mantlet}, {g.evacuator}")
        if g.length is None and not t.ring - g.trunnion[0] + spec.gun_length - spec.length > 0:
            raise ValueError(f"{n}: gun_length {spec.gun_length} leaves the muzzle behind the trunnion")
    links = ("hull",) if turret is None else ("hull", "turret", "gun")
    for i, e in enumerate(spec.extras):
        if e.link not in links:
            raise ValueError(f"{n}: extras[{i}] is on the {e.link}, which the vehicle does not have")
        if not all(_number(v) and v > 0 for v in e.size):
            raise ValueError(f"{n}: extras[{i}].size must be positive numbers; got {e.size}")
        if not all(_number(v) for v in e.xyz):  # a NaN centre was written into the URDF as 'nan'
            raise ValueError(f"{n}: extras[{i}].xyz must be finite numbers; got {e.xyz}")


def _cupola(x: float, y: float, d: float, z_top: float, h: float) -> Extra:
    """Commander's cupola / sight: a cylinder of diameter d whose top is at z_top (turret coordinates)."""
    return Extra("turret", "cylinder", (d / 2, h), (x, y, z_top - h / 2))


# ----------------------------------------------------------------------------------------------
# Training split: 6 per class.
# ----------------------------------------------------------------------------------------------
TANKS = (
    Tracked(
        "m1a2_abrams", "M1A2 Abrams", "tank", "General Dynamics Land Systems / US Army fact file",
        length=7.93, width=3.66, height=2.44, gun_length=9.77,
        deck=1.45, nose=0.95, glacis=1.7, road_wheels=7, wheel_d=0.64, track_w=0.635, contact=4.62,
        turret=Turret(ring=3.9, front=2.0, rear=2.9, width=3.5, height=0.85, nose=0.45, slope=0.9, taper=0.12,
                      gun=Gun(0.2, trunnion=(1.6, 0.42), mantlet=(0.5, 0.9, 0.4), evacuator=0.55)),
        extras=(_cupola(-0.3, 0.6, 0.6, 0.99, 0.2),),
    ),
    # An early Cold War tank: a low hull, five large road wheels without return rollers, a cast dome turret.
    Tracked(
        "t_55", "T-55A", "tank", "Jane's Armour and Artillery",
        length=6.45, width=3.27, height=2.35, gun_length=9.0,
        deck=1.6, nose=0.95, glacis=1.15, road_wheels=5, wheel_d=0.81, track_w=0.58, contact=3.84,
        lower_glacis=0.5, belly=0.42, skirts=False,
        turret=Turret(ring=2.5, front=1.15, rear=1.15, width=2.25, height=0.75, round=True, slope=0.4, taper=0.45,
                      gun=Gun(0.14, trunnion=(0.95, 0.3), elevation=(-5.0, 18.0), mantlet=(0.35, 0.5, 0.35),
                              evacuator=0.9)),
        extras=(_cupola(-0.2, -0.5, 0.55, 0.72, 0.2),),
    ),
    # A Second World War heavy tank: a tall box hull with a vertical front plate and a superstructure over
    # the tracks, interleaved road wheels, a box turret with a short thick gun and muzzle brake.
    Tracked(
        "tiger_i", "Panzerkampfwagen VI Tiger I (Ausf. E)", "tank", "Jentz & Doyle, Germany's Tiger Tanks",
        length=6.316, width=3.547, height=3.0, gun_length=8.45,
        deck=1.9, nose=1.55, glacis=0.85, road_wheels=8, wheel_d=0.8, track_w=0.725, contact=3.6,
        lower_glacis=0.45, belly=0.47, rear_slope=0.1, skirts=False,
        turret=Turret(ring=2.9, front=1.2, rear=1.5, width=2.8, height=0.85, nose=0.85, slope=0.15, taper=0.08,
                      gun=Gun(0.17, trunnion=(1.25, 0.45), elevation=(-8.0, 15.0), mantlet=(0.45, 1.1, 0.7),
                              brake=True)),
        extras=(_cupola(-0.6, 0.7, 0.75, 1.1, 0.3),),
    ),
    # A self-propelled howitzer (SENSIAC's tank class holds the 2S3 and the ZSU-23-4): a large box turret
    # over the rear two thirds of the hull and a long barrel with a muzzle brake.
    Tracked(
        "m109_paladin", "M109A6 Paladin", "tank", "BAE Systems (United Defense) / US Army fact file",
        length=6.19, width=3.15, height=3.24, gun_length=9.12,
        deck=1.6, nose=1.0, glacis=1.0, road_wheels=7, wheel_d=0.61, track_w=0.38, contact=3.96,
        lower_glacis=0.55, belly=0.45, rear_slope=0.05, skirts=False,
        turret=Turret(ring=4.0, front=1.7, rear=2.1, width=3.0, height=1.45, nose=0.85, slope=0.35, taper=0.1,
                      gun=Gun(0.22, trunnion=(1.5, 0.7), elevation=(-3.0, 75.0), mantlet=(0.5, 0.8, 0.6),
                              evacuator=0.45, brake=True)),
        extras=(_cupola(-0.5, 0.8, 0.7, 1.64, 0.2),),
    ),
    # A light tank: a small hull, five small road wheels, a small turret near the rear.
    Tracked(
        "fv101_scorpion", "FV101 Scorpion", "tank", "Alvis / British Army equipment data",
        length=4.52, width=2.235, height=2.102, gun_length=4.79,
        deck=1.45, nose=0.75, glacis=1.3, road_wheels=5, wheel_d=0.55, track_w=0.432, contact=2.46,
        lower_glacis=0.45, belly=0.35, rear_slope=0.05, skirts=False,
        turret=Turret(ring=2.85, front=0.75, rear=0.85, width=1.75, height=0.55, nose=0.5, slope=0.3, taper=0.2,
                      gun=Gun(0.11, trunnion=(0.6, 0.28), elevation=(-10.0, 35.0), mantlet=(0.3, 0.45, 0.3))),
        extras=(_cupola(-0.3, 0.4, 0.5, 0.65, 0.15),),
    ),
    # A Second World War medium tank: a tall narrow hull (radial engine) with sponsons over the tracks,
    # six small road wheels in three bogies, a cast round turret with a short gun.
    Tracked(
        "m4_sherman", "M4A1 Sherman (75 mm)", "tank", "US Army TM 9-731B / Hunnicutt, Sherman",
        length=5.84, width=2.62, height=2.74, gun_length=6.1,
        deck=1.95, nose=1.0, glacis=1.3, road_wheels=6, wheel_d=0.51, track_w=0.42, contact=3.7,
        lower_glacis=0.6, belly=0.43, rear_slope=0.1, skirts=False,
        turret=Turret(ring=2.6, front=1.0, rear=1.2, width=2.0, height=0.65, round=True, slope=0.35, taper=0.3,
                      gun=Gun(0.12, trunnion=(0.85, 0.3), elevation=(-10.0, 25.0), mantlet=(0.35, 0.7, 0.45))),
        extras=(_cupola(-0.4, 0.45, 0.6, 0.79, 0.2),),
    ),
)

APCS = (
    Tracked(
        "m113", "M113A2", "apc", "FMC / US Army TM 9-2350-261-10",
        length=4.863, width=2.686, height=2.5, gun_length=None,
        deck=1.85, nose=1.25, glacis=1.0, road_wheels=5, wheel_d=0.61, track_w=0.38, contact=2.67,
        lower_glacis=0.3, belly=0.43, rear_slope=0.02, skirts=False,
        turret=Turret(ring=2.3, front=0.45, rear=0.45, width=0.9, height=0.32, round=True, slope=0.08, taper=0.08,
                      gun=Gun(0.06, trunnion=(0.3, 0.42), length=1.3, elevation=(-15.0, 60.0),
                              mantlet=(0.45, 0.2, 0.22))),
        extras=(Extra("gun", "box", (0.04, 0.7, 0.4), (0.3, 0.0, 0.03)),),  # gun shield
    ),
    Tracked(
        "m2_bradley", "M2A2 Bradley", "apc", "BAE Systems (United Defense) / US Army fact file",
        length=6.55, width=3.6, height=2.98, gun_length=None,
        deck=1.95, nose=1.0, glacis=1.4, road_wheels=6, wheel_d=0.6, track_w=0.53, contact=3.9,
        turret=Turret(ring=2.9, front=1.0, rear=1.1, width=2.1, height=0.75, nose=0.75, slope=0.35, taper=0.12,
                      offset=-0.3,
                      gun=Gun(0.08, trunnion=(0.9, 0.4), length=1.9, elevation=(-10.0, 60.0), mantlet=(0.4, 0.5, 0.35))),
        extras=(Extra("turret", "box", (1.2, 0.5, 0.55), (-0.2, 1.3, 0.55)),  # TOW launcher, stowed
                _cupola(0.0, -0.5, 0.5, 1.03, 0.3)),
    ),
    Wheeled(
        "btr_80", "BTR-80", "apc", "Arzamas Machine-Building Plant data / Jane's",
        length=7.55, width=2.95, height=2.41, axles=(1.6, 2.95, 4.65, 6.0),
        wheel_d=1.1, tyre_w=0.33, track=2.41, deck=2.0, nose=0.95, glacis=1.4, lower_glacis=0.9,
        belly=0.475, rear_slope=0.6, side_slope=0.3,
        turret=Turret(ring=2.55, front=0.7, rear=0.7, width=1.4, height=0.41, round=True, slope=0.25, taper=0.25,
                      gun=Gun(0.07, trunnion=(0.55, 0.22), length=1.6, elevation=(-4.0, 60.0), mantlet=(0.3, 0.3, 0.25))),
    ),
    # A tracked infantry fighting vehicle with a two-man turret (the class is half tracked, half wheeled).
    Tracked(
        "cv90", "CV9040 (Strf 9040)", "apc", "BAE Systems Hagglunds data sheet",
        length=6.47, width=3.1, height=2.7, gun_length=None,
        deck=1.9, nose=1.0, glacis=1.2, road_wheels=7, wheel_d=0.6, track_w=0.53, contact=3.9,
        lower_glacis=0.5, belly=0.45, rear_slope=0.1, skirts=True,
        turret=Turret(ring=3.2, front=1.1, rear=1.2, width=2.3, height=0.8, nose=0.6, slope=0.4, taper=0.15,
                      gun=Gun(0.1, trunnion=(0.9, 0.35), length=2.4, elevation=(-8.0, 50.0), mantlet=(0.4, 0.5, 0.35))),
    ),
    # A 4 x 4 armoured personnel carrier: wheeled APCs run from 4 x 4 to 8 x 8.
    Wheeled(
        "vab", "Renault VAB (4 x 4)", "apc", "Renault Trucks Defense data / Jane's",
        length=5.98, width=2.49, height=2.06, axles=(1.45, 4.45),
        wheel_d=1.05, tyre_w=0.33, track=2.04, deck=2.06, nose=1.1, glacis=1.0, lower_glacis=0.7,
        belly=0.45, rear_slope=0.15, side_slope=0.15,
    ),
    Wheeled(
        "lav_25", "LAV-25", "apc", "General Dynamics Land Systems / USMC fact file",
        length=6.39, width=2.5, height=2.69, axles=(1.35, 2.39, 3.8, 4.84),
        wheel_d=0.98, tyre_w=0.3, track=2.18, deck=1.95, nose=0.85, glacis=1.5, lower_glacis=0.5,
        belly=0.5, rear_slope=0.45, side_slope=0.22,
        turret=Turret(ring=2.9, front=0.8, rear=0.9, width=1.7, height=0.6, nose=0.6, slope=0.3, taper=0.15,
                      gun=Gun(0.08, trunnion=(0.7, 0.35), length=1.8, elevation=(-10.0, 60.0), mantlet=(0.35, 0.4, 0.3))),
        extras=(_cupola(-0.2, 0.4, 0.4, 0.74, 0.2),),
    ),
)

PICKUPS = (
    Road("toyota_hilux", "Toyota Hilux (AN120, 2016, Double Cab)", "pickup", "Toyota specifications",
         length=5.33, width=1.855, height=1.815, wheelbase=3.085, front=0.92, wheel_d=0.78, track=1.54,
         shape=CREW_CAB, bed=1.525, clearance=0.28, tyre_w=0.26),
    Road("ford_ranger", "Ford Ranger (PX, 2015, Double Cab)", "pickup", "Ford specifications",
         length=5.359, width=1.85, height=1.815, wheelbase=3.22, front=0.93, wheel_d=0.79, track=1.56,
         shape=CREW_CAB, bed=1.55, clearance=0.28, tyre_w=0.26),
    Road("chevrolet_silverado", "Chevrolet Silverado 1500 (2014, Crew Cab, short box)", "pickup",
         "General Motors specifications",
         length=5.842, width=2.032, height=1.88, wheelbase=3.645, front=0.92, wheel_d=0.79, track=1.74,
         shape=CREW_CAB, bed=1.74, clearance=0.25, tyre_w=0.27),
    Road("ram_1500", "Ram 1500 (DS, 2012, Regular Cab, 8 ft box)", "pickup", "Chrysler (Ram) specifications",
         length=5.817, width=2.017, height=1.88, wheelbase=3.556, front=0.95, wheel_d=0.79, track=1.72,
         shape=REG_CAB, bed=2.44, clearance=0.25, tyre_w=0.27),
    Road("toyota_tacoma", "Toyota Tacoma (N300, 2016, Access Cab, long bed)", "pickup", "Toyota specifications",
         length=5.728, width=1.89, height=1.781, wheelbase=3.571, front=0.9, wheel_d=0.77, track=1.6,
         shape=EXT_CAB, bed=1.86, clearance=0.24, tyre_w=0.26),
    Road("nissan_navara", "Nissan Navara (D40, 2005, King Cab)", "pickup", "Nissan specifications",
         length=5.22, width=1.85, height=1.78, wheelbase=3.2, front=0.86, wheel_d=0.76, track=1.57,
         shape=EXT_CAB, bed=1.86, clearance=0.23, tyre_w=0.26),
)

SUVS = (
    Road("toyota_land_cruiser_200", "Toyota Land Cruiser 200 (2008)", "suv", "Toyota specifications",
         length=4.95, width=1.98, height=1.88, wheelbase=2.85, front=0.93, wheel_d=0.79, track=1.64,
         shape=SUV, clearance=0.23, tyre_w=0.27),
    Road("toyota_rav4", "Toyota RAV4 (XA40, 2013, with roof rails)", "suv", "Toyota specifications",
         length=4.57, width=1.845, height=1.705, wheelbase=2.66, front=0.93, wheel_d=0.72, track=1.57,
         shape=CROSSOVER, clearance=0.19, tyre_w=0.23, rails=0.045),
    Road("chevrolet_tahoe", "Chevrolet Tahoe (GMT900, 2007, with roof rails)", "suv", "General Motors specifications",
         length=5.131, width=2.007, height=1.953, wheelbase=2.946, front=0.98, wheel_d=0.79, track=1.73,
         shape=SUV, clearance=0.23, tyre_w=0.27, rails=0.06),
    Road("nissan_qashqai", "Nissan Qashqai (J11, 2014)", "suv", "Nissan specifications",
         length=4.377, width=1.806, height=1.59, wheelbase=2.646, front=0.9, wheel_d=0.69, track=1.565,
         shape=dataclasses.replace(CROSSOVER, round=0.95), clearance=0.18, tyre_w=0.22),
    # A subcompact crossover: SUVs run down to 4.1-4.3 m (Renegade, Juke, Kona, CX-3) at 1.55-1.7 m high.
    Road("jeep_renegade", "Jeep Renegade (BU, 2015, with roof rails)", "suv", "FCA (Jeep) specifications",
         length=4.236, width=1.805, height=1.697, wheelbase=2.57, front=0.89, wheel_d=0.69, track=1.545,
         shape=Shape(nose=0.56, belt=0.6, windshield=0.3, roof=(0.44, 0.95), tail=0.99, deck=0.6, roof_w=0.85,
                     round=0.55),
         clearance=0.2, tyre_w=0.22, rails=0.03),
    Road("land_rover_defender_110", "Land Rover Defender 110 (1990, Station Wagon, spare wheel on the door)", "suv",
         "Land Rover specifications",
         length=4.639, width=1.79, height=2.035, wheelbase=2.794, front=0.7, wheel_d=0.78, track=1.49,
         shape=Shape(nose=0.5, belt=0.55, windshield=0.27, roof=(0.31, 0.99), tail=0.995, deck=0.55, roof_w=0.93,
                     round=0.15),
         clearance=0.25, tyre_w=0.24, spare=True),
)

CARS = (
    Road("toyota_camry", "Toyota Camry (XV70, 2018)", "car", "Toyota specifications",
         length=4.88, width=1.84, height=1.445, wheelbase=2.825, front=0.98, wheel_d=0.67, track=1.58,
         shape=SEDAN, clearance=0.14),
    Road("honda_civic", "Honda Civic sedan (10th gen., 2016)", "car", "Honda specifications",
         length=4.63, width=1.799, height=1.416, wheelbase=2.698, front=0.93, wheel_d=0.65, track=1.55,
         shape=Shape(nose=0.5, belt=0.67, windshield=0.33, roof=(0.47, 0.64), tail=0.86, deck=0.71, roof_w=0.78,
                     round=0.85),
         clearance=0.13),
    Road("bmw_3_series", "BMW 3 Series sedan (F30, 2012)", "car", "BMW specifications",
         length=4.624, width=1.811, height=1.429, wheelbase=2.81, front=0.78, wheel_d=0.66, track=1.54,
         shape=Shape(nose=0.53, belt=0.68, windshield=0.37, roof=(0.5, 0.7), tail=0.84, deck=0.72, roof_w=0.78,
                     round=0.85),
         clearance=0.14),
    Road("vw_golf", "Volkswagen Golf (Mk7, 2013, 5-door)", "car", "Volkswagen specifications",
         length=4.255, width=1.799, height=1.452, wheelbase=2.637, front=0.88, wheel_d=0.63, track=1.54,
         shape=HATCH, clearance=0.14),
    Road("ford_focus", "Ford Focus hatchback (Mk3, 2011)", "car", "Ford specifications",
         length=4.358, width=1.823, height=1.484, wheelbase=2.648, front=0.92, wheel_d=0.64, track=1.56,
         shape=Shape(nose=0.5, belt=0.64, windshield=0.31, roof=(0.47, 0.86), tail=0.965, deck=0.64, roof_w=0.8,
                     round=0.85, drop=0.04),
         clearance=0.14),
    Road("vw_up", "Volkswagen up! (2011, 5-door)", "car", "Volkswagen specifications",
         length=3.54, width=1.641, height=1.478, wheelbase=2.42, front=0.6, wheel_d=0.59, track=1.43,
         shape=Shape(nose=0.5, belt=0.62, windshield=0.22, roof=(0.4, 0.9), tail=0.985, deck=0.62, roof_w=0.82,
                     round=0.85, drop=0.03),
         clearance=0.14, tyre_w=0.17),
)

MINIVANS = (
    Road("honda_odyssey", "Honda Odyssey (RL6, 2018)", "minivan", "Honda specifications",
         length=5.159, width=1.994, height=1.735, wheelbase=3.0, front=1.0, wheel_d=0.72, track=1.72,
         shape=MINIVAN, clearance=0.15, tyre_w=0.25),
    Road("toyota_sienna", "Toyota Sienna (XL30, 2011)", "minivan", "Toyota specifications",
         length=5.085, width=1.985, height=1.75, wheelbase=3.03, front=0.96, wheel_d=0.72, track=1.72,
         shape=MINIVAN, clearance=0.16, tyre_w=0.25),
    Road("vw_multivan", "Volkswagen Multivan (T6, 2015)", "minivan", "Volkswagen Commercial Vehicles specifications",
         length=4.904, width=1.904, height=1.97, wheelbase=3.0, front=0.88, wheel_d=0.7, track=1.63,
         shape=ONE_BOX, clearance=0.18, tyre_w=0.24),
    # The van class reaches past minivans: a cab-over van, a high-roof panel van and a cutaway box van.
    Road("toyota_hiace", "Toyota HiAce (H200, 2004, long body, standard roof)", "minivan", "Toyota specifications",
         length=4.695, width=1.695, height=1.98, wheelbase=2.57, front=0.98, wheel_d=0.69, track=1.47,
         shape=CAB_OVER, clearance=0.18, tyre_w=0.2, mirror=0.15),
    Road("mercedes_sprinter", "Mercedes-Benz Sprinter (W906, 2006, 316 CDI, medium wheelbase, high roof)", "minivan",
         "Daimler specifications",
         length=5.91, width=1.993, height=2.72, wheelbase=3.665, front=0.995, wheel_d=0.71, track=1.71,
         shape=Shape(nose=0.36, belt=0.4, windshield=0.16, roof=(0.27, 0.99), tail=0.995, deck=0.4, roof_w=0.92,
                     round=0.35),
         clearance=0.18, tyre_w=0.235, mirror=0.22),
    Road("ford_e350_cutaway", "Ford E-350 Super Duty cutaway (2008, 158 in wheelbase, 12 ft box body)", "minivan",
         "Ford specifications; box: a Type III ambulance / 12 ft cube-van body",
         length=6.7, width=2.39, height=2.77, wheelbase=4.01, front=0.98, wheel_d=0.76, track=1.74,
         shape=Shape(nose=0.5, belt=0.55, windshield=0.42, roof=(0.62, 1.0), tail=1.0, deck=0.55, roof_w=0.88,
                     round=0.4),
         clearance=0.2, tyre_w=0.23, mirror=0.22, box=3.67, cab=(2.01, 2.1)),
)

TRAIN: tuple[Spec, ...] = TANKS + APCS + PICKUPS + SUVS + CARS + MINIVANS

# ----------------------------------------------------------------------------------------------
# Test split: the eight SENSIAC targets' types, never used for training.
# ----------------------------------------------------------------------------------------------
TEST: tuple[Spec, ...] = (
    Tracked(
        "t_72", "T-72A", "tank", "Uralvagonzavod data / Jane's",
        length=6.95, width=3.59, height=2.23, gun_length=9.53,
        deck=1.4, nose=0.95, glacis=1.5, road_wheels=6, wheel_d=0.75, track_w=0.58, contact=4.28, skirts=False,
        turret=Turret(ring=3.2, front=1.3, rear=1.2, width=2.2, height=0.68, round=True, slope=0.35, taper=0.35,
                      gun=Gun(0.18, trunnion=(1.1, 0.35), elevation=(-6.0, 14.0), mantlet=(0.4, 0.5, 0.35),
                              evacuator=0.45)),
        extras=(_cupola(-0.1, 0.45, 0.55, 0.83, 0.2),
                Extra("hull", "cylinder", (0.3, 1.4), (6.62, 0.75, 1.5), axis="y"),  # rear fuel drums
                Extra("hull", "cylinder", (0.3, 1.4), (6.62, -0.75, 1.5), axis="y")),
    ),
    Tracked(
        "zsu_23_4", "ZSU-23-4 Shilka", "tank", "Jane's Land-Based Air Defence (radar stowed)",
        length=6.535, width=3.125, height=2.576, gun_length=None,
        deck=1.35, nose=0.9, glacis=0.9, road_wheels=6, wheel_d=0.67, track_w=0.38, contact=3.8,
        lower_glacis=0.5, skirts=False,
        turret=Turret(ring=2.9, front=1.25, rear=1.35, width=2.9, height=0.85, nose=0.85, slope=0.25, taper=0.1,
                      gun=Gun(0.09, trunnion=(1.0, 0.45), length=1.8, elevation=(-4.0, 85.0),
                              barrels=((0.42, 0.1), (0.42, -0.1), (-0.42, 0.1), (-0.42, -0.1)),
                              mantlet=(0.3, 1.3, 0.45))),
        extras=(Extra("turret", "box", (0.35, 1.2, 0.45), (-1.0, 0.0, 1.0)),),  # Gun Dish radar, stowed
    ),
    Tracked(
        "2s3_akatsiya", "2S3 Akatsiya", "tank", "Jane's Armour and Artillery",
        length=7.765, width=3.25, height=3.05, gun_length=8.4,
        deck=1.6, nose=1.0, glacis=1.2, road_wheels=6, wheel_d=0.7, track_w=0.5, contact=4.5,
        lower_glacis=0.5, skirts=False,
        turret=Turret(ring=5.3, front=1.7, rear=1.6, width=3.0, height=1.15, nose=0.8, slope=0.4, taper=0.15,
                      gun=Gun(0.2, trunnion=(1.5, 0.55), elevation=(-4.0, 60.0), mantlet=(0.5, 0.7, 0.5),
                              evacuator=0.5, brake=True)),
        extras=(_cupola(-0.2, 0.8, 0.6, 1.45, 0.3),),
    ),
    Wheeled(
        "btr_70", "BTR-70", "apc", "Jane's Armour and Artillery",
        length=7.535, width=2.8, height=2.235, axles=(1.55, 2.9, 4.6, 5.95),
        wheel_d=1.07, tyre_w=0.33, track=2.38, deck=1.85, nose=0.9, glacis=1.5, lower_glacis=0.8,
        belly=0.475, rear_slope=0.7, side_slope=0.3,
        turret=Turret(ring=2.4, front=0.65, rear=0.65, width=1.3, height=0.385, round=True, slope=0.25, taper=0.25,
                      gun=Gun(0.07, trunnion=(0.5, 0.2), length=1.5, elevation=(-5.0, 30.0), mantlet=(0.3, 0.3, 0.25))),
    ),
    Wheeled(
        "brdm_2", "BRDM-2", "apc", "Jane's Armour and Artillery",
        length=5.75, width=2.37, height=2.31, axles=(1.25, 4.35),
        wheel_d=1.07, tyre_w=0.33, track=1.84, deck=1.9, nose=1.0, glacis=1.2, lower_glacis=0.7,
        belly=0.43, rear_slope=0.6, side_slope=0.25,
        turret=Turret(ring=2.6, front=0.6, rear=0.6, width=1.2, height=0.41, round=True, slope=0.25, taper=0.25,
                      gun=Gun(0.07, trunnion=(0.45, 0.2), length=1.5, elevation=(-5.0, 30.0), mantlet=(0.3, 0.3, 0.25))),
    ),
    Tracked(
        "bmp_2", "BMP-2", "apc", "Kurganmashzavod data / Jane's",
        length=6.735, width=3.15, height=2.45, gun_length=None,
        deck=1.65, nose=0.75, glacis=1.9, road_wheels=6, wheel_d=0.68, track_w=0.3, contact=3.75,
        lower_glacis=0.5, belly=0.42, skirts=False,
        turret=Turret(ring=3.0, front=0.9, rear=1.0, width=1.9, height=0.55, round=True, slope=0.3, taper=0.3,
                      gun=Gun(0.09, trunnion=(0.8, 0.3), length=2.1, elevation=(-5.0, 74.0), mantlet=(0.35, 0.4, 0.3))),
        extras=(_cupola(0.1, 0.5, 0.45, 0.8, 0.3),
                Extra("turret", "cylinder", (0.1, 1.1), (-0.1, -0.1, 0.66), axis="x")),  # ATGM tube
    ),
    Road("ford_f150", "Ford F-150 (12th gen., 2009, SuperCab, 6.5 ft box)", "pickup", "Ford specifications",
         length=5.89, width=2.009, height=1.913, wheelbase=3.683, front=0.95, wheel_d=0.79, track=1.7,
         shape=EXT_CAB, bed=1.98, clearance=0.24, tyre_w=0.27),
    Road("isuzu_rodeo", "Isuzu Rodeo (2nd gen., 1998)", "suv", "Isuzu specifications",
         length=4.488, width=1.788, height=1.745, wheelbase=2.703, front=0.78, wheel_d=0.74, track=1.49,
         shape=SUV, clearance=0.22, tyre_w=0.24),
)

SPLITS: dict[str, tuple[Spec, ...]] = {"train": TRAIN, "test": TEST}
