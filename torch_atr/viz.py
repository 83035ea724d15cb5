"""Pictures for TensorBoard and reports: template grids and the identity circle.

Everything returns arrays or matplotlib figures; writing them is the caller's business
(``SummaryWriter.add_image`` / ``add_figure``, or ``save_png``).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from torch_atr._checks import check_shape
from torch_atr.io import atomic_path


def to_display(images: torch.Tensor) -> torch.Tensor:
    """Map templates to [0, 1] grey for display.

    images: (N, H, W) bool silhouettes (white inside) or float signed distances in [-1, 1]
    (mapped linearly, 0.5 at the boundary). Returns (N, H, W) float32 on the CPU.
    """
    if images.dim() != 3:
        raise ValueError(f"Expected images to have shape (N, H, W); got {tuple(images.shape)}")
    images = images.detach().cpu()
    if images.dtype == torch.bool:
        return images.float()
    return ((images.float().clamp(-1, 1) + 1) / 2)


def tile(images: torch.Tensor, ncol: int, pad: int = 1, pad_value: float = 0.3) -> torch.Tensor:
    """Tile (N, H, W) display images in [0, 1] into one (H', W') image, row-major, ``ncol`` per row."""
    if images.dim() != 3:
        raise ValueError(f"Expected images to have shape (N, H, W); got {tuple(images.shape)}")
    if ncol < 1:
        raise ValueError(f"Expected ncol >= 1; got {ncol}")
    n, h, w = images.shape
    nrow = max(1, math.ceil(n / ncol))
    out = torch.full((nrow * (h + pad) + pad, ncol * (w + pad) + pad), pad_value, dtype=images.dtype)
    for idx in range(n):
        r, c = divmod(idx, ncol)
        y, x = pad + r * (h + pad), pad + c * (w + pad)
        out[y:y + h, x:x + w] = images[idx]
    return out


def overlay_pairs(truth: torch.Tensor, recon: torch.Tensor) -> torch.Tensor:
    """Colour comparison of silhouettes, (N, H, W) bool each -> (N, 3, H, W) float in [0, 1].

    White: both; red: truth only (missed); cyan: reconstruction only (extra); black: neither.
    """
    if truth.shape != recon.shape or truth.dim() != 3:
        raise ValueError(f"Expected truth and recon of equal shape (N, H, W); got {tuple(truth.shape)} "
                         f"and {tuple(recon.shape)}")
    t, r = truth.detach().cpu().float(), recon.detach().cpu().float()
    return torch.stack([t, r, r], dim=1)


def identity_circle_figure(alphas: Sequence[float], vehicle_names: Sequence[str], vehicle_classes: Sequence[int],
                           class_names: Sequence[str], arcs: Sequence[tuple[int, float, float]]):
    """The identity manifold as a circle: class arcs as coloured bands, each vehicle at its αₖ.

    alphas: (K,) radians; vehicle_classes: (K,) indices into ``class_names``;
    arcs: (class index, start, end) radians, counter-clockwise from start to end.
    Returns a matplotlib Figure.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Wedge

    if not (len(alphas) == len(vehicle_names) == len(vehicle_classes)):
        raise ValueError(f"Expected alphas, names and classes of one length; got {len(alphas)}, "
                         f"{len(vehicle_names)}, {len(vehicle_classes)}")
    colours = plt.get_cmap("tab10")
    fig, ax = plt.subplots(figsize=(7.5, 7.5))
    for c, start, end in arcs:
        end = end if end > start else end + 2 * math.pi
        ax.add_patch(Wedge((0, 0), 1.08, math.degrees(start), math.degrees(end), width=0.16,
                           color=colours(c % 10), alpha=0.55))
    ax.add_patch(plt.Circle((0, 0), 1.0, fill=False, lw=1.0, color="0.3"))
    for c, name in enumerate(class_names):
        ax.plot([], [], lw=8, color=colours(c % 10), alpha=0.55, label=name)
    for a, name, c in zip(alphas, vehicle_names, vehicle_classes):
        x, y = math.cos(a), math.sin(a)
        ax.plot(x, y, "o", color=colours(int(c) % 10), ms=5)
        deg = math.degrees(a)
        rot = deg if -90 <= ((deg + 180) % 360 - 180) <= 90 else deg + 180
        ax.text(1.2 * x, 1.2 * y, name, rotation=rot, rotation_mode="anchor", fontsize=7,
                ha="left" if math.cos(a) >= 0 else "right", va="center")
    ax.set_xlim(-1.9, 1.9)
    ax.set_ylim(-1.9, 1.9)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.legend(loc="center", fontsize=8, frameon=False)
    ax.set_title("identity manifold: α ∈ [0, 2π), class arcs and training vehicles")
    fig.tight_layout()
    return fig


def save_png(image: np.ndarray | torch.Tensor, path: str | Path) -> None:
    """Write a (H, W) or (3, H, W) float image in [0, 1] as an 8-bit PNG, atomically."""
    import cv2

    arr = image.detach().cpu().numpy() if isinstance(image, torch.Tensor) else np.asarray(image)
    if arr.ndim == 3:
        arr = arr.transpose(1, 2, 0)[..., ::-1]  # RGB -> OpenCV's BGR
    arr = (np.clip(arr, 0, 1) * 255).round().astype(np.uint8)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(arr))
    if not ok:
        raise OSError(f"could not encode {path} as PNG")
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.tobytes())


@torch.no_grad()
def view_sweep(model, alpha: float, theta0: float, phi0: float, d_theta: float, d_phi: float,
               between: int = 3) -> torch.Tensor:
    """Silhouettes along the view manifold (Fig. 6.3) at identity ``alpha``.

    From (θ₀, φ₀) to (θ₀ + dθ, φ₀) (an azimuth step), then to (θ₀ + dθ, φ₀ + dφ) (an elevation
    step), with ``between`` interpolated views inside each step. Returns (2·between + 3, H, W) bool.
    """
    s = torch.linspace(0, 1, between + 2, dtype=torch.float64)
    theta = torch.cat([theta0 + s * d_theta, torch.full((between + 1,), theta0 + d_theta, dtype=torch.float64)])
    phi = torch.cat([torch.full((between + 2,), phi0, dtype=torch.float64), phi0 + s[1:] * d_phi])
    like = model.alphas
    a = torch.full_like(theta, alpha)
    return model.silhouette(a.to(like), theta.to(like), phi.to(like)).cpu()


@torch.no_grad()
def identity_sweep(model, alphas: Sequence[float], theta: float, phi: float, between: int = 3) -> torch.Tensor:
    """Silhouettes along the identity manifold (Fig. 6.4-6.5) at one view.

    alphas: anchor α values (e.g. three adjacent training vehicles' αₖ), visited in order going
    counter-clockwise (increasing α, wrapping at 2π), with ``between`` interpolated identities in
    each gap. Returns ((len(alphas) − 1)·(between + 1) + 1, H, W) bool.
    """
    if len(alphas) < 2:
        raise ValueError(f"Expected at least two anchor alphas; got {len(alphas)}")
    path = [float(alphas[0])]
    for a0, a1 in zip(alphas, alphas[1:]):
        gap = (a1 - a0) % (2 * math.pi)
        path += [a0 + gap * (i + 1) / (between + 1) for i in range(between + 1)]
    like = model.alphas
    a = torch.tensor(path, dtype=like.dtype, device=like.device)
    return model.silhouette(a, torch.full_like(a, theta), torch.full_like(a, phi)).cpu()


@torch.no_grad()
def model_figures(model, masks: torch.Tensor, theta: torch.Tensor, phi: torch.Tensor, step_theta: float,
                  step_phi: float) -> dict:
    """The pictures of a trained model (what ``train.py`` logs).

    masks: (K, V, H, W) bool training templates at theta, phi (V,) radians; step_theta, step_phi:
    the view grid's steps, radians. Returns name -> (C, H', W') image in [0, 1] or a Figure:
    ``reconstructions`` (10 views per vehicle, :func:`overlay_pairs` colours), ``view_sweeps``
    (Fig. 6.3, one vehicle per class), ``identity_sweeps_within_class`` (Fig. 6.4),
    ``identity_sweeps_between_classes`` (Fig. 6.5) and ``identity_manifold``.
    """
    check_shape("masks", masks, ("K", "V", None, None))
    V = masks.shape[1]
    like = model.alphas
    pick = torch.linspace(0, V - 1, 10).round().long()  # 10 views spread over the grid
    recon = torch.cat([model.reconstruct_grid(model.alphas[k:k + 1], theta[pick].to(like), phi[pick].to(like))[0]
                       for k in range(masks.shape[0])]).cpu() > 0
    pairs = overlay_pairs(masks[:, pick].reshape(recon.shape), recon)
    figures: dict = {"reconstructions": torch.stack([tile(pairs[:, c], ncol=len(pick)) for c in range(3)])}
    order = model.identity.order.tolist()
    classes = model.vehicle_classes
    view_rows, within_rows = [], []
    for c in range(len(model.class_names)):
        members = [k for k in order if classes[k] == c]
        if members:
            view_rows.append(view_sweep(model, model.alphas[members[0]].item(), math.radians(36), math.radians(10),
                                        step_theta, step_phi))
        if len(members) >= 3:
            within_rows.append(identity_sweep(model, [model.alphas[m].item() for m in members[:3]],
                                              math.radians(60), math.radians(10)))
    between = [identity_sweep(model, [model.alphas[a].item(), model.alphas[b].item()], math.radians(60),
                              math.radians(10), between=5)
               for a, b in zip([order[-1]] + order[:-1], order) if classes[a] != classes[b]]
    for name, rows in (("view_sweeps", view_rows), ("identity_sweeps_within_class", within_rows),
                       ("identity_sweeps_between_classes", between)):
        if rows:
            figures[name] = tile(to_display(torch.cat(rows)), ncol=len(rows[0])).unsqueeze(0)
    figures["identity_manifold"] = identity_circle_figure(model.alphas.tolist(), model.vehicle_names, classes,
                                                          model.class_names, model.identity.class_arcs())
    return figures


def save_figures(figures: dict, folder: str | Path) -> None:
    """Write each (C, H, W) image or matplotlib Figure of ``figures`` as ``folder/<name>.png``, atomically."""
    folder = Path(folder)
    for name, image in figures.items():
        if isinstance(image, torch.Tensor):
            save_png(image, folder / f"{name}.png")
        else:
            with atomic_path(folder / f"{name}.png") as tmp:
                image.savefig(tmp, format="png", dpi=110)

