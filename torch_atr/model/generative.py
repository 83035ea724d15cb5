"""The generative shape model y(α, Θ) = 𝒜 ×₃ i(α) ×₂ Ψ(Θ) (eq. 4.18), its fit and its checkpoints."""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import math
import numbers
import os
import pickle
import warnings
import zipfile
from collections import Counter, OrderedDict
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

import torch_atr
from torch_atr._checks import as_float_tensor, check_device, check_finite, check_shape
from torch_atr.config import ConfigError, ModelConfig, TemplateConfig, config_from_dict
from torch_atr.io import atomic_torch_save, check_output_file
from torch_atr.model.identity import DEGREE, TWO_PI, IdentityManifold, dissimilarity, shortest_closed_path
from torch_atr.model.rbf import RBFViewMapping, ridge_hat
from torch_atr.model.tensor import TensorCore, principal_basis
from torch_atr.validate import InputError, integer, show

log = logging.getLogger(__name__)

FORMAT = "torch_atr.generative"
FORMAT_VERSION = 2  # 2 adds "sha256", the content checksum; version 1 files are still read
MAX_CHECKPOINT_BYTES = 2 ** 31  # a checkpoint is read whole; the shipped one is 5 MB
MAX_CENTRES = 10_000  # Nc, as many as train.py's views
MAX_VEHICLES = 1000  # K
MAX_CLASSES = 1000  # C
_MODEL_ARG_KEYS = ("num_centres", "num_vehicles", "pixel_rank", "vehicle_names", "vehicle_classes", "class_names",
                   "template")
_CHECKPOINT_KEYS = {"format", "format_version", "torch_atr_version", "model_args", "state_dict", "extra", "sha256"}
_FLOAT_DTYPES = (torch.float32, torch.float64)
MAX_ABS_VALUE = 1e6  # |x| of any stored float (the shipped model's largest is 262): reconstructions stay finite
MAX_ELEVATION = math.pi / 2 + 1e-6  # |φ| of a view (radians) that fit takes (float32 rounds π/2 up)
LOG_WIDTH_RANGE = (-20.0, 20.0)  # kernel widths exp(log_width) stay positive and finite in float32
_INDEX_KEYS = ("identity.order", "identity.labels")  # int64; every other tensor is floating


class GenerativeShapeModel(nn.Module):
    """Signed-distance templates from the identity α and the view Θ = (θ, φ) (eq. 4.16-4.18).

    Args:
        rbf: the view mapping Ψ(Θ) with Nc centres.
        core: the decomposed mapping tensor (𝒜, U₁, iᵏ) of K vehicles, d = H·W pixels.
        identity: the identity manifold i(α) through the K identity vectors; its labels are the
            vehicles' class indices.
        vehicle_names: K names; class_names: C names, indexed by the labels.
        template: the template geometry (H = W = ``template.size_px``).

    Use :meth:`fit` to learn a model and :meth:`from_checkpoint` to load one. The whole state
    lives in ``state_dict()``; :attr:`model_args` holds what rebuilds the modules.
    """

    def __init__(self, rbf: RBFViewMapping, core: TensorCore, identity: IdentityManifold,
                 vehicle_names: Sequence[str], class_names: Sequence[str], template: TemplateConfig):
        super().__init__()
        K = core.num_vehicles
        if core.psi_dim != rbf.psi_dim:
            raise ValueError(f"core expects Ψ of length {core.psi_dim}; the RBF mapping gives {rbf.psi_dim}")
        if core.pixels != template.size_px ** 2:
            raise ValueError(f"core has {core.pixels} pixels; template.size_px = {template.size_px} "
                             f"needs {template.size_px ** 2}")
        if identity.num_vehicles != K or len(vehicle_names) != K:
            raise ValueError(f"Expected {K} vehicles in the identity manifold and names; got "
                             f"{identity.num_vehicles} and {len(vehicle_names)}")
        labels = identity.labels.tolist()
        if any(not 0 <= c < len(class_names) for c in labels):
            raise ValueError(f"vehicle classes {labels} out of range for {len(class_names)} class names")
        _check_distinct(vehicle_names, class_names)
        self.rbf = rbf
        self.core = core
        self.identity = identity
        self.vehicle_names = [str(name) for name in vehicle_names]
        self.class_names = [str(name) for name in class_names]
        self.template = template
        self.width_history: list[float] = []  # validation MSE per width-tuning step of fit(); not saved

    @property
    def vehicle_classes(self) -> list[int]:
        """Class index per vehicle (K,), into :attr:`class_names`."""
        return self.identity.labels.tolist()

    @property
    def alphas(self) -> torch.Tensor:
        """(K,) αₖ of each training vehicle on the identity manifold."""
        return self.identity.alphas

    @property
    def model_args(self) -> dict:
        """Plain-Python arguments that rebuild this model's modules (:meth:`from_model_args`)."""
        return {"num_centres": self.rbf.num_centres, "num_vehicles": self.core.num_vehicles,
                "pixel_rank": self.core.pixel_rank, "vehicle_names": list(self.vehicle_names),
                "vehicle_classes": self.vehicle_classes, "class_names": list(self.class_names),
                "template": dataclasses.asdict(self.template)}

    @classmethod
    def from_model_args(cls, model_args: dict) -> GenerativeShapeModel:
        """A model of the right sizes with placeholder values, for ``load_state_dict``.

        Raises InputError naming the key when ``model_args`` is incomplete, mistyped or out of
        bounds (:func:`check_model_args`) before anything is allocated.
        """
        template = check_model_args(model_args)
        K, Nc = model_args["num_vehicles"], model_args["num_centres"]
        rbf = RBFViewMapping(torch.zeros(Nc), torch.zeros(Nc), init_width=1.0)
        core = TensorCore(template.size_px ** 2, Nc + 4, K, model_args["pixel_rank"])
        identity = IdentityManifold(K)
        identity.labels.copy_(torch.tensor(model_args["vehicle_classes"], dtype=torch.long))
        return cls(rbf, core, identity, model_args["vehicle_names"], model_args["class_names"], template)

    @classmethod
    def fit(cls, templates: torch.Tensor, theta: torch.Tensor, phi: torch.Tensor, vehicle_names: Sequence[str],
            vehicle_classes, class_names: Sequence[str], template_cfg: TemplateConfig,
            cfg: ModelConfig | None = None, *, centres: tuple[torch.Tensor, torch.Tensor] | None = None,
            val_templates: torch.Tensor | None = None, val_theta: torch.Tensor | None = None,
            val_phi: torch.Tensor | None = None) -> GenerativeShapeModel:
        """Learn the model from signed-distance templates (chapter 4).

        templates: (K, V, H, W) clipped signed distance, positive inside; theta, phi: (V,) the
        training views, radians; vehicle_names: K names; vehicle_classes: (K,) class indices into
        class_names; template_cfg: H = W = size_px; cfg: defaults if None.
        centres: (Nc,) azimuths and elevations of the RBF centres; default the training views.
        val_templates: (K, Vv, H, W) and val_theta, val_phi: (Vv,) held-out views for tuning the
        kernel widths (``cfg.width_steps`` > 0).

        Steps: Ψ centres; widths (tuned if asked); every Bᵏ in closed form (eq. 4.13); HOSVD
        core with a rank-r pixel basis (eq. 4.14); D and the class-constrained shortest closed
        path (eq. 4.8-4.11); the closed spline i(α). The fit runs in float64; the model is
        returned in the templates' dtype and device.
        """
        cfg = ModelConfig() if cfg is None else cfg
        check_shape("templates", templates, ("K", "V", template_cfg.size_px, template_cfg.size_px))
        K, V = templates.shape[:2]
        if K < 2:
            raise ValueError(f"Expected at least 2 vehicles for an identity manifold; got {K}")
        if not templates.is_floating_point():
            raise ValueError(f"Expected signed-distance templates (floating); got dtype {templates.dtype}")
        check_finite("templates", templates)
        if not isinstance(vehicle_classes, torch.Tensor) and any(  # a list, tuple or array of names
                isinstance(c, str) for c in np.ravel(np.asarray(vehicle_classes, dtype=object))):
            raise ValueError(f"Expected vehicle_classes as indices into class_names; got names "
                             f"{[str(c) for c in vehicle_classes][:3]}... "
                             f"(e.g. [class_names.index(c) for c in classes])")
        given = torch.as_tensor(vehicle_classes, device=templates.device)
        labels = given.to(torch.long)  # casting alone truncated 1.9 to class 1
        check_shape("vehicle_classes", labels, (K,))
        if given.dtype == torch.bool or not torch.equal(labels.to(given.dtype), given):
            raise ValueError(f"Expected vehicle_classes as whole indices into class_names; got {given.tolist()}")
        if not 0 <= labels.min() <= labels.max() < len(class_names):
            raise ValueError(f"vehicle classes {labels.tolist()} out of range for {len(class_names)} class names")
        if len(vehicle_names) != K:
            raise ValueError(f"Expected {K} vehicle names; got {len(vehicle_names)}")
        _check_distinct(vehicle_names, class_names)  # before the fit, not after it
        wide = templates.to(torch.float64)

        def as_wide(name: str, x) -> torch.Tensor:
            angles = check_finite(name, as_float_tensor(name, x, like=wide).to(wide), "radians")
            # Elevations in degrees (0-40) fitted a model of meaningless views (cos 40 < 0: the far side).
            if name.endswith("phi") and angles.numel() and angles.abs().max().item() > MAX_ELEVATION:
                raise ValueError(f"Expected {name} to be elevations in [-π/2, π/2] radians; got values up to "
                                 f"{angles.abs().max().item():.6g} (degrees?)")
            return angles

        theta, phi = as_wide("theta", theta), as_wide("phi", phi)
        check_shape("theta", theta, (V,))
        check_shape("phi", phi, (V,))
        Y = wide.reshape(K, V, -1)  # (K, V, d)
        centres_theta, centres_phi = (theta, phi) if centres is None else centres
        rbf = RBFViewMapping(as_wide("centres_theta", centres_theta), as_wide("centres_phi", centres_phi),
                             cfg.init_width)
        width_history: list[float] = []
        if cfg.width_steps > 0:
            if val_templates is None or val_theta is None or val_phi is None:
                raise ValueError("cfg.width_steps > 0 needs val_templates, val_theta and val_phi")
            check_shape("val_templates", val_templates, (K, None, template_cfg.size_px, template_cfg.size_px))
            if not val_templates.is_floating_point():  # masks tuned the widths to 0/1 targets without a word
                raise ValueError(f"Expected signed-distance val_templates (floating); got dtype {val_templates.dtype}")
            val = val_templates.reshape(K, val_templates.shape[1], -1)  # (K, Vv, d), widened per vehicle later
            width_history = fine_tune_widths(rbf, Y, theta, phi, val, as_wide("val_theta", val_theta),
                                             as_wide("val_phi", val_phi), cfg.width_steps, cfg.width_lr,
                                             ridge=cfg.ridge)
        order = shortest_closed_path(dissimilarity(Y, labels, cfg.class_penalty), labels)
        core, identity = _fit_core_and_identity(rbf, Y, theta, phi, cfg.ridge, cfg.pixel_rank, labels, order)
        log.info("fitted K=%d V=%d Nc=%d r=%s: truncation error %.3g, order %s", K, V, rbf.num_centres,
                 core.pixel_rank, core.relative_error.item(), order.tolist())
        model = cls(rbf, core, identity, vehicle_names, class_names, template_cfg)
        model.width_history = width_history
        return model.to(templates.dtype)

    def _queries(self, **queries) -> list[torch.Tensor]:
        """Check that each query is (N,) of one N and finite, and convert it to the model's dtype
        and device (a NaN α would reconstruct NaN and classify as the first class)."""
        like = self.core.core
        out = [as_float_tensor(name, value, like=like).to(like) for name, value in queries.items()]
        for name, value in zip(queries, out):
            check_shape(name, value, ("N",))
            check_finite(name, value, "radians")
        if len({value.shape[0] for value in out}) > 1:
            raise ValueError("Expected " + ", ".join(queries) + " of one length N; got "
                             + ", ".join(str(tuple(v.shape)) for v in out))
        return out

    def forward(self, alpha: torch.Tensor, theta: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
        """Signed-distance reconstruction y(α, Θ) (eq. 4.18).

        alpha: (N,) identity angles; theta, phi: (N,) view, radians, any float dtype. Returns
        (N, H, W), positive inside, in the model's dtype and on its device; differentiable in the
        queries and the kernel widths (a parameter), so under ``torch.no_grad()`` for plain values.
        """
        alpha, theta, phi = self._queries(alpha=alpha, theta=theta, phi=phi)
        y = self.core.reconstruct(self.identity(alpha), self.rbf(theta, phi))  # (N, d)
        return y.view(-1, self.template.size_px, self.template.size_px)

    def reconstruct_grid(self, alpha: torch.Tensor, theta: torch.Tensor, phi: torch.Tensor,
                         in_basis: bool = False) -> torch.Tensor:
        """y(α, Θ) for every α at every view (eq. 4.18), far cheaper than one query per pair.

        alpha: (A,) identity angles; theta, phi: (V,) view, radians. Returns (A, V, H, W), or
        with ``in_basis`` the (A, V, r) pixel-basis coordinates (compare them with :meth:`project`).
        """
        (alpha,) = self._queries(alpha=alpha)
        theta, phi = self._queries(theta=theta, phi=phi)
        y = self.core.reconstruct_grid(self.identity(alpha), self.rbf(theta, phi), in_basis)  # (A, V, d or r)
        if in_basis:
            return y
        return y.view(alpha.shape[0], theta.shape[0], self.template.size_px, self.template.size_px)

    def project(self, templates: torch.Tensor) -> torch.Tensor:
        """Pixel-basis coordinates of signed-distance templates: (..., H, W) -> (..., r)."""
        like = self.core.core
        templates = as_float_tensor("templates", templates, like=like).to(like)
        if templates.shape[-2:] != (self.template.size_px, self.template.size_px):
            raise ValueError(f"Expected templates of shape (..., {self.template.size_px}, {self.template.size_px}); "
                             f"got {tuple(templates.shape)}")
        return self.core.project(templates.flatten(-2))

    def silhouette(self, alpha: torch.Tensor, theta: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
        """The reconstructed silhouette y(α, Θ) > 0 for alpha, theta, phi: (N,). Returns (N, H, W) bool."""
        return self(alpha, theta, phi) > 0

    def reconstruct_vehicle(self, k: int, theta: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
        """Vehicle k's templates from its identity vector iᵏ exactly (eq. 4.14-4.15).

        k: vehicle index; theta, phi: (N,) radians. Returns (N, H, W).
        """
        if isinstance(k, bool) or not isinstance(k, numbers.Integral) or not 0 <= k < self.core.num_vehicles:
            raise ValueError(f"Expected a whole vehicle index in [0, {self.core.num_vehicles}); got {k!r}")
        k = int(k)
        theta, phi = self._queries(theta=theta, phi=phi)
        identity = self.core.identity_vectors[k].expand(theta.shape[0], -1)  # (N, K)
        y = self.core.reconstruct(identity, self.rbf(theta, phi))
        return y.view(-1, self.template.size_px, self.template.size_px)

    def classify(self, alpha: torch.Tensor) -> torch.Tensor:
        """Class index whose identity arc holds alpha: (N,), taken in the model's dtype (a float64 α
        within rounding of an arc's start may fall on either side). Returns (N,) int64."""
        return self.identity.classify(*self._queries(alpha=alpha))

    def nearest_vehicles(self, alpha: torch.Tensor, k: int = 2) -> torch.Tensor:
        """The k training vehicles nearest to alpha: (N,) on the identity circle. Returns (N, k) int64."""
        return self.identity.nearest_vehicles(*self._queries(alpha=alpha), k)

    def save(self, path: str | os.PathLike, extra: dict | None = None) -> None:
        """Write a self-describing checkpoint atomically; it loads with ``torch.load(weights_only=True)``.

        extra: plain data to store alongside (tensors, numbers, strings, None, lists/dicts of them).
        The file stores the SHA-256 of its content (:func:`content_sha256`), checked on load. An
        existing checkpoint at ``path`` is replaced; any other file is not (``OutputExistsError``).
        A model :func:`load_checkpoint` would refuse (say one cast to float16) is not written. The
        tensors (the state's and those in ``extra``) are stored on the CPU, whatever the model's device,
        so a machine without that device loads the file.
        """
        _check_plain("extra", extra)
        path = check_output_file(path, True, is_checkpoint, "checkpoint")
        model_args, state, extra = self.model_args, self.state_dict(), _on_cpu(extra)
        for key, tensor in state.items():
            state[key] = tensor.detach().cpu()
        _check_state(state, model_args, f"{path} (not written, as it would not load)")
        atomic_torch_save({"format": FORMAT, "format_version": FORMAT_VERSION,
                           "torch_atr_version": torch_atr.__version__, "model_args": model_args,
                           "state_dict": state, "extra": extra,
                           "sha256": content_sha256(model_args, state, extra)}, path)

    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike, map_location=None) -> GenerativeShapeModel:
        """Load a model written by :meth:`save` (see :func:`load_checkpoint` for the errors)."""
        return load_checkpoint(path, map_location)[0]


def _check_plain(name: str, value) -> None:
    """Raise ValueError unless ``value`` holds only tensors and plain Python data."""
    # type(), not isinstance: np.float64 is a float and an IntEnum member an int, which torch.load(weights_only) refuses
    if value is None or type(value) in (bool, int, float, str) or isinstance(value, torch.Tensor):
        return
    if type(value) in (list, tuple):  # a namedtuple is not plain: torch.load(weights_only) refuses it
        for i, item in enumerate(value):
            _check_plain(f"{name}[{i}]", item)
        return
    if isinstance(value, dict):
        for key, item in value.items():
            if type(key) is not str:  # np.str_ keys (from an array of names) are refused by torch.load(weights_only)
                raise ValueError(f"{name} has a non-string key {key!r} of type {type(key).__name__}")
            _check_plain(f"{name}[{key!r}]", item)
        return
    raise ValueError(f"{name} holds a {type(value).__name__}; checkpoints store only tensors and plain data")


def _on_cpu(value):
    """``value`` (plain data, :func:`_check_plain`) with each tensor in it moved to the CPU."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu()
    if isinstance(value, (list, tuple)):
        return type(value)(_on_cpu(item) for item in value)
    if isinstance(value, dict):
        return {key: _on_cpu(item) for key, item in value.items()}
    return value


def content_sha256(model_args: dict, state_dict: dict, extra) -> str:
    """SHA-256 (hex) of a checkpoint's content, independent of how ``torch.save`` lays it out.

    The digest covers model_args, the state_dict and extra, fed in a canonical order: dict items
    sorted by key, each value tagged with its type; a tensor as its dtype, shape and raw bytes
    (C order, native byte order). Raises InputError for data a checkpoint cannot hold.
    """
    digest = hashlib.sha256()
    _feed(digest, {"model_args": model_args, "state_dict": state_dict, "extra": extra})
    return digest.hexdigest()


def _feed(digest, value) -> None:
    """Feed ``value`` to ``digest`` in the canonical encoding of :func:`content_sha256`."""
    if value is None:
        digest.update(b"N")
    elif isinstance(value, bool):
        digest.update(b"T" if value else b"F")
    elif isinstance(value, int):
        digest.update(b"i%d;" % value)
    elif isinstance(value, float):
        digest.update(b"f" + value.hex().encode() + b";")
    elif isinstance(value, str):
        data = value.encode("utf-8", "surrogatepass")
        digest.update(b"s%d;" % len(data) + data)
    elif isinstance(value, (list, tuple)):
        digest.update(b"l%d;" % len(value))
        for item in value:
            _feed(digest, item)
    elif isinstance(value, dict):
        if not all(isinstance(key, str) for key in value):
            raise InputError(f"a dict with non-string keys {show(list(value))}")
        digest.update(b"d%d;" % len(value))
        for key in sorted(value):
            _feed(digest, key)
            _feed(digest, value[key])
    elif isinstance(value, torch.Tensor):
        if value.layout != torch.strided:
            raise InputError(f"a {value.layout} tensor; checkpoints hold dense tensors")
        t = value.detach().to("cpu").contiguous()
        digest.update(f"t{t.dtype};{tuple(t.shape)};".encode())
        digest.update(t.reshape(-1).view(torch.uint8).numpy())
    else:
        raise InputError(f"a {type(value).__name__}; checkpoints hold only tensors and plain data")


def is_checkpoint(path: str | os.PathLike) -> bool:
    """True when ``path`` is a file :meth:`GenerativeShapeModel.save` wrote (its format says so; the
    tensors are memory-mapped, not read, and nothing else is checked)."""
    try:
        ckpt = torch.load(os.fspath(path), map_location="cpu", weights_only=True, mmap=True)  # str: torch 2.2's mmap
    except Exception:  # anything torch cannot read is not ours
        return False
    return isinstance(ckpt, dict) and ckpt.get("format") == FORMAT


def check_model_args(model_args, where: str = "model_args") -> TemplateConfig:
    """Check a checkpoint's ``model_args``: every key present, of its type and within the bounds
    (K in [2, 1000], Nc in [1, 10000], C in [1, 1000], template as :class:`TemplateConfig`, r in
    [1, H·W] or None, K names, K class indices in [0, C)); return the template. Raises InputError
    naming ``where`` and the key. Allocates nothing.
    """
    if not isinstance(model_args, dict):
        raise InputError(f"{where}: expected a dict; got {type(model_args).__name__}")
    missing = [k for k in _MODEL_ARG_KEYS if k not in model_args]
    unknown = sorted(set(model_args) - set(_MODEL_ARG_KEYS), key=str)
    if missing or unknown:
        raise InputError(f"{where}: " + "; ".join(
            ([f"lacks {', '.join(map(repr, missing))}"] if missing else [])
            + ([f"unknown key(s) {', '.join(map(show, unknown))}"] if unknown else [])))

    def key(name: str) -> str:
        return f"{where}[{name!r}]"

    K = integer(key("num_vehicles"), model_args["num_vehicles"], 2, MAX_VEHICLES)
    integer(key("num_centres"), model_args["num_centres"], 1, MAX_CENTRES)
    try:
        template = config_from_dict(TemplateConfig, model_args["template"])
    except ConfigError as exc:
        raise InputError(f"{key('template')}: {exc}") from None
    if model_args["pixel_rank"] is not None:
        integer(key("pixel_rank"), model_args["pixel_rank"], 1, template.size_px ** 2)
    names, class_names, classes = (model_args[k] for k in ("vehicle_names", "class_names", "vehicle_classes"))
    if not isinstance(class_names, list) or not 1 <= len(class_names) <= MAX_CLASSES or not all(
            isinstance(c, str) for c in class_names):
        raise InputError(f"{key('class_names')}: expected a list of 1 to {MAX_CLASSES} strings; "
                         f"got {show(class_names)}")
    if not isinstance(names, list) or len(names) != K or not all(isinstance(n, str) for n in names):
        raise InputError(f"{key('vehicle_names')}: expected a list of {K} strings; got {show(names)}")
    for name, values in (("class_names", class_names), ("vehicle_names", names)):
        if _repeated(values):
            raise InputError(f"{key(name)}: expected distinct names; {show(_repeated(values))} repeat(s)")
    if not isinstance(classes, list) or len(classes) != K:
        raise InputError(f"{key('vehicle_classes')}: expected a list of {K} class indices; got {show(classes)}")
    for k, c in enumerate(classes):
        integer(f"{key('vehicle_classes')}[{k}]", c, 0, len(class_names) - 1)
    return template


def _repeated(names: Sequence) -> list[str]:
    """The names (as text) that occur more than once in ``names``, sorted. A class named twice was two
    classes: ``class_names.index`` (recognition, a truth start's arc) found only the first, and the
    tracker's per-class columns p_<name> overwrote each other; a vehicle named twice re-rendered one
    mesh for both (Method IV)."""
    return sorted(name for name, count in Counter(map(str, names)).items() if count > 1)


def _check_distinct(vehicle_names: Sequence[str], class_names: Sequence[str]) -> None:
    """Raise ValueError naming the list and the names that repeat in it (:func:`_repeated`), or a list
    given as one string (its characters were taken for names: class_names="tank" made four classes)."""
    for what, names in (("vehicle_names", vehicle_names), ("class_names", class_names)):
        if isinstance(names, str):
            raise ValueError(f"Expected {what} to be a list of names; got the single string {show(names)}")
        if _repeated(names):
            raise ValueError(f"Expected {what} to be distinct; {show(_repeated(names))} repeat(s) in "
                             f"{show(list(names))}")


def state_shapes(model_args: dict) -> dict[str, tuple[int, ...]]:
    """The state_dict shapes that checked ``model_args`` call for (the buffers of RBFViewMapping,
    TensorCore and IdentityManifold), computed without building the model."""
    K, Nc, rank = model_args["num_vehicles"], model_args["num_centres"], model_args["pixel_rank"]
    d = model_args["template"]["size_px"] ** 2
    shapes = {"rbf.centres_theta": (Nc,), "rbf.centres_phi": (Nc,), "rbf.log_width": (Nc,),
              "core.core": (d if rank is None else rank, Nc + 4, K), "core.identity_vectors": (K, K),
              "core.relative_error": (), "identity.knots": (K + 1 + 2 * DEGREE,),
              "identity.coefficients": (K + DEGREE, K), "identity.alphas": (K,), "identity.order": (K,),
              "identity.labels": (K,)}
    if rank is not None:
        shapes["core.pixel_basis"] = (d, rank)
    return shapes


def _check_state(state, model_args: dict, where: str) -> None:
    """Check a loaded state_dict against checked ``model_args``: the keys, shapes and dtypes they
    call for (one float dtype, float32 or float64; int64 order and labels), dense finite tensors
    within MAX_ABS_VALUE (log widths within LOG_WIDTH_RANGE), strictly increasing knots,
    ``identity.order`` a permutation, ``identity.alphas`` the spline's data sites from 0 to 2π along it
    and ``identity.labels`` equal to ``vehicle_classes``: what keeps every reconstruction finite and
    each vehicle at its αₖ."""
    if not isinstance(state, dict):
        raise InputError(f"{where}: state_dict is a {type(state).__name__}; expected a dict of tensors")
    shapes = state_shapes(model_args)
    missing = sorted(set(shapes) - set(state))
    unexpected = sorted(map(str, set(state) - set(shapes)))
    if missing or unexpected:
        raise InputError(f"{where}: state_dict does not match model_args: " + "; ".join(
            ([f"missing {', '.join(missing)}"] if missing else [])
            + ([f"unexpected {', '.join(map(show, unexpected))}"] if unexpected else [])))
    float_dtype = None
    for name, shape in shapes.items():
        t = state[name]
        if not isinstance(t, torch.Tensor) or t.layout != torch.strided:
            raise InputError(f"{where}: state_dict[{name!r}] is a {type(t).__name__}; expected a dense tensor")
        if tuple(t.shape) != shape:
            raise InputError(f"{where}: state_dict does not match model_args: {name} has shape {tuple(t.shape)}; "
                             f"model_args call for {shape}")
        if name in _INDEX_KEYS:
            if t.dtype != torch.int64:
                raise InputError(f"{where}: state_dict[{name!r}] has dtype {t.dtype}; expected torch.int64")
            continue
        float_dtype = float_dtype or t.dtype
        if t.dtype not in _FLOAT_DTYPES or t.dtype != float_dtype:
            raise InputError(f"{where}: state_dict[{name!r}] has dtype {t.dtype}; expected the model's one float "
                             f"dtype, float32 or float64 ({float_dtype} here)")
        if not bool(torch.isfinite(t).all()):
            raise InputError(f"{where}: state_dict[{name!r}] holds {int((~torch.isfinite(t)).sum())} NaN or "
                             f"infinite value(s)")
        lo, hi = LOG_WIDTH_RANGE if name == "rbf.log_width" else (-MAX_ABS_VALUE, MAX_ABS_VALUE)
        if t.numel() and not lo <= t.min().item() <= t.max().item() <= hi:
            raise InputError(f"{where}: state_dict[{name!r}] holds values in [{t.min().item():.3g}, "
                             f"{t.max().item():.3g}]; expected them within [{lo:g}, {hi:g}]")
    knots = state["identity.knots"]
    if not bool((knots[1:] > knots[:-1]).all()):
        raise InputError(f"{where}: state_dict['identity.knots'] is not strictly increasing")
    K = model_args["num_vehicles"]
    order = state["identity.order"]
    if not torch.equal(order.sort().values.cpu(), torch.arange(K)):
        raise InputError(f"{where}: state_dict['identity.order'] is not a permutation of 0..{K - 1}: "
                         f"{show(order.tolist())}")
    # The αₖ are the spline's data sites along the path (IdentityManifold.fit), which spans one turn from 0: other
    # αₖ loaded and put each vehicle where the spline does not reproduce it, and class_arcs off the circle.
    sites = knots[DEGREE:DEGREE + K + 1]
    if (not torch.equal(state["identity.alphas"][order], sites[:-1]) or sites[0].item() != 0.0
            or not math.isclose(sites[-1].item(), TWO_PI, rel_tol=1e-6)):
        raise InputError(f"{where}: state_dict['identity.alphas'] along identity.order, "
                         f"{show(state['identity.alphas'][order].tolist())}, are not the identity spline's data sites "
                         f"from 0 to 2π, identity.knots[{DEGREE}:{DEGREE + K + 1}] = {show(sites.tolist())}")
    if state["identity.labels"].tolist() != model_args["vehicle_classes"]:
        raise InputError(f"{where}: state_dict labels {show(state['identity.labels'].tolist())} differ from "
                         f"model_args vehicle_classes {show(model_args['vehicle_classes'])}")


def _check_archive(path: Path) -> None:
    """Check, before unpickling anything, that ``path`` is a zip archive as ``torch.save`` writes
    it: at most MAX_CHECKPOINT_BYTES, entries stored uncompressed, so what ``torch.load``
    allocates is bounded by the file's size."""
    size = path.stat().st_size
    if size > MAX_CHECKPOINT_BYTES:
        raise InputError(f"{path}: {size} bytes; a checkpoint is at most {MAX_CHECKPOINT_BYTES}")
    try:
        with zipfile.ZipFile(path) as archive:
            entries = archive.infolist()
    except OSError as exc:  # the file system's refusal (permission, I/O error): corrupt bytes raise other kinds
        raise OSError(exc.errno, f"{path}: cannot read it: {exc.strerror}") from None
    except Exception as exc:  # zipfile raises many kinds on corrupt bytes
        raise InputError(f"{path}: not a readable checkpoint (corrupt, truncated or another kind of file): not a "
                         f"zip archive as torch.save writes ({type(exc).__name__}: {show(str(exc))})") from None
    for entry in entries:
        if entry.compress_type != zipfile.ZIP_STORED or entry.compress_size != entry.file_size:
            raise InputError(f"{path}: archive entry {show(entry.filename)} is compressed; torch.save stores "
                             f"entries uncompressed")
    if sum(entry.file_size for entry in entries) > size:
        raise InputError(f"{path}: the archive's entries claim more bytes than the file holds (corrupt)")


def _load_error(path: Path, exc: Exception) -> InputError:
    """An InputError for an exception of ``torch.load``, without PyTorch's advice to retry with
    ``weights_only=False`` (which would run whatever the file holds)."""
    boilerplate = ("Weights only load failed", "Please file an issue", "Check the documentation")
    text = str(exc).split("WeightsUnpickler error:")[-1]  # torch 2.2 gives the reason after this, on the advice's line
    detail = " ".join(line.strip() for line in text.splitlines() if line.strip()
                      and not line.startswith(boilerplate) and "weights_only" not in line)[:200] or type(exc).__name__
    if isinstance(exc, pickle.UnpicklingError):
        return InputError(f"{path}: refused to load: it holds something other than tensors and plain data, which "
                          f"torch_atr checkpoints never do ({detail})")
    return InputError(f"{path}: not a readable checkpoint (corrupt or truncated?): {detail}")


def checkpoint_file(path: str | os.PathLike) -> Path:
    """``path`` as a Path, where it names a file: FileNotFoundError where nothing is there, InputError
    for a folder or a device (what :func:`load_checkpoint` checks before reading)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    if not path.is_file():
        raise InputError(f"{path}: expected a checkpoint file; it is a folder or a device")
    return path


def load_checkpoint(path: str | os.PathLike, map_location=None) -> tuple[GenerativeShapeModel, dict | None]:
    """Load a model and its ``extra`` data from a checkpoint written by :meth:`GenerativeShapeModel.save`.

    Everything is checked before the model is built: the archive (:func:`_check_archive`), the
    format and version, the content checksum (version 2; a version-1 file has none and loads
    with a warning), ``model_args`` (:func:`check_model_args`) and the state_dict against them
    (keys, shapes, dtypes, finite values, ``identity.order`` a permutation). Raises
    FileNotFoundError for a missing file, OSError (PermissionError, ...) naming a file it cannot
    read, InputError naming the file and the problem, and ValueError where ``map_location`` names
    a device this machine lacks.
    """
    path = checkpoint_file(path)
    _check_archive(path)
    if isinstance(map_location, (str, int, torch.device)):  # a missing device is not a corrupt file; 0 is cuda:0
        map_location = check_device(map_location)
    try:
        with warnings.catch_warnings():  # a corrupt pickle header's protocol warning: our checks decide
            warnings.filterwarnings("ignore", message="Detected pickle protocol", category=UserWarning)
            ckpt = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # torch.load raises many kinds on corrupt bytes
        raise _load_error(path, exc) from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        found = ckpt.get("format") if isinstance(ckpt, dict) else type(ckpt).__name__
        raise InputError(f"{path}: not a {FORMAT} checkpoint (format: {show(found)})")
    version = ckpt.get("format_version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise InputError(f"{path}: format_version {show(version)} is not a version number")
    if version > FORMAT_VERSION:
        raise InputError(f"{path}: format_version {version} is not supported (this torch_atr reads up to "
                         f"{FORMAT_VERSION}; upgrade torch_atr)")
    required = {"format_version", "model_args", "state_dict"} | ({"sha256"} if version >= 2 else set())
    missing = sorted(required - set(ckpt))
    if missing:
        raise InputError(f"{path}: checkpoint lacks {', '.join(missing)}")
    unknown = sorted(map(str, set(ckpt) - _CHECKPOINT_KEYS))
    if unknown:
        raise InputError(f"{path}: unknown checkpoint key(s) {', '.join(map(show, unknown))}")
    model_args, state, extra = ckpt["model_args"], ckpt["state_dict"], ckpt.get("extra")
    if version >= 2:
        try:
            digest = content_sha256(model_args, state, extra)
        except InputError as exc:
            raise InputError(f"{path}: holds {exc}") from None
        if digest != ckpt["sha256"]:
            raise InputError(f"{path}: content checksum mismatch (stored sha256 {show(ckpt['sha256'])}, content "
                             f"{digest}): the file is corrupt or was edited")
    else:
        log.warning("%s: format_version 1 carries no checksum, so its content cannot be verified; re-save it "
                    "with this torch_atr to add one", path)
    check_model_args(model_args, f"{path}: model_args")
    _check_state(state, model_args, str(path))
    try:
        _check_plain("extra", extra)
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None
    model = GenerativeShapeModel.from_model_args(model_args)
    # Only the checked tensors go in: a state_dict's ``_metadata`` attribute is unpickled data too
    # (a fuzzed file set it to None, which crashed load_state_dict with a TypeError).
    model.load_state_dict(OrderedDict(state.items()), assign=True)
    return model, extra


def _fit_core_and_identity(rbf: RBFViewMapping, Y: torch.Tensor, theta: torch.Tensor, phi: torch.Tensor,
                           ridge: float, pixel_rank: int | None, labels: torch.Tensor,
                           order: torch.Tensor) -> tuple[TensorCore, IdentityManifold]:
    """Bᵏ in closed form (eq. 4.13), the HOSVD core (eq. 4.14) and the spline through the iᵏ.

    The truncated pixel basis is the principal basis of the training templates Y (K, V, d): it
    keeps the pixel directions the templates need, whereas the mode-1 singular vectors of 𝒞 rank
    them by the RBF weights, which over-weight detail that changes fast with the view (a tank's
    gun): measured on the catalog at r = 128, template IoU 0.99 against 0.90.
    """
    with torch.no_grad():
        B = rbf.fit(theta, phi, Y, ridge)  # (K, d, P)
        basis = None
        if pixel_rank is not None:
            basis, template_error = principal_basis(Y.reshape(-1, Y.shape[-1]), pixel_rank)
            log.info("pixel basis r=%d: relative template error %.4f", basis.shape[1], template_error.item())
        core = TensorCore.from_mappings(B, pixel_basis=basis) if basis is not None else TensorCore.from_mappings(B)
        identity = IdentityManifold.fit(core.identity_vectors, labels, order)
    return core, identity


def fine_tune_widths(rbf: RBFViewMapping, train: torch.Tensor, theta, phi, val: torch.Tensor, val_theta, val_phi,
                     steps: int, lr: float, ridge: float = ModelConfig.ridge) -> list[float]:
    """Tune the kernel widths by Adam on the reconstruction error of held-out views.

    train: (K, V, d) templates at the training views theta, phi: (V,); val: (K, Vv, d) templates
    at the held-out views val_theta, val_phi: (Vv,); steps: Adam steps at learning rate lr on
    log(width); ridge: λ. Returns the validation MSE before each step (length ``steps``); raises
    ValueError, with the widths put back, when the tuning diverges (:func:`_check_tuning`).

    Every step re-solves all Bᵏ in closed form, Bᵏ = Yᵏᵀ W with W = Ψ (ΨᵀΨ + λI)⁻¹ (eq. 4.13),
    so the gradient flows through the solve. The held-out prediction is Hₖ = M Yᵏ with the small
    matrix M = Ψ_val Wᵀ (Vv × V), so the loss Σₖ ‖M Yᵏ − Valᵏ‖² = tr(M G Mᵀ) − 2 tr(M E) + ‖Val‖²
    needs only the Gram matrices G = Σₖ Yᵏ Yᵏᵀ (V × V) and E = Σₖ Yᵏ Valᵏᵀ (V × Vv), computed once:
    a step costs microseconds instead of a K·Vv·V·d contraction. :meth:`GenerativeShapeModel.fit`
    calls this before it solves the mappings it keeps.
    """
    if not isinstance(rbf, RBFViewMapping):
        raise ValueError(f"Expected an RBFViewMapping; got {type(rbf).__name__}")
    like = rbf.log_width
    theta, phi, val_theta, val_phi = (  # a NaN view made eigh fail to converge, or every kernel width NaN
        check_finite(name, as_float_tensor(name, x, like=like).to(like), "radians")
        for name, x in (("theta", theta), ("phi", phi), ("val_theta", val_theta), ("val_phi", val_phi)))
    check_shape("train", train, ("K", theta.shape[0], "d"))
    check_shape("val", val, (train.shape[0], val_theta.shape[0], train.shape[2]))
    with torch.no_grad():  # one vehicle at a time, so no widened copy of the templates is made
        G = torch.zeros(theta.shape[0], theta.shape[0], dtype=like.dtype, device=like.device)  # Σₖ Yᵏ Yᵏᵀ
        E = torch.zeros(theta.shape[0], val_theta.shape[0], dtype=like.dtype, device=like.device)  # Σₖ Yᵏ Valᵏᵀ
        val_energy = torch.zeros((), dtype=like.dtype, device=like.device)
        for k, (Yk, Vk) in enumerate(zip(train, val)):
            Yk, Vk = Yk.to(like), Vk.to(like)
            for name, x in (("train", Yk), ("val", Vk)):  # a NaN made every width NaN
                if not bool(x.isfinite().all()):
                    raise ValueError(f"Expected finite {name} templates; vehicle {k} has "
                                     f"{int((~x.isfinite()).sum())} NaN or infinite value(s)")
            G += Yk @ Yk.T
            E += Yk @ Vk.T
            val_energy += Vk.square().sum()
    count = val.numel()
    optimiser = torch.optim.Adam([rbf.log_width], lr=lr)
    initial = rbf.log_width.detach().clone()
    history = []
    for step in tqdm(range(steps), desc="kernel widths", unit="step", leave=False):
        optimiser.zero_grad()
        W = ridge_hat(rbf(theta, phi), ridge)  # (V, P)
        M = rbf(val_theta, val_phi) @ W.T  # (Vv, V): the held-out prediction is M Yᵏ
        loss = ((M @ G * M).sum() - 2 * (M * E.T).sum() + val_energy) / count  # MSE of M Yᵏ against Valᵏ
        loss.backward()
        optimiser.step()
        history.append(loss.item())
        log.debug("width step %d: validation MSE %.6g", step, history[-1])
        _check_tuning(rbf, initial, step, history[-1], lr)
    return history


def _check_tuning(rbf: RBFViewMapping, initial: torch.Tensor, step: int, loss: float, lr: float) -> None:
    """Raise ValueError, with the widths put back to ``initial``, when width tuning has diverged: a NaN or
    infinite validation MSE, or log widths outside LOG_WIDTH_RANGE. Adam at lr = 10 (model.width_lr's
    bound) went NaN on the test templates, and fit then failed in eigh with an ill-conditioning error; at
    ridge 0 it drifted to log widths of -108, whose exp underflows in float32, and fit returned a model
    that reconstructed NaN."""
    lo, hi = LOG_WIDTH_RANGE
    least, most = rbf.log_width.min().item(), rbf.log_width.max().item()
    if math.isfinite(loss) and lo <= least and most <= hi:
        return
    with torch.no_grad():
        rbf.log_width.copy_(initial)
    raise ValueError(f"kernel-width tuning diverged in step {step + 1}: validation MSE {loss:.6g}, log widths "
                     f"in [{least:.3g}, {most:.3g}] (expected within [{lo:g}, {hi:g}]); lower the learning rate "
                     f"lr = {lr:g} (model.width_lr) or the steps; the widths are left as they were")
