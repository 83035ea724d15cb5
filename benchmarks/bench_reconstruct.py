"""Batched reconstruction y(α, Θ) (eq. 4.18) against a naive per-query loop over the full tensor.

Two models reconstruct N random (α, θ, φ) queries each: the shipped checkpoint (``--checkpoint``)
and a model with random contents of the requested sizes (K vehicles, Nc = V centres on the
training-view grid, H = W pixels, pixel rank r). The shipped model's trained kernel widths make
most of Ψ(Θ) tiny, which a random model does not show (the denormal pitfall of METHOD.md). The
naive reference evaluates 𝒜 ×₃ i(α) ×₂ Ψ(Θ) one query at a time on the full d × P × K core (no
pixel basis) for a subset of queries, scaled to N. Rates are reported against a dense float32
matmul measured in the same run.

    python benchmarks/bench_reconstruct.py --vehicles 36 --size 64 --rank 128 --batch 4096
"""

from __future__ import annotations

import argparse
import logging
import math
import time

import torch

from torch_atr.cli import run_main
from torch_atr.config import ConfigError, TemplateConfig
from torch_atr.model import GenerativeShapeModel, IdentityManifold, RBFViewMapping, TensorCore, mode_product

from benchlib import SHIPPED, check_at_least

log = logging.getLogger("bench_reconstruct")


def timed(fn, repeats: int) -> float:
    """Best wall time of ``fn()`` in seconds over ``repeats`` runs after one warm-up.

    The minimum, not the mean: on a shared machine other processes only ever add time.
    """
    fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def random_model(K: int, azimuths: int, elevations: int, size: int, rank: int, g: torch.Generator
                 ) -> GenerativeShapeModel:
    """A model of the requested sizes with a random core, orthonormal bases and a random class per vehicle."""
    theta = torch.arange(azimuths).repeat(elevations) * (2 * math.pi / azimuths)
    phi = torch.arange(elevations).repeat_interleave(azimuths) * math.radians(10.0)
    rbf = RBFViewMapping(theta, phi)  # Nc = V, centres at the training views
    d = size * size
    core = TensorCore(d, rbf.psi_dim, K, rank)
    core.core.copy_(torch.randn(core.core.shape, generator=g))
    core.pixel_basis.copy_(torch.linalg.qr(torch.randn(d, rank, generator=g))[0])
    core.identity_vectors.copy_(torch.linalg.qr(torch.randn(K, K, generator=g))[0])
    labels = torch.randint(0, 4, (K,), generator=g)
    identity = IdentityManifold.fit(core.identity_vectors, labels, torch.arange(K))
    return GenerativeShapeModel(rbf, core, identity, [f"vehicle{k}" for k in range(K)],
                                ["tank", "apc", "suv", "pickup"], TemplateConfig(size_px=size))


def bench(model: GenerativeShapeModel, label: str, N: int, n_naive: int, repeats: int, matmul_rate: float,
          g: torch.Generator) -> None:
    """Time the reconstruction stages of ``model`` on N random queries and log a table."""
    K, r, P = model.core.num_vehicles, model.core.pixel_rank, model.rbf.psi_dim
    d = model.core.pixels
    alpha = torch.rand(N, generator=g) * 2 * math.pi
    theta = torch.rand(N, generator=g) * 2 * math.pi
    phi = torch.rand(N, generator=g) * math.radians(40.0)
    with torch.no_grad():
        identity, psi = model.identity(alpha), model.rbf(theta, phi)
        A = model.core.core  # (r, P, K)
        rows = [
            ("Ψ(Θ)", timed(lambda: model.rbf(theta, phi), repeats), 0.0),
            ("i(α)", timed(lambda: model.identity(alpha), repeats), 0.0),
            ("core: Ψ first (ours)", timed(lambda: model.core.reconstruct(identity, psi), repeats),
             2 * N * P * K * r + 2 * N * K * r + 2 * N * r * d),
            # The other order materialises 𝒜 ×₃ i per query: N × r × P.
            ("core: identity first", timed(lambda: torch.bmm(torch.einsum("rpk,nk->nrp", A, identity),
                                                            psi.unsqueeze(-1)).squeeze(-1) @ model.core.pixel_basis.T,
                                           repeats), 2 * N * r * P * K + 2 * N * r * P + 2 * N * r * d),
            ("forward (α, θ, φ) total", timed(lambda: model(alpha, theta, phi), repeats),
             2 * N * P * K * r + 2 * N * K * r + 2 * N * r * d),
        ]
        # Naive eq. 4.18 on the full core 𝒜 ×₁ U₁ (d × P × K), one query at a time.
        A_full = mode_product(A, model.core.pixel_basis, 0)
        n = min(n_naive, N)

        def naive() -> torch.Tensor:
            return torch.stack([mode_product(A_full, identity[q], 2) @ psi[q] for q in range(n)])

        t_naive = timed(naive, repeats) * N / n
        rows.append((f"naive per query (x{N / n:.0f} from {n})", t_naive, N * (2 * d * P * K + 2 * d * P)))
        error = (naive() - model.core.reconstruct(identity[:n], psi[:n])).abs().max().item()
    log.info("%s: K=%d Nc=%d P=%d d=%d r=%d N=%d threads=%d", label, K, P - 4, P, d, r, N, torch.get_num_threads())
    log.info("%-34s %10s %9s %9s %8s %9s", "stage", "time ms", "GFLOP", "GFLOP/s", "of mm", "speed-up")
    for name, seconds, flops in rows:
        rate = flops / seconds / 1e9
        log.info("%-34s %10.2f %9.2f %9.1f %7.0f%% %8.1fx", name, 1e3 * seconds, flops / 1e9, rate,
                 100 * rate / matmul_rate, t_naive / seconds)
    log.info("max |naive - batched| over %d queries: %.2e", n, error)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", default=str(SHIPPED), help="a trained model to time (default: the shipped one)")
    parser.add_argument("--vehicles", type=int, default=36, help="K of the random model")
    parser.add_argument("--azimuths", type=int, default=30, help="training azimuths (12° steps)")
    parser.add_argument("--elevations", type=int, default=5, help="training elevations (10° steps); V = Nc = product")
    parser.add_argument("--size", type=int, default=64, help="H = W template pixels")
    parser.add_argument("--rank", type=int, default=128, help="r of the pixel basis")
    parser.add_argument("--batch", type=int, default=4096, help="N queries")
    parser.add_argument("--naive", type=int, default=64, help="queries in the naive per-query loop")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs of each stage (the best counts)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random model and the queries")
    args = parser.parse_args(argv)
    check_at_least("vehicles", args.vehicles, 2)  # a closed identity manifold
    for flag in ("azimuths", "elevations", "batch", "naive", "repeats"):
        check_at_least(flag, getattr(args, flag), 1)
    if args.azimuths * args.elevations < 2:
        raise ConfigError(f"--azimuths x --elevations must be at least 2 views (the RBF centres); got "
                          f"{args.azimuths} x {args.elevations}")
    try:
        TemplateConfig(size_px=args.size)
    except ConfigError as exc:
        raise ConfigError(f"--size {args.size}: {exc}") from None
    if not 1 <= args.rank <= args.size ** 2:
        raise ConfigError(f"--rank must be in [1, --size squared = {args.size ** 2}]; got {args.rank}")
    shipped = GenerativeShapeModel.from_checkpoint(args.checkpoint)
    logging.basicConfig(level=logging.INFO, format="%(message)s")

    g = torch.Generator().manual_seed(args.seed)
    a = torch.randn(2048, 2048, generator=g)
    t_matmul = timed(lambda: a @ a, 2 * args.repeats)
    matmul_rate = 2 * 2048 ** 3 / t_matmul / 1e9
    log.info("dense 2048x2048 float32 matmul: %.1f ms, %.1f GFLOP/s", 1e3 * t_matmul, matmul_rate)
    bench(shipped, f"checkpoint {args.checkpoint}", args.batch, args.naive, args.repeats, matmul_rate, g)
    random = random_model(args.vehicles, args.azimuths, args.elevations, args.size, args.rank, g)
    bench(random, "random model", args.batch, args.naive, args.repeats, matmul_rate, g)


if __name__ == "__main__":
    run_main(main)
