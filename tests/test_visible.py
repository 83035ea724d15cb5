"""The visible band (thesis 6.3): the simulator's visible mode, rendered checkerboards and their
calibration, and the visible-band experiment, against hand-worked formulas, an independent
rasteriser (render_mask), the rendered ground-truth camera and the run's own sequences."""

import hashlib
import json
import math

import numpy as np
import pytest
import torch
from scipy import ndimage

import torch_atr
from torch_atr.calibration import calibrate_checkerboard, find_checkerboard, floor_pose, levelled_camera
from torch_atr.camera import Camera
from torch_atr.config import ConfigError
from torch_atr.data.checkerboard import calibration_poses, render_checkerboard
from torch_atr.data.synthetic import SceneConfig, SyntheticSequence, lambert, scene_camera, visible_scene

PATTERN = (9, 6)
# Board on the floor, X -> world x, Y -> world z (forward), Z -> world y (up): board Z = X × Y up.
SMALL = {"width": 320, "height": 240, "focal_px": 240.0}  # the visible scene at half the resolution (fast)
FLOOR_R = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]], dtype=torch.float64)


def _sha(a: np.ndarray) -> str:
    return hashlib.sha256(a.tobytes()).hexdigest()[:16]


# SHA-256 prefixes of IR frames, warm-up frames and truths, computed on the simulator before the
# visible band was added: the IR band must stay bit-identical.
IR_BEFORE = {
    "default": (["53705d7b7febe77b", "d340f2abdd09a6fb", "2adabf217dfe360a", "35e582f8c333c275", "d4b77118b94a0504"],
                "c54ea41a6dd11f3a",
                (0.1666663580248728, 950.0002777775205, 322.3184357541899, 247.048683160415, 1.567287555243055,
                 0.004086817762915808)),
    "day_occluder": (["4657334048b10547", "db82725fc6247975", "df25d88d4fb07c04", "d8bb329252405bd5"],
                     "b8a50f827638ebf9",
                     (8.518226326237071, 1950.730944597496, 363.7682926829268, 250.890243902439, 1.3952300783128286,
                      0.0019902578335535314)),
}


@pytest.mark.parametrize("name, cfg", [
    ("default", SceneConfig(frames=5)),
    ("day_occluder", SceneConfig(frames=4, range_m=2000, night=False, occluder_width_m=6, seed=3, start_deg=170))])
def test_ir_frames_are_unchanged_by_the_visible_band(name, cfg):
    frames, warmup, truth = IR_BEFORE[name]
    seq = SyntheticSequence("btr_70", cfg)
    assert [_sha(seq.frame(i)) for i in range(len(seq))] == frames
    assert _sha(next(iter(seq.warmup_frames(1)))) == warmup
    t = seq.truth(1)
    assert (t.x, t.z, t.u, t.v, t.theta, t.phi) == truth


@pytest.fixture(scope="module")
def pickup():
    """A test-split vehicle in the visible scene, light noise-free (the tests add none)."""
    return SyntheticSequence("ford_f150", visible_scene(frames=40, start_deg=150, seed=2, **SMALL))


def test_visible_frames_are_uint8_deterministic_and_warmup_is_target_free(pickup):
    f5 = pickup.frame(5)
    assert f5.dtype == np.uint8 and f5.shape == (240, 320)
    assert 10 < math.degrees(pickup.truth(5).phi) < 40  # inside the trained elevations [0°, 40°]
    pickup.frame(30)
    assert np.array_equal(pickup.frame(5), f5)  # frame i depends only on (cfg, i)
    again = SyntheticSequence("ford_f150", visible_scene(frames=40, start_deg=150, seed=2, **SMALL))
    assert np.array_equal(again.frame(5), f5)
    w0, w1 = list(pickup.warmup_frames(2))
    assert w0.dtype == np.uint8 and not np.array_equal(w0, w1)  # fresh noise
    mask = pickup.true_mask(5)
    # Off the target the frame is the warm-up's background up to the noise (σ = 2 grey levels).
    off = ~ndimage.binary_dilation(mask, iterations=4)
    diff = f5.astype(float)[off] - w0.astype(float)[off]
    assert abs(diff.mean()) < 0.1 and diff.std() == pytest.approx(2 * math.sqrt(2), rel=0.1)


def test_visible_target_matches_the_independent_rasteriser(pickup):
    """Where the noise-free frame differs from the background is render_mask's silhouette (true_mask)."""
    background = next(iter(SyntheticSequence("ford_f150", visible_scene(frames=40, start_deg=150, seed=2,
                                                                       noise_dn=0.0, **SMALL)).warmup_frames(1)))
    for i in (0, 20, 39):
        changed = np.abs(pickup.scene(i) - background.astype(np.float32)) > 6
        mask = pickup.true_mask(i)
        assert mask.sum() > 1500  # close range: a large target
        # Nothing changes beyond the PSF's reach around the silhouette, and most of it stands out
        # (the rest: dark tyres or shaded faces close to the floor's grey).
        assert (changed & ~ndimage.binary_dilation(mask, iterations=3)).sum() == 0
        assert (changed & mask).sum() / mask.sum() > 0.88


def test_lambert_head_on_is_brighter_than_grazing():
    light = np.array([0.0, 1.0, 0.0])
    normals = np.array([[0.0, 1.0, 0.0], [math.sin(1.2), math.cos(1.2), 0.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    got = lambert(np.full(4, 0.5), normals, light, ambient=0.2)
    expected = [0.5 * (0.2 + 0.8 * c) for c in (1.0, math.cos(1.2), 0.0, 0.0)]  # by hand; facing away: ambient
    assert got == pytest.approx(expected)
    assert got[0] > got[1] > got[2]
    with pytest.raises(ValueError, match=r"normals \(N, 3\)"):
        lambert(np.ones(3), normals, light, 0.2)


def test_floor_shading_follows_the_light_elevation():
    """The floor (normal up) lit at elevation e is shaded ambient + (1 − ambient) sin e, texture and all."""
    scenes = {e: SyntheticSequence("ford_f150", visible_scene(frames=1, light_elevation_deg=e, noise_dn=0.0,
                                                                  **SMALL))
              for e in (90.0, 20.0)}
    off = ~ndimage.binary_dilation(scenes[90.0].true_mask(0), iterations=6)
    high, low = (scenes[e].scene(0)[off].astype(np.float64) for e in (90.0, 20.0))
    a = 0.35
    assert np.median(high / low) == pytest.approx(1.0 / (a + (1 - a) * math.sin(math.radians(20))), rel=1e-3)
    assert high.mean() > low.mean()  # head-on brighter than grazing


def test_visible_config_checks():
    assert visible_scene().range_m - visible_scene().radius_m < 20  # closer than the IR band allows
    with pytest.raises(ConfigError, match="range_m"):
        SceneConfig(range_m=13.0, circle_diameter_m=10.0)  # the IR band keeps its occluder room
    with pytest.raises(ConfigError, match="band"):
        SceneConfig(band="uv")
    with pytest.raises(ConfigError, match="occluder_width_m"):
        visible_scene(occluder_width_m=3.0)
    with pytest.raises(ConfigError, match="ambient"):
        visible_scene(ambient=float("nan"))
    with pytest.raises(ConfigError, match="range_m"):
        visible_scene(range_m=6.5)  # the circle would pass under the camera
    from torch_atr.experiments.visible import VisibleConfig

    with pytest.raises(ConfigError, match="override filter.sigma=-1: filter: bad value"):  # before any worker runs
        VisibleConfig(tracker=("filter.sigma=-1",))


# --- checkerboards ---------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def camera():
    return scene_camera(visible_scene())


def test_rendered_corners_are_where_the_camera_projects_them(camera):
    square = 0.5
    t = torch.tensor([-2.0, -6.5, 12.0], dtype=torch.float64)
    image = render_checkerboard(camera, PATTERN, square, FLOOR_R, t, noise=0.0)
    found = find_checkerboard(image, PATTERN)
    assert found is not None, "no checkerboard found on the floor board (OpenCV 4.8 and 4.9 find none; >= 4.10 does)"
    cols, rows = PATTERN
    board = torch.tensor([[k % cols * square, k // cols * square, 0.0] for k in range(cols * rows)],
                         dtype=torch.float64)
    expected, _ = camera.project(board @ FLOOR_R.T + t)
    error = np.abs(found - expected.numpy())
    assert error.max() < 0.3 and error.mean() < 0.1  # sub-pixel, in the floor frame's corner order


def test_calibration_from_rendered_boards_recovers_the_true_camera(camera):
    """Intrinsics from tilted boards, the pose from a floor board, levelled: the rendered truth."""
    g = torch.Generator().manual_seed(0)
    square = 0.1
    images = [render_checkerboard(camera, PATTERN, square, R, t, generator=g)
              for R, t in calibration_poses(camera, PATTERN, square, count=5)]
    intrinsics, rms = calibrate_checkerboard(images, PATTERN, square)
    assert rms < 0.2
    assert (intrinsics.fx, intrinsics.fy) == pytest.approx((camera.fx, camera.fy), rel=5e-3)
    assert (intrinsics.cx, intrinsics.cy) == pytest.approx((camera.cx, camera.cy), abs=2.0)
    floor_square = 0.5
    t = torch.tensor([-2.0, -6.5, 11.0], dtype=torch.float64)
    floor = render_checkerboard(camera, PATTERN, floor_square, FLOOR_R, t, generator=g)
    levelled, height = levelled_camera(floor_pose(intrinsics, floor, PATTERN, floor_square))
    assert height == pytest.approx(6.5, abs=0.03)
    assert torch.allclose(levelled.t, torch.zeros(3, dtype=torch.float64))
    angle = math.degrees(math.acos(min(1.0, (float(torch.trace(levelled.R.T @ camera.R)) - 1) / 2)))
    assert angle < 0.2
    # The levelled camera sees a floor point where the true camera does.
    point = torch.tensor([[1.5, -6.5, 12.0]], dtype=torch.float64)
    assert torch.allclose(levelled.project(point)[0], camera.project(point)[0], atol=1.0)


def test_levelled_camera_refuses_a_sensor_like_world_and_a_vertical_axis(camera):
    with pytest.raises(ValueError, match="floor frame"):
        levelled_camera(camera)
    down = Camera(500.0, 500.0, 320.0, 240.0, 640, 480, R=torch.diag(torch.tensor([1.0, 1.0, -1.0])),
                  t=torch.tensor([0.0, 0.0, 5.0]))  # looking straight down at the floor, det R = −1
    with pytest.raises(ValueError, match="not vertical"):
        levelled_camera(down)


def test_render_checkerboard_checks_its_inputs(camera):
    with pytest.raises(ValueError, match="shape"):
        render_checkerboard(camera, PATTERN, 0.1, torch.eye(3), torch.zeros(2))
    with pytest.raises(ValueError, match="orthogonal"):
        render_checkerboard(camera, PATTERN, 0.1, 2 * torch.eye(3), torch.zeros(3))
    for pattern in ((1, 5), (2, 2)):  # 2 x 2 rendered a board find_checkerboard cannot find
        with pytest.raises(ValueError, match=r"at least 3 x 3 inner corners \(the fewest OpenCV finds\)"):
            render_checkerboard(camera, pattern, 0.1, torch.eye(3), torch.zeros(3))


# --- the experiment ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    from torch_atr.experiments.__main__ import main

    out = tmp_path_factory.mktemp("visible")
    agg = main(["visible", "--out", str(out), "--quick", "--workers", "1"])
    return out, agg, json.loads((out / "results.json").read_text(encoding="utf-8"))


def test_quick_run_writes_its_report(quick_run):
    out, agg, results = quick_run
    assert results["format"] == "torch_atr.visible_report" and results["aggregate"] == agg
    assert results["torch_atr_version"] == torch_atr.__version__ and results["wall_s"] > 0
    assert results["config"]["frames"] == 8 and results["config"]["methods"] == ["I", "IV"]
    for name in ("overlap", "calibration", "view_car", "view_suv", "view_van", "identity_car", "identity_van"):
        assert (out / f"{name}.png").stat().st_size > 1000
    report = (out / "report.md").read_text(encoding="utf-8")
    assert "## Calibration (thesis 3.3)" in report and "Fig. 6.13" in report and "Fig. 6.15" in report


def test_quick_run_calibration_is_close_to_the_true_camera(quick_run):
    cal = quick_run[2]["calibration"]
    true, got, errors = cal["true"], cal["calibrated"], cal["errors"]
    assert errors["fx_rel"] == pytest.approx(got["fx"] / true["fx"] - 1)
    assert abs(errors["fx_rel"]) < 0.01 and abs(errors["cx_px"]) < 2 and abs(errors["cy_px"]) < 2
    assert abs(cal["height_m"] - 6.5) < 0.1 and errors["rotation_deg"] < 0.5
    assert np.linalg.det(np.array(got["R"])) == pytest.approx(1.0)  # sensor-like, as the tracker wants


def test_quick_run_numbers_agree_with_its_sequences(quick_run):
    """The aggregate against the per-frame lists, recomputed here by hand, and the truth against
    the simulator opened afresh."""
    from torch_atr.experiments.sensiac_like import worker_model, load_experiment_vehicle
    from torch_atr.experiments.visible import VisibleConfig, scene

    _, agg, results = quick_run
    model = worker_model("checkpoints/default.pt")
    cfg = VisibleConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in results["config"].items()})
    for seq in results["sequences"]:
        assert seq["calibrated"] == (seq["role"] != "van")
        for method, m in seq["methods"].items():
            row = agg[seq["role"]][method]
            overlap = [v for v in m["overlap"] if v is not None]
            assert len(m["alpha"]) == 8 and all(0 < v <= 1 for v in overlap)
            assert row["overlap_ratio"] == pytest.approx(np.mean(overlap), abs=1e-4)
            classes = model.classify(torch.tensor(m["alpha"], dtype=model.alphas.dtype)).tolist()
            on_class = np.mean([model.class_names[c] == seq["class"] for c in classes])
            assert row["recognition_pct"] == pytest.approx(100 * on_class)
            if seq["calibrated"]:
                horizontal = np.mean(np.abs(np.array(m["x"]) - np.array(m["true_x"])))
                assert row["horizontal_error_m"] == pytest.approx(horizontal, abs=1e-4)
                assert row["horizontal_error_m"] < 1.5 and row["range_error_m"] < 3.0  # metres at ~10 m
            else:
                assert row["horizontal_error_m"] is None and all(v is None for v in m["x"])
        truth = SyntheticSequence(load_experiment_vehicle(seq["vehicle"]), scene(seq["role"], cfg)).truth(3)
        assert seq["methods"]["I"]["true_theta"][3] == pytest.approx(truth.theta, abs=1e-4)
        assert seq["methods"]["I"]["true_x"][3] == pytest.approx(truth.x, abs=1e-4)  # the van's too
    assert agg["car"]["I"]["recognition_pct"] == 100  # the car is a car from the first frame on


def test_quick_run_resumes_and_refuses_foreign_folders(quick_run, tmp_path, monkeypatch):
    from torch_atr.experiments import visible
    from torch_atr.experiments.__main__ import main
    from torch_atr.io import OutputExistsError

    out = quick_run[0]

    def no_rerun(*args):
        raise AssertionError("a finished sequence was run again")

    monkeypatch.setattr(visible, "run_visible_sequence", no_rerun)
    agg = main(["visible", "--out", str(out), "--quick", "--workers", "1"])
    assert agg == quick_run[1]
    with pytest.raises(ConfigError, match="another configuration"):
        main(["visible", "--out", str(out), "--quick", "--workers", "1", "--particles", "100"])
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(OutputExistsError):
        main(["visible", "--out", str(tmp_path), "--quick"])
    with pytest.raises(ConfigError, match="--ranges"):
        main(["visible", "--out", str(tmp_path / "new"), "--quick", "--ranges", "1000"])


def test_the_calibration_figure_and_report_refuse_a_drawn_image_that_is_not_bgr(tmp_path):
    """A grey (H, W) image was mirrored left to right by drawn[..., ::-1] (meant to turn BGR into RGB) and
    shown without a word; the report refuses it before writing anything."""
    from torch_atr.experiments.visible import VisibleConfig, calibration_figure, write_visible_report

    grey = np.zeros((48, 64), dtype=np.uint8)
    calibration = {"floor_square_m": 0.5, "errors": {"fx_rel": 0.0, "height_m": 0.0, "rotation_deg": 0.0}}
    with pytest.raises(ValueError, match=r"Expected drawn to have shape \(H, W, 3\) \(BGR\); got shape \(48, 64\)"):
        calibration_figure(grey, calibration)
    with pytest.raises(ValueError, match=r"Expected drawn to have shape \(H, W, 3\) \(BGR\); got shape \(48, 64\)"):
        write_visible_report(tmp_path, VisibleConfig(), calibration, grey, [], None, 0.0)
    assert list(tmp_path.iterdir()) == []
