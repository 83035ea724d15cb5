"""The observation model (METHOD.md "Tracking"; eq. 5.2): what each particle sees of the frame.

Per frame, the segmented foreground mask is turned once into its signed distance D in IMAGE
pixels (:func:`~torch_atr.shape.signed_distance_px`). Per particle j with centre pⱼ = (x, y, z):

1. the window: the camera projects pⱼ to (uⱼ, vⱼ) at depth zⱼ; a window of W metres (the
   template's ``window_m``) spans sᵤ = f_x W / zⱼ by s_v = f_y W / zⱼ image pixels around it;
2. the samples: D is sampled bilinearly (``grid_sample``) at the centres of an L × L grid over
   the window (L = the likelihood resolution; the trained templates are H × W = S × S, and L
   divides S), rows running down the image like template rows;
3. the units: an image distance is S zⱼ / (√(f_x f_y) W) template pixels, then clipped to τ and
   divided by τ exactly as the templates were (:func:`~torch_atr.shape.clip_distance`), giving
   zⱼ of shape (L, L) in [−1, 1];
4. the likelihood, eq. 5.2: log wⱼ = −mean((zⱼ − yⱼ)²) / (2σ²) against the predicted template yⱼ.

Outside the frame the distance of the nearest border pixel is used (``padding_mode="border"``).
Where the blob is clear of an edge by τ or more (in the window's image pixels) that is right: the
target is one connected blob, so beyond that edge lies background, whose distance clips like the
edge's. Nearer the edge it falls short: beyond the edge the distance keeps the edge pixel's value
(a blob 2 px from the edge reads its 3 px at cells 5 and 9 px from the blob), so such a frame's
windows take the background beyond that edge for nearer the vehicle than it is (τ is about 11 image
px at 1000 m, more nearer). Extending the per-frame distance past such an edge by its margin
mends it, and was measured and not kept (docs/tracking.md, "Edges"): on a T-72 leaving the image
it changed nothing beyond the runs' spread. Beyond an edge that cuts the
blob (:func:`cut_edges`) nothing is known, and the padding would carry the blob's edge pixels on
as if the vehicle went on; there the tracker compares only the cells it observes
(:func:`observed_cells`): eq. 5.2's sum runs over them, with its divisor L² kept, so the others
are marginalised out of its Gaussian (a mean over the observed cells alone favours windows that
observe more of the vehicle's interior: 0.2–0.4 m further inside on a T-72 leaving the image,
docs/tracking.md). A window wholly outside the
image sees nothing of the frame but the padding, and one behind the camera nothing at all (0);
the tracker gives their particles no weight (:func:`sees_image`), nor those that observe no cell.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from torch_atr._checks import check_shape
from torch_atr.camera import Camera
from torch_atr.config import TemplateConfig
from torch_atr.shape import signed_distance_px


def project_windows(camera: Camera, centres: torch.Tensor, window_m: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Image placement of the particles' windows.

    Args:
        camera: the scene's camera (world -> sensor, intrinsics; distortion moves the centre).
        centres: (N, 3) window centres in the camera's world frame, metres.
        window_m: W, the window's world size, metres.
    Returns:
        uv: (N, 2) pixel position of each window centre (NaN at or behind the camera, and
            beyond the radius where the lens distortion folds back: :meth:`Camera.project`);
        side: (N, 2) window size (sᵤ, s_v) in image pixels (NaN where uv is).
    """
    check_shape("centres", centres, ("N", 3))
    uv, depth = camera.project(centres)
    f = torch.stack([camera.K[0, 0], camera.K[1, 1]]).to(uv)
    side = torch.where(uv.isfinite(), window_m * f / depth.unsqueeze(-1), torch.full_like(uv, math.nan))
    return uv, side


def cell_offsets(size: int, like: torch.Tensor) -> torch.Tensor:
    """(L,) offsets of the L cell centres of a window from its centre, in window sides:
    (k + ½)/L − ½ for k = 0 … L − 1 (the sampling grid of :func:`sample_windows`); ``like``'s
    dtype and device."""
    return (torch.arange(int(size), dtype=like.dtype, device=like.device) + 0.5) / size - 0.5


def sees_image(uv: torch.Tensor, side: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """Whether each window sees part of an image of ``shape`` (H, W): it is finite (not behind the
    camera) and its box, ``side`` (N, 2) pixels around ``uv`` (N, 2), meets a pixel (pixel centres
    at 0 … W − 1, edges half a pixel beyond). Returns (N,) bool."""
    check_shape("uv", uv, ("N", 2))
    check_shape("side", side, (uv.shape[0], 2))
    far = uv.new_tensor([shape[1], shape[0]]) - 0.5
    return ((uv + side / 2 >= -0.5) & (uv - side / 2 <= far)).all(dim=1)


def cut_edges(mask: np.ndarray, margin: int = 1) -> tuple[bool, bool, bool, bool]:
    """The image edges (left, top, right, bottom) within ``margin`` pixels of which the blob
    ``mask`` (H, W) bool has a pixel: those that cut it (``margin`` 1: a pixel on the edge itself;
    0: none)."""
    if not (isinstance(mask, np.ndarray) and mask.ndim == 2):
        raise ValueError(f"Expected mask to be a (H, W) array; got {getattr(mask, 'shape', type(mask))}")
    if margin <= 0:
        return False, False, False, False
    return (bool(mask[:, :margin].any()), bool(mask[:margin].any()), bool(mask[:, -margin:].any()),
            bool(mask[-margin:].any()))


def observed_cells(uv: torch.Tensor, side: torch.Tensor, size: int, shape: tuple[int, int],
                   cut: tuple[bool, bool, bool, bool]) -> tuple[torch.Tensor, torch.Tensor]:
    """Which cells of each window's L × L sampling grid (:func:`sample_windows`) are observed: their
    centre lies on an image of ``shape`` (H, W) (pixel centres 0 … W − 1, its edges half a pixel
    beyond) or beyond an edge that does not cut the blob (module docstring).

    Args:
        uv: (N, 2) window centres and side: (N, 2) window sizes, pixels; size: L.
        cut: (left, top, right, bottom), the edges that cut the blob (:func:`cut_edges`).
    Returns:
        columns (N, L) and rows (N, L) bool: cell (i, j) of window n is observed when
        ``rows[n, i]`` and ``columns[n, j]`` are; a non-finite window (behind the camera) has none.
    """
    check_shape("uv", uv, ("N", 2))
    check_shape("side", side, (uv.shape[0], 2))
    centres = uv[:, None, :] + cell_offsets(size, uv)[None, :, None] * side[:, None, :]  # (N, L, 2): u, v of each cell
    low = uv.new_tensor([-0.5 if cut[0] else -math.inf, -0.5 if cut[1] else -math.inf])
    high = uv.new_tensor([shape[1] - 0.5 if cut[2] else math.inf, shape[0] - 0.5 if cut[3] else math.inf])
    observed = (centres >= low) & (centres <= high)  # NaN compares False
    return observed[..., 0], observed[..., 1]


def silhouette_boxes(silhouettes: torch.Tensor) -> torch.Tensor:
    """Bounding boxes of silhouettes: (M, S, S) bool -> (M, 4) [c0, r0, c1, r1] inclusive pixel
    bounds, NaN for an empty silhouette; float32 on their device."""
    check_shape("silhouettes", silhouettes, ("M", "S", "S"))
    idx = torch.arange(silhouettes.shape[-1], device=silhouettes.device, dtype=torch.float32)
    bounds = []
    for occupied in (silhouettes.any(dim=1), silhouettes.any(dim=2)):  # columns, rows: (M, S) each
        bounds.append((torch.where(occupied, idx, math.inf).amin(1), torch.where(occupied, idx, -math.inf).amax(1)))
    (c0, c1), (r0, r1) = bounds
    box = torch.stack([c0, r0, c1, r1], dim=1)
    return torch.where(box.isfinite(), box, math.nan)


def blob_windows(boxes: torch.Tensor, blob_box: torch.Tensor, size: int, side: torch.Tensor | None = None
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """Windows that lay each hypothesis's silhouette on a blob: its box onto the blob's box.

    Args:
        boxes: (M, 4) silhouette boxes [c0, r0, c1, r1] in pixels of an ``size`` × ``size``
            template (:func:`silhouette_boxes`).
        blob_box: (4,) the blob's box [u0, v0, u1, v1] in image pixels (inclusive).
        size: the template's side in pixels (the boxes' pixels).
        side: window sizes (width, height) in image pixels to use (e.g. from a known range), a
            tensor (1, 2), the same for every box, or (M, 2), one per box (a 1-D side is refused:
            with M = 2, (2,) reads as one size or as one per box); default: those that give each
            silhouette the blob's size (geometric mean of the width and height ratios, so the
            silhouette's aspect is kept).
    Returns:
        uv: (M, 2) window centres and side: (M, 2) window sizes, image pixels (NaN for an empty
        silhouette); the dtype and device of ``boxes``.
    """
    check_shape("boxes", boxes, ("M", 4))
    check_shape("blob_box", blob_box, (4,))
    blob_box = blob_box.to(boxes)
    size_t = boxes[:, 2:] - boxes[:, :2] + 1  # (M, 2) template pixels
    if side is None:
        ratio = ((blob_box[2:] - blob_box[:2] + 1) / size_t).prod(dim=1).sqrt()  # image px per template px
        side = (size * ratio)[:, None].expand(-1, 2)
    elif not (isinstance(side, torch.Tensor) and side.dim() == 2 and side.shape[0] in (1, boxes.shape[0])
              and side.shape[1] == 2):
        got = tuple(side.shape) if isinstance(side, torch.Tensor) else type(side).__name__
        raise ValueError(f"Expected side to have shape (1, 2) or ({boxes.shape[0]}, 2), one window size for every box "
                         f"or one per box; got {got}")
    side = side.to(boxes).expand(boxes.shape[0], 2)
    offset_t = (boxes[:, :2] + boxes[:, 2:]) / 2 - (size - 1) / 2  # silhouette box centre − window centre
    uv = (blob_box[:2] + blob_box[2:]) / 2 - offset_t * side / size
    return uv, side


def mask_box(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    """The box (u0, v0, u1, v1), first and last column and row, of the pixels set in ``mask`` (H, W)
    bool (another dtype: its non-zero pixels); None when none is (``cv2.boundingRect``, which reads
    a strided array as empty: made contiguous first)."""
    if not (isinstance(mask, np.ndarray) and mask.ndim == 2):
        raise ValueError(f"Expected mask to be a (H, W) array; got {getattr(mask, 'shape', type(mask))}")
    u0, v0, w, h = cv2.boundingRect(np.ascontiguousarray(mask, dtype=bool).view(np.uint8))
    return None if w == 0 else (u0, v0, u0 + w - 1, v0 + h - 1)


def frame_distance(mask: np.ndarray, margin: float) -> tuple[torch.Tensor, tuple[int, int]]:
    """The signed distance of a frame's target mask in image pixels, on the region that matters.

    Only the mask's bounding box grown by ``margin`` pixels is transformed: every distance a
    window clips at ``margin`` or less is exact there, and beyond it the border's value (at least
    ``margin`` from the target) stands in, as ``sample_windows`` pads. A full frame costs two
    640 × 512 distance transforms (~4 ms); a 1000 m target's region a tenth of that.

    Args:
        mask: (H, W) bool, non-empty.
        margin: pixels >= 0 (e.g. τ in image pixels of the largest window, plus a little; ``inf``:
            the whole frame).
    Returns:
        distance: (h, w) float32 tensor; origin: (u0, v0), the frame pixel of its (0, 0).
    """
    box = mask_box(mask)
    if box is None:
        raise ValueError("Expected a non-empty mask")
    if not margin >= 0:  # NaN too
        raise ValueError(f"Expected margin to be >= 0 pixels; got {margin!r}")
    pad = int(math.ceil(min(margin, max(mask.shape)))) + 1  # beyond the image's size: the whole frame
    r0, r1 = max(box[1] - pad, 0), min(box[3] + pad + 1, mask.shape[0])
    c0, c1 = max(box[0] - pad, 0), min(box[2] + pad + 1, mask.shape[1])
    return signed_distance_px(mask[r0:r1, c0:c1]), (c0, r0)


def sample_windows(distance: torch.Tensor, uv: torch.Tensor, side: torch.Tensor, size: int,
                   origin: tuple[int, int] = (0, 0)) -> torch.Tensor:
    """Bilinear samples of an image at the centres of an L × L grid over each window.

    Args:
        distance: (H, W) image (e.g. the frame's signed distance in pixels), or a region of one.
        uv: (N, 2) window centres in pixels (u right, v down; pixel (0, 0)'s centre at (0, 0)).
        side: (N, 2) window width and height in pixels.
        size: L.
        origin: (u0, v0) the frame pixel of ``distance[0, 0]`` when it is a region.
    Returns:
        (N, L, L), rows running down the image; beyond the image the border pixel's value, and
        0 for a window with a non-finite centre or size.
    """
    check_shape("distance", distance, ("H", "W"))
    check_shape("uv", uv, ("N", 2))
    check_shape("side", side, (uv.shape[0], 2))
    H, W = distance.shape
    N, L = uv.shape[0], int(size)
    valid = (uv.isfinite() & side.isfinite()).all(dim=1)
    all_valid = bool(valid.all())
    if not all_valid:
        uv, side = torch.where(valid[:, None], uv, 0.0), torch.where(valid[:, None], side, 0.0)
    # grid_sample's normalised coordinates (align_corners=False): −1 is the left edge of pixel 0, so
    # pixel u is (2u + 1) / W − 1; the L cell centres of a window of side s sit at u_c + s·((k + ½)/L − ½).
    # The extents divide as tensors: CUDA multiplies by the reciprocal of a Python number (a last bit).
    offsets, extents = cell_offsets(L, uv), uv.new_tensor([W, H])
    gx, gy = ((2 * ((uv[:, i] - origin[i])[:, None] + offsets * side[:, i, None]) + 1) / extents[i] - 1
              for i in range(2))  # (N, L) each: columns, rows
    columns = gx.to(distance.dtype)[:, None, :].expand(N, L, L)
    rows = gy.to(distance.dtype)[:, :, None].expand(N, L, L)
    if distance.device.type == "cpu":  # a complex tensor's real view: one pass writes both (stacking: twice as long)
        grid = torch.view_as_real(torch.complex(columns, rows))
    else:  # complex tensors are not on every device (MPS)
        grid = torch.stack((columns, rows), dim=-1)
    # One batch item per window, the image broadcast (not copied), so grid_sample runs in parallel.
    out = F.grid_sample(distance[None, None].expand(N, 1, H, W), grid, mode="bilinear", padding_mode="border",
                        align_corners=False)[:, 0].to(uv.dtype)
    return out if all_valid else torch.where(valid[:, None, None], out, 0.0)


def observe_windows(distance: torch.Tensor, uv: torch.Tensor, side: torch.Tensor, template: TemplateConfig,
                    size: int, origin: tuple[int, int] = (0, 0), image_px: torch.Tensor | None = None
                    ) -> torch.Tensor:
    """The frame's distance in template units inside given windows (module docstring, steps 2-3).

    Args:
        distance: (H, W) the frame's signed distance in image pixels, positive on the foreground,
            or a region of it whose (0, 0) is the frame pixel ``origin`` (:func:`frame_distance`).
        uv: (N, 2) window centres and side: (N, 2) window sizes, pixels.
        template: the model's template geometry (S = ``size_px``, τ = ``tau_px``).
        size: L, the likelihood resolution; S must be a multiple of L.
        image_px: (N,) image pixels per template pixel; default that of a whole template window,
            √(sᵤ s_v) / S (give it when the windows are parts of template windows).
    Returns:
        (N, L, L) in [−1, 1], the dtype and device of ``uv``.
    """
    if size < 1 or template.size_px % size:
        raise ValueError(f"Expected a likelihood size L dividing the template size {template.size_px}; got {size}")
    samples = sample_windows(distance.to(uv.device), uv, side, size, origin)  # image pixels
    if image_px is not None:  # an (N, 1) broadcast against the samples to (N, N, L, L)
        check_shape("image_px", image_px, (uv.shape[0],))
    if image_px is None:
        image_px = side.prod(dim=1).sqrt() / template.size_px
    per_tau = 1.0 / (image_px * template.tau_px)  # (N,) τ-units per image px
    per_tau = torch.where(per_tau.isfinite(), per_tau, 0.0)
    return (samples * per_tau[:, None, None]).clamp_(-1.0, 1.0)  # clip_distance in one pass


def observe(distance: torch.Tensor, camera: Camera, centres: torch.Tensor, template: TemplateConfig,
            size: int, origin: tuple[int, int] = (0, 0)) -> torch.Tensor:
    """What particles at ``centres`` (N, 3) world metres see: :func:`observe_windows` of their
    windows placed by the camera (:func:`project_windows`).

    distance: (H, W) the frame's signed distance in image pixels, positive on the foreground, or a
    region of it whose (0, 0) is the frame pixel ``origin`` (u0, v0) (:func:`frame_distance`);
    template: the model's template geometry; size: L. Returns (N, L, L) in [−1, 1].
    """
    uv, side = project_windows(camera, centres, template.window_m)
    return observe_windows(distance, uv, side, template, size, origin)


def place_silhouette(y: torch.Tensor, uv: torch.Tensor, side: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """A template's silhouette y > 0 placed in the image by its window (the inverse of sampling).

    Args:
        y: (S, S) signed-distance template (rows down, like the image).
        uv: (2,) window centre in pixels; side: (2,) window width and height in pixels.
        shape: (H, W) of the image.
    Returns:
        (H, W) bool on ``y``'s device: image pixels whose centre falls on y > 0 (bilinear in y);
        all False for a non-finite window.
    """
    check_shape("y", y, ("S", "S"))
    check_shape("uv", uv, (2,))
    check_shape("side", side, (2,))
    H, W = int(shape[0]), int(shape[1])
    out = torch.zeros(H, W, dtype=torch.bool, device=y.device)
    if not bool(uv.isfinite().all() and side.isfinite().all() and (side > 0).all()):
        return out
    u0, v0 = (uv - side / 2).floor().long().tolist()
    u1, v1 = (uv + side / 2).ceil().long().tolist()
    c0, c1, r0, r1 = max(u0, 0), min(u1 + 1, W), max(v0, 0), min(v1 + 1, H)
    if c0 >= c1 or r0 >= r1:
        return out
    # Image pixel centre u lies at template coordinate (u − u_c) / s · 2 in grid_sample's [−1, 1].
    gu = (torch.arange(c0, c1, dtype=y.dtype, device=y.device) - uv[0].to(y)) * (2.0 / side[0].to(y))
    gv = (torch.arange(r0, r1, dtype=y.dtype, device=y.device) - uv[1].to(y)) * (2.0 / side[1].to(y))
    grid = torch.stack(torch.broadcast_tensors(gu[None, :], gv[:, None]), dim=-1)[None]  # (1, h, w, 2)
    inside = F.grid_sample(y[None, None], grid, mode="bilinear", padding_mode="border", align_corners=False)
    out[r0:r1, c0:c1] = (inside[0, 0] > 0) & (grid[0].abs() <= 1).all(dim=-1)
    return out


def log_likelihood(z: torch.Tensor, y: torch.Tensor, sigma: float) -> torch.Tensor:
    """Eq. 5.2 in log space: log wⱼ = −mean((zⱼ − yⱼ)²) / (2σ²).

    z, y: (N, L, L) observed and predicted signed distances; sigma: σ > 0. Returns (N,).
    """
    check_shape("z", z, ("N", "L", "L"))
    check_shape("y", y, tuple(z.shape))
    if not sigma > 0:
        raise ValueError(f"Expected sigma > 0; got {sigma}")
    return -(z - y).square().mean(dim=(1, 2)) / (2.0 * sigma * sigma)
