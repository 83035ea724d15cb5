"""Binary silhouettes of a vehicle mesh: orthographic templates and perspective camera masks.

Views (METHOD.md, "Frames and angles"). The view Θ = (θ, φ) is the direction from the vehicle
to the camera in the body frame (+X forward, +Y left, +Z up), as the unit vector

    u(θ, φ) = (cos φ cos θ, cos φ sin θ, sin φ).

A template camera sits at direction u and looks along −u. Its image axes are

    right = (−sin θ, cos θ, 0)                        (always horizontal)
    up    = u × right = (−sin φ cos θ, −sin φ sin θ, cos φ)

so right × up = u (the image is seen from outside, never mirrored). At θ = 0, φ = 0 (camera
in front, looking back along −X) image-right is the vehicle's +Y (its left) and image-up is +Z;
at θ = π/2 (camera on the vehicle's left) image-right is −X, so the front is on the image left.
Both axes are smooth in (θ, φ) up to φ = π/2, where up = (−cos θ, −sin θ, 0) points away from
the camera's azimuth (the far side of the vehicle is at the top of the image).

Template pixels. A template is H × W (``TemplateConfig.size_px``) over a square of
``window_m`` metres, m = window_m / W metres per pixel, centred on the projection of the centre
of the mesh's axis-aligned 3D bounding box. Row 0 is the top. Pixel (i, j) covers the square
centred at ((j + 0.5 − W/2)·m, (H/2 − i − 0.5)·m) in (right, up) coordinates, and it is set
exactly when its CENTRE lies inside the projected silhouette (the union of the projected
triangles).

Rasterisation (:func:`fill_triangles`) is exact and counts, for every pixel centre, the
triangles that contain it (the non-zero rule per triangle), so overlapping triangles, open
meshes and arbitrary winding are all fine: no back-face culling, and no even-odd rule (that of
``cv2.fillPoly``, which cancels overlaps). A scanline crossing test does the counting: with o
the sign of a triangle's area in pixel coordinates, the signed crossings o·sign(dy) of its edges
with a point's row, to the right of the point, sum to 1 inside it and to 0 outside. So every
edge adds o·sign(dy) to the pixel centres left of where it crosses each row, and a difference
array and one cumulative sum along the rows give the counts. Edges shared by triangles are summed first:
between two triangles facing the same way they cancel, so only contour edges (and the borders of
open meshes) generate row crossings. Rows are half-open at the edge end points and columns are
taken strictly left of the crossing, so triangles sharing an edge never both claim, or both
miss, a pixel centre lying exactly on it. All views are processed together in a few
vectorised tensor operations: about 0.3 ms per 64 × 64 template of a 2,840-triangle mesh on
one core (``benchmarks/bench_render.py``).

Camera masks. :func:`render_mask` places the body frame in the camera's world frame with
:func:`~torch_atr.pose.body_to_world` (frames: :mod:`torch_atr.pose`) and projects the vertices
with :meth:`Camera.project` (lens distortion included; triangle edges stay straight between
projected vertices). Pixel (u, v) centres are integers, (0, 0) the top-left pixel.

Like every rendered silhouette and model output of the library, both return torch tensors;
frames and masks that come from OpenCV (sequences, segmentation) are NumPy arrays.
"""

from __future__ import annotations

import math
import numbers

import torch
import trimesh

from torch_atr._checks import as_float_tensor, check_finite, check_shape
from torch_atr.camera import Camera
from torch_atr.config import TemplateConfig
from torch_atr.pose import VehiclePose, body_to_world, check_sensor_like, view_vectors

# Triangle-views per vectorised batch in render_templates (peak memory ~0.1 GB).
_TRIANGLES_PER_BATCH = 1 << 19


def _view_angles(theta, phi) -> tuple[torch.Tensor, torch.Tensor]:
    """Convert and check theta, phi: (V,) each."""
    theta = as_float_tensor("theta", theta)
    phi = as_float_tensor("phi", phi, like=theta)
    check_shape("theta", theta, ("V",))
    if phi.shape != theta.shape:
        raise ValueError(f"Expected phi to have the shape of theta {tuple(theta.shape)}; got {tuple(phi.shape)}")
    return theta, phi.to(theta)


def view_directions(theta, phi) -> torch.Tensor:
    """Unit view vectors u(θ, φ) = (cos φ cos θ, cos φ sin θ, sin φ) in the body frame.

    Args:
        theta: (V,) azimuth, radians. phi: (V,) elevation, radians.
    Returns:
        (V, 3), dtype and device of ``theta``.
    """
    return view_vectors(*_view_angles(theta, phi))


def view_basis(theta, phi) -> tuple[torch.Tensor, torch.Tensor]:
    """Image axes of the orthographic template camera at view (θ, φ) (module docstring).

    Args:
        theta: (V,) azimuth, radians. phi: (V,) elevation, radians.
    Returns:
        right: (V, 3) = (−sin θ, cos θ, 0); up: (V, 3) = u × right = (−sin φ cos θ, −sin φ sin θ, cos φ).
    """
    theta, phi = _view_angles(theta, phi)
    ct, st, cp, sp = theta.cos(), theta.sin(), phi.cos(), phi.sin()
    right = torch.stack([-st, ct, torch.zeros_like(st)], dim=-1)
    up = torch.stack([-sp * ct, -sp * st, cp], dim=-1)
    return right, up


def _mesh_arrays(vehicle) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Vertices (M, 3) float64, faces (F, 3) long and the bounding-box centre (3,) of a
    Vehicle's or a Trimesh's mesh.

    Coincident vertices (equal to 1e-8 m, e.g. split at texture seams) are merged, so that
    triangles share their edges and the shared crossings cancel (module docstring).
    """
    mesh = getattr(vehicle, "mesh", vehicle)
    if not isinstance(mesh, trimesh.Trimesh):
        raise ValueError(f"Expected a Vehicle or a trimesh.Trimesh; got {type(vehicle).__name__}")
    if len(mesh.faces) == 0:
        raise ValueError(f"Mesh of {getattr(vehicle, 'name', 'vehicle')!r} has no faces")
    first, inverse = trimesh.grouping.unique_rows(mesh.vertices)
    verts = torch.tensor(mesh.vertices[first], dtype=torch.float64)
    faces = torch.tensor(inverse[mesh.faces], dtype=torch.long)
    return verts, faces, torch.tensor(mesh.bounds, dtype=torch.float64).mean(dim=0)


def _mesh_edges(faces: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Unique undirected edges of a triangle list.

    Args:
        faces: (F, 3) vertex indices.
    Returns:
        edges: (E, 2) vertex indices; slot_edge: (3F,) edge of each directed triangle side
        k -> k+1 (faces row-major); slot_sign: (3F,) +1 where that side runs edges[:, 0] -> edges[:, 1].
    """
    sides = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)  # (3F, 2)
    low, high = sides.min(dim=1).values, sides.max(dim=1).values
    n = int(high.max()) + 1 if len(sides) else 1
    keys, slot_edge = torch.unique(low * n + high, return_inverse=True)  # 1-D unique: fast
    edges = torch.stack([keys // n, keys % n], dim=1)
    slot_sign = torch.where(sides[:, 0] == low, 1.0, -1.0).to(torch.float64)
    return edges, slot_edge, slot_sign


def _orientation(xy: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Sign of the area of each 2D triangle: xy (B, M, 2), faces (F, 3) -> (B, F) float64 in {−1, 0, 1};
    0 for degenerate triangles and those with a non-finite corner."""
    tri = xy[:, faces].to(torch.float64)  # (B, F, 3, 2)
    a, b = tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0]
    sign = torch.sign(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])
    return torch.where(tri.isfinite().all(dim=-1).all(dim=-1), sign, torch.zeros_like(sign)).nan_to_num(0.0)


def _fill(xy: torch.Tensor, faces: torch.Tensor, orient: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """Pixel centres covered by triangles (module docstring, "Rasterisation").

    Args:
        xy: (B, M, 2) vertices in pixel coordinates (x = column, y = row); non-finite vertices
            must only belong to triangles of orientation 0.
        faces: (F, 3) vertex indices; orient: (B, F) sign of each triangle's area in (x, y).
    Returns:
        (B, H, W) bool.
    """
    B, H, W = xy.shape[0], height, width
    edges, slot_edge, slot_sign = _mesh_edges(faces)
    # Σ over the triangle sides on each edge of o·(+1 along edges[:, 0] -> edges[:, 1], else −1). These sums (and
    # bincount's below) are of small integers in float64, exact in any order, so CUDA's atomic adds stay deterministic.
    weight = torch.zeros(B, len(edges), dtype=torch.float64, device=xy.device)
    weight.index_add_(1, slot_edge, orient.repeat_interleave(3, dim=1) * slot_sign)
    xy = torch.where(xy.isfinite(), xy, torch.zeros_like(xy)).to(torch.float64)
    p0, p1 = xy[:, edges[:, 0]], xy[:, edges[:, 1]]  # (B, E, 2) each
    weight = (weight * torch.sign(p1[..., 1] - p0[..., 1])).reshape(-1)  # per upward crossing
    x0, y0 = p0[..., 0].reshape(-1), p0[..., 1].reshape(-1)
    x1, y1 = p1[..., 0].reshape(-1), p1[..., 1].reshape(-1)
    # Rows i with min(y0, y1) <= i < max(y0, y1), clipped to the image.
    row0 = torch.minimum(y0, y1).ceil().clamp(0, H).long()
    row1 = torch.maximum(y0, y1).ceil().clamp(0, H).long()
    live = ((row1 > row0) & (weight != 0)).nonzero().squeeze(1)
    n_rows = row1[live] - row0[live]
    first = torch.cumsum(n_rows, 0) - n_rows
    e = torch.repeat_interleave(live, n_rows)  # (R,) edge of each (edge, row) crossing
    row = row0[e] + torch.arange(e.numel(), device=xy.device) - torch.repeat_interleave(first, n_rows)
    x_cross = x0[e] + (row - y0[e]) * (x1[e] - x0[e]) / (y1[e] - y0[e])
    # Columns j < x_cross are left of the crossing, i.e. j < ceil(x_cross).
    col = x_cross.ceil().clamp(0, W).long()
    view = e // len(edges)
    # count(j) = Σ w·[j < col] = −Σ_{col <= j} w, since each triangle's w sum to 0 on a row.
    delta = torch.bincount((view * H + row) * (W + 1) + col, weights=weight[e], minlength=B * H * (W + 1))
    count = -delta.reshape(B, H, W + 1).cumsum(dim=-1)[..., :W]
    return count > 0


def fill_triangles(tri: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """Exact union-of-triangles rasterisation at pixel centres (module docstring).

    Args:
        tri: (B, F, 3, 2) triangle corners in pixel coordinates (x = column, y = row; the centre
            of pixel (i, j) is at x = j, y = i). Any winding; degenerate triangles cover nothing,
            triangles with a non-finite corner are skipped.
        height, width: image size H, W in pixels.
    Returns:
        (B, H, W) bool on ``tri``'s device: pixel centres inside at least one triangle.
    """
    check_shape("tri", tri, ("B", "F", 3, 2))
    if not all(isinstance(n, numbers.Real) and not isinstance(n, bool) and n > 0 and float(n).is_integer()
               for n in (height, width)):  # int() cut 4.6 rows to 4
        raise ValueError(f"Expected a positive whole image size; got height={height!r}, width={width!r}")
    B, F = tri.shape[:2]
    xy = tri.reshape(B, 3 * F, 2)
    faces = torch.arange(3 * F, device=tri.device).reshape(F, 3)
    return _fill(xy, faces, _orientation(xy, faces), int(height), int(width))


def render_templates(vehicle, theta, phi, cfg: TemplateConfig | None = None) -> torch.Tensor:
    """Orthographic silhouette templates of a vehicle (METHOD.md, "Templates").

    Args:
        vehicle: a Vehicle (its ``.mesh``) or a ``trimesh.Trimesh`` in the body frame.
        theta: (V,) azimuth, radians. phi: (V,) elevation, radians (tensors, arrays or lists).
        cfg: window size and resolution; ``TemplateConfig()`` if None.
    Returns:
        (V, H, W) bool on the CPU, H = W = ``cfg.size_px``; row 0 is the top of the image.
    """
    cfg = TemplateConfig() if cfg is None else cfg
    verts, faces, centre = _mesh_arrays(vehicle)
    theta, phi = _view_angles(theta, phi)
    theta, phi = theta.detach().cpu().double(), phi.detach().cpu().double()
    check_finite("theta", theta, "radians")
    check_finite("phi", phi, "radians")
    if phi.numel() and float(phi.abs().max()) > math.pi / 2 + 1e-6:  # beyond, drawn upside down (float32 π/2 is in)
        raise ValueError(f"Expected elevations phi in [-π/2, π/2] radians; got {float(phi.abs().max()):.3f} "
                         f"(the view (θ + π, π − φ) is the one meant)")
    right, up = view_basis(theta, phi)
    axes = torch.stack([right, up], dim=-1)  # (V, 3, 2)
    verts = verts - centre
    v0, v1, v2 = verts[faces].unbind(dim=1)
    normals = torch.linalg.cross(v1 - v0, v2 - v0)  # (F, 3), unnormalised
    directions = view_directions(theta, phi)  # (V, 3)
    size, m = cfg.size_px, cfg.metres_per_px
    step = max(1, _TRIANGLES_PER_BATCH // len(faces))
    out = []
    for start in range(0, len(theta), step):  # every (view, face) array a batch at a time: the memory cap
        q = verts @ axes[start:start + step]  # (b, M, 2) metres along (right, up)
        xy = torch.stack([q[..., 0] / m + size / 2 - 0.5, size / 2 - 0.5 - q[..., 1] / m], dim=-1)
        # Image (right, up) has right × up = u, so a triangle's area there has the sign of n·u; the
        # pixel grid's rows run down, which flips it.
        orient = -torch.sign(directions[start:start + step] @ normals.T)  # (b, F)
        out.append(_fill(xy, faces, orient, size, size))
    if not out:
        return torch.zeros(0, size, size, dtype=torch.bool)
    return torch.cat(out)


def render_mask(vehicle, camera: Camera, pose: VehiclePose) -> torch.Tensor:
    """Perspective silhouette of a vehicle seen by a pinhole camera.

    Pixel (v, u) is set when its centre lies inside a projected triangle. Triangles with a
    vertex at or behind the camera (depth <= 0), or beyond the radius where the lens distortion
    folds back (:meth:`Camera.project` gives it no pixel), are skipped.

    Args:
        vehicle: a Vehicle (its ``.mesh``) or a ``trimesh.Trimesh`` in the body frame.
        camera: intrinsics, distortion and world -> sensor pose (a sensor-like world frame).
        pose: one pose of the body-frame origin (scalar fields) in the camera's world frame.
    Returns:
        (camera.height, camera.width) bool tensor on the camera's device.
    """
    verts, faces, _ = _mesh_arrays(vehicle)
    check_sensor_like(camera)
    R, t = body_to_world(pose)
    if t.dim() != 1:
        raise ValueError(f"Expected one pose (scalar fields); got fields of shape {tuple(t.shape[:-1])}")
    verts = verts.to(camera.K)
    uv, _ = camera.project(verts @ R.to(verts).T + t.to(verts))  # (M, 2), NaN behind the camera
    uv = uv.unsqueeze(0)  # (1, M, 2)
    faces = faces.to(uv.device)
    return _fill(uv, faces, _orientation(uv, faces), camera.height, camera.width)[0]
