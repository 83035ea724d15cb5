"""Figures for people, TensorBoard and reports: the trained model's reconstructions and sweeps,
the identity circle, and a tracking run's identity, errors, views and frames.

Every figure is a matplotlib Figure with a title, labelled axes with units or labelled rows and
columns, and a legend or colour key, so it reads without this docstring. Writing them is the
caller's business (:func:`save_figures`, or ``SummaryWriter.add_figure``).
"""

from __future__ import annotations

import contextlib
import math
import shutil
import tempfile
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from torch_atr._checks import check_shape
from torch_atr.io import atomic_path
from torch_atr.validate import opencv_can_open


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


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
    """The identity manifold as a circle: class arcs as coloured bands, each vehicle at its αₖ,
    α ticks every π/4 (labelled every π/2) with α = 0 marked, α growing counter-clockwise.

    alphas: (K,) radians; vehicle_classes: (K,) indices into ``class_names``;
    arcs: (class index, start, end) radians, counter-clockwise from start to end.
    Returns a matplotlib Figure.
    """
    from matplotlib.patches import Wedge

    plt = pyplot()

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

    def at(r: float, a: float) -> tuple[float, float]:
        return r * math.cos(a), r * math.sin(a)

    # α ticks every π/4, labelled every π/2, and α = 0 marked across the bands: the tracking
    # figures plot α in radians, and these say where each value lies on the circle.
    for i in range(8):
        ax.plot(*zip(at(0.9 if i % 2 else 0.84, i * math.pi / 4), at(1.0, i * math.pi / 4)), lw=1.0, color="0.2")
    for i, label in enumerate(("π/2", "π", "3π/2"), start=1):
        ax.text(*at(0.68, i * math.pi / 2), f"{label}\n({i * math.pi / 2:.2f} rad)", fontsize=8, ha="center",
                va="center")
    ax.plot(*zip(at(0.84, 0.0), at(1.1, 0.0)), lw=2.5, color="k", zorder=3)
    ax.text(*at(0.68, 0.0), "α = 0", fontsize=8, ha="center", va="center")
    ax.annotate("", xy=at(0.56, 0.75), xytext=at(0.56, 0.2),
                arrowprops={"arrowstyle": "->", "color": "0.3", "connectionstyle": "arc3,rad=0.2"})
    ax.text(*at(0.4, 0.45), "α grows", fontsize=7, color="0.3", ha="center", va="center")
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


def image_grid_figure(images: np.ndarray, row_labels: Sequence[str], col_labels: Sequence[str], title: str,
                      legend: Sequence[tuple[str, tuple[float, float, float]]] = (), col_title: str = ""):
    """A grid of small images with labelled rows and columns.

    Args:
        images: (R, C, H, W) grey in [0, 1] or (R, C, H, W, 3) RGB in [0, 1].
        row_labels: R labels (left of each row); col_labels: C labels (above the first row).
        title: the figure's title; col_title: what the column labels are (e.g. "view (θ, φ)").
        legend: (label, RGB colour) entries of a colour key.
    Returns:
        A matplotlib Figure.
    """
    images = np.asarray(images, dtype=np.float64)
    R, C = images.shape[:2]
    if len(row_labels) != R or len(col_labels) != C:
        raise ValueError(f"Expected {R} row and {C} column labels; got {len(row_labels)} and {len(col_labels)}")
    plt = pyplot()
    label_in = 0.065 * max((len(label) for label in row_labels), default=0)  # room for the row labels
    top_in, bottom_in = 0.75, 0.45 if legend else 0.15  # title above, colour key below
    width, height = 0.9 * C + label_in + 0.4, 0.9 * R + top_in + bottom_in
    fig, axes = plt.subplots(R, C, figsize=(width, height), squeeze=False)
    fig.subplots_adjust(left=(label_in + 0.2) / width, right=1 - 0.1 / width, top=1 - top_in / height,
                        bottom=bottom_in / height, wspace=0.08, hspace=0.12)
    for r in range(R):
        for c in range(C):
            ax = axes[r, c]
            ax.imshow(images[r, c], cmap="gray", vmin=0, vmax=1, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if c == 0:
                ax.set_ylabel(row_labels[r], rotation=0, ha="right", va="center", fontsize=7)
            if r == 0:
                ax.set_title(col_labels[c], fontsize=6)
    if legend:
        from matplotlib.patches import Patch

        fig.legend(handles=[Patch(facecolor=colour, edgecolor="0.5", label=label) for label, colour in legend],
                   loc="lower center", ncol=len(legend), fontsize=7, frameon=False)
    fig.suptitle(title + (f"\n(columns: {col_title})" if col_title else ""), fontsize=9, y=1 - 0.1 / height,
                 va="top")
    return fig


_SILHOUETTE_KEY = (("silhouette (y > 0)", (1.0, 1.0, 1.0)), ("background", (0.0, 0.0, 0.0)))
_OVERLAY_KEY = (("template and reconstruction", (1.0, 1.0, 1.0)), ("template only (missed)", (1.0, 0.0, 0.0)),
                ("reconstruction only (extra)", (0.0, 1.0, 1.0)), ("neither", (0.0, 0.0, 0.0)))


def _degrees(theta: float, phi: float) -> str:
    return f"{math.degrees(theta) % 360:.0f}°, {math.degrees(phi):.0f}°"


def _is_view_of(theta: float, phi: float, thetas: np.ndarray, phis: np.ndarray) -> bool:
    """Whether (θ, φ) is one of the views (thetas, phis) (V,), all radians, to 1e-4 rad (θ wrapped)."""
    from torch_atr.evaluation import wrapped_abs

    return bool(((wrapped_abs(thetas - theta) < 1e-4) & (np.abs(phis - phi) < 1e-4)).any())


# The figures each entry point may write, by name (a run's folder is theirs; other PNGs there are the user's).
MODEL_FIGURES = ("reconstructions", "view_sweeps", "identity_sweeps_within_class", "identity_sweeps_between_classes",
                 "identity_manifold")
TRACK_FIGURES = ("alpha_over_time", "errors_over_time", "view_trajectory", "frames")


@torch.no_grad()
def model_figures(model, masks: torch.Tensor, theta: torch.Tensor, phi: torch.Tensor, step_theta: float,
                  step_phi: float) -> dict:
    """The figures of a trained model (what ``train.py`` logs): name -> matplotlib Figure.

    masks: (K, V, H, W) bool training templates at theta, phi (V,) radians; step_theta, step_phi:
    the view grid's steps, radians. ``reconstructions``: 10 views per vehicle, template against
    the reconstruction at αₖ (:func:`overlay_pairs` colours); ``view_sweeps`` (Fig. 6.3, one
    vehicle per class); ``identity_sweeps_within_class`` (Fig. 6.4);
    ``identity_sweeps_between_classes`` (Fig. 6.5); ``identity_manifold``.
    """
    check_shape("masks", masks, ("K", "V", None, None))
    V = masks.shape[1]
    check_shape("theta", theta, (V,))
    check_shape("phi", phi, (V,))
    like = model.alphas
    names, classes, class_names = model.vehicle_names, model.vehicle_classes, model.class_names
    pick = torch.linspace(0, V - 1, 10).round().long()  # 10 views spread over the grid
    recon = torch.cat([model.reconstruct_grid(model.alphas[k:k + 1], theta[pick].to(like), phi[pick].to(like))[0]
                       for k in range(masks.shape[0])]).cpu() > 0
    pairs = overlay_pairs(masks[:, pick].reshape(recon.shape), recon)  # (K·10, 3, H, W)
    pairs = pairs.reshape(masks.shape[0], len(pick), 3, *masks.shape[2:]).permute(0, 1, 3, 4, 2).numpy()
    views = [_degrees(theta[v].item(), phi[v].item()) for v in pick]
    figures: dict = {"reconstructions": image_grid_figure(
        pairs, [f"{n} ({class_names[c]})" for n, c in zip(names, classes)], views,
        "Training templates against the model's reconstruction at each vehicle's αₖ", _OVERLAY_KEY,
        "view (θ, φ)")}
    order = model.identity.order.tolist()
    view_rows, view_labels, within_rows, within_labels = [], [], [], []
    for c, cls in enumerate(class_names):
        members = [k for k in order if classes[k] == c]
        if members:
            view_rows.append(view_sweep(model, model.alphas[members[0]].item(), math.radians(36), math.radians(10),
                                        step_theta, step_phi))
            view_labels.append(f"{names[members[0]]} ({cls})")
        if len(members) >= 3:
            within_rows.append(identity_sweep(model, [model.alphas[m].item() for m in members[:3]],
                                              math.radians(60), math.radians(10)))
            within_labels.append(f"{cls}: " + " → ".join(names[m] for m in members[:3]))
    between, between_labels = [], []
    for a, b in zip([order[-1]] + order[:-1], order):
        if classes[a] != classes[b]:
            between.append(identity_sweep(model, [model.alphas[a].item(), model.alphas[b].item()], math.radians(60),
                                          math.radians(10), between=5))
            between_labels.append(f"{class_names[classes[a]]} → {class_names[classes[b]]}: {names[a]} → {names[b]}")
    if view_rows:
        n = view_rows[0].shape[0] // 2
        sweep = [(math.radians(36) + i / n * step_theta, math.radians(10)) for i in range(n + 1)]
        sweep += [(math.radians(36) + step_theta, math.radians(10) + i / n * step_phi) for i in range(1, n + 1)]
        trained = theta.double().cpu().numpy(), phi.double().cpu().numpy()
        columns = [f"{round(math.degrees(t) % 360, 1):g}°, {round(math.degrees(p), 1):g}°"
                   + ("\n(training)" if _is_view_of(t, p, *trained) else "") for t, p in sweep]
        figures["view_sweeps"] = image_grid_figure(
            torch.stack(view_rows).float().numpy(), view_labels, columns,
            f"Along the view manifold from (θ₀, φ₀) = (36°, 10°): one azimuth step Δθ = "
            f"{math.degrees(step_theta):.0f}°, then one elevation step Δφ = {math.degrees(step_phi):.0f}° (Fig. 6.3)",
            _SILHOUETTE_KEY, "view (θ, φ); (training): a training view, the others interpolated")
    for name, rows, labels, anchors, what in (
            ("identity_sweeps_within_class", within_rows, within_labels, 3,
             "Along the identity manifold through three neighbouring vehicles of each class (Fig. 6.4)"),
            ("identity_sweeps_between_classes", between, between_labels, 2,
             "Along the identity manifold across each class border (Fig. 6.5)")):
        if rows:
            last = rows[0].shape[0] - 1
            every = last // (anchors - 1)  # the named vehicles' columns
            steps = [f"{i}/{last}" + (f"\nvehicle {i // every + 1}" if i % every == 0 else "") for i in range(last + 1)]
            figures[name] = image_grid_figure(torch.stack(rows).float().numpy(), labels, steps,
                                              f"{what}, view (60°, 10°)", _SILHOUETTE_KEY,
                                              "position along the path; vehicle k: the row's k-th named vehicle, "
                                              "a training vehicle")
    figures["identity_manifold"] = identity_circle_figure(model.alphas.tolist(), names, classes, class_names,
                                                          model.identity.class_arcs())
    return figures


def save_figures(figures: dict, folder: str | Path) -> None:
    """Write each matplotlib Figure of ``figures`` as ``folder/<name>.png``, atomically, and close it."""
    plt = pyplot()
    folder = Path(folder)
    for name, fig in figures.items():
        with atomic_path(folder / f"{name}.png") as tmp:
            fig.savefig(tmp, format="png", dpi=110)
        plt.close(fig)


# --- tracking figures (chapter 6.2) -------------------------------------------------------------

def _note_no_estimate(ax) -> None:
    """Say so in an axes of a run in which no frame had an estimate, rather than draw it empty."""
    ax.text(0.5, 0.5, "no estimate: no frame had a target to start on", transform=ax.transAxes,
            ha="center", va="center", fontsize=10, bbox={"facecolor": "white", "alpha": 0.8, "lw": 0})


def span_run(ax, t: np.ndarray) -> None:
    """Set the time axis of ``ax`` to the whole run, frames with an estimate or not, and half a frame
    after the last (whose marker the edge cut in half); t: (T,) seconds. A one-frame run gets half a
    second either side, cut at 0 s (matplotlib's ±0.05 s ran through negative time). The first frame
    sits on the edge: draw its marker with ``clip_on=False`` (the edge cut it in half)."""
    times = np.unique(t[np.isfinite(t)])
    if times.size == 1:
        ax.set_xlim(times[0] - 0.5 if times[0] < 0 else max(times[0] - 0.5, 0.0), times[0] + 0.5)
    elif times.size:
        ax.set_xlim(times[0], times[-1] + 0.5 * np.median(np.diff(times)))


def class_arc_bands(ax, model, alpha: float = 0.18) -> None:
    """The model's class arcs as bands across ``ax`` over its α axis (radians), keyed in the order
    of the model's classes, each key as pale as its band. Used by every figure of α over time."""
    colours = pyplot().get_cmap("tab10")
    for c, start, end in model.identity.class_arcs():
        for lo, hi in ((start, min(end, 2 * math.pi)), (0.0, end - 2 * math.pi)):
            if hi > lo:
                ax.axhspan(lo, hi, color=colours(c % 10), alpha=alpha, lw=0)
    for c, name in enumerate(model.class_names):
        ax.plot([], [], lw=8, color=colours(c % 10), alpha=alpha, label=f"{name} arc")


def alpha_figure(rows: list[dict], model, title: str):
    """α over time with the class arcs as coloured bands and the two nearest training vehicles
    of the sequence as dashed lines over the estimates (Fig. 6.10). rows: estimate rows. Returns a Figure."""
    from matplotlib import patheffects

    from torch_atr.evaluation import best_matches
    from torch_atr.tracking.filter import column

    plt = pyplot()
    t, alpha = column(rows, "time_s"), column(rows, "alpha")
    fig, ax = plt.subplots(figsize=(9, 4.5))
    class_arc_bands(ax, model)
    for k, name in enumerate(best_matches(model, alpha)):  # above the α̂ dots (haloed), which hid the match they sat on
        a = float(model.alphas[model.vehicle_names.index(name)])
        ax.axhline(a, ls="--", lw=1.2, color="0.25" if k == 0 else "0.55", zorder=3,
                   path_effects=[patheffects.withStroke(linewidth=3, foreground="white")],
                   label=f"best match {k + 1}: {name}")
    ax.plot(t, alpha, ".", ms=3, color="k", zorder=2, clip_on=False,  # α in [0, 2π): the first frame's dot whole
            label="estimated α")
    span_run(ax, t)
    if not np.isfinite(alpha).any():
        _note_no_estimate(ax)
    true_class = next((r.get("true_class") for r in rows if r.get("true_class")), "")
    ax.set(xlabel="time (s)", ylabel="identity α (rad)", ylim=(0, 2 * math.pi),
           title=f"{title}: identity over time" + (f" (true class: {true_class})" if true_class else ""))
    ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8)
    fig.tight_layout()
    return fig


def error_figure(rows: list[dict], title: str):
    """Horizontal, range and aspect errors over time (Fig. 6.8), with their means; the aspect also
    against the nearer of θ and π − θ, the silhouette's mirror at a grazing view (dashed). The title
    says what the panels hold: a run without a camera has no 3D estimate, only its view's error.
    Returns a Figure (None when no row has both an estimate and its truth)."""
    from torch_atr.tracking.filter import column, row_errors

    t = column(rows, "time_s")
    by_frame = row_errors(rows)
    errors = [("horizontal |x̂ − x|", "m", by_frame["horizontal_error_m"], None),
              ("range |ẑ − z|", "m", by_frame["range_error_m"], None),
              ("aspect |θ̂ − θ|", "rad", by_frame["aspect_error_rad"], by_frame["aspect_error_up_to_mirror_rad"])]
    errors = [error for error in errors if np.isfinite(error[2]).any()]  # no x, z without a camera
    if not errors:
        return None
    if len(errors) == 3:
        what = "3D tracking errors over time"
    elif not any("x" in row for row in rows):
        what = "view error over time (no camera: no 3D)"
    else:  # a 3D estimate against a truth without a position (SENSIAC's)
        what = " and ".join(name.split(" ")[0] for name, *_ in errors) + " error over time (truth: no position)"
    plt = pyplot()
    fig, axes = plt.subplots(len(errors), 1, figsize=(9, 1.2 + 1.9 * len(errors)), sharex=True, squeeze=False)
    axes = axes[:, 0]
    for ax, (name, unit, e, mirrored) in zip(axes, errors):
        ax.plot(t, e, ".-", lw=1.0, ms=2.5, clip_on=False,  # a lone frame too; the first frame's dot whole
                label=f"{name}: mean {np.nanmean(e):.2f} {unit}")
        if mirrored is not None:
            ax.plot(t, mirrored, "--", lw=1.0, color="tab:orange",
                    label=f"up to the mirror θ ↔ π − θ (same silhouette at φ = 0): mean {np.nanmean(mirrored):.2f} "
                          f"{unit}")
        ax.set(ylabel=f"error ({unit})")
        ax.legend(loc="best", fontsize=8)  # errors often grow late: upper right hid their end
        ax.grid(alpha=0.3)
    axes[-1].set(xlabel="time (s)")
    span_run(axes[-1], t)
    axes[0].set_title(f"{title}: {what}")
    fig.tight_layout()
    return fig


def view_figure(rows: list[dict], title: str, training_phi: tuple[float, float] | None = None):
    """The view Θ = (θ, φ) over the run: above, on the view manifold (Fig. 6.15), azimuth against
    elevation in degrees, coloured by time, the elevation axis fitted to the run's views and the
    training elevations (``training_phi``: lowest, highest, radians) shaded; below, the azimuth
    against time, where a grazing camera's views (φ near 0) are told apart. The truth where known,
    as hollow rings under the estimate (at a grazing camera both lie on φ ≈ 0). Returns a Figure."""
    from torch_atr.tracking.filter import column

    plt = pyplot()
    fig, (ax, ax_time) = plt.subplots(2, 1, figsize=(8, 7), height_ratios=[3, 2], layout="constrained")
    t = column(rows, "time_s")
    true_theta, true_phi = np.degrees(column(rows, "true_theta")) % 360, np.degrees(column(rows, "true_phi"))
    phi = np.degrees(column(rows, "phi"))
    theta = np.degrees(column(rows, "theta")) % 360
    est = np.isfinite(theta) & np.isfinite(phi)  # a frame without an estimate is a transparent point (and the legend's)
    sc = ax.scatter(theta[est], phi[est], c=t[est], s=10, cmap="viridis", label="estimate", zorder=3)
    ax_time.scatter(t[est], theta[est], c=t[est], s=10, cmap="viridis", label="estimate", zorder=3)
    truth = {"ls": "none", "marker": "o", "ms": 4.5, "mfc": "none", "mec": "crimson", "mew": 0.6, "zorder": 2}
    if np.isfinite(true_phi).any():
        ax.plot(true_theta, true_phi, label="truth", **truth)
    elif np.isfinite(true_theta).any():  # an aspect without an elevation (SENSIAC's truth): ticks along the bottom
        ax.plot(true_theta, np.full(true_theta.shape, 0.02), "|", ms=8, color="crimson",
                transform=ax.get_xaxis_transform(), label="true azimuth (elevation unknown)")
    if np.isfinite(true_theta).any():
        ax_time.plot(t, true_theta, label="truth", **truth)
    if not est.any():
        _note_no_estimate(ax)
    shown = np.concatenate([phi[np.isfinite(phi)], true_phi[np.isfinite(true_phi)]])
    low, high = (shown.min(), shown.max()) if shown.size else np.degrees(training_phi or (0.0, math.pi / 2))
    pad = max(1.0, 0.08 * (high - low))
    if training_phi is not None:
        lowest, highest = np.degrees(training_phi)
        ax.axhspan(lowest, highest, color="0.88", lw=0, zorder=0,
                   label=f"training elevations ({lowest:.0f}°–{highest:.0f}°)")
    ax.set(xlim=(0, 360), xticks=range(0, 361, 45), ylim=(low - pad, high + pad),
           xlabel="azimuth θ from the vehicle's front (degrees)", ylabel="elevation φ (degrees)",
           title=f"{title}: the view over the run")
    ax_time.set(ylim=(0, 360), yticks=range(0, 361, 90), xlabel="time (s)", ylabel="azimuth θ (degrees)")
    span_run(ax_time, t)
    for a in (ax, ax_time):
        a.grid(alpha=0.3)
        a.legend(loc="best", fontsize=8)  # upper right hid the views of a run ending at θ near 360°
    fig.colorbar(sc, ax=[ax, ax_time], label="time (s)")
    return fig


def frame_strip_figure(snapshots: list[dict], rows: list[dict], title: str, crop: int = 80):
    """Frames with the segmented target (cyan) and the estimate's reconstructed silhouette (red
    contour) overlaid, cropped around the estimate (Fig. 6.9), each titled with its estimated class
    and α, and the true class where the sequence has one. Returns a Figure."""
    import cv2

    plt = pyplot()
    fig, axes = plt.subplots(1, len(snapshots), figsize=(2.6 * len(snapshots), 3.2), squeeze=False)
    for ax, shot in zip(axes[0], snapshots):
        image = np.repeat(shot["image"][..., None], 3, axis=2)
        for mask, colour in ((shot["mask"], (0, 255, 255)), (shot["silhouette"], (255, 40, 40))):
            contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(image, contours, -1, colour, 1)
        where = np.argwhere(shot["silhouette"] | shot["mask"])
        v, u = where.mean(0).astype(int) if len(where) else (image.shape[0] // 2, image.shape[1] // 2)
        r0, c0 = max(v - crop, 0), max(u - crop, 0)
        ax.imshow(image[r0:v + crop, c0:u + crop], extent=(c0, c0 + image[r0:v + crop, c0:u + crop].shape[1],
                                                           r0 + image[r0:v + crop, c0:u + crop].shape[0], r0))
        row = rows[shot["frame"]]
        true = f" (true: {row['true_class']})" if row.get("true_class") else ""
        estimate = f"{row['class']}{true}\nα = {row['alpha']:.2f}" if "alpha" in row else f"no estimate{true}"
        ax.set_title(f"frame {shot['frame']}: {estimate}", fontsize=8)
        ax.set_xlabel("u (px)", fontsize=7)
        ax.set_ylabel("v (px)", fontsize=7)
        ax.tick_params(labelsize=6)
    axes[0, 0].plot([], [], color="cyan", label="segmented target")
    axes[0, 0].plot([], [], color=(1.0, 0.16, 0.16), label="reconstruction at the estimate")
    fig.legend(loc="lower center", ncol=2, fontsize=8)
    fig.suptitle(f"{title}: frames with the estimated shape")
    fig.tight_layout(rect=(0, 0.13, 1, 1))  # the legend below the x labels
    return fig


def track_figures(result, model, title: str) -> dict:
    """The figures of a tracking run: ``alpha_over_time``, ``errors_over_time`` (truth and an estimate),
    ``view_trajectory`` and ``frames``. Returns name -> Figure."""
    figures = {"alpha_over_time": alpha_figure(result.rows, model, title),
               "errors_over_time": error_figure(result.rows, title),
               "view_trajectory": view_figure(result.rows, title, (model.rbf.centres_phi.min().item(),
                                                                   model.rbf.centres_phi.max().item())),
               "frames": frame_strip_figure(result.snapshots, result.rows, title) if result.snapshots else None}
    return {name: fig for name, fig in figures.items() if fig is not None}


_TENSORBOARD_ESTIMATES = {"x": "x_m", "y": "y_m", "z": "z_m", "heading": "heading_rad", "speed": "speed_mps",
                          "alpha": "alpha_rad", "theta": "theta_rad", "phi": "phi_rad", "ess": "ess_particles",
                          "overlap": "overlap_dice"}  # row key -> TensorBoard tag, with its unit


def log_track_tensorboard(folder: str | Path, result, figures: dict) -> None:
    """Per-frame scalars, each tag with its unit (the estimate's position, heading, speed, α and
    view; ESS, overlap, lost; the class posterior ``recognition/p_<class>`` and, where the true
    class is one of the model's and the row has an estimate, ``recognition/correct`` (metrics.json's
    recognition also counts a frame without an estimate, as wrong);
    the errors where the truth is known, the aspect's also up to the mirror θ ↔ π − θ) and the
    figures, to TensorBoard event files in ``folder``."""
    from torch.utils.tensorboard import SummaryWriter

    from torch_atr.tracking.filter import error_columns

    with SummaryWriter(str(folder)) as writer:
        for row in result.rows:
            step = row["frame"]
            writer.add_scalar("estimate/lost", row["lost"], step)
            for name, tag in _TENSORBOARD_ESTIMATES.items():
                if name in row:
                    writer.add_scalar(f"estimate/{tag}", row[name], step)
            for name in row:
                if name.startswith("p_"):
                    writer.add_scalar(f"recognition/{name}", row[name], step)
            if "class" in row and f"p_{row.get('true_class')}" in row:  # a true class of the model's (metrics.json's)
                writer.add_scalar("recognition/correct", float(row["class"] == row["true_class"]), step)
            for name, error in error_columns(row).items():  # where the truth and the estimate are known
                writer.add_scalar(name.replace("error_", "error/", 1), error, step)  # error_range_m: error/range_m
        for name, fig in figures.items():
            writer.add_figure(name, fig, close=False)


class OverlayVideo:
    """A tracking run's frames as the segmenter sees them, each with its estimate's silhouette
    contour (red) over the segmented target's (cyan), both keyed top left under the frame's class,
    α and true class where known, written
    to an MP4 (OpenCV's mp4v codec) as the run steps: pass it as ``Tracker.run(..., on_frame=video)``
    inside its ``with`` block. Each frame is drawn
    while the tracker is at that frame, so with the kernel widths then in force (``adapt`` changes
    them over a run), and no frame is read twice. The file appears, atomically, when the block
    ends without an error.

    Args:
        path: the MP4 to write; its rate is the run's (``1 / tracker.dt``: the sequence's fps).
        tracker: the run's :class:`~torch_atr.tracking.filter.Tracker` (or ``BlobTracker``).
    """

    CONTOUR_BGR = (40, 40, 255)  # the estimate's silhouette (red)
    MASK_BGR = (255, 255, 0)  # the segmented target (cyan), as frames.png draws it

    def __init__(self, path: str | Path, tracker):
        self.path, self.tracker = Path(path), tracker

    def __enter__(self) -> OverlayVideo:
        with contextlib.ExitStack() as stack:  # unwound if a step fails; kept until __exit__ otherwise
            self._tmp = stack.enter_context(atomic_path(self.path, suffix=".mp4"))
            scratch = stack.enter_context(tempfile.TemporaryDirectory())
            # OpenCV picks the container by the extension; its writer cannot take every path Python can
            self._video = self._tmp if opencv_can_open(self._tmp) else Path(scratch) / "overlay.mp4"
            self._writer = None
            self._stack = stack.pop_all()
        return self

    def __call__(self, i: int, frame: np.ndarray, row: dict) -> None:
        """Draw frame ``i`` (as the sequence gave it) with ``row``, the tracker's estimate at it."""
        import cv2

        image = cv2.cvtColor(self.tracker.segmenter.display(frame), cv2.COLOR_GRAY2BGR)
        if self._writer is None:
            self._writer = cv2.VideoWriter(str(self._video), cv2.VideoWriter_fourcc(*"mp4v"), 1.0 / self.tracker.dt,
                                           (image.shape[1], image.shape[0]))
        mask = getattr(self.tracker, "last_mask", None)  # the frame's segmentation, under the estimate's contour
        if mask is not None and mask.shape == image.shape[:2]:
            contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(image, contours, -1, self.MASK_BGR, 1)
        if "alpha" in row:
            placed = self.tracker.silhouette_at(row, image.shape[:2]).cpu().numpy().astype(np.uint8)
            contours, _ = cv2.findContours(placed, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(image, contours, -1, self.CONTOUR_BGR, 1)
        # OpenCV's Hershey fonts have no α; the key names the contour's colour
        estimate = f"{row['class']} alpha={row['alpha']:.2f}" if "alpha" in row else "no estimate"
        true = f" (true: {row['true_class']})" if row.get("true_class") else ""
        white = (255, 255, 255)
        cv2.putText(image, f"frame {i}: {estimate}{true}", (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, white, 1)
        cv2.line(image, (8, 34), (28, 34), self.CONTOUR_BGR, 2)
        cv2.putText(image, "estimate's silhouette", (34, 38), cv2.FONT_HERSHEY_SIMPLEX, 0.4, white, 1)
        cv2.line(image, (8, 48), (28, 48), self.MASK_BGR, 2)
        cv2.putText(image, "segmented target", (34, 52), cv2.FONT_HERSHEY_SIMPLEX, 0.4, white, 1)
        self._writer.write(image)

    def __exit__(self, *exc) -> bool:
        """Close the video; it replaces ``path`` unless the block raised (the temporary file goes)."""
        try:
            if self._writer is not None:
                self._writer.release()
            if exc[0] is None and self._video != self._tmp and self._video.exists():
                shutil.copyfile(self._video, self._tmp)
        except BaseException as error:
            self._stack.__exit__(type(error), error, error.__traceback__)
            raise
        return self._stack.__exit__(*exc)
