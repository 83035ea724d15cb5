"""The generative model (eq. 4.18) on synthetic signed-distance templates, and its checkpoints."""

import collections
import copy
import enum
import itertools
import math

import numpy as np
import pytest
import torch
from scipy.ndimage import distance_transform_edt

from torch_atr.config import ConfigError, ModelConfig, TemplateConfig, load_config
from torch_atr.model import GenerativeShapeModel, fine_tune_widths, load_checkpoint

TEMPLATE = TemplateConfig(size_px=24, window_m=12.0, tau_px=4.0)
# Ellipsoid semi-axes (length, width, height) in metres and whether a turret sits on top.
VEHICLES = [(2.0, 0.8, 0.6, False), (2.3, 0.9, 0.7, False), (2.6, 1.0, 0.7, True),
            (2.9, 1.1, 0.6, True), (1.8, 0.8, 0.8, False), (3.1, 1.2, 0.5, True)]
CLASSES = [0, 0, 1, 1, 0, 1]
NAMES = [f"v{k}" for k in range(len(VEHICLES))]


def _ellipsoids(a: float, b: float, c: float, turret: bool):
    """(centre, semi-axes) of the body and the turret in the body frame (X fwd, Y left, Z up)."""
    parts = [(np.zeros(3), np.array([a, b, c]))]
    if turret:
        parts.append((np.array([0.2 * a, 0.0, 0.9 * c]), np.array([0.4 * a, 0.6 * b, 0.5 * c])))
    return parts


def synthetic_templates(theta: np.ndarray, phi: np.ndarray) -> torch.Tensor:
    """Orthographic silhouettes of the VEHICLES, clipped signed distance / τ: (K, V, H, W) float32."""
    H, tau = TEMPLATE.size_px, TEMPLATE.tau_px
    coords = (np.arange(H) + 0.5) * TEMPLATE.metres_per_px - TEMPLATE.window_m / 2
    x, y = np.meshgrid(coords, -coords)  # image x right, y up (row 0 at the top)
    pixels = np.stack([x, y], axis=-1)
    out = np.zeros((len(VEHICLES), len(theta), H, H))
    for k, vehicle in enumerate(VEHICLES):
        for m, (th, ph) in enumerate(zip(theta, phi)):
            u = np.array([np.cos(ph) * np.cos(th), np.cos(ph) * np.sin(th), np.sin(ph)])
            right = np.array([-np.sin(th), np.cos(th), 0.0])
            basis = np.stack([right, np.cross(u, right)], axis=1)  # (3, 2) image axes in the body frame
            mask = np.zeros((H, H), dtype=bool)
            for centre, axes in _ellipsoids(*vehicle):
                # The projection of an ellipsoid with shape matrix S is the ellipse with Pᵀ S P.
                shape = basis.T @ np.diag(axes ** 2) @ basis
                offset = pixels - basis.T @ centre
                mask |= np.einsum("...i,ij,...j->...", offset, np.linalg.inv(shape), offset) <= 1.0
            signed = np.where(mask, distance_transform_edt(mask), -distance_transform_edt(~mask))
            out[k, m] = np.clip(signed, -tau, tau) / tau
    return torch.tensor(out, dtype=torch.float32)


def _views(azimuth_offset_deg: float, elevations_deg) -> tuple[torch.Tensor, torch.Tensor]:
    theta = np.deg2rad(np.arange(0.0, 360.0, 30.0) + azimuth_offset_deg)
    T, P = np.meshgrid(theta, np.deg2rad(elevations_deg), indexing="ij")
    return torch.tensor(T.ravel(), dtype=torch.float32), torch.tensor(P.ravel(), dtype=torch.float32)


@pytest.fixture(scope="module")
def data():
    theta, phi = _views(0.0, [0.0, 20.0, 40.0])
    val_theta, val_phi = _views(15.0, [10.0, 30.0])
    return {"theta": theta, "phi": phi, "templates": synthetic_templates(theta.numpy(), phi.numpy()),
            "val_theta": val_theta, "val_phi": val_phi,
            "val": synthetic_templates(val_theta.numpy(), val_phi.numpy())}


def _fit(data, cfg: ModelConfig, **kwargs) -> GenerativeShapeModel:
    return GenerativeShapeModel.fit(data["templates"], data["theta"], data["phi"], NAMES, CLASSES, ["car", "tank"],
                                    TEMPLATE, cfg, **kwargs)


@pytest.fixture(scope="module")
def model(data):
    return _fit(data, ModelConfig(pixel_rank=None, ridge=1e-9))


def _all_views(model, data):
    K, V = data["templates"].shape[:2]
    return model.alphas.repeat_interleave(V), data["theta"].repeat(K), data["phi"].repeat(K)


def _iou(a: torch.Tensor, b: torch.Tensor) -> float:
    return ((a & b).sum() / (a | b).sum()).item()


def test_training_views_are_reproduced_at_alpha_k(model, data):
    with torch.no_grad():
        recon = model(*_all_views(model, data)).reshape(data["templates"].shape)
    assert recon.dtype == torch.float32
    assert (recon - data["templates"]).abs().max() < 1e-3
    assert _iou(recon > 0, data["templates"] > 0) > 0.999


def test_reconstruction_at_alpha_k_is_nearest_to_vehicle_k(model, data):
    K, V = data["templates"].shape[:2]
    with torch.no_grad():
        for k in range(K):
            recon = model(model.alphas[k].expand(V), data["theta"], data["phi"])
            errors = ((data["templates"] - recon) ** 2).mean(dim=(1, 2, 3))
            assert errors.argmin().item() == k


def test_truncated_rank_and_half_step_views(data):
    model = _fit(data, ModelConfig(pixel_rank=40, ridge=1e-4))
    assert model.core.pixel_rank == 40 and 0 < model.core.relative_error.item() < 0.1
    with torch.no_grad():
        train = model(*_all_views(model, data)).reshape(data["templates"].shape)
        K, V = data["val"].shape[:2]
        val = model(model.alphas.repeat_interleave(V), data["val_theta"].repeat(K), data["val_phi"].repeat(K))
    assert _iou(train > 0, data["templates"] > 0) > 0.99
    # Coarse synthetic views (30° x 20° steps, vehicles ~10 px long): halfway views stay close.
    assert _iou(val.reshape(data["val"].shape) > 0, data["val"] > 0) > 0.8


def test_identity_metadata_and_classes(model):
    assert model.vehicle_names == NAMES and model.vehicle_classes == CLASSES and model.class_names == ["car", "tank"]
    assert model.classify(model.alphas).tolist() == CLASSES
    torch.testing.assert_close(model.nearest_vehicles(model.alphas, k=1)[:, 0], torch.arange(6))
    # The default class penalty keeps each class on one arc.
    assert sorted(c for c, _, _ in model.identity.class_arcs()) == [0, 1]


def test_batched_forward_equals_loop(model):
    g = torch.Generator().manual_seed(0)
    alpha, theta, phi = torch.rand(3, 8, generator=g) * torch.tensor([[7.0], [7.0], [1.4]])
    with torch.no_grad():
        batched = model(alpha, theta, phi)
        for n in range(8):
            torch.testing.assert_close(batched[n], model(alpha[n:n + 1], theta[n:n + 1], phi[n:n + 1])[0])
        assert torch.equal(model.silhouette(alpha, theta, phi), batched > 0)


def test_reconstruct_vehicle_uses_identity_vector(model, data):
    with torch.no_grad():
        for k in (0, 3):
            torch.testing.assert_close(model.reconstruct_vehicle(k, data["theta"], data["phi"]),
                                       data["templates"][k], atol=1e-3, rtol=0)
    for bad in (6, 1.5, True):  # 1.5 indexed the identity vectors and failed in torch
        with pytest.raises(ValueError, match="Expected a whole vehicle index in"):
            model.reconstruct_vehicle(bad, data["theta"], data["phi"])
    torch.testing.assert_close(model.reconstruct_vehicle(np.int64(1), data["theta"], data["phi"]),
                               model.reconstruct_vehicle(1, data["theta"], data["phi"]))


def test_forward_rejects_mismatched_queries(model):
    with pytest.raises(ValueError, match="one length"):
        model(torch.zeros(3), torch.zeros(3), torch.zeros(2))


def test_queries_must_be_finite_and_submodules_take_any_float(model):
    theta, phi = torch.tensor([0.3, 2.0]), torch.tensor([0.1, 0.4])
    for bad in (math.nan, math.inf):  # a NaN α reconstructed NaN and classified as the first class
        alpha = torch.tensor([bad, 1.0])
        for query in (lambda: model(alpha, theta, phi), lambda: model.classify(alpha),
                      lambda: model.nearest_vehicles(alpha)):
            with pytest.raises(ValueError, match="Expected alpha to be finite"):
                query()
    # The RBF mapping and the identity manifold alone take float64 queries (they raised a dtype error).
    torch.testing.assert_close(model.rbf(theta.double(), phi.double()), model.rbf(theta, phi))
    torch.testing.assert_close(model.identity(model.alphas[:2].double()), model.identity(model.alphas[:2]))
    assert torch.equal(model.identity.classify(model.alphas.double()), model.identity.labels)
    with pytest.raises(ValueError, match="whole k"):
        model.nearest_vehicles(model.alphas[:2], k=2.5)
    two = model.alphas[:2]
    assert torch.equal(model.nearest_vehicles(two, k=np.int64(2)), model.nearest_vehicles(two))  # numpy's integers
    size = model.template.size_px
    torch.testing.assert_close(model.project(np.zeros((size, size)).tolist()), model.project(torch.zeros(size, size)))


def test_gradients_reach_alpha_view_and_widths(model):
    model64 = GenerativeShapeModel.from_model_args(model.model_args).double()
    model64.load_state_dict(model.state_dict())
    alpha = torch.tensor([0.4, 2.0, 5.5], dtype=torch.float64, requires_grad=True)
    theta = torch.tensor([0.1, 3.0, 4.0], dtype=torch.float64, requires_grad=True)
    phi = torch.tensor([0.1, 0.3, 0.6], dtype=torch.float64, requires_grad=True)
    model64(alpha, theta, phi).square().sum().backward()
    for grad in (alpha.grad, theta.grad, phi.grad, model64.rbf.log_width.grad):
        assert grad is not None and torch.isfinite(grad).all() and grad.abs().max() > 0
    check = lambda a, t, p: model64(a, t, p)[:, 10:14, 10:14]
    inputs = tuple(x.detach()[:2].requires_grad_(True) for x in (alpha, theta, phi))
    assert torch.autograd.gradcheck(check, inputs)


def test_float64_conversion_and_state_dict_rebuild(model):
    g = torch.Generator().manual_seed(1)
    alpha, theta, phi = torch.rand(3, 5, generator=g)
    model64 = GenerativeShapeModel.from_model_args(model.model_args)
    model64.load_state_dict(model.state_dict())
    model64 = model64.to(torch.float64)
    assert all(t.dtype == torch.float64 for t in model64.state_dict().values() if t.is_floating_point())
    with torch.no_grad():
        torch.testing.assert_close(model64(alpha.double(), theta.double(), phi.double()).float(),
                                   model(alpha, theta, phi), atol=1e-4, rtol=0)
    expected = {"rbf.centres_theta", "rbf.centres_phi", "rbf.log_width", "core.core", "core.identity_vectors",
                "core.relative_error", "identity.knots", "identity.coefficients", "identity.alphas",
                "identity.order", "identity.labels"}
    assert set(model.state_dict()) == expected


def test_checkpoint_round_trip_is_exact(model, tmp_path):
    path = tmp_path / "model.pt"
    model.save(path, extra={"note": "synthetic", "views": torch.arange(3), "nested": [1, 2.5, None]})
    raw = torch.load(path, weights_only=True)
    assert raw["format"] == "torch_atr.generative" and raw["format_version"] == 2 and len(raw["sha256"]) == 64
    assert raw["model_args"]["template"] == {"size_px": 24, "window_m": 12.0, "tau_px": 4.0}
    loaded, extra = load_checkpoint(path)
    assert extra["note"] == "synthetic" and torch.equal(extra["views"], torch.arange(3))
    assert loaded.vehicle_names == NAMES and loaded.vehicle_classes == CLASSES and loaded.template == TEMPLATE
    g = torch.Generator().manual_seed(2)
    alpha, theta, phi = torch.rand(3, 6, generator=g)
    with torch.no_grad():
        assert torch.equal(loaded(alpha, theta, phi), model(alpha, theta, phi))
    model64 = GenerativeShapeModel.from_model_args(model.model_args).double()
    model64.load_state_dict(model.state_dict())
    model64.save(tmp_path / "model64.pt")
    assert GenerativeShapeModel.from_checkpoint(tmp_path / "model64.pt").core.core.dtype == torch.float64


def test_state_dict_metadata_is_not_trusted(model, tmp_path):
    """A file's state_dict carries an unpickled ``_metadata``; junk there (found by the fuzz suite:
    ``{"rbf": None}``) must not reach load_state_dict, which raised a TypeError on it."""
    path = tmp_path / "model.pt"
    model.save(path)
    raw = torch.load(path, weights_only=True)
    raw["state_dict"]._metadata = {"": None, "rbf": None}
    torch.save(raw, path)
    loaded, _ = load_checkpoint(path)
    assert torch.equal(loaded.core.core, model.core.core)


def test_save_rejects_non_plain_extra(model, tmp_path):
    with pytest.raises(ValueError, match=r"extra\['obj'\] holds a object"):
        model.save(tmp_path / "x.pt", extra={"obj": object()})
    pair = collections.namedtuple("pair", "a b")  # passed as a tuple, then crashed rebuilding it
    with pytest.raises(ValueError, match=r"extra\['p'\] holds a pair; checkpoints store only tensors and plain data"):
        model.save(tmp_path / "x.pt", extra={"p": pair(1, 2)})
    # Subclasses of float and int passed as plain and were written, and then load_checkpoint refused the file.
    with pytest.raises(ValueError, match=r"extra\['iou'\] holds a float64; checkpoints store only tensors and plain"):
        model.save(tmp_path / "x.pt", extra={"iou": np.float64(0.9)})
    with pytest.raises(ValueError, match=r"extra\[.mode.\]\[0\] holds a Mode; checkpoints store only"):
        model.save(tmp_path / "x.pt", extra={"mode": [enum.IntEnum("Mode", "A B").B]})
    with pytest.raises(ValueError, match=r"extra\['iou'\] has a non-string key (np.str_\()?'tank'\)? of type str_$"):
        model.save(tmp_path / "x.pt", extra={"iou": {np.str_("tank"): 0.9}})
    assert not (tmp_path / "x.pt").exists()


def test_checkpoint_errors_name_file_and_problem(model, tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        GenerativeShapeModel.from_checkpoint(tmp_path / "missing.pt")
    good = tmp_path / "good.pt"
    model.save(good)
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(np.random.default_rng(0).bytes(4096))
    for path in (truncated, garbage):
        with pytest.raises(ValueError, match=rf"{path.name}.*not a readable checkpoint"):
            GenerativeShapeModel.from_checkpoint(path)
    # Version 1 payloads (no checksum) reach the structural checks with any content.
    ckpt = {k: v for k, v in torch.load(good, weights_only=True).items() if k != "sha256"} | {"format_version": 1}
    cases = {
        "other.pt": ({"weights": torch.zeros(2)}, "not a torch_atr.generative checkpoint"),
        "keys.pt": ({"format": "torch_atr.generative", "format_version": 2}, "lacks model_args, sha256, state_dict"),
        "newer.pt": ({**ckpt, "format_version": 3}, "format_version 3 is not supported"),
        "bool_version.pt": ({**ckpt, "format_version": True}, "format_version True is not a version number"),
        "args.pt": ({**ckpt, "model_args": {**ckpt["model_args"], "num_centres": "36"}},
                    r"model_args\['num_centres'\]: expected an integer in \[1, 10000\]; got '36'"),
        "missing_key.pt": ({**ckpt, "state_dict": {k: v for k, v in ckpt["state_dict"].items()
                                                   if k != "core.core"}}, "state_dict does not match.*core.core"),
        "shape.pt": ({**ckpt, "model_args": {**ckpt["model_args"], "num_centres": 30}},
                     r"state_dict does not match model_args: rbf.centres_theta has shape \(36,\); model_args call "
                     r"for \(30,\)"),
        "labels.pt": ({**ckpt, "model_args": {**ckpt["model_args"], "vehicle_classes": [1, 0, 0, 1, 1, 0]}},
                      "differ from model_args"),
    }
    for name, (payload, message) in cases.items():
        torch.save(payload, tmp_path / name)
        with pytest.raises(ValueError, match=rf"(?s){name}: .*{message}"):
            GenerativeShapeModel.from_checkpoint(tmp_path / name)


def test_fine_tune_widths_lowers_validation_error(data):
    K, V = data["templates"].shape[:2]
    rbf = _fit(data, ModelConfig(pixel_rank=None, ridge=1e-4)).double().rbf
    train = data["templates"].double().reshape(K, V, -1)
    val = data["val"].double().reshape(K, data["val"].shape[1], -1)
    before = rbf.widths.detach().clone()
    history = fine_tune_widths(rbf, train, data["theta"], data["phi"], val, data["val_theta"].tolist(),
                               data["val_phi"].numpy(), steps=15, lr=0.05)  # views as tensors, lists, arrays
    assert len(history) == 15 and history[-1] < history[0]
    assert not torch.equal(rbf.widths, before)
    with pytest.raises(ValueError, match="RBFViewMapping"):
        fine_tune_widths(object(), train, data["theta"], data["phi"], val, data["val_theta"], data["val_phi"], 1, 0.1)


@pytest.mark.parametrize("ridge", [1e-4, 0.0])
def test_diverged_width_tuning_is_refused_not_fitted(data, ridge):
    """Adam at lr = 10 (model.width_lr's bound) went NaN at ridge 1e-4, and fit failed in eigh with an
    ill-conditioning error; at ridge 0 the log widths drifted to about -108, whose exp underflows in
    float32, and fit returned a model that reconstructed NaN. Both are a ValueError naming the rate."""
    cfg = ModelConfig(pixel_rank=20, ridge=ridge, width_steps=50, width_lr=10.0)
    with pytest.raises(ValueError, match=r"kernel-width tuning diverged in step \d+: validation MSE .*, log widths in "
                                         r"\[.*\] \(expected within \[-20, 20\]\); lower the learning rate lr = 10 "
                                         r"\(model.width_lr\)"):
        _fit(data, cfg, val_templates=data["val"], val_theta=data["val_theta"], val_phi=data["val_phi"])
    K, V = data["templates"].shape[:2]
    rbf = _fit(data, ModelConfig(pixel_rank=None, ridge=ridge)).double().rbf
    before = rbf.log_width.detach().clone()
    with pytest.raises(ValueError, match="kernel-width tuning diverged"):
        fine_tune_widths(rbf, data["templates"].double().reshape(K, V, -1), data["theta"], data["phi"],
                         data["val"].double().reshape(K, data["val"].shape[1], -1), data["val_theta"],
                         data["val_phi"], steps=50, lr=10.0, ridge=ridge)
    assert torch.equal(rbf.log_width, before)  # left as they were


@pytest.mark.parametrize("log_width", [20.5, -20.5, 0.0])
def test_width_tuning_check_bounds_log_widths_on_both_sides(log_width):
    """LOG_WIDTH_RANGE = (-20, 20) is closed on both ends: one log width past either end (a finite MSE)
    is refused with the widths put back; within it nothing changes (the runs above only hit the low end)."""
    from torch_atr.model.generative import LOG_WIDTH_RANGE, RBFViewMapping, _check_tuning

    assert LOG_WIDTH_RANGE == (-20.0, 20.0)
    rbf = RBFViewMapping(torch.tensor([0.0, 1.0, 2.0]), torch.zeros(3), init_width=0.5)
    initial = rbf.log_width.detach().clone()
    with torch.no_grad():
        rbf.log_width[1] = log_width
    if log_width == 0.0:
        _check_tuning(rbf, initial, 0, 0.1, 0.05)
        assert rbf.log_width[1].item() == 0.0
        return
    with pytest.raises(ValueError, match=r"diverged in step 1: validation MSE 0.1, log widths in .*expected within "
                                         r"\[-20, 20\]"):
        _check_tuning(rbf, initial, 0, 0.1, 0.05)
    assert torch.equal(rbf.log_width, initial)


def test_fine_tune_widths_loss_is_the_mse_of_explicit_mappings(data):
    """The Gram-matrix loss equals the MSE of explicitly solved Bᵏ applied at the held-out views."""
    K, V = data["templates"].shape[:2]
    model = _fit(data, ModelConfig(pixel_rank=None, ridge=1e-3)).double()
    train = data["templates"].double().reshape(K, V, -1)
    val = data["val"].double().reshape(K, data["val"].shape[1], -1)
    theta, phi, val_theta, val_phi = (x.double() for x in (data["theta"], data["phi"], data["val_theta"],
                                                           data["val_phi"]))
    with torch.no_grad():
        B = model.rbf.fit(theta, phi, train, 1e-3)  # (K, d, P)
        pred = torch.einsum("kdp,up->kud", B, model.rbf(val_theta, val_phi))
        direct = ((pred - val) ** 2).mean().item()
    history = fine_tune_widths(model.rbf, train, theta, phi, val, val_theta, val_phi, steps=1, lr=1e-9, ridge=1e-3)
    assert history[0] == pytest.approx(direct, rel=1e-8)


def test_fit_tunes_widths_when_asked(data):
    cfg = ModelConfig(pixel_rank=None, ridge=1e-4, width_steps=5, width_lr=0.05)
    with pytest.raises(ValueError, match="needs val_templates"):
        _fit(data, cfg)
    with pytest.raises(ValueError, match=r"Expected signed-distance val_templates \(floating\); got dtype torch.bool"):
        _fit(data, cfg, val_templates=data["val"] > 0, val_theta=data["val_theta"], val_phi=data["val_phi"])
    tuned = _fit(data, cfg, val_templates=data["val"], val_theta=data["val_theta"], val_phi=data["val_phi"])
    untuned = _fit(data, ModelConfig(pixel_rank=None, ridge=1e-4))
    assert tuned.rbf.widths.std() > 0  # one width per centre, tuned apart from the shared initial value
    assert len(tuned.width_history) == 5 and not untuned.width_history

    def val_error(model):
        with torch.no_grad():
            recon = torch.stack([model.reconstruct_grid(model.alphas[k:k + 1], data["val_theta"], data["val_phi"])[0]
                                 for k in range(len(NAMES))])
        return ((recon - data["val"]) ** 2).mean().item()

    assert val_error(tuned) < val_error(untuned)
    # The kept mappings are the closed form at the tuned widths (the core was built after tuning).
    K, V = data["templates"].shape[:2]
    rbf = tuned.rbf.double()
    B = rbf.fit(data["theta"].double(), data["phi"].double(), data["templates"].double().reshape(K, V, -1), 1e-4)
    with torch.no_grad():
        for k in range(K):
            Bk = torch.einsum("dpj,j->dp", tuned.core.core.double(), tuned.core.identity_vectors[k].double())
            torch.testing.assert_close(Bk, B[k], rtol=1e-4, atol=1e-4)


def test_fit_tunes_widths_at_the_configured_ridge(data):
    """fit's first validation MSE is that of numpy ridge regression at cfg.ridge (λ = 0.5, far from the
    default 1e-4 that fine_tune_widths falls back to): Ψ a direct Gaussian kernel sum at the default
    width (mean nearest-centre chord), each Bᵏ np.linalg.lstsq on [Ψ; √λ I] b = [y; 0]."""
    ridge = 0.5
    cfg = ModelConfig(pixel_rank=None, ridge=ridge, width_steps=1, width_lr=1e-9)
    model = _fit(data, cfg, val_templates=data["val"], val_theta=data["val_theta"], val_phi=data["val_phi"])

    def unit(theta, phi):
        t, p = theta.double().numpy(), phi.double().numpy()
        return np.stack([np.cos(p) * np.cos(t), np.cos(p) * np.sin(t), np.sin(p)], axis=1)

    centres, val_u = unit(data["theta"], data["phi"]), unit(data["val_theta"], data["val_phi"])
    chords = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    np.fill_diagonal(chords, np.inf)
    width = chords.min(axis=1).mean()

    def psi(u):
        r2 = ((u[:, None] - centres[None]) ** 2).sum(-1)
        return np.hstack([np.exp(-r2 / (2 * width ** 2)), np.ones((len(u), 1)), u])

    train_psi, val_psi = psi(centres), psi(val_u)
    P = train_psi.shape[1]
    A = np.vstack([train_psi, math.sqrt(ridge) * np.eye(P)])
    K, V = data["templates"].shape[:2]
    Y = data["templates"].double().reshape(K, V, -1).numpy()
    val = data["val"].double().reshape(K, data["val"].shape[1], -1).numpy()
    errors = []
    for Yk, Vk in zip(Y, val):
        b = np.linalg.lstsq(A, np.vstack([Yk, np.zeros((P, Yk.shape[1]))]), rcond=None)[0]  # (P, d)
        errors.append((val_psi @ b - Vk) ** 2)
    assert model.width_history[0] == pytest.approx(float(np.mean(errors)), rel=1e-6)


def test_fit_uses_the_configured_init_width(data):
    """cfg.init_width s is every kept kernel width (untuned), and Ψ at the training views is the direct
    Gaussian kernel sum exp(−‖u − cₗ‖² / (2 s²)) at that width, in numpy (float32 model: atol 2e-6)."""
    model = _fit(data, ModelConfig(pixel_rank=None, ridge=1e-9, init_width=0.3))
    torch.testing.assert_close(model.rbf.widths, torch.full((len(data["theta"]),), 0.3))
    t, p = data["theta"].double().numpy(), data["phi"].double().numpy()
    u = np.stack([np.cos(p) * np.cos(t), np.cos(p) * np.sin(t), np.sin(p)], axis=1)
    psi = np.hstack([np.exp(-((u[:, None] - u[None]) ** 2).sum(-1) / (2 * 0.3 ** 2)), np.ones((len(u), 1)), u])
    with torch.no_grad():
        got = model.rbf(data["theta"], data["phi"]).double().numpy()
    np.testing.assert_allclose(got[:, :len(u)], np.where(psi[:, :len(u)] >= 1e-9, psi[:, :len(u)], 0.0), atol=2e-6)


def test_fit_orders_vehicles_at_the_configured_class_penalty(data):
    """With class_penalty 0 the order is the brute-force shortest closed tour of D₀ (a double loop of
    per-view template distances), which splits the classes [0, 0, 1, 0, 1, 1]; the default penalty keeps
    each class contiguous instead."""
    classes = [0, 0, 1, 0, 1, 1]
    K, V = data["templates"].shape[:2]
    Y = data["templates"].double().reshape(K, V, -1).numpy()
    D0 = np.array([[sum(np.linalg.norm(Y[u, m] - Y[v, m]) for m in range(V)) for v in range(K)] for u in range(K)])

    def cost(tour):
        return sum(D0[tour[i], tour[(i + 1) % K]] for i in range(K))

    best = min(((0, *p) for p in itertools.permutations(range(1, K)) if p[0] < p[-1]), key=cost)
    assert sum(classes[best[i]] != classes[best[i - 1]] for i in range(K)) > 2  # not contiguous

    def order(penalty):
        model = GenerativeShapeModel.fit(data["templates"], data["theta"], data["phi"], NAMES, classes,
                                         ["car", "tank"], TEMPLATE, ModelConfig(pixel_rank=None, class_penalty=penalty))
        return model.identity.order.tolist()

    assert order(0.0) == list(best)
    contiguous = order(None)
    assert sum(classes[contiguous[i]] != classes[contiguous[i - 1]] for i in range(K)) == 2


def test_fit_rejects_bad_inputs(data):
    with pytest.raises(ValueError, match="templates"):
        GenerativeShapeModel.fit(data["templates"][..., :20], data["theta"], data["phi"], NAMES, CLASSES,
                                 ["car", "tank"], TEMPLATE)
    with pytest.raises(ValueError, match="6 vehicle names"):
        GenerativeShapeModel.fit(data["templates"], data["theta"], data["phi"], NAMES[:5], CLASSES,
                                 ["car", "tank"], TEMPLATE)
    with pytest.raises(ValueError, match="out of range"):
        GenerativeShapeModel.fit(data["templates"], data["theta"], data["phi"], NAMES, CLASSES, ["car"], TEMPLATE)
    for names in (["car", "tank"] * 3, np.array(["car", "tank"] * 3)):  # a list or an array of names
        with pytest.raises(ValueError, match=r"vehicle_classes as indices into class_names; got names \['car'"):
            GenerativeShapeModel.fit(data["templates"], data["theta"], data["phi"], NAMES, names, ["car", "tank"],
                                     TEMPLATE)
    for classes in (np.array([0.4, 0, 1.9, 1, 0, 1]), torch.tensor([0, 0, 1, 1, 0, math.nan]), [True, False] * 3):
        with pytest.raises(ValueError, match=r"vehicle_classes as whole indices into class_names; got \["):
            GenerativeShapeModel.fit(data["templates"], data["theta"], data["phi"], NAMES, classes, ["car", "tank"],
                                     TEMPLATE)
    bad = data["templates"].clone()
    bad[1, 2, 3, 4] = math.nan
    with pytest.raises(ValueError, match=r"Expected templates to be finite; 1 value\(s\) are NaN or infinite"):
        GenerativeShapeModel.fit(bad, data["theta"], data["phi"], NAMES, CLASSES, ["car", "tank"], TEMPLATE)


@pytest.mark.parametrize("key, message", [
    ("theta", r"Expected theta to be finite radians; 1 value\(s\) are NaN or infinite"),
    ("phi", r"Expected phi to be finite radians; 1 value"),
    ("centres", r"Expected centres_theta to be finite radians; 1 value"),
    ("val_theta", r"Expected val_theta to be finite radians; 1 value"),
    ("val_phi", r"Expected val_phi to be finite radians; 1 value"),
    ("val", r"Expected finite val templates; vehicle 0 has 1 NaN or infinite value\(s\)"),
])
def test_fit_rejects_non_finite_views_and_validation_templates(data, key, message):
    # A NaN view made eigh fail to converge (LinAlgError); a NaN validation template made every width NaN.
    inputs = {name: data[name].clone() for name in ("theta", "phi", "val_theta", "val_phi", "val")}
    inputs["centres"] = data["theta"].clone()
    inputs[key].view(-1)[1] = math.inf if key == "phi" else math.nan
    with pytest.raises(ValueError, match=message):
        GenerativeShapeModel.fit(data["templates"], inputs["theta"], inputs["phi"], NAMES, CLASSES, ["car", "tank"],
                                 TEMPLATE, ModelConfig(pixel_rank=None, ridge=1e-9, width_steps=2),
                                 centres=(inputs["centres"], data["phi"]), val_templates=inputs["val"],
                                 val_theta=inputs["val_theta"], val_phi=inputs["val_phi"])


@pytest.mark.parametrize("key", ["phi", "centres_phi", "val_phi"])
def test_fit_refuses_elevations_in_degrees(data, key):
    """Elevations given in degrees (0, 20, 40) fitted, without a word, a model of meaningless views (cos 40 < 0
    put the top row on the far side); an elevation is in [-π/2, π/2] radians, the zenith included."""
    views = {name: data[name] for name in ("phi", "val_phi")}
    views["centres_phi"] = data["phi"]
    views[key] = views[key].rad2deg()
    with pytest.raises(ValueError, match=rf"Expected {key} to be elevations in \[-π/2, π/2\] radians; got values "
                                         r"up to [34]0 \(degrees\?\)"):
        GenerativeShapeModel.fit(data["templates"], data["theta"], views["phi"], NAMES, CLASSES, ["car", "tank"],
                                 TEMPLATE, ModelConfig(pixel_rank=8, width_steps=1),
                                 centres=(data["theta"], views["centres_phi"]), val_templates=data["val"],
                                 val_theta=data["val_theta"], val_phi=views["val_phi"])
    zenith = torch.full_like(data["phi"], math.pi / 2).where(data["phi"] > 0.6, data["phi"])  # the top row at 90°
    GenerativeShapeModel.fit(data["templates"], data["theta"], zenith, NAMES, CLASSES, ["car", "tank"], TEMPLATE,
                             ModelConfig(pixel_rank=8))


@pytest.mark.parametrize("key", ["theta", "val_theta", "train", "val"])
def test_fine_tune_widths_rejects_non_finite_inputs(model, data, key):
    inputs = {"theta": data["theta"].clone(), "val_theta": data["val_theta"].clone(),
              "train": data["templates"].flatten(2).clone(), "val": data["val"].flatten(2).clone()}
    inputs[key].view(-1)[-1] = math.nan
    rbf = copy.deepcopy(model.rbf)
    before = rbf.log_width.detach().clone()
    with pytest.raises(ValueError, match=rf"{key}.* NaN or infinite"):
        fine_tune_widths(rbf, inputs["train"], inputs["theta"], data["phi"], inputs["val"], inputs["val_theta"],
                         data["val_phi"], 2, 0.01)
    assert torch.equal(rbf.log_width.detach(), before)  # refused before any step


def test_names_must_be_distinct(data):
    """A class named twice was two classes: recognition_accuracy wanted class_names.index (the first)
    where classify gave the second, a truth start drew α on the first's arcs only and the tracker's
    p_<class> columns overwrote each other. A vehicle named twice re-rendered one mesh for both."""
    with pytest.raises(ValueError, match=r"Expected class_names to be distinct; \['car'\] repeat\(s\) in "
                                         r"\['car', 'car'\]"):
        GenerativeShapeModel.fit(data["templates"], data["theta"], data["phi"], NAMES, CLASSES, ["car", "car"],
                                 TEMPLATE, ModelConfig(pixel_rank=8))
    with pytest.raises(ValueError, match=r"Expected vehicle_names to be distinct; \['v0'\] repeat"):
        GenerativeShapeModel.fit(data["templates"], data["theta"], data["phi"], ["v0"] * len(NAMES), CLASSES,
                                 ["car", "tank"], TEMPLATE, ModelConfig(pixel_rank=8))
    with pytest.raises(ValueError, match=r"Expected class_names to be a list of names; got the single string 'ab'"):
        GenerativeShapeModel.fit(data["templates"], data["theta"], data["phi"], NAMES, CLASSES, "ab",
                                 TEMPLATE, ModelConfig(pixel_rank=8))


def test_model_config_from_yaml_and_overrides(tmp_path):
    path = tmp_path / "model.yaml"
    path.write_text("pixel_rank: null\nridge: 0.001\n", encoding="utf-8")
    cfg = load_config(ModelConfig, path, ["width_steps=20"])
    assert cfg == ModelConfig(pixel_rank=None, ridge=1e-3, width_steps=20)
    with pytest.raises(ConfigError, match="pixel_rank"):
        load_config(ModelConfig, overrides=["pixel_rank=0"])
    with pytest.raises(ConfigError, match="unknown config key"):
        load_config(ModelConfig, overrides=["rank=3"])


def test_reconstruct_grid_equals_per_query_forward(model, data):
    g = torch.Generator().manual_seed(5)
    alpha = torch.rand(4, generator=g) * 2 * math.pi
    theta, phi = torch.rand(3, generator=g) * 6.2, torch.rand(3, generator=g) * 0.7
    grid = model.reconstruct_grid(alpha, theta, phi)
    assert grid.shape == (4, 3, *data["templates"].shape[2:])
    for a in range(4):
        for v in range(3):
            single = model(alpha[a:a + 1], theta[v:v + 1], phi[v:v + 1])[0]
            torch.testing.assert_close(grid[a, v], single, rtol=1e-5, atol=1e-5)


def test_queries_of_another_dtype_or_type_are_converted(model):
    g = torch.Generator().manual_seed(1)
    alpha, theta, phi = torch.rand(3, generator=g), torch.rand(3, generator=g) * 6, torch.rand(3, generator=g)
    expected = model(alpha, theta, phi)
    torch.testing.assert_close(model(alpha.double(), theta.double().numpy(), phi.tolist()), expected)
    assert torch.equal(model.classify(alpha.double()), model.classify(alpha))

