"""The visible-band experiment (thesis 6.3) on the simulator's visible band.

The thesis filmed two remote-controlled toy cars (a Lexus IS350 sedan and a BMW X5 SUV) in its
lab, calibrated the camera with a checkerboard and tracked them in 3D; and it tracked a white
cargo van of a surveillance video (PETS2001) without a camera model, pose and identity only. Here:

1. **Calibration** (thesis 3.3). The lab camera of :func:`~torch_atr.data.synthetic.visible_scene`
   (6.5 m up, tilted down 32°, focal 480 px at 640 x 480) photographs a 9 x 6 checkerboard of
   10 cm squares held at ``boards`` tilted poses (:func:`~torch_atr.data.checkerboard.calibration_poses`)
   for the intrinsics, and one of 50 cm squares lying on the floor at the circle's centre for the
   pose (:func:`~torch_atr.calibration.floor_pose`), which :func:`~torch_atr.calibration.levelled_camera`
   turns into the tracker's camera and camera height. Its errors against the true camera are reported.
2. **Calibrated 3D tracking.** Two held-out meshes the model never saw, a car (a Toyota Prius,
   ``sedan/gazebo_prius_hybrid.obj``) and an SUV (a generic compact SUV,
   ``suv/quaternius_suv.obj``), full size, drive the lab's 10 m circle at 1.5 m/s (a curved path:
   at 10 fps, 120 frames cover 207° of it, from 120° round to the near point and beyond), each
   tracked with Methods I–IV through the CALIBRATED camera from a blind start (``init``).
3. **Uncalibrated pose only** (the cargo van): the UAZ-452 van (``van/chrono_uaz_bus_chassis.obj``,
   class minivan) drives a 16 m circle at 2 m/s seen from farther away (24 m, 8 m up, tilted
   22°, focal 640 px), and :class:`~torch_atr.tracking.blob.BlobTracker` tracks view and
   identity on its normalised blob with no camera at all.

Every tracker closes the segmented mask with a 9 px kernel (``SEGMENTATION``; the default 3 px
leaves holes where the textured vehicle matches the textured floor). Each sequence is simulated
once and tracked by every method; it is one job (worker processes,
:func:`~torch_atr.experiments.sensiac_like.in_processes`) whose result is kept in
``OUT/sequences/ROLE.json``, so an interrupted run resumes. Reported per sequence and method: the
overlap ratio ξ (eq. 6.1) between the reconstructed silhouette placed at the estimate and the
segmented target, per frame (Fig. 6.13) and its mean; recognition (% of frames whose α lies in
the true class's arc) and the two best-matching training vehicles (Fig. 6.14); the 3D errors
(horizontal, range, aspect; for the van only the aspect, θ); and the view over the run on the
hemisphere (Fig. 6.15). The estimates live in the calibrated camera's world frame and the truth in
the true one, so calibration errors count in the tracking errors.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import torch_atr
from torch_atr._checks import describe_array
from torch_atr.config import ConfigError, load_config
from torch_atr.experiments.sensiac_like import (HELDOUT_PREFIX, FrameCache, check_vehicle, in_processes, json_number,
                                                kept_results, resolve_checkpoint, worker_model,
                                                worker_templates)
from torch_atr.io import atomic_write_text
from torch_atr.tracking import METHODS, TrackerConfig
from torch_atr.validate import show

log = logging.getLogger(__name__)

VISIBLE_FORMAT = "torch_atr.visible_report"
SEQUENCE_FORMAT = "torch_atr.visible_sequence"
ROLES = ("car", "suv", "van")  # the van is the uncalibrated sequence
CALIBRATED = ("car", "suv")
# The van's outdoor-like view on top of the lab scene: farther, higher, shallower.
VAN_SCENE = {"range_m": 24.0, "circle_diameter_m": 16.0, "camera_height_m": 8.0, "tilt_deg": 22.0,
             "focal_px": 640.0, "speed_mps": 2.0}
PATTERN = (9, 6)  # inner corners of the checkerboards
HAND_SQUARE_M = 0.1  # the boards held before the camera (intrinsics)
FLOOR_SQUARE_M = 0.5  # the board on the floor (pose), at image_scale 1; larger in smaller images
# The visible band's textured vehicle on its textured floor leaves holes in MOG2's mask wherever the
# two happen to match; a 9 px closing (the tracker's default is 3, set on small IR targets) fills
# them. Measured on the van, 50 frames: overlap 0.74-0.84 -> 0.89-0.96.
SEGMENTATION = ("segmentation.close_px=9",)
PER_FRAME = ("time_s", "overlap", "alpha", "theta", "phi", "x", "z", "true_theta", "true_phi", "true_x",
             "true_z")  # kept per frame (x, z: NaN for the van)


@dataclass(frozen=True)
class VisibleConfig:
    """The visible-band experiment (module docstring): vehicles, methods and the tracker's settings."""

    car: str = HELDOUT_PREFIX + "sedan/gazebo_prius_hybrid.obj"
    suv: str = HELDOUT_PREFIX + "suv/quaternius_suv.obj"
    van: str = HELDOUT_PREFIX + "van/chrono_uaz_bus_chassis.obj"
    methods: tuple[str, ...] = METHODS
    frames: int = 120  # per sequence, at 10 fps
    particles: int = 1000
    init: str = "blind"  # or "truth"
    seed: int = 0  # the scenes', the boards' noise and the tracker's
    start_deg: float = 120.0  # circle position at frame 0 (0 far, 90 right, 180 near)
    image_scale: float = 1.0  # scales every scene's width, height and focal length (quick: 0.5)
    boards: int = 8  # tilted board poses for the intrinsics
    checkpoint: str = "checkpoints/default.pt"
    tracker: tuple[str, ...] = field(default_factory=tuple)  # extra TrackerConfig overrides, key=value

    def __post_init__(self) -> None:
        bad = [m for m in self.methods if m not in METHODS]
        if not self.methods or bad:
            raise ConfigError(f"methods: expected some of {METHODS}; got {self.methods}")
        if self.init not in ("blind", "truth"):
            raise ConfigError(f"init must be 'blind' or 'truth'; got {show(self.init)}")
        if not 1 <= self.frames <= 100_000 or not 1 <= self.particles <= 10_000_000:
            raise ConfigError(f"frames in [1, 1e5] and particles in [1, 1e7]; got {self.frames}, {self.particles}")
        if not (0.25 <= self.image_scale <= 2 and 3 <= self.boards <= 100 and math.isfinite(self.start_deg)):
            raise ConfigError(f"expected image_scale in [0.25, 2], boards in [3, 100] and a finite start_deg; got "
                              f"{self.image_scale}, {self.boards}, {self.start_deg}")
        for role in ROLES:
            scene(role, self)  # fails here, naming the field, not in a worker
            check_vehicle(getattr(self, role))  # as do the vehicles and the checkpoint, before a run folder is made
        resolve_checkpoint(self.checkpoint)
        for method in self.methods:  # and the tracker's overrides
            load_config(TrackerConfig, None, self.tracker_overrides(method))

    def tracker_overrides(self, method: str) -> list[str]:
        return [f"filter.particles={self.particles}", f"filter.method={method}", f"init.mode={self.init}",
                *SEGMENTATION, *self.tracker]


QUICK = {"frames": 8, "particles": 200, "methods": ("I", "IV"), "image_scale": 0.5, "boards": 5}  # the CI-sized run


def scene(role: str, cfg: VisibleConfig):
    """The simulator's scene of a role: the lab (car, SUV) or the van's view, at ``cfg.image_scale``."""
    from torch_atr.data.synthetic import VISIBLE_SCENE, visible_scene

    base = VISIBLE_SCENE | (VAN_SCENE if role == "van" else {})
    s = cfg.image_scale
    return visible_scene(**(base | {"width": round(base["width"] * s), "height": round(base["height"] * s),
                                    "focal_px": base["focal_px"] * s, "frames": cfg.frames, "seed": cfg.seed,
                                    "start_deg": cfg.start_deg}))


def floor_square_m(cfg: VisibleConfig) -> float:
    """The floor board's square: FLOOR_SQUARE_M, grown in images smaller than the lab's so the
    detector still finds its foreshortened squares."""
    return FLOOR_SQUARE_M / min(cfg.image_scale, 1.0)


def floor_board(cfg: VisibleConfig):
    """(R (3, 3), t (3,)): the floor board's pose in the lab's world frame, centred on the circle's
    centre; board X -> world x (right), Y -> z (forward), Z -> y (up)."""
    import torch

    lab, square = scene("car", cfg), floor_square_m(cfg)
    cols, rows = PATTERN
    R = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]], dtype=torch.float64)
    t = torch.tensor([-(cols - 1) * square / 2, -lab.camera_height_m, lab.range_m - (rows - 1) * square / 2],
                     dtype=torch.float64)
    return R, t


def calibrate(cfg: VisibleConfig) -> tuple[dict, np.ndarray]:
    """Calibrate the lab camera from rendered checkerboards (module docstring, step 1).

    Returns:
        ({"true", "calibrated": ``Camera.to_dict()`` (the calibrated one levelled: the tracker's),
        "height_m", "true_height_m", "rms_px", "errors": {"fx_rel", "fy_rel", "cx_px", "cy_px",
        "height_m", "rotation_deg"}}, the floor board's image (H, W, 3) uint8 BGR with cubes drawn by
        the floor-posed calibrated camera (Fig. 3.7; :func:`~torch_atr.calibration.draw_cubes`)).
    """
    import torch

    from torch_atr.calibration import calibrate_checkerboard, draw_cubes, floor_pose, levelled_camera
    from torch_atr.data.checkerboard import calibration_poses, render_checkerboard
    from torch_atr.data.synthetic import scene_camera

    lab = scene("car", cfg)
    true = scene_camera(lab)
    generator = torch.Generator().manual_seed(cfg.seed)
    images = [render_checkerboard(true, PATTERN, HAND_SQUARE_M, R, t, generator=generator)
              for R, t in calibration_poses(true, PATTERN, HAND_SQUARE_M, cfg.boards)]
    intrinsics, rms = calibrate_checkerboard(images, PATTERN, HAND_SQUARE_M)
    square = floor_square_m(cfg)
    floor = render_checkerboard(true, PATTERN, square, *floor_board(cfg), generator=generator)
    posed = floor_pose(intrinsics, floor, PATTERN, square)
    camera, height = levelled_camera(posed)
    cos = (float(torch.trace(camera.R.T @ true.R)) - 1) / 2
    errors = {"fx_rel": camera.fx / true.fx - 1, "fy_rel": camera.fy / true.fy - 1, "cx_px": camera.cx - true.cx,
              "cy_px": camera.cy - true.cy, "height_m": height - lab.camera_height_m,
              "rotation_deg": math.degrees(math.acos(max(-1.0, min(1.0, cos))))}
    log.info("calibration: rms %.3f px, focal %+.2f %%, height %+.3f m, rotation %.3f°", rms,
             100 * errors["fx_rel"], errors["height_m"], errors["rotation_deg"])
    cubes = [[x * square, y * square, 0.0] for x, y in ((0, 0), (7, 0), (0, 4), (7, 4))]
    drawn = draw_cubes(floor, posed, square, cubes, color=(60, 60, 255), thickness=1)  # BGR: red
    return ({"true": true.to_dict(), "calibrated": camera.to_dict(), "height_m": height, "floor_square_m": square,
             "true_height_m": lab.camera_height_m, "rms_px": rms, "errors": errors}, drawn)


def run_visible_sequence(role: str, vehicle: str, calibration: dict | None, cfg: VisibleConfig) -> dict:
    """Simulate one sequence and track it with every method; the result file's content.

    ``calibration`` ({"camera": ``Camera.to_dict()``, "height_m"}) gives the 3D tracker its camera;
    None tracks the normalised blob without one (:class:`~torch_atr.tracking.blob.BlobTracker`).
    Runs on one CPU thread (see :func:`~torch_atr.experiments.sensiac_like.run_sequence`).

    Returns {"format", "role", "vehicle", "class", "calibrated", "scene", "config", "methods":
    {method: {"metrics": ``run_summary``, PER_FRAME key: list per frame (null: unknown)}}, "wall_s"}.
    """
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _run_visible_sequence(role, vehicle, calibration, cfg)
    finally:
        torch.set_num_threads(threads)


def _run_visible_sequence(role: str, vehicle: str, calibration: dict | None, cfg: VisibleConfig) -> dict:
    import torch

    from torch_atr.camera import Camera
    from torch_atr.data.synthetic import SyntheticSequence
    from torch_atr.experiments.sensiac_like import load_experiment_vehicle
    from torch_atr.tracking import Tracker
    from torch_atr.tracking.blob import BlobTracker
    from torch_atr.tracking.filter import column
    from torch_atr.tracking.job import run_summary

    start = time.perf_counter()
    model = worker_model(cfg.checkpoint)
    scene_cfg = scene(role, cfg)
    seq = SyntheticSequence(load_experiment_vehicle(vehicle), scene_cfg)
    frames = FrameCache(seq)  # simulated once, tracked by every method; the truth is the true camera's
    if calibration is None:
        frames.camera, frames.camera_height_m = None, math.nan
    else:
        frames.camera = Camera.from_dict(calibration["camera"], "calibration")
        frames.camera_height_m = calibration["height_m"]
    out = {"format": SEQUENCE_FORMAT, "role": role, "vehicle": vehicle, "class": seq.vehicle.cls,
           "calibrated": calibration is not None, "scene": dataclasses.asdict(scene_cfg),
           "config": dataclasses.asdict(cfg), "methods": {}}
    for method in cfg.methods:
        tracker_cfg = load_config(TrackerConfig, None, cfg.tracker_overrides(method))
        templates = worker_templates(cfg.checkpoint) if method == "IV" else None
        if calibration is None:
            tracker = BlobTracker(model, tracker_cfg, seed=cfg.seed, templates=templates)
        else:
            tracker = Tracker(model, frames.camera, tracker_cfg, seed=cfg.seed, templates=templates)
        with torch.no_grad():
            result = tracker.run(frames, progress=False, snapshots=0)
        out["methods"][method] = {"metrics": run_summary(result, model, cfg.frames // 4),
                                  **{k: [json_number(v) for v in column(result.rows, k)] for k in PER_FRAME}}
    out["wall_s"] = time.perf_counter() - start
    return out


def run_visible(cfg: VisibleConfig, out: Path, workers: int = 0) -> tuple[dict, np.ndarray, list[dict]]:
    """Calibrate, then run every sequence not already in ``out/sequences`` (resumable), ``workers``
    at a time (0: one per core). Returns (calibration, the floor image with cubes, the sequences'
    results in ROLES order). A result file of another configuration is refused (``ConfigError``)."""
    import os

    folder = out / "sequences"
    folder.mkdir(parents=True, exist_ok=True)
    done = kept_results(folder, SEQUENCE_FORMAT, cfg)  # every file: another experiment's too
    calibration, drawn = calibrate(cfg)
    camera = {"camera": calibration["calibrated"], "height_m": calibration["height_m"]}
    todo = [(role, getattr(cfg, role), camera if role in CALIBRATED else None) for role in ROLES if role not in done]
    log.info("%d sequences: %d done before, %d to run", len(ROLES), len(done), len(todo))
    for job, result in in_processes(todo, cfg, workers or os.cpu_count() or 1, run=run_visible_sequence):
        atomic_write_text(json.dumps(result) + "\n", folder / f"{job[0]}.json")
        done[job[0]] = result
    return calibration, drawn, [done[role] for role in ROLES]


def aggregate_visible(results: list[dict], cfg: VisibleConfig) -> dict:
    """{role: {method: {"overlap_ratio", "recognition_pct", "best_matches", "horizontal_error_m",
    "range_error_m", "aspect_error_rad"}}}: means over the frames (None where unknown)."""
    agg: dict = {}
    for r in results:
        for method, m in r["methods"].items():
            metrics = m["metrics"]
            rec = metrics["recognition_accuracy"]
            agg.setdefault(r["role"], {})[method] = {
                "overlap_ratio": metrics["overlap_ratio"], "recognition_pct": None if rec is None else 100 * rec,
                "best_matches": metrics["best_matches"],
                **{k: metrics[k] for k in ("horizontal_error_m", "range_error_m", "aspect_error_rad")}}
    return agg


def _rows(result: dict, method: str) -> list[dict]:
    """Estimate rows rebuilt from a result's per-frame lists (for the figures of :mod:`torch_atr.viz`)."""
    m = result["methods"][method]
    return [{**{k: math.nan if m[k][i] is None else m[k][i] for k in PER_FRAME}, "true_class": result["class"]}
            for i in range(len(m["time_s"]))]


def _title(result: dict) -> str:
    name = result["vehicle"].removeprefix(HELDOUT_PREFIX)
    return f"{result['role']} ({name}, {'calibrated' if result['calibrated'] else 'uncalibrated'})"


def overlap_figure(results: list[dict], cfg: VisibleConfig):
    """Overlap ratio ξ per frame, one panel per sequence, one line per method (Fig. 6.13)."""
    from torch_atr.viz import pyplot

    plt = pyplot()
    fig, axes = plt.subplots(1, len(results), figsize=(5 * len(results), 4), squeeze=False, sharey=True)
    for ax, r in zip(axes[0], results):
        for method in cfg.methods:
            rows = _rows(r, method)
            overlap = [row["overlap"] for row in rows]
            ax.plot([row["time_s"] for row in rows], overlap, lw=1.2,
                    label=f"Method {method}: mean {np.nanmean(overlap):.2f}" if np.isfinite(overlap).any()
                    else f"Method {method}")
        ax.set(xlabel="time (s)", title=_title(r), ylim=(0, 1))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
    axes[0, 0].set_ylabel("overlap ratio ξ (eq. 6.1)")
    fig.suptitle("Overlap of the reconstructed silhouette at the estimate with the segmented target (Fig. 6.13)")
    fig.tight_layout()
    return fig


def _check_drawn(drawn) -> None:
    """ValueError unless ``drawn`` is an (H, W, 3) BGR image (:func:`calibrate`'s)."""
    if not (isinstance(drawn, np.ndarray) and drawn.ndim == 3 and drawn.shape[2] == 3):
        raise ValueError(f"Expected drawn to have shape (H, W, 3) (BGR); got {describe_array(drawn)}")


def calibration_figure(drawn: np.ndarray, calibration: dict):
    """The floor board with cubes drawn through the calibrated camera (Fig. 3.7).

    drawn: (H, W, 3) uint8 BGR, :func:`calibrate`'s image; calibration: its dict.
    """
    from torch_atr.viz import pyplot

    _check_drawn(drawn)

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 6.4))
    ax.imshow(drawn[..., ::-1])
    ax.plot([], [], color=(1.0, 0.24, 0.24),
            label=f"{100 * calibration['floor_square_m']:g} cm cubes drawn with the calibrated camera")
    e = calibration["errors"]
    ax.set(xlabel="u (px)", ylabel="v (px)",
           title=f"Floor checkerboard with cubes (Fig. 3.7)\ncalibrated minus true camera: focal "
                 f"{100 * e['fx_rel']:+.2f} %, height {100 * e['height_m']:+.1f} cm, rotation {e['rotation_deg']:.2f}°")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    return fig


def _number(v, fmt: str = ".2f") -> str:
    return "—" if v is None else format(v, fmt)


def write_visible_report(out: Path, cfg: VisibleConfig, calibration: dict, drawn: np.ndarray,
                         results: list[dict], model, wall_s: float) -> dict:
    """``results.json``, ``report.md`` and the figures in ``out``, atomically; returns the aggregate.

    calibration, drawn: :func:`calibrate`'s dict and its (H, W, 3) uint8 BGR floor board image.
    """
    from torch_atr.viz import alpha_figure, save_figures, view_figure

    _check_drawn(drawn)

    agg = aggregate_visible(results, cfg)
    summary = {"format": VISIBLE_FORMAT, "torch_atr_version": torch_atr.__version__,
               "config": dataclasses.asdict(cfg), "wall_s": wall_s, "calibration": calibration, "aggregate": agg,
               "sequences": [{k: v for k, v in r.items() if k != "config"} for r in results]}
    atomic_write_text(json.dumps(summary, indent=1) + "\n", out / "results.json")
    shown = cfg.methods[0]  # the trajectory and identity figures show the first method (I by default)
    figures = {"overlap": overlap_figure(results, cfg), "calibration": calibration_figure(drawn, calibration)}
    for r in results:
        rows = _rows(r, shown)
        figures[f"view_{r['role']}"] = view_figure(rows, f"{_title(r)}, Method {shown}")
        # Two lines: in one, the title and its "(true class: ...)" ran past the figure's left edge.
        figures[f"identity_{r['role']}"] = alpha_figure(rows, model, f"{_title(r)}\nMethod {shown}")
    save_figures(figures, out)
    e, cal = calibration["errors"], calibration["calibrated"]
    true = calibration["true"]
    methods = "/".join(cfg.methods)
    lines = [
        "# Visible-band experiment (thesis 6.3) on the simulator",
        "",
        f"A car and an SUV the model never saw, tracked in 3D through a camera calibrated from rendered "
        f"checkerboards, and a van tracked without a camera; Methods {', '.join(cfg.methods)}, {cfg.frames} frames "
        f"per sequence, {cfg.particles} particles, {cfg.init} start, seed {cfg.seed}; torch_atr "
        f"{torch_atr.__version__}. The thesis's sequences are real video of toy cars and a van; ours are simulated "
        "full-size vehicles: the numbers sit side by side, they are not the same experiment.",
        "",
        "## Calibration (thesis 3.3)",
        "",
        f"{cfg.boards} tilted boards ({PATTERN[0]} x {PATTERN[1]} inner corners, {100 * HAND_SQUARE_M:g} cm squares) "
        f"for the intrinsics, one board of {100 * calibration['floor_square_m']:g} cm squares on the floor for "
        "the pose; RMS "
        f"reprojection error {calibration['rms_px']:.3f} px.",
        "",
        "| | fx (px) | fy (px) | cx (px) | cy (px) | camera height (m) |",
        "|---|---|---|---|---|---|",
        f"| true | {true['fx']:.1f} | {true['fy']:.1f} | {true['cx']:.1f} | {true['cy']:.1f} | "
        f"{calibration['true_height_m']:.3f} |",
        f"| calibrated | {cal['fx']:.1f} | {cal['fy']:.1f} | {cal['cx']:.1f} | {cal['cy']:.1f} | "
        f"{calibration['height_m']:.3f} |",
        "",
        f"Errors: focal {100 * e['fx_rel']:+.2f} % / {100 * e['fy_rel']:+.2f} %, principal point "
        f"({e['cx_px']:+.2f}, {e['cy_px']:+.2f}) px, height {100 * e['height_m']:+.1f} cm, rotation "
        f"{e['rotation_deg']:.3f}°.",
        "",
        "![calibration](calibration.png)",
        "",
        f"## Per sequence, Methods {methods}",
        "",
        "| sequence | class | overlap ξ (eq. 6.1) | recognition (% of frames) | horizontal (m) | range (m) | "
        "aspect (rad) | two best matches (Method " + shown + ") |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        a = agg[r["role"]]
        cells = ["/".join(_number(a[m][k], fmt) for m in cfg.methods)
                 for k, fmt in (("overlap_ratio", ".2f"), ("recognition_pct", ".0f"), ("horizontal_error_m", ".2f"),
                                ("range_error_m", ".2f"), ("aspect_error_rad", ".2f"))]
        lines.append(f"| {_title(r)} | {r['class']} | " + " | ".join(cells) + " | "
                     + ", ".join(a[shown]["best_matches"]) + " |")
    lines += [
        "",
        "Overlap is against the segmented target, as in the thesis. The van has no camera, so no position: "
        "only the view (aspect θ) is compared with the truth.",
        "",
        "### Overlap per frame (Fig. 6.13)",
        "",
        "![overlap](overlap.png)",
        "",
        f"## Views on the hemisphere (Fig. 6.15) and identity over time (Fig. 6.14), Method {shown}",
        "",
        *[f"![view {r['role']}](view_{r['role']}.png) ![identity {r['role']}](identity_{r['role']}.png)"
          for r in results],
        "",
        "## Run",
        "",
        f"- {len(results)} sequences; wall time {wall_s:.0f} s (this run; sequences kept from an earlier run are "
        "not re-run).",
        "- config: `" + json.dumps(dataclasses.asdict(cfg)) + "`.",
        "",
    ]
    atomic_write_text("\n".join(lines), out / "report.md")
    return agg
