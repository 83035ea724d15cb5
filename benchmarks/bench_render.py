"""Time render_templates on a training-set-sized job: K vehicle meshes x 150 views at 64 x 64.

The meshes are built here (a hull, a turret, a gun and road wheels: boxes and cylinders, about
3,000 triangles each, sizes drawn from a seeded generator), taken from the vehicle catalog with
``--catalog train``, or loaded with ``--mesh FILE ...`` and scaled to a 7 m length (timing only:
their axes are not fixed up).

    python benchmarks/bench_render.py --vehicles 36 --size 64 --threads 1
"""

from __future__ import annotations

import argparse
import logging
import math
import time

import numpy as np
import torch
import trimesh

from torch_atr.cli import run_main
from torch_atr.config import ConfigError, TemplateConfig
from torch_atr.render import render_templates
from torch_atr.shape import signed_distance
from torch_atr.vehicles import load_catalog, load_vehicle

from benchlib import check_at_least

logger = logging.getLogger("bench_render")


def _cylinder(radius: float, start, end, sections: int) -> trimesh.Trimesh:
    """Cylinder between two points."""
    return trimesh.creation.cylinder(radius=radius, segment=np.array([start, end], dtype=float), sections=sections)


def vehicle_mesh(rng: np.random.Generator, sections: int) -> trimesh.Trimesh:
    """A tank-like mesh in the body frame (+X forward, +Y left, +Z up, origin on the ground)."""
    length, width, height = rng.uniform(5.0, 7.5), rng.uniform(2.6, 3.4), rng.uniform(1.0, 1.5)
    wheel_r = rng.uniform(0.35, 0.45)
    hull = trimesh.creation.box((length, width, height)).apply_translation((0.0, 0.0, wheel_r + height / 2))
    top = wheel_r + height
    turret = trimesh.creation.box((length * 0.4, width * 0.6, 0.8)).apply_translation((-0.3, 0.0, top + 0.4))
    gun = _cylinder(0.1, (0.0, 0.0, top + 0.45), (length * 0.7, 0.0, top + 0.45), sections)
    wheels = [_cylinder(wheel_r, (x, y - 0.25, wheel_r), (x, y + 0.25, wheel_r), sections)
              for x in np.linspace(-length / 2 + wheel_r, length / 2 - wheel_r, 5) for y in (-width / 2, width / 2)]
    return trimesh.util.concatenate([hull, turret, gun] + wheels)


def loaded_mesh(path: str) -> trimesh.Trimesh:
    """The mesh of a URDF or mesh file (every part kept), scaled to a 7 m length."""
    mesh = load_vehicle(path, min_thickness=0.0).mesh
    mesh.apply_scale(7.0 / float(np.max(mesh.extents)))
    return mesh


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--vehicles", type=int, default=36, help="K meshes to build (without --mesh / --catalog)")
    parser.add_argument("--sections", type=int, default=64, help="cylinder sections (64: ~2,900 triangles)")
    parser.add_argument("--azimuths", type=int, default=30, help="views: azimuth steps over 360°")
    parser.add_argument("--elevations", type=int, default=5, help="views: 10° elevation steps from 0°")
    parser.add_argument("--size", type=int, default=64, help="template size in pixels")
    parser.add_argument("--window", type=float, default=12.0, help="template window in metres")
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--mesh", nargs="+", default=[], metavar="FILE", help="URDF or mesh files to render instead")
    source.add_argument("--catalog", choices=("train", "test"), help="render torch_atr.vehicles' catalog instead")
    parser.add_argument("--seed", type=int, default=0, help="seed of the built meshes' sizes")
    parser.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's)")
    args = parser.parse_args(argv)
    for flag, low in (("vehicles", 1), ("sections", 3), ("azimuths", 1), ("elevations", 1)):
        check_at_least(flag, getattr(args, flag), low)
    if args.threads is not None:
        check_at_least("threads", args.threads, 1)
    try:
        cfg = TemplateConfig(size_px=args.size, window_m=args.window)
    except ConfigError as exc:
        raise ConfigError(f"--size {args.size} --window {args.window:g}: {exc}") from None
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.threads is not None:
        torch.set_num_threads(args.threads)

    rng = np.random.default_rng(args.seed)
    if args.catalog:
        meshes = [vehicle.mesh for vehicle in load_catalog(args.catalog)]
    elif args.mesh:
        meshes = [loaded_mesh(p) for p in args.mesh]
    else:
        meshes = [vehicle_mesh(rng, args.sections) for _ in range(args.vehicles)]
    theta = torch.arange(args.azimuths, dtype=torch.float64) * (2 * math.pi / args.azimuths)
    phi = torch.arange(args.elevations, dtype=torch.float64) * math.radians(10.0)
    theta, phi = (g.reshape(-1) for g in torch.meshgrid(theta, phi, indexing="ij"))
    render_templates(meshes[0], theta[:2], phi[:2], cfg)  # warm-up

    start = time.perf_counter()
    templates = [render_templates(mesh, theta, phi, cfg) for mesh in meshes]
    seconds = time.perf_counter() - start
    start = time.perf_counter()
    for t in templates:
        signed_distance(t, cfg.tau_px)
    sdt_seconds = time.perf_counter() - start

    n_tpl = len(meshes) * len(theta)
    triangles = sum(len(m.faces) for m in meshes)
    logger.info("torch %s, %d threads", torch.__version__, torch.get_num_threads())
    logger.info("%d meshes (%.0f triangles on average) x %d views at %d x %d px",
                len(meshes), triangles / len(meshes), len(theta), args.size, args.size)
    logger.info("render: %.2f s total, %.3f ms per template, %.1f M triangles/s",
                seconds, 1e3 * seconds / n_tpl, triangles * len(theta) / seconds / 1e6)
    logger.info("signed distance: %.2f s total, %.3f ms per template", sdt_seconds, 1e3 * sdt_seconds / n_tpl)
    logger.info("mean silhouette area %.1f px", float(torch.cat(templates).sum(dim=(1, 2)).float().mean()))


if __name__ == "__main__":
    run_main(main)
