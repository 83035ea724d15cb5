"""Plain reference implementations shared by tests (written out, not taken from the package)."""

import math

import numpy as np


def bilinear(image: np.ndarray, u: float, v: float) -> float:
    """Bilinear interpolation of an (H, W) image at (u, v): pixel centres at integers (u right,
    v down), the border pixel's value outside."""
    H, W = image.shape
    u, v = min(max(u, 0.0), W - 1.0), min(max(v, 0.0), H - 1.0)
    u0, v0 = min(int(math.floor(u)), W - 2), min(int(math.floor(v)), H - 2)
    a, b = u - u0, v - v0
    return ((1 - a) * (1 - b) * image[v0, u0] + a * (1 - b) * image[v0, u0 + 1]
            + (1 - a) * b * image[v0 + 1, u0] + a * b * image[v0 + 1, u0 + 1])
