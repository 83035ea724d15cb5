"""Measures of the generative model (chapter 6.1) and of tracking and recognition (chapter 6.2).

The model measures take a fitted :class:`~torch_atr.model.GenerativeShapeModel` and use its
``reconstruct_grid`` (every α at every view), which contracts Ψ once per view. The tracking
measures take per-frame arrays (``track.py``'s ``estimates.csv`` columns) and give the thesis's
figures: mean absolute horizontal, range and aspect errors (Fig. 6.8), the fraction of frames
recognised (Table 6.1), the two best-matching training vehicles (Fig. 6.10); the overlap ratio ξ
(eq. 6.1) is :func:`torch_atr.shape.dice`.
"""

from __future__ import annotations

import copy
import logging
import math

import numpy as np
import torch

from torch_atr._checks import as_float_tensor, check_finite, check_shape, describe_array
from torch_atr.model.rbf import ridge_hat
from torch_atr.shape import iou
from torch_atr.validate import integer

log = logging.getLogger(__name__)


def _as_views(like: torch.Tensor, **views) -> list[torch.Tensor]:
    """Each view angle (a tensor, array or list, radians) in ``like``'s dtype and device. A list was
    read as float32 before it was widened (a float64 model saw θ off by ~1e-8), and bools were taken as
    0 and 1 radians (:func:`~torch_atr._checks.as_float_tensor` refuses them)."""
    return [as_float_tensor(name, value, like=like).to(like) for name, value in views.items()]


def _views(model, templates: torch.Tensor, theta, phi, view_dim: int) -> tuple[torch.Tensor, torch.Tensor]:
    theta, phi = _as_views(model.alphas, theta=theta, phi=phi)
    check_shape("theta", theta, (templates.shape[view_dim],))
    check_shape("phi", phi, (templates.shape[view_dim],))
    return theta, phi


def _check_templates(name: str, x: torch.Tensor, model, dims: tuple, masks: bool) -> None:
    """Raise ValueError unless ``x`` is ``dims`` + the model's (S, S) template size, with at least
    one view (the last of ``dims``), and bool silhouettes (``masks``) or finite floating signed
    distances (a NaN pixel made every loss NaN: fit_alpha answered α = 0 with a NaN error)."""
    size = model.template.size_px
    check_shape(name, x, (*dims, size, size))
    if masks != (x.dtype == torch.bool) or not (masks or x.is_floating_point()):
        want = "bool silhouettes" if masks else "floating signed distances (torch_atr.shape.signed_distance)"
        raise ValueError(f"Expected {name} to be {want}; got dtype {x.dtype}")
    if x.shape[len(dims) - 1] == 0:
        raise ValueError(f"Expected {name} to hold at least one view; got shape {tuple(x.shape)}")
    if not masks:
        check_finite(name, x, "signed distances")


def per_class_mean(values: torch.Tensor, classes, class_names) -> dict[str, float]:
    """Mean of per-vehicle values by class name, plus "all".

    values: (K,); classes: K class indices into ``class_names``. Classes with no vehicle are left out.
    """
    values = torch.as_tensor(values, dtype=torch.float64)
    classes = torch.as_tensor(classes)
    check_shape("classes", classes, ("K",))
    check_shape("values", values, (classes.shape[0],))
    out = {name: values[classes == c].mean().item() for c, name in enumerate(class_names) if (classes == c).any()}
    out["all"] = values.mean().item()
    return out


@torch.no_grad()
def rbf_mapping_iou(rbf, signed: torch.Tensor, theta, phi, masks_out: torch.Tensor, theta_out, phi_out,
                    ridge: float) -> torch.Tensor:
    """IoU at new views of the per-vehicle RBF mappings alone (eq. 4.13; no pixel basis, no identity spline).

    rbf: an RBFViewMapping; signed: (K, V, H, W) templates at theta, phi (V,); masks_out: (K, Vo, H, W)
    bool silhouettes at theta_out, phi_out (Vo,); ridge: λ. Returns (K, Vo). Measures the kernel
    widths by themselves: the prediction Bᵏ Ψ_out with Bᵏ = Yᵏᵀ W is Yᵏᵀ (W Ψ_outᵀ), so B is never formed.
    In float64 whatever ``rbf``'s dtype: train.py measured the initial widths in float64 and the tuned
    ones (the fitted float32 model's) in float32, where Ψ's rounding alone moves the IoU.
    """
    check_shape("signed", signed, ("K", "V", None, None))
    check_shape("masks_out", masks_out, (signed.shape[0], "Vo", *signed.shape[2:]))
    check_finite("signed", signed, "signed distances")  # a NaN pixel scored as outside, lowering the IoU unseen
    rbf = copy.deepcopy(rbf).to(torch.float64)
    like = rbf.log_width
    theta, phi, theta_out, phi_out = _as_views(like, theta=theta, phi=phi, theta_out=theta_out, phi_out=phi_out)
    W = ridge_hat(rbf(theta, phi), ridge)  # (V, P)
    H = rbf(theta_out, phi_out) @ W.T  # (Vo, V)
    pred = torch.einsum("uv,kvhw->kuhw", H.to(signed), signed)
    return iou(pred > 0, masks_out)


@torch.no_grad()
def reconstruction_iou(model, templates: torch.Tensor, theta, phi) -> torch.Tensor:
    """IoU of each vehicle's reconstruction at its own αₖ against its true silhouettes.

    templates: (K, V, H, W) bool silhouettes of the K training vehicles; theta, phi: (V,) radians.
    Returns (K, V) IoU.
    """
    _check_templates("templates", templates, model, (len(model.alphas), "V"), masks=True)
    theta, phi = _views(model, templates, theta, phi, 1)
    return torch.stack([iou(model.reconstruct_grid(model.alphas[k:k + 1], theta, phi)[0].cpu() > 0, templates[k])
                        for k in range(templates.shape[0])])


@torch.no_grad()
def identity_distances(model, signed: torch.Tensor, theta, phi) -> torch.Tensor:
    """Mean squared error between the reconstruction at αₖ and vehicle j's templates.

    signed: (K, V, H, W) signed-distance templates; theta, phi: (V,) radians.
    Returns (K, K) on the CPU, in the wider of the model's and the templates' float dtypes: row k =
    reconstruction at αₖ, column j = vehicle j. A good model has its row minima on the diagonal.
    The errors are computed on the model's device (templates there were subtracted from a CPU copy
    of the reconstruction), and were stored in float32 whatever the model's dtype.
    """
    _check_templates("signed", signed, model, (len(model.alphas), "V"), masks=False)
    theta, phi = _views(model, signed, theta, phi, 1)
    like = model.alphas
    target = signed.to(like.device, torch.promote_types(signed.dtype, like.dtype))  # (K, V, H, W)
    rows = [((target - model.reconstruct_grid(model.alphas[k:k + 1], theta, phi)) ** 2).mean(dim=(1, 2, 3))
            for k in range(len(like))]  # reconstruction (1, V, H, W) at αₖ against every vehicle
    return torch.stack(rows).cpu()


@torch.no_grad()
def fit_alpha(model, signed: torch.Tensor, theta, phi, grid: int = 360) -> tuple[float, float]:
    """Search the identity manifold for the α that best explains one vehicle's known views.

    A grid over α ∈ [0, 2π) brackets the minimum of the mean squared signed-distance error;
    a bounded scalar search (scipy's Brent method) within one grid step either side refines it.
    signed: (V, H, W) signed-distance templates of the vehicle; theta, phi: (V,) radians.
    Returns (alpha in [0, 2π), its mean squared error).
    """
    from scipy.optimize import minimize_scalar

    _check_templates("signed", signed, model, ("V",), masks=False)
    grid = integer("grid", grid, 3)  # 360.5 searched 361 α spaced 2π/360.5, unevenly across the wrap
    theta, phi = _views(model, signed, theta, phi, 0)
    target = signed.to(model.alphas)
    # In pixel-basis coordinates: ‖y − t‖² = ‖c − Uᵀt‖² + ‖t − UUᵀt‖², the last term fixed. Formed as a
    # residual, not as ‖t‖² − ‖Uᵀt‖²: that difference of two sums of ~10⁴ cancels in float32.
    coords = model.project(target)  # (V, r)
    basis = model.core.pixel_basis  # None: the coordinates are the pixels, nothing outside
    outside = 0.0 if basis is None else (target.flatten(1) - coords @ basis.T).square().sum()
    count = target.numel()

    def loss_of(alpha: torch.Tensor) -> torch.Tensor:  # alpha (A,) -> (A,)
        c = model.reconstruct_grid(alpha, theta, phi, in_basis=True)  # (A, V, r)
        return ((c - coords).square().sum(dim=(1, 2)) + outside) / count

    step = 2 * math.pi / grid
    candidates = torch.arange(grid, dtype=target.dtype, device=target.device) * step
    losses = torch.cat([loss_of(chunk) for chunk in candidates.split(max(1, 8192 // len(theta)))])
    start = candidates[losses.argmin()].item()
    res = minimize_scalar(lambda a: loss_of(torch.tensor([a], dtype=target.dtype, device=target.device)).item(),
                          bounds=(start - step, start + step), method="bounded", options={"xatol": 1e-6})
    if res.fun <= losses.min().item():
        alpha = float(res.x) % (2 * math.pi)  # -1e-20 % 2π rounds to 2π itself
        return (0.0 if alpha == 2 * math.pi else alpha), float(res.fun)
    return start, losses.min().item()


@torch.no_grad()
def alpha_grid_iou(model, masks: torch.Tensor, theta, phi, grid: int = 720) -> torch.Tensor:
    """Static α search: IoU of the reconstructed silhouette at ``grid`` evenly spaced α with each view.

    masks: (B, V, H, W) bool silhouettes of B vehicles at the views theta, phi (V,) radians.
    Returns (B, grid, V): entry [b, a, v] is the IoU of y(2π·a/grid, Θᵥ) > 0 with masks[b, v].
    IoU is 1.0 where both silhouettes are empty (as :func:`torch_atr.shape.iou`). The best α of
    a single view v is the argmax over a of [b, :, v]; that of the whole vehicle, the argmax of
    the mean over v.
    """
    _check_templates("masks", masks, model, ("B", "V"), masks=True)
    grid = integer("grid", grid, 1)  # 10.5 gave 11 columns, not grid, and True one
    theta, phi = _views(model, masks, theta, phi, 1)
    alpha = torch.arange(grid, dtype=theta.dtype, device=theta.device) * (2 * math.pi / grid)
    truth = masks.flatten(2).to(theta)  # (B, V, d)
    area = truth.sum(-1)  # (B, V)
    out = []
    for chunk in alpha.split(max(1, 4096 // masks.shape[1])):
        recon = (model.reconstruct_grid(chunk, theta, phi).flatten(2) > 0).to(theta)  # (A, V, d)
        inter = torch.einsum("avd,bvd->bav", recon, truth)
        union = recon.sum(-1) + area[:, None] - inter  # (B, A, V)
        out.append(torch.where(union > 0, inter / union.clamp_min(1), torch.ones_like(union)).cpu())
    return torch.cat(out, dim=1)


# --- tracking and recognition (chapter 6.2) ----------------------------------------------------

def wrapped_abs(a: np.ndarray) -> np.ndarray:
    """|a| of angle differences wrapped to [−π, π): (...,) radians -> (...,) in [0, π]."""
    return np.abs(np.remainder(np.asarray(a, dtype=np.float64) + math.pi, 2 * math.pi) - math.pi)


def mirror_aspect_error(theta: np.ndarray, true_theta: np.ndarray) -> np.ndarray:
    """The aspect error up to the silhouette's mirror: min(|θ̂ − θ|, |θ̂ − (π − θ)|), each wrapped.

    Seen at zero elevation, a vehicle symmetric left to right casts the same silhouette at θ and at
    π − θ (its twin point at −y lands where the point at y did), and the two headings move it the
    same way across the image, so at a grazing camera only the range rate tells them apart
    (docs/tracking.md, "Not met"). This error counts an estimate on either branch as right.

    theta, true_theta: (T,) radians (NaN where unknown). Returns (T,) in [0, π] (π only where θ = π/2, the
    branches one: θ̂ = θ + π).
    """
    theta, true_theta = np.asarray(theta, dtype=np.float64), np.asarray(true_theta, dtype=np.float64)
    if theta.ndim != 1 or theta.shape != true_theta.shape:
        raise ValueError(f"Expected theta and true_theta of one shape (T,); got {theta.shape} and {true_theta.shape}")
    return np.minimum(wrapped_abs(theta - true_theta), wrapped_abs(theta - (math.pi - true_theta)))


def _mean_finite(values: np.ndarray) -> float | None:
    """Mean over the finite entries; None when there are none (JSON null)."""
    values = np.asarray(values, dtype=np.float64)
    finite = values[np.isfinite(values)]
    return float(finite.mean()) if finite.size else None


def frame_errors(est: dict[str, np.ndarray], truth: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per-frame 3D tracking errors (Fig. 6.8), NaN where the estimate or the truth is unknown.

    est, truth: (T,) arrays ``x`` (horizontal, m), ``z`` (range, m) and ``theta`` (aspect: the
    view azimuth, radians). Returns (T,) arrays ``horizontal_error_m`` |x̂ − x|, ``range_error_m``
    |ẑ − z|, ``aspect_error_rad`` the wrapped |θ̂ − θ| and ``aspect_error_up_to_mirror_rad``
    (:func:`mirror_aspect_error`).
    """
    columns = {}
    for name, given in (("est", est), ("truth", truth)):
        for key in ("x", "z", "theta"):
            if key not in given:
                raise ValueError(f"Expected {name}[{key!r}], a (T,) array; {name} has keys {sorted(given)}")
            columns[name, key] = np.asarray(given[key], dtype=np.float64)
    shapes = {a.shape for a in columns.values()}
    if len(shapes) != 1 or len(shapes.pop()) != 1:
        got = ", ".join(f"{name}[{key!r}] {a.shape}" for (name, key), a in columns.items())
        raise ValueError(f"Expected est and truth arrays of one shape (T,); got {got}")
    theta, true_theta = columns["est", "theta"], columns["truth", "theta"]
    return {"horizontal_error_m": np.abs(columns["est", "x"] - columns["truth", "x"]),
            "range_error_m": np.abs(columns["est", "z"] - columns["truth", "z"]),
            "aspect_error_rad": wrapped_abs(theta - true_theta),
            "aspect_error_up_to_mirror_rad": mirror_aspect_error(theta, true_theta)}


def tracking_errors(est: dict[str, np.ndarray], truth: dict[str, np.ndarray]) -> dict[str, float | None]:
    """The means of :func:`frame_errors` (same arguments and keys) over the frames where both are
    known, None where no frame has both."""
    return {key: _mean_finite(error) for key, error in frame_errors(est, truth).items()}


def recognition_accuracy(model, alpha: np.ndarray, true_class: list[str]) -> float | None:
    """Fraction of frames whose α lies in the true class's arc (Table 6.1).

    alpha: (T,) estimated α (NaN where there is no estimate: counted as wrong); true_class: T class
    names. Frames whose true class is not one of ``model.class_names`` ("" where unknown, a vehicle
    of a class the model was not trained on, a misspelt or differently cased name) are left out,
    and logged at debug level. None when no frame has a class the model knows.
    """
    alpha = np.asarray(alpha, dtype=np.float64)
    if alpha.ndim != 1:
        raise ValueError(f"Expected alpha to have shape (T,); got {alpha.shape}")
    known = np.array([c in model.class_names for c in true_class], dtype=bool)
    if len(true_class) != alpha.shape[0]:
        raise ValueError(f"Expected one true class per frame ({alpha.shape[0]}); got {len(true_class)}")
    others = sorted({c for c, k in zip(true_class, known) if not k and c})
    if others:
        log.debug("recognition accuracy leaves out frames of classes the model does not know: %s", others)
    if not known.any():
        return None
    finite = np.isfinite(alpha)
    like = model.alphas
    got = model.classify(torch.as_tensor(np.where(finite, alpha, 0.0)).to(like)).cpu().numpy()
    want = np.array([model.class_names.index(c) if k else -1 for c, k in zip(true_class, known)])
    return float(((got == want) & finite)[known].mean())


def best_matches(model, alpha: np.ndarray, k: int = 2) -> list[str]:
    """The k training vehicles nearest the circular mean of the estimated α over a sequence (Fig. 6.10).

    alpha: (T,) radians (NaN entries ignored). Returns k names, nearest first ([] without any α).
    """
    alpha = np.asarray(alpha, dtype=np.float64)
    if alpha.ndim != 1:
        raise ValueError(f"Expected alpha to have shape (T,); got {alpha.shape}")
    alpha = alpha[np.isfinite(alpha)]
    if alpha.size == 0:
        return []
    mean = math.atan2(np.sin(alpha).mean(), np.cos(alpha).mean()) % (2 * math.pi)
    like = model.alphas
    nearest = model.nearest_vehicles(torch.tensor([mean], dtype=like.dtype, device=like.device), k)[0].tolist()
    return [model.vehicle_names[i] for i in nearest]


def frames_to_convergence(ok: np.ndarray, window: int = 10) -> int | None:
    """The first frame from which ``window`` consecutive frames are all ``ok``; None if never.

    ok: (T,) bool, e.g. horizontal error < 1 m, aspect error < 0.3 rad and the right class.
    """
    if window < 1:
        raise ValueError(f"Expected window >= 1; got {window}")
    ok = np.asarray(ok)
    if ok.dtype != bool or ok.ndim != 1:
        raise ValueError(f"Expected ok to be a bool array of shape (T,); got {describe_array(ok)}")
    run = 0
    for i, good in enumerate(ok):
        run = run + 1 if good else 0
        if run == window:
            return i - window + 1
    return None
