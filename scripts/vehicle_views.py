"""Render a PNG contact sheet of the vehicle catalog: one row per vehicle, four views.

Views (METHOD.md view angles, θ from the front, counter-clockwise seen from above): side
(θ = 90°, φ = 0), front (θ = 0, φ = 0), oblique (θ = 45°, φ = 30°) and top (θ = 90°, φ = 90°,
the front on the left as in the side view). Image axes are those of the templates
(:func:`torch_atr.render.view_basis`). Every cell uses the same metres per pixel, so sizes
compare across rows. Triangles are drawn one at a time with ``cv2.fillConvexPoly`` (far to
near, shaded by their facing), never ``cv2.fillPoly`` on many triangles at once, which fills
by the even-odd rule and leaves holes.

    python scripts/vehicle_views.py --out /tmp/vehicle_views.png [--split train test heldout]
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import cv2
import numpy as np
import torch
import trimesh

from torch_atr.io import atomic_path
from torch_atr.render import view_basis, view_directions
from torch_atr.vehicles import Vehicle, load_catalog, load_heldout_meshes

log = logging.getLogger("vehicle_views")

VIEWS = (("side", 90.0, 0.0), ("front", 0.0, 0.0), ("oblique", 45.0, 30.0), ("top", 90.0, 90.0))
LABEL_W = 230  # pixels of the name column


def view_bases() -> np.ndarray:
    """(V, 3, 3) rows image right, image up, towards the camera, for each of VIEWS."""
    angles = torch.tensor([(th, ph) for _, th, ph in VIEWS], dtype=torch.float64).deg2rad()  # (V, 2)
    theta, phi = angles[:, 0], angles[:, 1]
    right, up = view_basis(theta, phi)
    return torch.stack([right, up, view_directions(theta, phi)], dim=1).numpy()


def render(mesh: trimesh.Trimesh, basis: np.ndarray, size: tuple[int, int], m_per_px: float) -> np.ndarray:
    """Orthographic grey-shaded image (H, W) uint8 of ``mesh`` centred on its bounding-box centre.

    ``basis``: (3, 3) rows image right, image up, towards the camera. Painter's algorithm: the
    mesh's triangles (split to edges <= 0.2 m by the caller, so that sorting by mean depth
    occludes correctly for these convex-part meshes) are drawn far to near.
    """
    h, w = size
    pts = (mesh.vertices - mesh.bounds.mean(axis=0)) @ basis.T  # (M, 3): right, up, depth
    px = np.stack([w / 2 + pts[:, 0] / m_per_px, h / 2 - pts[:, 1] / m_per_px], axis=1)
    tri_px = np.round(px[mesh.faces] * 16).astype(np.int32)  # (F, 3, 2), 4 fractional bits
    facing = np.abs(mesh.face_normals @ basis[2])
    shade = (60 + 130 * facing).astype(np.uint8)  # darker than the white background
    order = np.argsort(pts[mesh.faces, 2].mean(axis=1))  # far (small depth) first
    img = np.full((h, w), 255, np.uint8)
    for f in order:
        cv2.fillConvexPoly(img, tri_px[f], int(shade[f]), lineType=cv2.LINE_8, shift=4)
    return img


def contact_sheet(vehicles: list[Vehicle], cell: tuple[int, int] = (170, 300), m_per_px: float = 0.042) -> np.ndarray:
    """One row per vehicle (name and class on the left), one column per view; (H, W) uint8."""
    h, w = cell
    header = np.full((24, LABEL_W + w * len(VIEWS)), 255, np.uint8)
    for j, (title, th, ph) in enumerate(VIEWS):
        cv2.putText(header, f"{title} ({th:g}, {ph:g})", (LABEL_W + j * w + 8, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.5, 0, 1)
    rows = [header]
    bases = view_bases()
    for v in vehicles:
        label = np.full((h, LABEL_W), 255, np.uint8)
        cv2.putText(label, v.name, (6, h // 2 - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.45, 0, 1)
        length, width, height = v.mesh.extents
        cv2.putText(label, f"{v.cls}  {length:.2f}x{width:.2f}x{height:.2f} m", (6, h // 2 + 16),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.4, 80, 1)
        verts, faces = trimesh.remesh.subdivide_to_size(v.mesh.vertices, v.mesh.faces, max_edge=0.2, max_iter=20)
        fine = trimesh.Trimesh(verts, faces, process=False)
        cells = [render(fine, basis, cell, m_per_px) for basis in bases]
        row = np.concatenate([label, *cells], axis=1)
        row[-1, :] = 200
        rows.append(row)
    return np.concatenate(rows, axis=0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("/tmp/vehicle_views.png"))
    parser.add_argument("--split", nargs="+", default=["train", "test"], choices=["train", "test", "heldout"])
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    vehicles = [v for s in args.split for v in (load_heldout_meshes() if s == "heldout" else load_catalog(s))]
    sheet = contact_sheet(vehicles)
    ok, png = cv2.imencode(".png", sheet)  # cv2.imwrite crashes the process on a path that is not UTF-8
    if not ok:
        raise OSError(f"could not encode {args.out}")
    with atomic_path(args.out) as tmp:
        png.tofile(tmp)
    log.info("wrote %s: %d vehicles, %dx%d px", args.out, len(vehicles), sheet.shape[1], sheet.shape[0])


if __name__ == "__main__":
    main()
