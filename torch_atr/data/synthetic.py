"""A SENSIAC-like infrared scene simulator: one vehicle driving a circle before a static MWIR camera
(or, in the visible band, a lit indoor-like scene before a close visible camera).

Scene (METHOD.md, "The SENSIAC setting"). The vehicle's body origin drives a circle of
``circle_diameter_m`` on flat ground at ``speed_mps``; the circle's centre lies ``range_m``
metres ahead of the camera (horizontally). The camera is ``camera_height_m`` above the ground
and tilted down by ``tilt_deg`` (default: its optical axis aims at the circle's centre on the
ground), 640 x 512 pixels, focal length ``focal_px`` (10,000 px: a 7 m vehicle spans 70 px at
1000 m), principal point at the image centre, no lens distortion.

World frame. The camera's world frame is sensor-like and ground-levelled: origin at the camera
centre, x right (horizontal), y up (vertical), z forward (horizontal, along the camera's
azimuth); metres. It is left-handed like the sensor frame (:mod:`torch_atr.pose`). The ground is the plane
y = −camera_height_m. The camera's rotation world -> sensor is the proper rotation (det +1)

    R = [[1, 0, 0], [0, cos τ, sin τ], [0, −sin τ, cos τ]],   t = 0,

with τ the downward tilt (the optical axis is Rᵀ(0, 0, 1) = (0, −sin τ, cos τ)); with τ = 0
the world frame is the sensor frame. Ground truth positions and headings are given in this world
frame, the motion model's of METHOD.md (x += v sin h Δt, z += v cos h Δt): a frame's step along
the heading lands off the circle by its curvature only, v² Δt² / (2 r) (0.28 mm at the defaults).

Circle. The position at frame i is c + r (sin a, 0, cos a) with c = (0, −camera_height_m,
range_m), r the radius and a = a₀ ± (speed / r) · i / fps (+ clockwise seen from above, i.e.
from +z towards +x like the heading). a = 0 is the far point, 90° the right-most, 180° the near
point. ``start_deg`` = None centres the run on the near point, where the camera sees the
vehicle side-on. Note the field of view: width · range / focal_px metres across, 64 m at
1000 m and 96 m at 1500 m, narrower than the 100 m circle; at 1000 m a run longer than about
340 frames (at 5 m/s, centred on the near point) takes a T-72 partly out of the frame. Truth
keeps position, view and pixel centre (outside the image) there; a target wholly outside has no
bounding box (NaN).

Thermal model. Everything is an apparent temperature in kelvin, read out as 14-bit counts
``(T − ZERO_COUNT_K) · COUNTS_PER_K`` (rounded, clipped to [0, 16383]). The vehicle's one mesh
is split geometrically into PARTS (:func:`surface_parts`): running gear (the lower band), engine
deck (the upward-facing surfaces of the engine third of the chassis: the rear for tanks, APCs
and unknown classes, the front for wheeled civilian classes), exhaust (a small patch at the
engine end's rear plate, or the tailpipe region at the rear bottom of a front-engined vehicle)
and body (the rest). A surface point has its part's temperature plus ``top_delta_k`` times
|n_Z| of its face (night: horizontal surfaces radiate to the cold sky and are cooler; day: they
are sun-loaded and warmer). Night (the default): the vehicle is warmer than the ground; day:
the ground is warm, the body about as warm as the ground and only the engine, exhaust and
running gear stand out, so the contrast is lower. :meth:`SceneConfig.temperatures` gives the
resolved values. The atmosphere pulls a target's apparent temperature towards the ground's
mean: T_app = ground_k + τ_atm (T − ground_k), τ_atm = exp(−extinction_per_km · slant range / 1 km).
A z-buffer (:func:`visible_faces`) finds the surface point seen at 3 x 3 sub-samples of every
pixel; a pixel's radiance mixes the target's mean over its covered sub-samples with the scene
behind by the covered fraction, so thin parts (a gun barrel at 3500 m) show with their partial
coverage, while the true mask stays the pixel-centre silhouette of
:func:`~torch_atr.render.render_mask`.

Background (static, fixed by the seed so a background model can learn it, thesis 3.1): ground
below the horizon row with a linear vertical gradient (``ground_k`` ± ``ground_gradient_k`` / 2
from the bottom row to the horizon), smooth clutter (white noise low-passed by a Gaussian of
``clutter_scale_px`` vertically and ``clutter_stretch`` times that horizontally, as ground seen
at a grazing angle, scaled to a standard deviation of ``clutter_k``), and sky above the horizon
cooling from the horizon's temperature to ``sky_k`` over an eighth of the image height. An
optional occluder (a berm with a bushy top, ``occluder_width_m`` > 0) stands on the ground at
``occluder_range_m`` in front of the circle, ``occluder_x_m`` across, and hides the vehicle
wherever they overlap in the image.

Image formation. Frame i = blur(static scene with the visible target) + sensor noise: the whole
frame is blurred by a Gaussian PSF of σ = psf_sigma_px + psf_sigma_per_km · range_m / 1 km
(diffraction and turbulence grow with range), then white noise of ``noise_k`` (the NETD) is
added and the result quantised. Frame i depends only on (cfg, i): each frame's noise comes from
its own generator seeded from (seed, stream, i), so random access equals sequential reading.
:meth:`SyntheticSequence.warmup_frames` gives target-free frames of the same noise process (on
another stream) for learning the background.

Visible band (``band="visible"``; thesis 6.3, the toy cars of the lab, here at full size:
:func:`visible_scene` gives the indoor-like geometry, a camera 6.5 m up, tilted down 32°, 13 m
from the centre of a 10 m circle, focal 480 px at 640 x 480, so the view elevation φ stays inside
the trained range [0°, 40°] of ``checkpoints/default.pt`` while the vehicle's near end is much
closer than its far end and perspective matters). Everything is a grey level (0-255) instead
of a temperature. The floor y = −camera_height_m is a matte tiling: tiles of 1 m separated by
2 cm grout lines 40 % darker, its albedo ``floor_albedo`` modulated by a static procedural
texture (a sum of plane waves of 0.15-1.5 m wavelength, fixed by the seed; relative amplitude
``texture_contrast``), shaded by :func:`lambert` under a distant light (``light_azimuth_deg``
from +z towards +x, ``light_elevation_deg`` above the floor) plus ``ambient`` light; above the
horizon a plain wall lit by the ambient light only. The vehicle's surface points (from the same
z-buffer and 3 x 3 sub-samples as the IR's) take the albedo of their part (``body_albedo`` for
the body and engine deck, 0.1 for the running gear and the exhaust) times the same kind of
texture in body coordinates, and are shaded by :func:`lambert` with their face's normal turned
towards the camera (meshes' windings need not be consistent). There are no cast shadows, no
specular highlights and no occluder (``occluder_width_m`` must be 0). The frame is blurred by
the PSF, white noise of ``noise_dn`` grey levels is added, and it is read out as uint8 (H, W);
the determinism rules, :meth:`SyntheticSequence.warmup_frames` and the truth are the IR's. The
IR's minimum distance from the camera to the circle (20 m, room for the occluder) becomes 2 m.

Ground truth (:class:`~torch_atr.data.sequence.FrameTruth`), exact per frame: x, y, z of the
vehicle's centre (the centre of its rest-pose 3D bounding box, a fixed point of the body: the
point templates are centred on and the tracker's state follows), heading and speed, all in the
world frame above; θ, φ the view from that centre (:func:`~torch_atr.pose.view_of_pose`); u, v
the centroid of the pixel centres of the complete
silhouette (:meth:`SyntheticSequence.true_mask` when the target is inside the frame; parts
outside the frame count too); u0, v0, u1, v1 the first and last column and row of the true
mask inside the frame (NaN when it is empty); range_m the slant range from the camera centre to
the vehicle's centre; aspect = θ (the vehicle's clockwise turn, seen
from above, away from facing the sensor, SENSIAC's convention); time_s = i / fps.

Spec: ``open_sequence("synthetic:vehicle=NAME_OR_PATH,range=2000,frames=300,seed=0,...")``,
any :class:`SceneConfig` field as a key (``range`` is short for ``range_m``); values are read
as YAML scalars (``night=false``, ``tilt_deg=null``); NAME is a catalog vehicle of either split
(``t_72``, ``BTR-70``), PATH a URDF or mesh file (without commas).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import numbers
import os
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
import torch
import trimesh

from torch_atr._checks import check_shape
from torch_atr.camera import FOCAL_RANGE_PX, Camera
from torch_atr.config import ConfigError, load_config
from torch_atr.data.sequence import MAX_CAMERA_HEIGHT_M, FrameTruth, Sequence, parse_spec_options, register_scheme
from torch_atr.pose import VehiclePose, body_to_world, view_of_pose
from torch_atr.render import render_mask
from torch_atr.validate import InputError, show
from torch_atr.vehicles import Vehicle, load_vehicle
from torch_atr.vehicles import load_catalog_vehicle

logger = logging.getLogger(__name__)

PARTS: tuple[str, ...] = ("body", "running_gear", "engine_deck", "exhaust")
BODY, RUNNING_GEAR, ENGINE_DECK, EXHAUST = range(len(PARTS))
REAR_ENGINE_CLASSES = frozenset({"tank", "apc", "unknown"})

COUNTS_PER_K = 100.0  # counts per kelvin of apparent temperature
ZERO_COUNT_K = 230.0  # apparent temperature read as 0 counts
_MAX_K = 1e4  # bound on a scene's temperatures, differences and noise (the sensor saturates near 394 K): no overflow
MAX_COUNT = 2 ** 14 - 1  # 14-bit sensor

# Geometric part split (fractions of the mesh height / chassis length, body frame).
_GEAR_HEIGHT = 0.35  # running gear: surface points below this fraction of the height
_ENGINE_LENGTH = 1 / 3  # engine deck: the engine end's third of the chassis
_EXHAUST_LENGTH = 0.08  # exhaust: the last 8 % of the chassis ...
_EXHAUST_TOP = 0.75  # ... up to this fraction of the height (rear-engined vehicles)
_DECK_FACING = 0.5  # the engine deck's faces have |n_Z| above this
_SKY_SCALE = 1 / 8  # the sky cools from the horizon over this fraction of the image height
_OCCLUDER_GAP_M = 10.0  # the occluder stands at least this far in front of the circle
_VISIBLE_GAP_M = 2.0  # visible band: the circle's nearest point at least this far from the camera
_OCCLUDER_BUMPS_M = 1.5  # spacing of the occluder's top profile samples
_PSF_TRUNCATE = 4.0  # Gaussian kernels reach 4 σ
_SUPERSAMPLE = 3  # the target's radiance is averaged over 3 x 3 sub-samples per pixel
_MAX_BLUR_PX = 100.0  # Gaussian σ of the PSF and the clutter: kernels of at most 801 taps
# Least fps, circle_diameter_m and turret_period_s: the circle's angle (speed_mps / radius / fps per frame) and the
# turret's phase then stay finite over 10**7 frames (fps=5e-324 made it inf · 0 = NaN at frame 0, which was
# reported as 'the vehicle reaches behind the camera'; turret_period_s=1e-300 gave sin(inf), 'math domain error').
_MIN_TIME_OR_SIZE = 1e-3
# Memory bounds of one rendered frame (measured: a 512 px target in a 2048 x 2048 frame peaks ~0.6 GB above the
# process's baseline, a 1024 px one in a 2048 x 2048 frame 2 GB).
MAX_TARGET_PX = 512  # the vehicle's 3D diagonal at the circle's nearest point, in pixels (rendered x 3 x 3)
MAX_FRAME_SIDE = 4096
MAX_FRAME_PIXELS = 2 ** 22  # 4 Mpx: e.g. 2048 x 2048; SENSIAC's 640 x 512 is 0.33 Mpx

# Resolved defaults of the temperature fields (kelvin) at night and by day.
_NIGHT = {"ground_k": 285.0, "sky_k": 262.0, "body_k": 291.0, "running_gear_k": 295.0, "engine_deck_k": 305.0,
          "exhaust_k": 320.0, "occluder_k": 286.0, "top_delta_k": -1.5}
_DAY = {"ground_k": 300.0, "sky_k": 278.0, "body_k": 300.5, "running_gear_k": 304.0, "engine_deck_k": 310.0,
        "exhaust_k": 325.0, "occluder_k": 299.0, "top_delta_k": 4.0}

# Random streams of the seed.
_CLUTTER, _OCCLUDER, _NOISE, _WARMUP, _TEXTURE = range(5)

BANDS = ("ir", "visible")
MAX_GREY = 255  # visible band: 8-bit read-out
_DARK_ALBEDO = 0.1  # visible band: tyres, running gear and exhaust
_WALL_ALBEDO = 0.6  # visible band: the plain wall above the horizon, lit by the ambient light only
_TILE_M = 1.0  # visible band: floor tiles' side ...
_GROUT_M = 0.02  # ... and the width of the darker grout lines between them
_GROUT_SHADE = 0.6  # grout albedo / tile albedo
_TEXTURE_WAVES = 8  # sinusoids summed by the procedural texture
_TEXTURE_WAVELENGTH_M = (0.15, 1.5)  # their wavelengths' range
_FLOOR_BAND_ROWS = 32  # visible band: the floor is rendered in bands of this many pixel rows

# The visible band's indoor-like scene (thesis 6.3, the toy cars, at full size): a camera 6.5 m up,
# tilted down 32°, wide-angle (67° x 53° field of view), 13 m from the centre of a 10 m circle
# driven at 1.5 m/s. See :func:`visible_scene`.
VISIBLE_SCENE = {"band": "visible", "range_m": 13.0, "circle_diameter_m": 10.0, "camera_height_m": 6.5,
                 "tilt_deg": 32.0, "focal_px": 480.0, "width": 640, "height": 480, "fps": 10.0,
                 "speed_mps": 1.5, "psf_sigma_px": 0.6, "psf_sigma_per_km": 0.0}


@dataclass(frozen=True)
class SceneConfig:
    """One simulated sequence (module docstring). Temperatures left None take the night or day default."""

    range_m: float = 1000.0  # horizontal distance camera -> circle centre
    circle_diameter_m: float = 100.0
    frames: int = 300
    fps: float = 30.0
    speed_mps: float = 5.0  # a lap of a 100 m circle in 63 s, about a SENSIAC sequence
    start_deg: float | None = None  # circle position at frame 0: 0 far, 90 right, 180 near; None: run centred on 180
    clockwise: bool = True  # seen from above (heading increases)
    width: int = 640
    height: int = 512
    focal_px: float = 10000.0
    camera_height_m: float = 5.0
    tilt_deg: float | None = None  # downward tilt of the camera; None: aim at the circle centre on the ground
    night: bool = True  # night: vehicle warmer than the background; day: low contrast (module docstring)
    ground_k: float | None = None  # mean apparent ground temperature
    sky_k: float | None = None  # sky temperature far above the horizon
    body_k: float | None = None
    running_gear_k: float | None = None  # tracks / wheels
    engine_deck_k: float | None = None
    exhaust_k: float | None = None
    occluder_k: float | None = None
    top_delta_k: float | None = None  # added to a face's temperature times |n_Z|
    ground_gradient_k: float = -1.0  # ground temperature at the horizon minus that at the bottom row
    clutter_k: float = 1.0  # standard deviation of the static ground clutter
    clutter_scale_px: float = 3.0  # vertical correlation length (Gaussian σ) of the clutter
    clutter_stretch: float = 3.0  # horizontal / vertical correlation length
    noise_k: float = 0.08  # per-frame sensor noise σ (NETD)
    extinction_per_km: float = 0.15  # atmospheric extinction of the target's contrast
    psf_sigma_px: float = 0.5  # PSF σ at zero range
    psf_sigma_per_km: float = 0.3  # PSF σ growth per km of range_m
    occluder_width_m: float = 0.0  # 0: no occluder
    occluder_x_m: float = 0.0  # centre of the occluder across the line of sight
    occluder_height_m: float = 1.5  # mean height of its top
    occluder_range_m: float | None = None  # None: 20 m in front of the circle's near point
    turret_sweep_deg: float = 0.0  # turret yaw amplitude (vehicles with a turret_yaw joint)
    turret_period_s: float = 8.0  # period of the turret sweep
    band: str = "ir"  # "ir": thermal, uint16 counts; "visible": lit and textured, uint8 grey (module docstring)
    light_azimuth_deg: float = 30.0  # visible: direction to the (distant) light, from +z towards +x ...
    light_elevation_deg: float = 60.0  # ... and above the floor
    ambient: float = 0.35  # visible: the share of the light every surface gets whatever its normal
    floor_albedo: float = 0.4  # visible: mean reflectance of the floor tiles
    body_albedo: float = 0.8  # visible: the vehicle's paint (running gear and exhaust: 0.1)
    texture_contrast: float = 0.15  # visible: relative amplitude of the procedural textures
    noise_dn: float = 2.0  # visible: per-frame sensor noise σ in grey levels
    seed: int = 0

    def __post_init__(self) -> None:
        self._check_types()
        r = self.circle_diameter_m / 2
        visible = self.band == "visible"
        gap = _VISIBLE_GAP_M if visible else 2 * _OCCLUDER_GAP_M  # the IR's leaves room for the occluder
        checks = {
            "band": (self.band in BANDS, f"one of {BANDS}"),
            "range_m": (self.range_m - r > gap and self.range_m <= 1e5,
                        f"at most 100 km, more than circle_diameter_m / 2 + {gap:g} m"),
            "circle_diameter_m": (_MIN_TIME_OR_SIZE <= self.circle_diameter_m <= 1e4, "in [0.001, 10000]"),
            "frames": (1 <= self.frames <= 10 ** 7, "in [1, 10**7]"),
            "fps": (_MIN_TIME_OR_SIZE <= self.fps <= 1e4, "in [0.001, 10000]"),
            "speed_mps": (0 <= self.speed_mps <= 1e3, "in [0, 1000]"),
            "start_deg": (self.start_deg is None or math.isfinite(self.start_deg), "finite or null"),
            "width": (1 <= self.width <= MAX_FRAME_SIDE, f"in [1, {MAX_FRAME_SIDE}]"),
            "height": (1 <= self.height <= MAX_FRAME_SIDE and self.width * self.height <= MAX_FRAME_PIXELS,
                       f"in [1, {MAX_FRAME_SIDE}], width x height at most {MAX_FRAME_PIXELS}"),
            "focal_px": (FOCAL_RANGE_PX[0] <= self.focal_px <= 1e6, f"in [{FOCAL_RANGE_PX[0]:g}, 1e6]"),  # Camera's
            "camera_height_m": (0 < self.camera_height_m <= MAX_CAMERA_HEIGHT_M, f"in (0, {MAX_CAMERA_HEIGHT_M:g}]"),
            "tilt_deg": (self.tilt_deg is None or -45 <= self.tilt_deg <= 45, "in [-45, 45] or null"),
            "ground_gradient_k": (abs(self.ground_gradient_k) <= _MAX_K, f"in [-{_MAX_K:g}, {_MAX_K:g}]"),
            "clutter_k": (0 <= self.clutter_k <= _MAX_K, f"in [0, {_MAX_K:g}]"),
            "clutter_scale_px": (0 < self.clutter_scale_px <= _MAX_BLUR_PX, f"in (0, {_MAX_BLUR_PX:g}]"),
            "clutter_stretch": (0 < self.clutter_stretch
                                and self.clutter_scale_px * self.clutter_stretch <= _MAX_BLUR_PX,
                                f"positive, clutter_scale_px x clutter_stretch at most {_MAX_BLUR_PX:g} px"),
            "noise_k": (0 <= self.noise_k <= _MAX_K, f"in [0, {_MAX_K:g}]"),
            "extinction_per_km": (0 <= self.extinction_per_km < math.inf, ">= 0"),
            "psf_sigma_px": (0 <= self.psf_sigma_px <= _MAX_BLUR_PX, f"in [0, {_MAX_BLUR_PX:g}]"),
            "psf_sigma_per_km": (0 <= self.psf_sigma_per_km and self.psf_sigma <= _MAX_BLUR_PX,
                                 f">= 0, with psf_sigma_px + psf_sigma_per_km * range_m / 1000 at most "
                                 f"{_MAX_BLUR_PX:g} px"),
            "occluder_width_m": (0 <= self.occluder_width_m <= 1e4 and not (visible and self.occluder_width_m),
                                 "0 in the visible band" if visible else "in [0, 10000]"),
            "occluder_x_m": (math.isfinite(self.occluder_x_m), "finite"),
            "occluder_height_m": (0 < self.occluder_height_m <= 1e3, "in (0, 1000]"),
            "occluder_range_m": (self.occluder_range_m is None
                                 or 0 < self.occluder_range_m <= self.range_m - r - _OCCLUDER_GAP_M,
                                 f"null or in (0, range_m - circle_diameter_m / 2 - {_OCCLUDER_GAP_M:g}]"),
            "turret_sweep_deg": (math.isfinite(self.turret_sweep_deg), "finite"),
            "turret_period_s": (_MIN_TIME_OR_SIZE <= self.turret_period_s < math.inf, ">= 0.001"),
            "light_azimuth_deg": (math.isfinite(self.light_azimuth_deg), "finite"),
            "light_elevation_deg": (0 < self.light_elevation_deg <= 90, "in (0, 90]"),
            "ambient": (0 <= self.ambient <= 1, "in [0, 1]"),
            "floor_albedo": (0 <= self.floor_albedo <= 1, "in [0, 1]"),
            "body_albedo": (0 <= self.body_albedo <= 1, "in [0, 1]"),
            "texture_contrast": (0 <= self.texture_contrast < 1, "in [0, 1)"),
            "noise_dn": (0 <= self.noise_dn <= MAX_GREY, f"in [0, {MAX_GREY}]"),
            "seed": (self.seed >= 0, ">= 0"),
        }
        for key in _NIGHT:
            value = getattr(self, key)
            checks[key] = (value is None or (abs(value) <= _MAX_K and (key == "top_delta_k" or value > ZERO_COUNT_K)),
                           f"null or in [-{_MAX_K:g}, {_MAX_K:g}] K" if key == "top_delta_k"
                           else f"null or in ({ZERO_COUNT_K:g}, {_MAX_K:g}] K")
        bad = [f"{k}={show(getattr(self, k))} (expected {why})" for k, (ok, why) in checks.items() if not ok]
        if bad:
            raise ConfigError("scene: bad value(s) " + "; ".join(bad))

    def _check_types(self) -> None:
        """ConfigError naming every field whose value is not of its declared kind: true or false for a
        bool (the string 'false' is truthy: night='false' ran a night scene), an integer for an int, text
        for a str, a real number (or None where the field allows it) for a float. Files and specs are
        typed by :func:`~torch_atr.config.load_config`; this catches the SceneConfig(...) of Python code."""
        bad, hints = [], typing.get_type_hints(type(self))
        for f in dataclasses.fields(self):
            value, tp = getattr(self, f.name), hints[f.name]
            if tp is bool:
                ok, kind = isinstance(value, (bool, np.bool_)), "true or false"
            elif tp is int:
                ok, kind = isinstance(value, numbers.Integral) and not isinstance(value, bool), "an integer"
            elif tp is str:
                ok, kind = isinstance(value, str), "text"
            else:  # float or float | None
                optional = type(None) in typing.get_args(tp)
                ok = (value is None and optional) or (isinstance(value, numbers.Real) and not isinstance(value, bool))
                kind = "a number or null" if optional else "a number"
            if not ok:
                bad.append(f"{f.name}={show(value)} (expected {kind})")
        if bad:
            raise ConfigError("scene: bad value(s) " + "; ".join(bad))

    @property
    def radius_m(self) -> float:
        return self.circle_diameter_m / 2

    @property
    def tilt_rad(self) -> float:
        """Downward tilt τ of the optical axis, radians."""
        if self.tilt_deg is None:
            return math.atan2(self.camera_height_m, self.range_m)
        return math.radians(self.tilt_deg)

    @property
    def psf_sigma(self) -> float:
        """PSF σ in pixels at this scene's range: psf_sigma_px + psf_sigma_per_km · range_m / 1000."""
        return self.psf_sigma_px + self.psf_sigma_per_km * self.range_m / 1000.0

    def light_direction(self) -> np.ndarray:
        """(3,) unit vector towards the visible band's light in the world frame (x right, y up, z forward)."""
        az, el = math.radians(self.light_azimuth_deg), math.radians(self.light_elevation_deg)
        return np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])

    def temperatures(self) -> dict[str, float]:
        """The temperature fields, None replaced by the night or day default (kelvin)."""
        defaults = _NIGHT if self.night else _DAY
        return {k: defaults[k] if getattr(self, k) is None else float(getattr(self, k)) for k in defaults}


def scene_camera(cfg: SceneConfig) -> Camera:
    """The scene's camera: centre at the world origin, tilted down by ``cfg.tilt_rad`` (module docstring)."""
    c, s = math.cos(cfg.tilt_rad), math.sin(cfg.tilt_rad)
    R = [[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]]
    return Camera(cfg.focal_px, cfg.focal_px, (cfg.width - 1) / 2, (cfg.height - 1) / 2, cfg.width, cfg.height, R=R)


def visible_scene(**overrides) -> SceneConfig:
    """The visible band's indoor-like scene (``VISIBLE_SCENE``) with ``overrides`` (SceneConfig fields).

    Full-size vehicles before a close, wide-angle camera, the thesis's toy-car lab scaled up
    (the model and the tracker work in metres): the views' elevation φ stays within the trained
    [0°, 40°] of ``checkpoints/default.pt`` (it is 18°-36° at a car's centre on the default circle),
    and a vehicle seen end on has its far end up to a third farther than its near end, so
    perspective matters.
    """
    return SceneConfig(**(VISIBLE_SCENE | overrides))


def lambert(albedo: np.ndarray, normals: np.ndarray, to_light: np.ndarray, ambient: float) -> np.ndarray:
    """Brightness of matte surface points under a distant light plus ambient light, in [0, 1]:
    albedo · (ambient + (1 − ambient) · max(0, n · l)).

    Args:
        albedo: (N,) reflectances in [0, 1].
        normals: (N, 3) unit surface normals (facing the viewer).
        to_light: (3,) unit vector towards the light, the normals' frame.
        ambient: in [0, 1].
    Returns:
        (N,) float64.
    """
    albedo, normals, to_light = (np.asarray(a, dtype=np.float64) for a in (albedo, normals, to_light))
    if albedo.ndim != 1 or normals.shape != (albedo.shape[0], 3) or to_light.shape != (3,):
        raise ValueError(f"Expected albedo (N,), normals (N, 3) and to_light (3,); got {albedo.shape}, "
                         f"{normals.shape} and {to_light.shape}")
    if not 0 <= ambient <= 1:
        raise ValueError(f"Expected ambient in [0, 1]; got {ambient}")
    return albedo * (ambient + (1 - ambient) * np.clip(normals @ to_light, 0.0, None))


def surface_parts(mesh: trimesh.Trimesh, points: np.ndarray, face_index: np.ndarray,
                  vehicle_class: str) -> np.ndarray:
    """The part (index into PARTS) of points on a vehicle's surface, in the body frame.

    Running gear below 0.35 of the mesh height; above it, the engine deck is the points on
    faces with |n_Z| > 0.5 in the engine third of the chassis (the X range of the vertices in the
    lower half of the height, so a gun does not count), and the exhaust the points in the last
    8 % of the chassis at the engine end up to 0.75 of the height (tank, apc, unknown: rear
    engine), or at the rear below 0.35 of the height (other classes: front engine, tailpipe at
    the back); the rest is body. Classifying surface points, not whole faces, keeps the part
    borders straight across large triangles.

    Args:
        mesh: +X forward, +Z up, ground at Z = 0.
        points: (N, 3) points on the mesh, metres.
        face_index: (N,) the face each point lies on.
        vehicle_class: the vehicle's class (``Vehicle.cls``).
    Returns:
        (N,) int64.
    """
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"Expected a trimesh.Trimesh with faces; got {type(mesh).__name__}")
    points, face_index = np.asarray(points, dtype=np.float64), np.asarray(face_index)
    if points.ndim != 2 or points.shape[1] != 3 or face_index.shape != points.shape[:1]:
        raise ValueError(f"Expected points (N, 3) and face_index (N,); got {points.shape} and {face_index.shape}")
    verts = np.asarray(mesh.vertices)
    height = float(verts[:, 2].max())
    chassis = verts[verts[:, 2] <= height / 2, 0]
    x_min, x_max = float(chassis.min()), float(chassis.max())
    length = max(x_max - x_min, 1e-9)
    x, z = points[:, 0], points[:, 2]
    rear_engine = vehicle_class in REAR_ENGINE_CLASSES
    from_engine = ((x - x_min) if rear_engine else (x_max - x)) / length  # 0 at the engine end
    from_rear = (x - x_min) / length  # 0 at the rear
    low = z < _GEAR_HEIGHT * height
    n_z = np.abs(np.asarray(mesh.face_normals)[face_index, 2])
    parts = np.full(len(points), BODY, dtype=np.int64)
    parts[low] = RUNNING_GEAR
    parts[~low & (from_engine < _ENGINE_LENGTH) & (n_z > _DECK_FACING)] = ENGINE_DECK
    if rear_engine:
        exhaust = ~low & (from_rear < _EXHAUST_LENGTH) & (z < _EXHAUST_TOP * height)
    else:
        exhaust = low & (from_rear < _EXHAUST_LENGTH)
    parts[exhaust] = EXHAUST
    return parts


def visible_faces(uv: torch.Tensor, depth: torch.Tensor, faces: torch.Tensor, height: int,
                  width: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Z-buffer: the nearest face whose projected triangle contains each pixel centre.

    Depth is interpolated as 1 / depth, which is linear in the image for a planar triangle.
    Pixel centres on a shared edge count for both triangles; the nearer wins, and of faces at
    equal depth the one of highest index. Cost grows with the summed areas of the triangles'
    pixel bounding boxes.

    Each face's three edge equations, divided by its doubled signed area and by its corners'
    depths, form one 3 x 3 matrix B: for a pixel centre p = (u, v) relative to the first pixel
    centre of the face's bounding box, B (u, v, 1) = (w_k / depth_k), k = 0, 1, 2, with w_k the
    image-plane barycentric weights (all >= 0 inside, for either winding); their sum is
    1 / depth at p.

    Args:
        uv: (M, 2) projected vertices in pixels (u right = column, v down = row).
        depth: (M,) depth of the vertices along the optical axis, positive.
        faces: (F, 3) vertex indices.
        height, width: image size H, W.
    Returns:
        face: (H, W) int64 face index, −1 where no triangle covers the pixel centre.
        weights: (H, W, 3) float64 perspective-correct barycentric coordinates of the seen point
        on its face (Σ weights · the face's 3D corners is the point), zeros where face is −1.
    """
    check_shape("uv", uv, ("M", 2))
    check_shape("depth", depth, (uv.shape[0],))
    check_shape("faces", faces, ("F", 3))
    if not bool((depth > 0).all()):
        raise ValueError("Expected every vertex in front of the camera (depth > 0)")
    H, W = int(height), int(width)
    device = uv.device
    tri = uv.to(torch.float64)[faces]  # (F, 3, 2)
    lo = tri.amin(1).ceil().clamp(min=0)  # (F, 2) first pixel centre of the bounding box
    hi = torch.minimum(tri.amax(1).floor(), torch.tensor([W - 1.0, H - 1.0], dtype=torch.float64, device=device))
    n_u = (hi[:, 0] - lo[:, 0] + 1).clamp(min=0).long()
    n_v = (hi[:, 1] - lo[:, 1] + 1).clamp(min=0).long()
    # Edge k runs through the other two corners (p0, p1); twice the signed area of (p0, p1, p) is
    # (p0_v − p1_v) u + (p1_u − p0_u) v + (p0_u p1_v − p1_u p0_v), and the three constants sum to
    # the face's doubled signed area.
    q = tri - lo[:, None, :]  # (F, 3, 2) corners relative to the bounding box
    p0, p1 = q.roll(-1, dims=1), q.roll(-2, dims=1)  # (F, 3, 2) corners k + 1 and k + 2
    edges = torch.stack([p0[..., 1] - p1[..., 1], p1[..., 0] - p0[..., 0],
                         p0[..., 0] * p1[..., 1] - p1[..., 0] * p0[..., 1]], dim=2)  # (F, 3, 3)
    area = edges[:, :, 2].sum(dim=1)  # (F,)
    flat = area == 0
    inv_z = (1.0 / depth.to(torch.float64))[faces]  # (F, 3)
    B = edges * (inv_z / torch.where(flat, 1.0, area)[:, None])[..., None]  # (F, 3, 3)
    count = torch.where(flat, torch.zeros_like(n_u), n_u * n_v)  # pixel centres in each bounding box
    f = torch.repeat_interleave(torch.arange(len(faces), device=device), count)  # (C,) candidate's face
    k = torch.arange(len(f), device=device) - torch.repeat_interleave(torch.cumsum(count, 0) - count, count)
    n = n_u.index_select(0, f)
    dv = k // n  # (C,) row and column in the face's bounding box
    du = k - dv * n
    p = torch.stack([du, dv, torch.ones_like(du)], dim=1).to(torch.float64)  # (C, 3)
    w = torch.einsum("cij,cj->ci", B.index_select(0, f), p)  # (C, 3): w_k / depth_k
    inside = (w >= 0).all(dim=1)
    f, w = f[inside], w[inside]
    first = lo[:, 1].long() * W + lo[:, 0].long()  # (F,) flat index of the bounding box's first pixel
    pix = first.index_select(0, f) + dv[inside] * W + du[inside]
    iz = w.sum(dim=1)  # 1 / depth at the pixel centre
    nearest = torch.full((H * W,), -math.inf, dtype=torch.float64, device=device)
    nearest = nearest.scatter_reduce(0, pix, iz, reduce="amax")
    win = (iz >= nearest[pix]).nonzero().squeeze(1)  # candidates at the nearest depth of their pixel
    chosen = torch.full((H * W,), -1, dtype=torch.long, device=device)
    chosen = chosen.scatter_reduce(0, pix[win], win, reduce="amax")  # one per pixel, deterministically
    hit = chosen >= 0
    face = torch.full((H * W,), -1, dtype=torch.long, device=device)
    weights = torch.zeros(H * W, 3, dtype=torch.float64, device=device)
    face[hit] = f[chosen[hit]]
    weights[hit] = w[chosen[hit]] / iz[chosen[hit], None]
    return face.reshape(H, W), weights.reshape(H, W, 3)


def resolve_vehicle(vehicle: Vehicle | str | os.PathLike) -> Vehicle:
    """A Vehicle from a Vehicle, a catalog name of either split (``"t_72"``, ``"BTR-70"``) or a file.

    A path to an existing URDF or mesh file is loaded with :func:`~torch_atr.vehicles.load_vehicle`
    (class "unknown"); a name is looked up in the train and test catalogs. ``ValueError`` names
    what was given and the catalog's names.
    """
    if isinstance(vehicle, Vehicle):
        return vehicle
    if not isinstance(vehicle, (str, os.PathLike)):
        raise ValueError(f"Expected a Vehicle, a catalog name or a file path; got {type(vehicle).__name__}")
    path = Path(vehicle)
    if path.is_file():
        return load_vehicle(path)
    try:
        return load_catalog_vehicle(str(vehicle))
    except ValueError as exc:
        raise InputError(f"Unknown vehicle {show(str(vehicle))}: not a file and not a catalog name ({exc})") from exc


def _generator(seed: int, stream: int, index: int) -> torch.Generator:
    """An independent generator for (seed, stream, index)."""
    state = np.random.SeedSequence([seed, stream, index]).generate_state(1, dtype=np.uint64)[0]
    return torch.Generator().manual_seed(int(state) & (2 ** 63 - 1))


def _texture(points: np.ndarray, generator: torch.Generator) -> np.ndarray:
    """A static procedural texture of points (N, D), D = 2 or 3 metres: (N,) in [−1, 1].

    The sum of ``_TEXTURE_WAVES`` plane waves of random directions, wavelengths (log-uniform in
    ``_TEXTURE_WAVELENGTH_M``) and phases drawn from ``generator``, scaled to unit standard
    deviation and clipped to [−1, 1].
    """
    n, d = _TEXTURE_WAVES, points.shape[1]
    directions = torch.randn(n, d, generator=generator, dtype=torch.float64).numpy()
    lo, hi = (math.log(x) for x in _TEXTURE_WAVELENGTH_M)
    wavelengths = np.exp(lo + (hi - lo) * torch.rand(n, generator=generator, dtype=torch.float64).numpy())
    phases = 2 * math.pi * torch.rand(n, generator=generator, dtype=torch.float64).numpy()
    k = directions / np.linalg.norm(directions, axis=1, keepdims=True) * (2 * math.pi / wavelengths)[:, None]
    waves = np.sin(points @ k.T + phases).sum(axis=1) / math.sqrt(n / 2)  # each sine has variance 1/2
    return np.clip(waves, -1.0, 1.0)


def _gaussian_blur(img: np.ndarray, sigma_x: float, sigma_y: float, border: int) -> np.ndarray:
    """cv2 Gaussian blur with kernels reaching 4 σ; a copy when σ_x = σ_y = 0."""
    if sigma_x == 0 and sigma_y == 0:
        return img.copy()
    kx, ky = (2 * math.ceil(_PSF_TRUNCATE * sigma) + 1 for sigma in (sigma_x, sigma_y))
    return cv2.GaussianBlur(img, (kx, ky), sigmaX=sigma_x, sigmaY=sigma_y, borderType=border)


@dataclass(frozen=True, eq=False)
class _Target:
    """The rendered target of one frame, in the window of the frame its silhouette's bounding box covers."""

    u0: int  # column of the window's first pixel in the frame
    v0: int  # row of the window's first pixel
    silhouette: np.ndarray  # (h, w) bool, pixel centres inside the silhouette
    parts: np.ndarray  # (h, w) int64 part of the surface seen at the pixel centre, -1 off the silhouette
    cover: np.ndarray  # (h, w) float32 fraction of the pixel's sub-samples on the target
    radiance: np.ndarray  # (h, w) float32 Σ apparent temperature over the target's sub-samples / sub-samples
    centroid: tuple[float, float]  # (u, v) of the complete silhouette's pixel centres, in or out of the frame


class SyntheticSequence(Sequence):
    """A simulated sequence of one vehicle driving a circle (module docstring).

    Args:
        vehicle: a Vehicle, a catalog name (train or test split) or a URDF / mesh path.
        cfg: the scene; ``SceneConfig()`` if None.

    Frames are (height, width) uint16 counts (IR) or uint8 grey levels (visible), generated on demand.
    ``camera`` is the scene's camera, ``truth(i)`` exact ground truth, and :meth:`true_mask`, :meth:`visible_mask` and
    :meth:`part_map` the rendered target of frame i.
    """

    def __init__(self, vehicle: Vehicle | str | os.PathLike, cfg: SceneConfig | None = None):
        cfg = SceneConfig() if cfg is None else cfg
        if not isinstance(cfg, SceneConfig):
            raise ValueError(f"Expected cfg to be a SceneConfig; got {type(cfg).__name__}")
        self.cfg = cfg
        self.vehicle = resolve_vehicle(vehicle)
        diagonal = float(np.linalg.norm(self.vehicle.mesh.extents))
        span = cfg.focal_px * diagonal / (cfg.range_m - cfg.radius_m)  # pixels at the nearest point
        if span > MAX_TARGET_PX:
            raise ConfigError(f"scene: {self.vehicle.name} ({diagonal:.1f} m across) would span {span:.0f} px at the "
                              f"circle's nearest point, {cfg.range_m - cfg.radius_m:g} m away; expected at most "
                              f"{MAX_TARGET_PX} (raise range_m or lower focal_px)")
        self.camera = scene_camera(cfg)
        self.camera_height_m = cfg.camera_height_m
        self.fps = cfg.fps
        band = "visible_" if cfg.band == "visible" else ""
        self.name = f"synthetic_{band}{self.vehicle.name}_{cfg.range_m:g}m_seed{cfg.seed}"
        self.meta = {"simulator": __name__, "vehicle": self.vehicle.name, "vehicle_class": self.vehicle.cls,
                     "vehicle_source": str(self.vehicle.source), "scene": dataclasses.asdict(cfg)}
        self._temps = cfg.temperatures()
        self._sweep = "turret_yaw" in self.vehicle.joint_names and cfg.turret_sweep_deg != 0
        if cfg.turret_sweep_deg != 0 and not self._sweep:
            logger.info("%s has no turret_yaw joint; turret_sweep_deg=%g is ignored", self.vehicle.name,
                        cfg.turret_sweep_deg)
        self._static: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._cached: tuple[int, _Target] | None = None

    def __len__(self) -> int:
        return self.cfg.frames

    # --- geometry -------------------------------------------------------------------------
    def pose(self, i: int) -> VehiclePose:
        """Pose of frame ``i`` in the camera's world frame (scalar float fields)."""
        i = self._index(i)
        cfg = self.cfg
        r, sign = cfg.radius_m, (1.0 if cfg.clockwise else -1.0)
        step = cfg.speed_mps / r / cfg.fps  # radians of circle per frame
        if cfg.start_deg is None:
            a0 = math.pi - sign * step * (cfg.frames - 1) / 2
        else:
            a0 = math.radians(cfg.start_deg)
        a = a0 + sign * step * i
        heading = (a + sign * math.pi / 2) % (2 * math.pi)
        heading = 0.0 if heading >= 2 * math.pi else heading
        return VehiclePose(r * math.sin(a), -cfg.camera_height_m, cfg.range_m + r * math.cos(a), heading)

    def centre(self, i: int) -> np.ndarray:
        """(3,) the vehicle's centre in frame ``i`` (world frame, metres): the centre of the rest
        pose's 3D bounding box, carried by the pose (what the truth's x, y, z report)."""
        R, t = body_to_world(self.pose(i))
        return (R @ torch.as_tensor(self.vehicle.mesh.bounds.mean(axis=0)) + t).numpy()

    def _posed_vehicle(self, i: int) -> Vehicle:
        """The vehicle of frame i, its turret turned by the sweep."""
        if not self._sweep:
            return self.vehicle
        phase = 2 * math.pi * i / self.cfg.fps / self.cfg.turret_period_s
        return self.vehicle.posed({"turret_yaw": math.radians(self.cfg.turret_sweep_deg) * math.sin(phase)})

    def _target(self, i: int) -> _Target:
        """Render frame i's target around its projected vertices (cached for the last frame asked)."""
        if self._cached is not None and self._cached[0] == i:
            return self._cached[1]
        cam = self.camera
        vehicle = self._posed_vehicle(i)
        pose = self.pose(i)
        R, t = body_to_world(pose)
        mesh = vehicle.mesh
        uv, depth = cam.project(torch.as_tensor(np.asarray(mesh.vertices)) @ R.T + t)  # (M, 2), (M,)
        if not bool((depth > 0).all()):
            raise ValueError(f"{self.name}: frame {i}: the vehicle reaches behind the camera")
        u0, v0 = (int(math.floor(float(x))) for x in uv.amin(0))
        u1, v1 = (int(math.ceil(float(x))) for x in uv.amax(0))
        window = Camera(cam.fx, cam.fy, cam.cx - u0, cam.cy - v0, u1 - u0 + 1, v1 - v0 + 1, R=cam.R)
        silhouette = render_mask(vehicle, window, pose).numpy()  # complete, for the centroid
        rows, cols = np.nonzero(silhouette)
        centroid = (u0 + float(cols.mean()), v0 + float(rows.mean())) if rows.size else (math.nan, math.nan)
        # The rest only inside the frame: the window clipped to it (possibly empty).
        fu0, fv0 = min(max(u0, 0), cam.width), min(max(v0, 0), cam.height)
        fu1, fv1 = max(min(u1 + 1, cam.width), fu0), max(min(v1 + 1, cam.height), fv0)
        silhouette = silhouette[fv0 - v0:fv1 - v0, fu0 - u0:fu1 - u0]
        cover, radiance, centre_parts = self._radiance(vehicle, uv - torch.tensor([fu0, fv0]), depth,
                                                       silhouette.shape, float(np.linalg.norm(self.centre(i))), pose)
        parts = np.where(silhouette, np.where(centre_parts >= 0, centre_parts, BODY), -1)
        target = _Target(fu0, fv0, silhouette, parts, cover, radiance, centroid)
        self._cached = (i, target)
        return target

    def _radiance(self, vehicle: Vehicle, uv: torch.Tensor, depth: torch.Tensor, shape: tuple[int, int],
                  slant_m: float, pose: VehiclePose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The target's pixels from SUPERSAMPLE² sub-samples each (module docstring, "Thermal model"
        and "Visible band").

        Sub-sample (a, b) of pixel (j, i) sits at (j + (a − k) / S, i + (b − k) / S), k = S // 2,
        so the middle one is the pixel centre.

        Args:
            uv: (M, 2) vertices in window pixels; depth: (M,) metres; shape: (h, w) of the window;
            slant_m: range for the atmospheric transmission (IR); pose: the vehicle's (visible).
        Returns:
            cover: (h, w) float32 fraction of sub-samples on the target; radiance: (h, w) float32
            Σ apparent temperature (IR) or grey level (visible) over them / S²; centre_parts: (h, w)
            int64 part at the pixel centre, −1 where no face covers it.
        """
        temps, S = self._temps, _SUPERSAMPLE
        k, (h, w) = S // 2, shape
        mesh = vehicle.mesh
        faces = np.asarray(mesh.faces)
        nearest, weights = visible_faces(S * uv + k, depth, torch.as_tensor(faces), S * h, S * w)
        nearest, weights = nearest.numpy(), weights.numpy()
        covered = nearest >= 0
        seen = nearest[covered]
        points = np.einsum("nk,nkd->nd", weights[covered], np.asarray(mesh.vertices)[faces[seen]])
        parts = np.full(nearest.shape, -1, dtype=np.int64)
        parts[covered] = surface_parts(mesh, points, seen, vehicle.cls)
        sub_k = np.zeros(nearest.shape)
        if self.cfg.band == "visible":
            sub_k[covered] = self._brightness(mesh, points, seen, parts[covered], pose)
        else:
            # Part temperature + top_delta |n_Z|, pulled towards the ground's by the atmosphere.
            part_k = np.array([temps[f"{p}_k"] for p in PARTS])
            kelvin = part_k[parts[covered]] + temps["top_delta_k"] * np.abs(np.asarray(mesh.face_normals)[seen, 2])
            tau = math.exp(-self.cfg.extinction_per_km * slant_m / 1000.0)
            sub_k[covered] = temps["ground_k"] + tau * (kelvin - temps["ground_k"])
        cover = covered.reshape(h, S, w, S).mean(axis=(1, 3), dtype=np.float64)
        radiance = sub_k.reshape(h, S, w, S).mean(axis=(1, 3))
        return cover.astype(np.float32), radiance.astype(np.float32), parts[k::S, k::S]

    def _brightness(self, mesh: trimesh.Trimesh, points: np.ndarray, faces: np.ndarray, parts: np.ndarray,
                    pose: VehiclePose) -> np.ndarray:
        """Grey levels of seen surface points (module docstring, "Visible band").

        Args:
            points: (N, 3) body frame; faces: (N,) their faces; parts: (N,) their PARTS.
        Returns:
            (N,) float64 in [0, MAX_GREY].
        """
        cfg = self.cfg
        R, t = (a.numpy() for a in body_to_world(pose))
        R_inv = np.linalg.inv(R)  # det R = −1 (the world frame is left-handed), still orthogonal
        to_camera = R_inv @ -t - points  # (N, 3) the camera centre (the world origin) in the body frame
        normals = np.asarray(mesh.face_normals)[faces]
        normals = np.where((np.einsum("nd,nd->n", normals, to_camera) < 0)[:, None], -normals, normals)
        dark = (parts == RUNNING_GEAR) | (parts == EXHAUST)
        albedo = np.where(dark, _DARK_ALBEDO, cfg.body_albedo)
        albedo = albedo * (1 + cfg.texture_contrast * _texture(points, _generator(cfg.seed, _TEXTURE, 1)))
        return MAX_GREY * lambert(albedo, normals, R_inv @ cfg.light_direction(), cfg.ambient)

    def _paste(self, target: _Target, window: np.ndarray, fill) -> np.ndarray:
        """A frame-sized array holding ``window`` (one of the target's arrays) at its place."""
        out = np.full((self.cfg.height, self.cfg.width), fill, dtype=window.dtype)
        h, w = window.shape
        out[target.v0:target.v0 + h, target.u0:target.u0 + w] = window
        return out

    def true_mask(self, i: int) -> np.ndarray:
        """(height, width) bool: the vehicle's rendered silhouette in frame ``i``, before occlusion."""
        target = self._target(self._index(i))
        return self._paste(target, target.silhouette, False)

    def visible_mask(self, i: int) -> np.ndarray:
        """(height, width) bool: the silhouette minus what the occluder hides."""
        return self.true_mask(i) & ~self.occluder_mask()

    def part_map(self, i: int) -> np.ndarray:
        """(height, width) int64: the PARTS index of the surface seen at each target pixel, −1 elsewhere
        (before occlusion)."""
        target = self._target(self._index(i))
        return self._paste(target, target.parts, -1)

    # --- background -----------------------------------------------------------------------
    def _static_scene(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(sharp scene, blurred scene, occluder mask), each (H, W), built once."""
        if self._static is not None:
            return self._static
        if self.cfg.band == "visible":
            scene = self._floor().astype(np.float32)
            blurred = _gaussian_blur(scene, self.cfg.psf_sigma, self.cfg.psf_sigma, cv2.BORDER_REFLECT_101)
            self._static = (scene, blurred, np.zeros(scene.shape, dtype=bool))
            return self._static
        cfg, temps = self.cfg, self._temps
        H = cfg.height
        f, cy = cfg.focal_px, (H - 1) / 2
        v_h = cy - f * math.tan(cfg.tilt_rad)  # horizon row (module docstring, R)
        v = np.arange(H, dtype=np.float64)[:, None]
        top = max(v_h, 0.0)  # the ground's gradient runs from the bottom row to the horizon (or frame top)
        frac = np.clip((H - 1 - v) / max(H - 1 - top, 1.0), 0.0, None)  # 0 at the bottom, 1 at the horizon
        horizon_k = temps["ground_k"] + cfg.ground_gradient_k / 2
        ground = temps["ground_k"] - cfg.ground_gradient_k / 2 + cfg.ground_gradient_k * frac
        # Rows below the horizon are ground: their exponent is held at 0 (a steep view overflowed it).
        sky = temps["sky_k"] + (horizon_k - temps["sky_k"]) * np.exp(np.minimum(v - v_h, 0.0) / (_SKY_SCALE * H))
        is_ground = v > v_h
        clutter = self._clutter(_CLUTTER)
        scene = np.where(is_ground, ground + cfg.clutter_k * clutter, sky)
        occluder = self._occluder_mask()
        scene = np.where(occluder, temps["occluder_k"] + cfg.clutter_k * self._clutter(_OCCLUDER), scene)
        scene = scene.astype(np.float32)
        blurred = _gaussian_blur(scene, cfg.psf_sigma, cfg.psf_sigma, cv2.BORDER_REFLECT_101)
        self._static = (scene, blurred, occluder)
        return self._static

    def _world_rays(self, uv: np.ndarray) -> np.ndarray:
        """(..., 3) world-frame directions (not normalised) of the rays through pixels uv (..., 2)."""
        rays = self.camera.R.T @ self.camera.pixel_rays(torch.as_tensor(uv)).reshape(-1, 3).T  # (3, P) world
        return rays.numpy().T.reshape(*uv.shape[:-1], 3)

    def _floor(self) -> np.ndarray:
        """(H, W) float64 grey levels of the visible band's static background (module docstring):
        the lit, tiled and textured floor below the horizon, averaged over S x S sub-samples per
        pixel like the target, and a plain wall above it."""
        cfg, S = self.cfg, _SUPERSAMPLE
        k = S // 2
        offsets = (np.arange(S) - k) / S
        u = (np.arange(cfg.width)[:, None] + offsets).ravel()  # (W·S,) sub-sample columns
        out = np.empty((cfg.height, cfg.width))
        # Bands of rows: the sub-samples' float64 temporaries of a whole 2048 x 2048 frame took 4.5 GB.
        for r0 in range(0, cfg.height, _FLOOR_BAND_ROWS):
            rows = np.arange(r0, min(r0 + _FLOOR_BAND_ROWS, cfg.height))
            v = (rows[:, None] + offsets).ravel()  # (h·S,) sub-sample rows of the band
            rays = self._world_rays(np.stack(np.meshgrid(u, v), axis=-1))  # (h·S, W·S, 3)
            down = rays[..., 1] < 0
            with np.errstate(divide="ignore", invalid="ignore"):
                s = np.where(down, cfg.camera_height_m / -rays[..., 1], 0.0)  # ray parameter at the floor y = −h
            ground = np.stack([s * rays[..., 0], s * rays[..., 2]], axis=-1)[down]  # (P, 2) floor (x, z), metres
            texture = _texture(ground, _generator(cfg.seed, _TEXTURE, 0))  # the same waves in every band
            albedo = cfg.floor_albedo * (1 + cfg.texture_contrast * texture)
            from_line = np.abs(ground / _TILE_M - np.round(ground / _TILE_M)).min(axis=1) * _TILE_M
            albedo = np.where(from_line < _GROUT_M / 2, _GROUT_SHADE * albedo, albedo)
            up = np.broadcast_to(np.array([0.0, 1.0, 0.0]), (len(albedo), 3))
            grey = np.full(down.shape, MAX_GREY * _WALL_ALBEDO * cfg.ambient)
            grey[down] = MAX_GREY * lambert(albedo, up, cfg.light_direction(), cfg.ambient)
            out[rows] = grey.reshape(len(rows), S, cfg.width, S).mean(axis=(1, 3))
        return out

    def _clutter(self, stream: int) -> np.ndarray:
        """(H, W) float64 static texture of unit standard deviation (module docstring)."""
        cfg = self.cfg
        white = torch.randn(cfg.height, cfg.width, generator=_generator(cfg.seed, stream, 0), dtype=torch.float64)
        smooth = _gaussian_blur(white.numpy(), cfg.clutter_scale_px * cfg.clutter_stretch, cfg.clutter_scale_px,
                                cv2.BORDER_REFLECT_101)
        return (smooth - smooth.mean()) / max(float(smooth.std()), 1e-12)

    def _occluder_mask(self) -> np.ndarray:
        """(H, W) bool: pixels whose ray meets the occluder's wall (module docstring)."""
        cfg = self.cfg
        H, W = cfg.height, cfg.width
        if cfg.occluder_width_m == 0:
            return np.zeros((H, W), dtype=bool)
        z_occ = cfg.occluder_range_m
        if z_occ is None:
            z_occ = cfg.range_m - cfg.radius_m - 2 * _OCCLUDER_GAP_M
        rays = self._world_rays(np.stack(np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64)),
                                         axis=-1))  # (H, W, 3)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(rays[..., 2] > 0, z_occ / rays[..., 2], np.nan)  # ray parameter at the wall z = z_occ
        x, y = s * rays[..., 0], s * rays[..., 1] + cfg.camera_height_m  # y: height above the ground
        # Bushy top: the height varies smoothly along x, ±25 % around occluder_height_m.
        n = int(math.ceil(cfg.occluder_width_m / _OCCLUDER_BUMPS_M)) + 2
        bumps = torch.rand(n, generator=_generator(cfg.seed, _OCCLUDER, 1), dtype=torch.float64).numpy()
        x0 = cfg.occluder_x_m - cfg.occluder_width_m / 2
        top = cfg.occluder_height_m * (0.75 + 0.5 * np.interp((x - x0) / _OCCLUDER_BUMPS_M, np.arange(n), bumps))
        inside = (np.abs(x - cfg.occluder_x_m) <= cfg.occluder_width_m / 2) & (y >= 0) & (y <= top)
        return inside

    def occluder_mask(self) -> np.ndarray:
        """(height, width) bool: the static occluder's pixels (all False without one)."""
        return self._static_scene()[2].copy()

    # --- frames ---------------------------------------------------------------------------
    def _counts(self, temperature: np.ndarray, stream: int, index: int) -> np.ndarray:
        """Add frame noise to an apparent-temperature image and read it out as uint16 counts."""
        cfg = self.cfg
        noise = torch.randn(cfg.height, cfg.width, generator=_generator(cfg.seed, stream, index), dtype=torch.float32)
        kelvin = temperature + np.float32(cfg.noise_k) * noise.numpy()
        return np.clip(np.rint((kelvin - ZERO_COUNT_K) * COUNTS_PER_K), 0, MAX_COUNT).astype(np.uint16)

    def scene(self, i: int) -> np.ndarray:
        """(height, width) float32: frame ``i``'s blurred apparent temperature (K; visible band: grey
        level) before noise and read-out."""
        i = self._index(i)
        sharp, blurred, occluder = self._static_scene()
        target = self._target(i)
        out = blurred.copy()
        h, w = target.cover.shape
        window = (slice(target.v0, target.v0 + h), slice(target.u0, target.u0 + w))
        cover = np.where(occluder[window], np.float32(0), target.cover)
        if not cover.any():
            return out
        # A pixel shows cover · T_target + (1 - cover) · T_scene, and blur is linear:
        # blur(scene with target) = blur(scene) + blur(cover · (T_target - T_scene)), zero beyond
        # the kernel's reach around the window; both blurs mirror at the frame's edges. The pad is one pixel
        # more than the reach, so that the mirror at a window edge inside the frame reads zeros only (at the
        # reach itself it read the target's first row back, doubling the kernel's tail: 6 mK at σ = 1 px).
        diff = np.where(cover > 0, target.radiance - cover * sharp[window], np.float32(0))
        sigma = self.cfg.psf_sigma
        pad = math.ceil(_PSF_TRUNCATE * sigma) + 1
        r0, r1 = max(target.v0 - pad, 0), min(target.v0 + h + pad, self.cfg.height)
        c0, c1 = max(target.u0 - pad, 0), min(target.u0 + w + pad, self.cfg.width)
        diff = np.pad(diff, ((target.v0 - r0, r1 - target.v0 - h), (target.u0 - c0, c1 - target.u0 - w)))
        out[r0:r1, c0:c1] += _gaussian_blur(diff, sigma, sigma, cv2.BORDER_REFLECT_101)
        return out

    def _grey(self, grey: np.ndarray, stream: int, index: int) -> np.ndarray:
        """Add frame noise to a grey-level image and read it out as uint8 (visible band)."""
        cfg = self.cfg
        noise = torch.randn(cfg.height, cfg.width, generator=_generator(cfg.seed, stream, index), dtype=torch.float32)
        return np.clip(np.rint(grey + np.float32(cfg.noise_dn) * noise.numpy()), 0, MAX_GREY).astype(np.uint8)

    def _read_out(self, image: np.ndarray, stream: int, index: int) -> np.ndarray:
        return (self._grey if self.cfg.band == "visible" else self._counts)(image, stream, index)

    def _read_frame(self, i: int) -> np.ndarray:
        return self._read_out(self.scene(i), _NOISE, i)

    def warmup_frames(self, n: int) -> Iterator[np.ndarray]:
        """``n`` target-free frames, (height, width) uint16 (IR) or uint8 (visible): the static
        background with fresh noise."""
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise ValueError(f"Expected n to be an integer >= 0; got {n!r}")
        blurred = self._static_scene()[1]
        return (self._read_out(blurred, _WARMUP, k) for k in range(n))

    def _truth(self, i: int) -> FrameTruth:
        cfg = self.cfg
        pose = self.pose(i)
        x, y, z = self.centre(i).tolist()
        target = self._target(i)
        theta, phi = view_of_pose(VehiclePose(x, y, z, pose.heading), self.camera)
        rows, cols = np.nonzero(target.silhouette)
        box = ((target.u0 + cols.min(), target.v0 + rows.min(), target.u0 + cols.max(), target.v0 + rows.max())
               if rows.size else (math.nan,) * 4)
        return FrameTruth(x=x, y=y, z=z, heading=pose.heading, speed=cfg.speed_mps,
                          theta=float(theta), phi=float(phi), u=target.centroid[0], v=target.centroid[1],
                          u0=box[0], v0=box[1], u1=box[2], v1=box[3], vehicle=self.vehicle.name,
                          vehicle_class=self.vehicle.cls, range_m=math.hypot(x, y, z),
                          aspect=float(theta), time_s=i / cfg.fps)


def parse_synthetic_spec(rest: str) -> tuple[str, SceneConfig]:
    """Split ``"vehicle=NAME_OR_PATH,key=value,..."`` into the vehicle and its SceneConfig.

    Keys are SceneConfig fields (``range`` is short for ``range_m``), values YAML scalars.
    ``ValueError`` names the spec and the bad part, key or value.
    """
    where = f"synthetic spec {show(rest)}"
    _, options = parse_spec_options(rest, has_target=False)
    if "range" in options:
        if "range_m" in options:
            raise InputError(f"{where}: option 'range_m' given twice (as 'range' and 'range_m')")
        options["range_m"] = options.pop("range")
    vehicle = options.pop("vehicle", "")
    if not vehicle:
        raise InputError(f"{where}: missing vehicle=NAME_OR_PATH")
    try:
        cfg = load_config(SceneConfig, overrides=[f"{k}={v}" for k, v in options.items()], what="option")
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return vehicle, cfg


def open_synthetic(rest: str) -> SyntheticSequence:
    """The opener of the ``synthetic:`` scheme (module docstring)."""
    vehicle, cfg = parse_synthetic_spec(rest)
    return SyntheticSequence(vehicle, cfg)


register_scheme("synthetic", open_synthetic)
