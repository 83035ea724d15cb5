"""The blind start's and the recovery paths' edge cases, each against an independent reference
(brute force, a closed form, the same computation on the whole frame)."""

import inspect
import math

import numpy as np
import pytest
import torch

from torch_atr.camera import Camera
from torch_atr.config import load_config
from torch_atr.data.synthetic import SceneConfig, SyntheticSequence
from torch_atr.pose import camera_centre
from torch_atr.tracking import ShapeAppearance, Tracker, TrackerConfig, initialise
from torch_atr.tracking import filter as filter_module
from torch_atr.tracking.blob import BlobTracker
from torch_atr.tracking.filter import FilterConfig
from torch_atr.tracking.ground import bottom_edge_px, interpolate_periodic
from torch_atr.tracking.initialise import InitConfig, best_hypotheses, ground_depth, hypothesis_shares
from torch_atr.tracking.motion import SPEED, X, Z
from torch_atr.tracking.observation import frame_distance, place_silhouette, project_windows


def _tilt(degrees: float) -> torch.Tensor:
    """A rotation about the sensor's x axis (negative: looking down), det +1."""
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    return torch.tensor([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]], dtype=torch.float64)


def _brute_best(log_lik: list[float], count: int, classes: list[int] | None) -> list[int] | None:
    """best_hypotheses by hand: the finite hypotheses only, each class with one keeping count // C of
    its best (at least one), classes ascending, best first. None where no score is finite: then any
    one index is right, none being better than another."""
    finite = [i for i, v in enumerate(log_lik) if math.isfinite(v)]
    if not finite:
        return None
    ranked = sorted(finite, key=lambda i: -log_lik[i])
    if classes is None:
        return ranked[:count]
    present = sorted({classes[i] for i in finite})
    per_class = max(1, count // len(present))
    return [i for c in present for i in [j for j in ranked if classes[j] == c][:per_class]]


@pytest.mark.parametrize("log_lik, count, classes", [
    ([1.0, math.nan, 3.0, 2.0], 2, None),
    ([1.0, math.nan, 3.0, 2.0], 2, [0, 1, 0, 1]),
    ([1.0, math.nan, math.nan, 2.0], 4, [0, 1, 1, 0]),  # class 1 has no finite score: no share
    ([math.nan, -math.inf, 0.5, math.nan, -1.0, 2.0], 3, None),
    ([math.inf, 1.0, 2.0], 2, None),
    ([-math.inf, 1.0, -math.inf, 2.0], 4, [0, 0, 1, 1]),
    ([1.0, 9.0, 3.0, 8.0, 2.0, 7.0], 4, [0, 1, 2, 0, 1, 2]),
    ([1.0, 2.0, 3.0], 10, [0, 0, 0]),
    ([math.nan, -math.inf, math.nan], 2, None),  # nothing finite: one hypothesis, any
    ([math.nan, -math.inf, math.nan], 2, [0, 1, 1]),
])
def test_best_hypotheses_never_prefer_a_nan_score(log_lik, count, classes):
    """A NaN log-likelihood (a diverged shape) sorted first in a descending argsort and was kept as the
    best hypothesis, and a class's finite best was dropped for it ([1, NaN, 3, 2], count 2: [1, 2]
    for [2, 3]); a NaN ranks now with −inf, and so does +inf, which no likelihood is."""
    got = best_hypotheses(torch.tensor(log_lik, dtype=torch.float64), count,
                          None if classes is None else torch.tensor(classes)).tolist()
    expected = _brute_best(log_lik, count, classes)
    assert got == expected if expected is not None else len(got) == 1


def test_hypothesis_shares_give_the_first_particle_to_the_best_finite_hypothesis():
    """With fewer particles than hypotheses the best goes first: a NaN, sorted first, took it."""
    log_lik = torch.tensor([math.nan, 1.0, 3.0], dtype=torch.float64)
    best = torch.tensor([0, 1, 2])
    assert hypothesis_shares(best, log_lik, 2).tolist() == [2, 1]


@pytest.mark.parametrize("count", [0, -3, 2.5, True])
def test_best_hypotheses_refuse_a_count_that_is_not_a_whole_number_from_one(count):
    """count 0 returned no index and the particles' shares then divided by zero (ZeroDivisionError)."""
    with pytest.raises(ValueError, match="count"):
        best_hypotheses(torch.zeros(4, dtype=torch.float64), count)


def test_best_hypotheses_refuse_no_hypotheses():
    """No hypothesis at all returned no index, though at least one is promised."""
    with pytest.raises(ValueError, match="at least one hypothesis"):
        best_hypotheses(torch.zeros(0, dtype=torch.float64), 4)


def _blob_of(model, view: torch.Tensor) -> np.ndarray:
    """The model's silhouette of one view [θ, φ, α] as a target mask: (120, 160) bool, laid in a window of
    100 px centred at (80, 60)."""
    with torch.no_grad():
        shape = model(view[2:].float(), view[:1].float(), view[1:2].float())[0]
    return place_silhouette(shape, torch.tensor([80.0, 60.0]), torch.tensor([100.0, 100.0]), (120, 160)).numpy()


def test_blob_tracker_scores_are_plain_numbers(model):
    """BlobTracker.score built an autograd graph through the model's kernel widths (Tracker.score runs
    without one): its result required grad, so ``.numpy()`` raised and each call kept the graph. The
    scores are those the next step weighs the same particles by (no resampling; a blob drawn from the
    first one's shape, so that none underflows)."""
    tracker = BlobTracker(model, TrackerConfig(filter=FilterConfig(particles=5, resample_ess=0.0)), seed=0)
    views = torch.tensor([[1.5 + 0.1 * k, 0.1, float(model.alphas[3]) + 0.05 * k] for k in range(5)],
                         dtype=torch.float64)
    mask = _blob_of(model, views[0])
    scores = tracker.score(mask, views)
    assert not scores.requires_grad and np.isfinite(scores.numpy()).all()
    tracker.reset(views)
    assert tracker.step(mask=mask)["lost"] == 0
    torch.testing.assert_close(tracker.log_weights, torch.log_softmax(scores, dim=0).to(tracker.log_weights))


def test_a_search_at_the_ground_range_scores_its_hypotheses_on_the_whole_frame(model, monkeypatch):
    """``redetect.keep_range=false`` places the hypotheses at the ground's range, but the frame's distance
    was transformed over a margin of τ in the particles' largest window only. With the particles at
    1.5 x the BTR-70's range (a track drifted in range: what that search is for) the hypotheses' windows
    are 1.5 x larger, their cells beyond the margin read the region's edge, nearer than τ, and the best
    hypothesis scored −0.73 for the whole frame's −0.32 (−3.9 at 3 x): the search fired less the
    further the track had drifted. Its hypotheses now score as on the whole frame's distance."""
    seq = SyntheticSequence("btr_70", SceneConfig(frames=2))
    cfg = load_config(TrackerConfig, None, [
        "init.mode=truth", "filter.particles=100", "init.alpha_steps=12", "init.azimuth_steps=12",
        "redetect.every=1", "redetect.until=0", "redetect.after_truth=true", "redetect.keep_range=false",
        f"init.camera_height_m={seq.camera_height_m}"])
    tracker = Tracker(model, seq.camera, cfg, seed=0)
    calls = []

    def spy(blob, distance, *args, **kwargs):
        calls.append((blob, distance, args, kwargs, initialise.blind_hypotheses(blob, distance, *args, **kwargs)))
        return calls[-1][-1]

    monkeypatch.setattr(filter_module, "blind_hypotheses", spy)
    mask = seq.true_mask(1)
    tracker.initialise(seq.truth(0))
    particles = tracker.particles.clone()
    centre = camera_centre(seq.camera).to(particles)
    particles[:, X:Z + 1] = centre + 1.5 * (particles[:, X:Z + 1] - centre)
    tracker.reset(particles)
    tracker.step(mask=np.zeros_like(mask))
    tracker.step(mask=mask)  # the search: one frame after the start
    (blob, distance, args, kwargs, (_, got)), = calls
    bound = inspect.signature(initialise.blind_hypotheses).bind(blob, distance, *args, **kwargs)
    bound.arguments["distance"], bound.arguments["origin"] = frame_distance(mask, math.inf)
    _, expected = initialise.blind_hypotheses(*bound.args, **bound.kwargs)
    torch.testing.assert_close(got, expected)


def test_a_search_keeps_the_range_of_the_particles_ahead_of_the_camera(model, monkeypatch):
    """The search places its hypotheses at the particles' weighted mean depth and jitters them by their
    relative spread. Particles behind the camera (they have no window; after a reset and a frame
    without a blob they still had weight) pulled the mean towards 0 and blew the spread up: half the
    BTR-70's particles mirrored behind the camera gave a relative spread of 7000, and the run stopped
    on 'init.range_std must be in [0, 1e3]'. The range kept is now that of the particles ahead of the
    camera (their mean depth, by numpy), the spread within init.range_std's bound."""
    seq = SyntheticSequence("btr_70", SceneConfig(frames=2))
    still = ["motion.sigma2_" + k + "=0" for k in ("x", "y", "z", "heading", "speed", "alpha")]
    cfg = load_config(TrackerConfig, None, [
        "init.mode=truth", "filter.particles=100", "init.alpha_steps=12", "init.azimuth_steps=12",
        "redetect.every=1", "redetect.until=0", "redetect.margin=0", "redetect.after_truth=true",
        "redetect.restart=0", *still])
    tracker = Tracker(model, seq.camera, cfg, seed=0)
    depths = []

    def spy(*args, **kwargs):
        depths.append(inspect.signature(initialise.blind_hypotheses).bind(*args, **kwargs).arguments["known_depth"])
        return initialise.blind_hypotheses(*args, **kwargs)

    monkeypatch.setattr(filter_module, "blind_hypotheses", spy)
    tracker.initialise(seq.truth(0))
    particles = tracker.particles.clone()
    particles[:, X] += 40.0  # beside the blob: the hypotheses beat them
    particles[:, SPEED] = 0.0
    centre = camera_centre(seq.camera).to(particles)
    particles[1::2, X:Z + 1] = centre - 0.9999 * (particles[1::2, X:Z + 1] - centre)  # behind the camera
    tracker.reset(particles)
    tracker.step(mask=np.zeros_like(seq.true_mask(1)))  # no blob: the weights stay equal
    sensor = (tracker.particles[:, X:Z + 1].numpy() @ seq.camera.R.numpy().T + seq.camera.t.numpy())[:, 2]
    row = tracker.step(mask=seq.true_mask(1))  # the search
    assert depths == [pytest.approx(sensor[sensor > 0].mean(), rel=1e-6)]  # the model's float32
    assert row["lost"] == 0 and abs(row["x"] - seq.truth(1).x) < 5.0


def _flat_ground_depth(camera, u: float, v: float, height: float) -> float:
    """The closed form: the ray through pixel (u, v) (no distortion), d = Rᵀ ((u − cx)/fx, −(v − cy)/fy, 1)
    in the world, meets the plane y = c_y − height at s = −height / d_y, whose sensor depth is s."""
    R = camera.R.numpy()
    ray = R.T @ np.array([(u - camera.cx) / camera.fx, -(v - camera.cy) / camera.fy, 1.0])
    return -height / ray[1] if ray[1] < 0 else math.nan


@pytest.mark.parametrize("height", [0.0, -5.0, math.inf, math.nan, None, True])
def test_ground_depth_refuses_a_camera_not_above_the_ground(height):
    """At height 0 every ray met the ground at the camera (depth 0) and below the ground behind it
    (−25 m for −5 m): the blind start placed every hypothesis nowhere (all −inf) and drew every
    particle at the world's origin; None raised a bare TypeError. The flat-ground intersection of a
    tilted camera stays the closed form's."""
    camera = Camera(1000, 1000, 320, 256, 640, 512, R=_tilt(-3.0), t=[1.0, -2.0, 3.0])
    pixel = torch.tensor([320.0, 400.0], dtype=torch.float64)
    with pytest.raises(ValueError, match="camera_height_m"):
        ground_depth(camera, pixel, height)
    assert ground_depth(camera, pixel, 5.0) == pytest.approx(_flat_ground_depth(camera, 320.0, 400.0, 5.0), rel=1e-12)
    assert math.isnan(ground_depth(camera, torch.tensor([320.0, 10.0], dtype=torch.float64), 5.0))  # above the horizon


def test_a_blind_start_on_a_camera_at_ground_level_is_refused(model):
    """A height of 0 given by hand reached the blind start, which laid every hypothesis at depth 0 (all
    −inf) and drew every particle at the world's origin without a word."""
    seq = SyntheticSequence("btr_70", SceneConfig(frames=1))
    mask = seq.true_mask(0)
    distance, origin = frame_distance(mask, math.inf)
    appearance = ShapeAppearance(model, "I", 32)
    with pytest.raises(ValueError, match="camera_height_m"):
        initialise.blind_hypotheses(torch.from_numpy(mask), distance, seq.camera, appearance,
                                    InitConfig(alpha_steps=4, azimuth_steps=4), 0.1, 0.0, origin=origin)


@pytest.mark.parametrize("fy", [1000.0, 1100.0])
def test_hypotheses_without_a_height_lay_each_silhouette_on_the_blob_with_non_square_pixels(model, fy):
    """Without the camera's height each hypothesis takes the range z at which its silhouette box
    (sw x sh template pixels) has the blob's size. Its window spans fx W / z by fy W / z pixels, so
    the laid box is sw fx W / (z S) by sh fy W / (z S): by hand, its centre is the blob box's and its
    area the blob box's (both sides matched in the geometric mean). With fy ≠ fx the window was taken
    square (fx W / z both ways) when the range was found, and the laid box's area was fy / fx of the
    blob's (1.1 x at fy = 1.1 fx)."""
    camera = Camera(1000.0, fy, 320, 256, 640, 512, R=_tilt(-2.0), t=[0.5, -4.0, 1.0])
    mask = np.zeros((512, 640), dtype=bool)
    mask[300:309, 200:231] = True  # 31 x 9 px
    distance, origin = frame_distance(mask, math.inf)
    cfg = InitConfig(alpha_steps=3, azimuth_steps=4)
    states, _ = initialise.blind_hypotheses(torch.from_numpy(mask), distance, camera,
                                            ShapeAppearance(model, "I", 32), cfg, 0.1, origin=origin)
    uv, side = project_windows(camera, states[:, X:Z + 1], model.template.window_m)
    S = model.template.size_px
    theta = torch.arange(4, dtype=torch.float64) * (math.pi / 2)
    alpha = torch.arange(3, dtype=torch.float64) * (2 * math.pi / 3)
    ray = camera.R.numpy().T @ np.array([(215 - 320) / 1000.0, -(304 - 256) / fy, 1.0])  # the blob centre's
    phi = math.asin(-ray[1] / np.linalg.norm(ray))  # the camera's elevation seen from there
    with torch.no_grad():
        y = model(alpha.repeat_interleave(4).float(), theta.repeat(3).float(), torch.full((12,), phi))
    for k in range(12):
        rows, cols = np.nonzero(y[k].numpy() > 0)
        sw, sh = cols.max() - cols.min() + 1, rows.max() - rows.min() + 1
        laid = (sw * float(side[k, 0]) / S, sh * float(side[k, 1]) / S)
        offset = ((cols.min() + cols.max()) / 2 - (S - 1) / 2, (rows.min() + rows.max()) / 2 - (S - 1) / 2)
        centre = [float(uv[k, i]) + offset[i] * float(side[k, i]) / S for i in range(2)]
        assert laid[0] * laid[1] == pytest.approx(31 * 9, rel=1e-6), k
        assert centre == pytest.approx([215.0, 304.0], abs=1e-6), k


def test_blob_tracker_gives_an_empty_silhouette_no_weight(model, monkeypatch):
    """A silhouette with no pixel y > 0 has no box to lay on the blob. Its NaN box became a window of
    zeros compared with the template's value at its centre: a finite score (−193 here, above the −225
    of the view's real shape), so a model with an empty view could give it weight. It is now −inf, as
    the 3D filter's blind hypotheses give an empty silhouette; the others' scores are unchanged. (The
    shipped model has no empty view: at least 16 pixels in each of 360 α x 72 θ x 4 φ.)"""
    tracker = BlobTracker(model, TrackerConfig(filter=FilterConfig(particles=4)), seed=0)
    views = torch.tensor([[1.5 + 0.2 * k, 0.1, float(model.alphas[3]) + 0.3 * k] for k in range(4)],
                         dtype=torch.float64)
    mask = _blob_of(model, views[0])
    before = tracker.score(mask, views)
    forward = type(tracker.appearance).forward

    def emptied(self, alpha, theta, phi):
        y = forward(self, alpha, theta, phi)
        y[2] = -y[2].abs() - 0.01  # the third particle's view: no pixel inside
        return y

    monkeypatch.setattr(type(tracker.appearance), "forward", emptied)
    after = tracker.score(mask, views)
    assert after[2] == -math.inf
    torch.testing.assert_close(after[[0, 1, 3]], before[[0, 1, 3]])


# --- found correct: each against its own reference -------------------------------------------------


def _rotation(yaw_deg: float, tilt_deg: float) -> torch.Tensor:
    """A sensor-like rotation world -> sensor (det +1): a turn about y, then a tilt about x."""
    a = math.radians(yaw_deg)
    yaw = torch.tensor([[math.cos(a), 0.0, -math.sin(a)], [0.0, 1.0, 0.0], [math.sin(a), 0.0, math.cos(a)]],
                       dtype=torch.float64)
    return _tilt(tilt_deg) @ yaw


@pytest.mark.parametrize("dist", [None, [-0.2, 0.05, 0.001, -0.002, 0.0]])
@pytest.mark.parametrize("tilt", [-10.0, -2.0, 0.0, 5.0])
def test_ground_depth_is_the_flat_ground_intersection_of_a_tilted_camera(dist, tilt):
    """Against the closed form with the pixel undistorted by scipy's root finder on OpenCV's model
    (x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2 x²), likewise y): the ray meets the
    plane 12 m below the camera centre at depth −12 / d_y; NaN for a ray at or above the horizon."""
    from scipy.optimize import fsolve

    fx, fy, cx, cy = 1000.0, 1010.0, 320.0, 256.0
    R = _rotation(7.0, tilt)
    camera = Camera(fx, fy, cx, cy, 640, 512, dist=dist, R=R, t=[1.0, -2.0, 3.0])
    k1, k2, p1, p2, k3 = dist or [0.0] * 5
    for u, v in [(320.0, 256.0), (100.0, 500.0), (600.0, 300.0), (320.0, 10.0)]:
        def residual(q):
            x, y = q
            r2 = x * x + y * y
            radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
            return [fx * (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)) + cx - u,
                    fy * (y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y) + cy - v]

        x, y = fsolve(residual, [(u - cx) / fx, (v - cy) / fy], xtol=1e-14)
        ray = R.numpy().T @ np.array([x, -y, 1.0])
        expected = -12.0 / ray[1] if ray[1] < 0 else math.nan
        got = ground_depth(camera, torch.tensor([u, v], dtype=torch.float64), 12.0)
        assert got == pytest.approx(expected, rel=1e-9, nan_ok=True), (u, v)


def test_hypotheses_on_flat_ground_have_the_window_of_the_contact_range(model):
    """With the camera's height, every hypothesis lies at the depth z where the ray through the blob's
    lowest row meets the ground (the closed form), its window spans (fx, fy) W / z pixels, and the
    silhouette's box is centred on the blob's box (by hand from each view's silhouette)."""
    camera = Camera(1000.0, 1000.0, 320, 256, 640, 512, R=_rotation(4.0, -3.0), t=[0.5, -4.0, 1.0])
    mask = np.zeros((512, 640), dtype=bool)
    mask[300:309, 200:231] = True
    distance, origin = frame_distance(mask, math.inf)
    states, _ = initialise.blind_hypotheses(torch.from_numpy(mask), distance, camera,
                                            ShapeAppearance(model, "I", 32), InitConfig(alpha_steps=3, azimuth_steps=4),
                                            0.1, camera_height_m=6.0, origin=origin)
    z = _flat_ground_depth(camera, 215.0, 308.0, 6.0)  # the lowest row's centre (ground_row 0)
    uv, side = project_windows(camera, states[:, X:Z + 1], model.template.window_m)
    torch.testing.assert_close(side, torch.full_like(side, 1000.0 * model.template.window_m / z))
    ray = camera.R.numpy().T @ np.array([(215 - 320) / 1000.0, -(304 - 256) / 1000.0, 1.0])
    phi = math.asin(-ray[1] / np.linalg.norm(ray))
    theta = torch.arange(4, dtype=torch.float64) * (math.pi / 2)
    alpha = torch.arange(3, dtype=torch.float64) * (2 * math.pi / 3)
    with torch.no_grad():
        y = model(alpha.repeat_interleave(4).float(), theta.repeat(3).float(), torch.full((12,), phi))
    S = model.template.size_px
    for k in range(12):
        rows, cols = np.nonzero(y[k].numpy() > 0)
        offset = ((cols.min() + cols.max()) / 2 - (S - 1) / 2, (rows.min() + rows.max()) / 2 - (S - 1) / 2)
        centre = [float(uv[k, i]) + offset[i] * float(side[k, i]) / S for i in range(2)]
        assert centre == pytest.approx([215.0, 304.0], abs=1e-6), k


def _roll(degrees: float) -> torch.Tensor:
    """A rotation about the sensor's optical axis (z), det +1."""
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    return torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)


def test_a_rolled_cameras_hypotheses_lie_at_the_ground_range_below_the_blobs_bottom_centre(model):
    """With a roll about the optical axis the ground's depth changes along a row, so the contact's column
    matters: every hypothesis lies at the depth z where the ray through the blob's bottom-centre pixel
    (215, 308: the middle of columns 200-230, the lowest row's centre) meets the plane 6 m below the
    camera centre (the closed form, _flat_ground_depth), its window (fx, fy) W / z pixels."""
    R = _roll(8.0) @ _rotation(4.0, -3.0)
    camera = Camera(1000.0, 1050.0, 320, 256, 640, 512, R=R, t=[0.5, -4.0, 1.0])
    mask = np.zeros((512, 640), dtype=bool)
    mask[300:309, 200:231] = True
    distance, origin = frame_distance(mask, math.inf)
    states, log_lik = initialise.blind_hypotheses(torch.from_numpy(mask), distance, camera,
                                                  ShapeAppearance(model, "I", 32),
                                                  InitConfig(alpha_steps=3, azimuth_steps=4), 0.1,
                                                  camera_height_m=6.0, origin=origin)
    z = _flat_ground_depth(camera, 215.0, 308.0, 6.0)
    assert abs(_flat_ground_depth(camera, 200.0, 308.0, 6.0) / z - 1) > 0.01  # the column matters here
    _, side = project_windows(camera, states[:, X:Z + 1], model.template.window_m)
    want = torch.tensor([1000.0, 1050.0], dtype=torch.float64) * model.template.window_m / z
    torch.testing.assert_close(side, want.expand_as(side).contiguous(), rtol=1e-9, atol=0)
    assert log_lik.isfinite().all()


@pytest.mark.parametrize("known_depth", [-500.0, -1e-3, 0.0])
def test_hypotheses_at_a_known_depth_at_or_behind_the_camera_have_no_likelihood(model, known_depth):
    """A known depth <= 0 places every hypothesis at or behind the camera, where its window sees nothing
    (observation: "nothing at all (0)", and the tracker gives such particles no weight): every
    log-likelihood is −inf, not the finite score of a window of zeros against the template."""
    camera = Camera(1000.0, 1000.0, 320, 256, 640, 512, R=_rotation(4.0, -3.0), t=[0.5, -4.0, 1.0])
    mask = np.zeros((512, 640), dtype=bool)
    mask[300:309, 200:231] = True
    distance, origin = frame_distance(mask, math.inf)
    _, log_lik = initialise.blind_hypotheses(torch.from_numpy(mask), distance, camera, ShapeAppearance(model, "I", 32),
                                             InitConfig(alpha_steps=3, azimuth_steps=4), 0.1, origin=origin,
                                             known_depth=known_depth)
    assert log_lik.shape == (12,) and (log_lik == -math.inf).all()


def test_blind_particles_have_the_promised_spreads():
    """Around each of two hypotheses (equal shares): the range from the camera centre scaled by
    1 + range_std N(0, 1) along the line of sight, h and α by half a grid step (σ = π / steps) and
    wrapped to [0, 2π), the signed speed N(0, speed_std²): sample moments of 10⁵ draws each."""
    camera = Camera(1000, 1000, 320, 256, 640, 512, R=_rotation(20.0, -3.0), t=[1.0, -5.0, 3.0])
    centre = camera_centre(camera)
    states = torch.tensor([[10.0, -5.0, 100.0, 6.25, 0.0, 6.27], [-20.0, -4.0, 300.0, 0.01, 3.0, 0.02]],
                          dtype=torch.float64)
    cfg = InitConfig(hypotheses=2, range_std=0.02, speed_std_mps=2.0, alpha_steps=10, azimuth_steps=20)
    out = initialise.blind_particles(states, torch.tensor([0.0, -1.0], dtype=torch.float64), 200_000, cfg, camera,
                                     torch.Generator().manual_seed(1))
    assert ((out[:, [3, 5]] >= 0) & (out[:, [3, 5]] < 2 * math.pi)).all()
    for i in range(2):
        drawn = out[i::2]
        ray, sight = drawn[:, X:Z + 1] - centre, states[i, X:Z + 1] - centre
        scale = ray.norm(dim=1) / sight.norm()
        torch.testing.assert_close(ray / ray.norm(dim=1, keepdim=True), (sight / sight.norm()).expand_as(ray))
        for values, mean, std in ((scale, 1.0, 0.02), (drawn[:, 4], 0.0, 2.0),
                                  (torch.remainder(drawn[:, 3] - states[i, 3] + math.pi, 2 * math.pi) - math.pi,
                                   0.0, math.pi / 20),
                                  (torch.remainder(drawn[:, 5] - states[i, 5] + math.pi, 2 * math.pi) - math.pi,
                                   0.0, math.pi / 10)):
            assert float(values.mean()) == pytest.approx(mean, abs=4 * std / math.sqrt(1e5))
            assert float(values.std()) == pytest.approx(std, rel=0.01)


@pytest.mark.parametrize("noise", [0.05, 0.005])
def test_speeds_from_track_are_the_posterior_of_numpys_least_squares_slope(noise):
    """The slope and its standard error from numpy.polyfit (cov='unscaled' times the residual variance),
    the measurement floor 0.1 m/s, and the posterior mean (v₀/σ₀² + s u/σ_u²) / (1/σ₀² + s²/σ_u²) with
    s the heading's component along a camera x axis turned 0.3 rad (R ≠ I). The standard error is about
    0.13 m/s at noise 0.05 and 0.013 m/s at 0.005, where the floor holds instead."""
    rng = np.random.default_rng(0)
    t = np.arange(10) / 30.0
    y = 3.0 + 4.0 * t + rng.normal(0, noise, 10)
    axis = np.array([math.cos(0.3), 0.0, -math.sin(0.3)])
    h = np.array([0.5, 1.5, 3.0, 0.3 + math.pi / 2])
    v0 = np.array([0.0, 1.0, -2.0, 0.5])
    (slope, _), cov = np.polyfit(t, y, 1, cov="unscaled")
    residual = y - np.polyval(np.polyfit(t, y, 1), t)
    var_u = max(math.sqrt((residual ** 2).sum() / (len(t) - 2) * cov[0, 0]), 0.1) ** 2
    s = axis[0] * np.sin(h) + axis[2] * np.cos(h)
    expected = (v0 / 1.5 ** 2 + s * slope / var_u) / (1 / 1.5 ** 2 + s ** 2 / var_u)
    got = initialise.speeds_from_track(*(torch.tensor(a) for a in (t, y, axis, h, v0)), 1.5)
    np.testing.assert_allclose(got.numpy(), expected, rtol=1e-10)
    with pytest.raises(ValueError, match="at least 3"):
        initialise.speeds_from_track(*(torch.tensor(a) for a in (t[:2], y[:2], axis, h, v0)), 1.5)
    with pytest.raises(ValueError, match="finite"):
        initialise.speeds_from_track(*(torch.tensor(a) for a in (t, np.where(t > 0.1, np.nan, y), axis, h, v0)), 1.5)


@pytest.mark.parametrize("size", [1, 2, 7, 256])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_periodic_interpolation_matches_scipy(size, dtype):
    """Against scipy's interp1d over the table closed by its first value at 2π, at α wrapped by numpy."""
    from scipy.interpolate import interp1d

    rng = np.random.default_rng(size)
    table = rng.normal(size=size)
    alpha = np.concatenate([rng.uniform(-50, 50, 500), [0.0, 2 * np.pi, -2 * np.pi, 1e6, np.nextafter(2 * np.pi, 0)]])
    reference = interp1d(np.arange(size + 1) * 2 * np.pi / size, np.append(table, table[0]))(np.mod(alpha, 2 * np.pi))
    got = interpolate_periodic(torch.tensor(table, dtype=dtype), torch.tensor(alpha))
    np.testing.assert_allclose(got.numpy(), reference, atol=1e-12 if dtype == torch.float64 else 1e-6)


def test_bottom_edge_is_the_lowest_zero_crossing_by_brute_force():
    """Random signed images (exact zeros among them): the largest r + 0.5 + a_r / (a_r − a_{r+1}) over
    every column's inside-to-outside step, S when a bottom pixel is inside, NaN without a step."""
    rng = np.random.default_rng(1)
    for _ in range(200):
        S = int(rng.integers(2, 12))
        a = rng.normal(size=(S, S)) - rng.uniform(-1, 2)
        a[rng.random((S, S)) < 0.1] = 0.0
        steps = [r + 0.5 + a[r, c] / (a[r, c] - a[r + 1, c]) for c in range(S) for r in range(S - 1)
                 if a[r, c] > 0 >= a[r + 1, c]]
        expected = float(S) if (a[-1] > 0).any() else (max(steps) if steps else math.nan)
        assert bottom_edge_px(torch.tensor(a)[None]).item() == pytest.approx(expected, abs=1e-12, nan_ok=True)


def test_a_sequence_whose_camera_height_is_none_starts_blind_as_unknown(model):
    """Sequence.camera_height_m is NaN where unknown; a Sequence of one's own that says None stopped the blind start
    on math.isfinite(None), a TypeError. It is taken as unknown: the ranges come from the blob's size."""
    seq = SyntheticSequence("btr_70", SceneConfig(frames=3))
    seq.camera_height_m = None
    rows = Tracker(model, seq.camera, load_config(TrackerConfig, None, ["filter.particles=100"]), seed=0).run(
        seq, progress=False).rows
    assert len(rows) == 3 and all(math.isfinite(row["x"]) for row in rows)


def test_hypothesis_shares_refuse_log_likelihoods_that_are_not_one_per_hypothesis():
    """A (4, 1) log_lik gave a (2, 1) index for 2 particles, not (2,)."""
    log_lik = torch.tensor([0.0, -1.0, -2.0, -3.0], dtype=torch.float64)
    best = best_hypotheses(log_lik, 4)
    with pytest.raises(ValueError, match=r"Expected log_lik to have shape \(M\); got \(4, 1\)"):
        hypothesis_shares(best, log_lik[:, None], 2)
    with pytest.raises(ValueError, match=r"Expected best to have shape \(K\); got \(4, 1\)"):
        hypothesis_shares(best[:, None], log_lik, 2)
    with pytest.raises(ValueError, match=r"Expected classes to have shape \(4\); got \(3,\)"):
        hypothesis_shares(best, log_lik, 2, torch.zeros(3, dtype=torch.int64))


def test_ground_depth_refuses_a_pixel_that_is_not_one_u_v():
    camera = Camera(1000, 1000, 320, 256, 640, 512, R=_tilt(-3.0), t=[1.0, -2.0, 3.0])
    with pytest.raises(ValueError, match=r"Expected pixel to have shape \(2\); got \(1, 2\)"):
        ground_depth(camera, torch.tensor([[320.0, 400.0]], dtype=torch.float64), 5.0)
    with pytest.raises(ValueError, match=r"Expected pixel to have shape \(2\); got \(3,\)"):
        ground_depth(camera, torch.tensor([320.0, 400.0, 1.0], dtype=torch.float64), 5.0)


def test_blind_hypotheses_refuse_a_numpy_or_non_bool_blob_and_a_2d_alpha_index(model):
    """The filter hands the blob over as a tensor; a numpy blob raised a TypeError from torch.nonzero."""
    mask = np.zeros((64, 80), dtype=bool)
    mask[30:36, 20:40] = True
    distance, origin = frame_distance(mask, math.inf)
    camera = Camera(1000, 1000, 40, 32, 80, 64, R=_tilt(-3.0), t=[0.0, -5.0, 0.0])
    args = (distance, camera, ShapeAppearance(model, "I", 32), InitConfig(alpha_steps=3, azimuth_steps=4), 0.1)
    with pytest.raises(ValueError, match=r"Expected blob to be a tensor of shape \(H, W\); got ndarray"):
        initialise.blind_hypotheses(mask, *args, origin=origin)
    with pytest.raises(ValueError, match=r"Expected blob to be a bool tensor; got dtype torch.uint8"):
        initialise.blind_hypotheses(torch.from_numpy(mask).to(torch.uint8), *args, origin=origin)
    with pytest.raises(ValueError, match=r"Expected alpha_index to have shape \(A\); got \(1, 2\)"):
        initialise.blind_hypotheses(torch.from_numpy(mask), *args, origin=origin, alpha_index=torch.tensor([[0, 2]]))


def test_blind_particles_refuse_states_that_are_not_one_6_state_per_log_likelihood():
    """States of 5 columns raised an IndexError from the jitter; one log-likelihood fewer than states
    picked among the first rows only."""
    camera = Camera(1000, 1000, 320, 256, 640, 512, R=_tilt(-3.0), t=[1.0, -5.0, 3.0])
    states = torch.zeros(3, 6, dtype=torch.float64)
    log_lik = torch.tensor([0.0, -1.0, -2.0], dtype=torch.float64)
    with pytest.raises(ValueError, match=r"Expected states to have shape \(M, 6\); got \(3, 5\)"):
        initialise.blind_particles(states[:, :5], log_lik, 4, InitConfig(), camera)
    with pytest.raises(ValueError, match=r"Expected log_lik to have shape \(3\); got \(2,\)"):
        initialise.blind_particles(states, log_lik[:2], 4, InitConfig(), camera)
