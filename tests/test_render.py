"""torch_atr.render against ray casting, brute-force point-in-triangle tests, OpenCV and closed forms."""

import math
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import torch
import trimesh

from torch_atr.camera import Camera
from torch_atr.config import TemplateConfig
from torch_atr.pose import VehiclePose, body_to_world, view_of_pose
from torch_atr.render import fill_triangles, render_mask, render_templates, view_basis, view_directions

TWO_PI = 2 * math.pi


def _box(extents, low) -> trimesh.Trimesh:
    """Axis-aligned box with its minimum corner at ``low``."""
    box = trimesh.creation.box(extents=extents)
    return box.apply_translation(np.asarray(low, dtype=float) + np.asarray(extents, dtype=float) / 2)


def _toy_car() -> trimesh.Trimesh:
    """Left-right symmetric car of overlapping boxes (body, cabin, four wheels)."""
    parts = [_box((4.0, 1.8, 0.9), (-2.0, -0.9, 0.35)), _box((2.0, 1.6, 0.7), (-1.3, -0.8, 1.1))]
    parts += [_box((0.7, 0.3, 0.7), (x - 0.35, y - 0.15, 0.0)) for x in (-1.3, 1.3) for y in (-0.85, 0.85)]
    return trimesh.util.concatenate(parts)


def _l_body() -> trimesh.Trimesh:
    """Asymmetric: the front half (+X) is 2.5 m tall, the rear 1.0 m."""
    return trimesh.util.concatenate([_box((2.0, 2.0, 2.5), (0.5, -1.0, 0.0)), _box((3.0, 2.0, 1.0), (-2.5, -1.0, 0.0))])


def _u_body() -> trimesh.Trimesh:
    """Concave U seen from above: two arms along X joined at the rear, overlapping at the corners."""
    arms = [_box((4.4, 0.8, 1.5), (-2.2, y, 0.0)) for y in (-2.0, 1.2)]
    return trimesh.util.concatenate(arms + [_box((0.9, 4.0, 1.2), (-2.2, -2.0, 0.0))])


def _arch() -> trimesh.Trimesh:
    """Concave arch seen from the front: two pillars and a top bar, open underneath."""
    pillars = [_box((1.0, 0.8, 2.5), (-0.5, y, 0.0)) for y in (-2.0, 1.2)]
    return trimesh.util.concatenate(pillars + [_box((1.0, 4.0, 0.6), (-0.5, -2.0, 2.4))])


def _flipped_faces(mesh: trimesh.Trimesh, seed: int) -> trimesh.Trimesh:
    """Same surface with a random half of the triangles wound the other way (no culling allowed)."""
    faces = mesh.faces.copy()
    flip = np.random.default_rng(seed).random(len(faces)) < 0.5
    faces[flip] = faces[flip][:, ::-1]
    return trimesh.Trimesh(mesh.vertices.copy(), faces, process=False)


def _soup(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Same surface as separate triangles: no vertex shared (as texture seams leave meshes)."""
    return trimesh.Trimesh(mesh.vertices[mesh.faces].reshape(-1, 3), np.arange(3 * len(mesh.faces)).reshape(-1, 3),
                           process=False)


def _raycast_template(mesh: trimesh.Trimesh, theta: float, phi: float, size: int, window: float) -> np.ndarray:
    """Independent reference: orthographic rays along −u through every pixel centre (rtree backend)."""
    u = np.array([math.cos(phi) * math.cos(theta), math.cos(phi) * math.sin(theta), math.sin(phi)])
    right = np.array([-math.sin(theta), math.cos(theta), 0.0])
    up = np.array([-math.sin(phi) * math.cos(theta), -math.sin(phi) * math.sin(theta), math.cos(phi)])
    m = window / size
    i, j = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
    a, b = (j + 0.5 - size / 2) * m, (size / 2 - i - 0.5) * m
    centre = mesh.bounds.mean(axis=0)
    origins = centre + a[..., None] * right + b[..., None] * up + 100.0 * u
    hits = mesh.ray.intersects_any(origins.reshape(-1, 3), np.tile(-u, (size * size, 1)))
    return hits.reshape(size, size)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


VIEWS = [(0.0, 0.0), (1e-3, 0.2), (TWO_PI - 1e-3, 0.3), (0.9, 0.6), (4.0, 0.9), (2.0, math.pi / 2 - 1e-3),
         (math.pi / 2, 0.0)]


@pytest.mark.parametrize("name, mesh", [("car", _toy_car()), ("car_flipped", _flipped_faces(_toy_car(), 0)),
                                        ("car_soup", _soup(_toy_car())), ("L", _l_body()), ("U", _u_body()),
                                        ("arch", _arch())])


def test_templates_match_ray_casting(name, mesh):
    cfg = TemplateConfig(size_px=48, window_m=9.0)
    theta, phi = zip(*VIEWS)
    got = render_templates(SimpleNamespace(name=name, cls="test", mesh=mesh), list(theta), list(phi), cfg)
    assert got.dtype == torch.bool and got.shape == (len(VIEWS), 48, 48) and got.device.type == "cpu"
    for k, (t, p) in enumerate(VIEWS):
        ref = _raycast_template(mesh, t, p, 48, 9.0)
        assert ref.sum() > 20, "the reference must see the vehicle"
        assert _iou(got[k].numpy(), ref) >= 0.98, f"{name} view {k} ({t:.3f}, {p:.3f})"


def test_concave_gap_is_empty():
    """U from above and the arch from the front: the gap pixels stay empty (48 px over 9 m)."""
    cfg = TemplateConfig(size_px=48, window_m=9.0)
    # Top view at θ = 0: image-right = +Y, image-up = −X; pixel (i, j) sees y = (j − 23.5)·m, x = (i − 23.5)·m.
    top = render_templates(_u_body(), [0.0], [math.pi / 2], cfg)[0]
    assert not top[24, 24] and top[14, 24] and top[24, 32]  # gap / rear base (x ≈ −1.78) / arm (y ≈ 1.59)
    # Front view: pixel (i, j) sees y = (j − 23.5)·m, z = 1.5 − (i − 23.5)·m.
    front = render_templates(_arch(), [0.0], [0.0], cfg)[0]
    assert not front[30, 24] and front[17, 24] and front[30, 15]  # under the bar / bar / pillar


def _mirror_ok(a: torch.Tensor, b: torch.Tensor) -> bool:
    return torch.equal(a, b.flip(-1)) and not torch.equal(a, a.flip(-1))


def test_left_right_symmetric_mesh_mirrors_at_minus_theta():
    theta = torch.tensor([0.3, 1.1, 2.0, 2.9, 4.4])
    phi = torch.tensor([0.0, 0.2, 0.5, 0.7, 1.2])
    a = render_templates(_toy_car(), theta, phi)
    b = render_templates(_toy_car(), TWO_PI - theta, phi)
    for k in range(len(theta)):
        assert _mirror_ok(a[k], b[k]), f"view {k}"


def test_front_back_symmetric_mesh_mirrors_at_pi():
    """Box with a bump on its left (+Y) side: symmetric front-back only."""
    mesh = trimesh.util.concatenate([_box((4.0, 2.0, 1.5), (-2.0, -1.0, 0.0)), _box((1.0, 0.7, 0.8), (-0.5, 1.0, 0.3))])
    for phi in (0.0, 0.45):
        front, rear = render_templates(mesh, [0.0, math.pi], [phi, phi])
        assert _mirror_ok(front, rear)
        cols = front.any(dim=0).nonzero().squeeze(1)
        low, high = front[:, cols[0]].sum(), front[:, cols[-1]].sum()
        assert high < low, "at θ = 0 the left (+Y) bump, lower than the box, is the image-right edge"


def test_box_covers_the_expected_pixel_rectangle():
    """4.1 x 2.3 x 1.7 m box, 64 px over 12 m (m = 0.1875): worked out by hand."""
    mesh = _box((4.1, 2.3, 1.7), (-2.05, -1.15, 0.0))
    front, side = render_templates(mesh, [0.0, math.pi / 2], [0.0, 0.0], TemplateConfig(64, 12.0, 6.0))
    # Front: |a| < 1.15 m = 6.13 px -> j + 0.5 in (25.87, 38.13) -> j = 26..37; |b| < 0.85 m = 4.53 px
    # -> i = 27..36. Side: |a| < 2.05 m = 10.93 px -> j = 21..42.
    want = torch.zeros(64, 64, dtype=torch.bool)
    want[27:37, 26:38] = True
    assert torch.equal(front, want)
    want = torch.zeros(64, 64, dtype=torch.bool)
    want[27:37, 21:43] = True
    assert torch.equal(side, want)


def test_front_lands_on_the_image_left_when_seen_from_the_left():
    """At θ = π/2 the camera is at +Y looking along −Y, image-right = −X: the tall front is on the left."""
    left, right, front = render_templates(_l_body(), [math.pi / 2, 3 * math.pi / 2, 0.0], [0.0, 0.0, 0.0])
    tall_rows = slice(0, 32)  # above the bbox centre (z > 1.25 m): only the 2.5 m tall front reaches there
    assert left[tall_rows, :32].any() and not left[tall_rows, 32:].any()
    assert right[tall_rows, 32:].any() and not right[tall_rows, :32].any()
    assert front[tall_rows].sum() > 0 and torch.equal(front, front.flip(-1))


def test_view_basis_closed_forms_and_frame():
    theta = torch.tensor([0.0, math.pi / 2, 0.4, 2.5, 5.9], dtype=torch.float64)
    phi = torch.tensor([0.0, 0.0, 0.3, 1.0, math.pi / 2], dtype=torch.float64)
    u = view_directions(theta, phi)
    right, up = view_basis(theta, phi)
    torch.testing.assert_close(right[0], torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
    torch.testing.assert_close(up[0], torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    torch.testing.assert_close(right[1], torch.tensor([-1.0, 0.0, 0.0], dtype=torch.float64), atol=1e-15, rtol=0)
    torch.testing.assert_close(u[1], torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64), atol=1e-15, rtol=0)
    for vec in (u, right, up):
        torch.testing.assert_close(vec.norm(dim=-1), torch.ones(5, dtype=torch.float64))
    torch.testing.assert_close((right * u).sum(-1), torch.zeros(5, dtype=torch.float64), atol=1e-15, rtol=0)
    torch.testing.assert_close((up * u).sum(-1), torch.zeros(5, dtype=torch.float64), atol=1e-15, rtol=0)
    torch.testing.assert_close(torch.linalg.cross(right, up), u)  # seen from outside, not mirrored
    assert (right[:, 2] == 0).all()
    # Continuous up to the pole.
    r_near, up_near = view_basis(theta[4:], phi[4:] - 1e-7)
    torch.testing.assert_close(up_near, up[4:], atol=1e-6, rtol=0)
    torch.testing.assert_close(r_near, right[4:], atol=1e-6, rtol=0)
    assert view_directions([0.1], [0.2]).dtype == torch.float32


def _fill_reference(tri: np.ndarray, height: int, width: int) -> np.ndarray:
    """Brute force: pixel centre (i, j) at (x = j, y = i) inside any non-degenerate, finite triangle."""
    y, x = np.mgrid[0:height, 0:width].astype(float)
    out = np.zeros((height, width), dtype=bool)
    for a, b, c in tri:
        if not np.isfinite([a, b, c]).all():
            continue
        e = [(q[0] - p[0]) * (y - p[1]) - (q[1] - p[1]) * (x - p[0]) for p, q in ((a, b), (b, c), (c, a))]
        area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        if area != 0:
            out |= ((e[0] >= 0) & (e[1] >= 0) & (e[2] >= 0)) | ((e[0] <= 0) & (e[1] <= 0) & (e[2] <= 0))
    return out


def test_fill_triangles_matches_brute_force():
    gen = torch.Generator().manual_seed(0)
    tri = torch.rand(3, 40, 3, 2, generator=gen, dtype=torch.float64) * torch.tensor([40.0, 30.0]) - 5.0
    tri[0, 1] = tri[0, 0]  # an exact duplicate: even-odd filling would cancel it
    tri[1, 0] = torch.tensor([[1.0, 1.0], [5.0, 5.0], [9.0, 9.0]])  # degenerate
    tri[1, 1, 2, 0] = float("nan")  # skipped
    got = fill_triangles(tri, 25, 30)
    assert got.shape == (3, 25, 30) and got.dtype == torch.bool
    for k in range(3):
        assert torch.equal(got[k], torch.from_numpy(_fill_reference(tri[k].numpy(), 25, 30))), f"batch {k}"
    one = fill_triangles(tri[0, :2].unsqueeze(0), 25, 30)[0]
    assert torch.equal(one, torch.from_numpy(_fill_reference(tri[0, :1].numpy(), 25, 30))) and one.any()


def test_fill_triangles_skips_infinite_corners():
    """±inf corners are skipped like NaN ones (brute-force reference): a −inf corner gave its triangle an
    orientation that a corner zeroed for the scan would otherwise fill."""
    tri = torch.tensor([[[[2.3, 2.2], [6.7, 2.4], [2.1, 6.6]],
                         [[10.3, 10.2], [-math.inf, 10.4], [10.6, 20.3]],
                         [[10.2, 10.4], [20.3, math.inf], [20.6, 10.1]]]], dtype=torch.float64)
    got = fill_triangles(tri, 25, 30)[0]
    assert torch.equal(got, torch.from_numpy(_fill_reference(tri[0].numpy(), 25, 30)))
    assert torch.equal(got, torch.from_numpy(_fill_reference(tri[0, :1].numpy(), 25, 30))) and got.any()


def test_templates_in_several_batches_equal_one_batch(monkeypatch):
    """Views split over batches (a small _TRIANGLES_PER_BATCH) give the templates of one view at a time,
    each a single batch: the batch loop takes each view's own axes and orientations."""
    import torch_atr.render as render

    cfg = TemplateConfig(size_px=32, window_m=9.0)
    mesh = _toy_car()
    theta, phi = [0.0, 0.7, 1.9, 3.0, 4.4], [0.0, 0.3, 0.6, 0.1, 1.2]
    single = torch.cat([render_templates(mesh, [t], [p], cfg) for t, p in zip(theta, phi)])
    monkeypatch.setattr(render, "_TRIANGLES_PER_BATCH", 2 * len(mesh.faces))  # 2 views a batch: 3 batches
    assert torch.equal(render_templates(mesh, theta, phi, cfg), single)
    assert len({tuple(m.flatten().tolist()) for m in single}) == 5  # the views differ


def _bounding_rows_cols(mask: np.ndarray) -> tuple[int, int, int, int]:
    rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    return rows[0], rows[-1], cols[0], cols[-1]


def test_render_mask_box_rectangle_centroid_and_range_scaling():
    cam = Camera(800.0, 780.0, 320.3, 240.7, 640, 480)
    Lx, Ly, Lz = 4.2, 2.2, 1.6
    box = _box((Lx, Ly, Lz), (-Lx / 2, -Ly / 2, 0.0))
    # Driving away, centred on the optical axis: the rear face (depth z − Lx/2) bounds the silhouette.
    z = 30.0
    mask = render_mask(box, cam, VehiclePose(0.0, -Lz / 2, z, 0.0))
    assert mask.shape == (480, 640) and mask.dtype == torch.bool
    mask = mask.numpy()
    half_u, half_v = 800.0 * (Ly / 2) / (z - Lx / 2), 780.0 * (Lz / 2) / (z - Lx / 2)
    v, u = np.mgrid[0:480, 0:640]
    want = (np.abs(u - 320.3) < half_u) & (np.abs(v - 240.7) < half_v)
    np.testing.assert_array_equal(mask, want)
    # Centroid at the projection of the box centre, off axis and turned (far enough that the
    # perspective shift of the centroid towards the near end stays well below a pixel).
    pose = VehiclePose(6.0, -2.5, 90.0, 0.7)
    mask = render_mask(box, cam, pose).numpy()
    centre, _ = cam.project(torch.tensor([6.0, -2.5 + Lz / 2, 90.0], dtype=torch.float64))
    v_m, u_m = np.nonzero(mask)
    assert abs(u_m.mean() - centre[0].item()) < 1.0 and abs(v_m.mean() - centre[1].item()) < 1.0
    # Seen from the side (heading π/2), the near side face at depth z − Ly/2 sets the size: ∝ 1/z.
    for z in (20.0, 40.0, 80.0):
        r0, r1, c0, c1 = _bounding_rows_cols(render_mask(box, cam, VehiclePose(0.0, -Lz / 2, z, math.pi / 2)).numpy())
        assert abs((c1 - c0 + 1) - 800.0 * Lx / (z - Ly / 2)) <= 1.0
        assert abs((r1 - r0 + 1) - 780.0 * Lz / (z - Ly / 2)) <= 1.0


def test_render_mask_matches_cv2_project_points_with_distortion():
    a, pan = 0.12, -0.05  # camera 5 m up, pitched down by a and panned; with lens distortion
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(a), math.sin(a)], [0.0, -math.sin(a), math.cos(a)]])
    turn = np.array([[math.cos(pan), 0.0, -math.sin(pan)], [0.0, 1.0, 0.0], [math.sin(pan), 0.0, math.cos(pan)]])
    R = tilt @ turn
    centre = np.array([0.5, 5.0, 0.0])
    cam = Camera(900.0, 900.0, 330.0, 250.0, 640, 512, dist=[-0.25, 0.1, 0.001, -0.002, 0.0], R=R, t=-R @ centre)
    mesh = _l_body()
    x, y, z, h = -1.5, 0.0, 30.0, 2.2
    mask = render_mask(mesh, cam, VehiclePose(x, y, z, h)).numpy()
    # Body -> world written out: forward (sin h, 0, cos h), left (−cos h, 0, sin h), up (0, 1, 0).
    fwd, left, up = np.array([math.sin(h), 0, math.cos(h)]), np.array([-math.cos(h), 0, math.sin(h)]), np.eye(3)[1]
    world = mesh.vertices @ np.stack([fwd, left, up]) + np.array([x, y, z])
    rvec, tvec = cam.opencv_pose()  # for OpenCV's right-handed world: y negated
    uv, _ = cv2.projectPoints(world * [1.0, -1.0, 1.0], rvec, tvec, cam.K.numpy(), cam.dist.numpy())
    want = _fill_reference(uv.reshape(-1, 2)[mesh.faces], 512, 640)
    assert want.sum() > 2000
    np.testing.assert_array_equal(mask, want)


def test_render_mask_skips_triangles_behind_the_camera():
    cam = Camera(500.0, 500.0, 320.0, 240.0, 640, 480)
    box = _box((4.0, 2.0, 1.5), (-2.0, -1.0, 0.0))
    assert not render_mask(box, cam, VehiclePose(0.0, -0.75, -10.0, 0.0)).any()
    # Straddling the camera (z from −1 to 3 m): only the two triangles of the front face at
    # z = 3 m have all corners in front, so the mask is that face: |x| < 1, −0.7 < y < 0.8 at 3 m.
    straddling = render_mask(box, cam, VehiclePose(0.0, -0.7, 1.0, 0.0)).numpy()
    v, u = np.mgrid[0:480, 0:640]
    want = (np.abs(u - 320.0) < 500 / 3) & (v > 240.0 - 500 * 0.8 / 3) & (v < 240.0 + 500 * 0.7 / 3)
    np.testing.assert_array_equal(straddling, want)


def test_render_mask_draws_no_ghost_of_a_vehicle_beyond_the_distortion_fold():
    """A box 63° right of the axis, outside this barrel lens's ~60° field of view: ray casting
    through the pixels (cv2.undistortPoints) meets nothing; OpenCV's folding polynomial put 36,541
    pixels of it inside the image."""
    cam = Camera(500.0, 500.0, 319.5, 239.5, 640, 480, dist=[-0.35, 0.15, 0.0, 0.0, -0.03])
    box = _box((4.0, 2.0, 1.5), (-2.0, -1.0, 0.0))
    v, u = np.mgrid[0:480:4, 0:640:4]  # every 4th pixel: the ghost spanned hundreds
    pixels = np.stack([u, v], axis=-1).reshape(-1, 1, 2).astype(np.float64)
    rays = cv2.undistortPoints(pixels, cam.K.numpy(), cam.dist.numpy()).reshape(-1, 2) * [1.0, -1.0]  # y up
    R, t = (a.numpy() for a in body_to_world(VehiclePose(20.0, -0.75, 10.0, 0.0)))
    origins = np.tile(-np.linalg.inv(R) @ t, (len(rays), 1))  # the camera centre in the body frame
    directions = np.column_stack([rays, np.ones(len(rays))]) @ np.linalg.inv(R).T
    assert not box.ray.intersects_any(origins, directions).any()
    assert not render_mask(box, cam, VehiclePose(20.0, -0.75, 10.0, 0.0)).any()


def test_far_camera_mask_matches_the_template_at_view_of_pose():
    """Conventions agree end to end: a distant camera aimed at the bbox centre sees the template
    of the view that view_of_pose reports (not mirrored, not flipped)."""
    cfg = TemplateConfig(64, 12.0, 6.0)
    mesh = _l_body()
    dist_m, a, h = 600.0, 0.25, 2.6  # range to the bbox centre, elevation of the line of sight, heading
    R_bw, _ = body_to_world(VehiclePose(0.0, 0.0, 0.0, h))
    centre_w = R_bw.numpy() @ mesh.bounds.mean(axis=0)
    pos = np.array([0.0, -dist_m * math.sin(a), dist_m * math.cos(a)]) - centre_w
    R = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(a), math.sin(a)], [0.0, -math.sin(a), math.cos(a)]])
    f = dist_m / cfg.metres_per_px  # one camera pixel = one template pixel at the target
    cam = Camera(f, f, 31.5, 31.5, 64, 64, R=R)
    pose = VehiclePose(*pos.tolist(), h)
    mask = render_mask(mesh, cam, pose).numpy()
    theta, phi = view_of_pose(pose, cam)
    assert phi.item() == pytest.approx(a, abs=0.01)
    template = render_templates(mesh, theta.reshape(1), phi.reshape(1), cfg)[0].numpy()
    assert template.sum() > 100 and not np.array_equal(template, template[:, ::-1])
    assert _iou(mask, template) >= 0.95


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match=r"phi to have the shape of theta \(3,\); got \(2,\)"):
        render_templates(_toy_car(), [0.0, 1.0, 2.0], [0.0, 0.1])
    with pytest.raises(ValueError, match=r"theta to have shape \(V\); got \(2, 2\)"):
        view_directions(torch.zeros(2, 2), torch.zeros(2, 2))
    # a NaN rendered an empty template
    with pytest.raises(ValueError, match=r"theta to be finite radians; 1 value\(s\) are NaN or infinite"):
        render_templates(_toy_car(), [0.0, math.nan], [0.0, 0.1])
    # Beyond π/2 the same view was drawn upside down: θ = 0.7, φ = π − 0.3 is θ + π, φ = 0.3 turned over.
    with pytest.raises(ValueError, match=r"elevations phi in \[-π/2, π/2\] radians; got 2\.842"):
        render_templates(_toy_car(), [0.7], [math.pi - 0.3])
    for bad in ([True], ["0.7"], [1, True], [[0.5], [False]]):  # a bool was 1 rad, a string was parsed
        with pytest.raises(ValueError, match="Expected theta to be numeric"):
            render_templates(_toy_car(), bad, [0.1])
    with pytest.raises(ValueError, match="size_px"):
        TemplateConfig(size_px=0)
    with pytest.raises(ValueError, match="window_m"):
        TemplateConfig(window_m=-1.0)
    with pytest.raises(ValueError, match=r"positive whole image size; got height=0"):
        fill_triangles(torch.zeros(1, 1, 3, 2), 0, 5)
    # A fractional or non-numeric size was cut by int() (4.6 rows filled as 4) or failed inside it.
    for height, width in ((4.6, 5), (4, "5"), (float("nan"), 5), (True, 5)):
        with pytest.raises(ValueError, match=r"positive whole image size; got height=.*, width="):
            fill_triangles(torch.zeros(1, 1, 3, 2), height, width)
    assert fill_triangles(torch.zeros(1, 1, 3, 2), 4.0, np.int64(5)).shape == (1, 4, 5)
    with pytest.raises(ValueError, match=r"tri to have shape \(B, F, 3, 2\); got \(4, 3, 2\)"):
        fill_triangles(torch.zeros(4, 3, 2), 5, 5)
    with pytest.raises(ValueError, match="trimesh.Trimesh; got str"):
        render_templates("tank", [0.0], [0.0])
    cam = Camera(500.0, 500.0, 320.0, 240.0, 640, 480)
    with pytest.raises(ValueError, match=r"one pose .*\(2,\)"):
        render_mask(_toy_car(), cam, VehiclePose(torch.zeros(2), 0.0, 10.0, 0.0))
    floor = Camera.from_opencv(cam.K.numpy(), np.zeros(5), np.zeros(3), np.array([0.0, 0.0, 5.0]), 640, 480)
    with pytest.raises(ValueError, match="sensor-like"):
        render_mask(_toy_car(), floor, VehiclePose(0.0, 0.0, 10.0, 0.0))


@pytest.mark.parametrize("name", ["t_72", "ford_f150"])


def test_catalog_vehicles_match_ray_casting(name):
    from torch_atr.vehicles import load_catalog

    vehicle = next(v for v in load_catalog("test") if v.name == name)
    cfg = TemplateConfig(size_px=48, window_m=12.0)
    theta, phi = zip(*VIEWS[:5])
    got = render_templates(vehicle, list(theta), list(phi), cfg)
    for k, (t, p) in enumerate(VIEWS[:5]):
        assert _iou(got[k].numpy(), _raycast_template(vehicle.mesh, t, p, 48, 12.0)) >= 0.98, f"{name} view {k}"
