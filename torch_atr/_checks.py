"""Input validation for public entry points: one helper, messages say expected vs. got."""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np
import torch


def check_device(name: str | int | torch.device) -> torch.device:
    """The torch device ``name`` (``"cpu"``, ``"cuda"``, ``"cuda:1"``, ``"mps"``, ..., or an index: 0 is
    ``cuda:0``, as ``torch.device(0)`` takes it) as a tensor on
    it reports it (``"cpu:0"`` → cpu, ``"cuda"`` → cuda:0), if this machine has it and it holds
    data; ``ValueError`` naming it otherwise (PyTorch would fail later, with less to go on)."""
    try:
        probe = torch.zeros(1, device=torch.device(name))  # raises where the build or machine lacks it
        probe.cpu()  # raises on a device without data (meta)
    except (RuntimeError, AssertionError, TypeError, NotImplementedError) as exc:
        reason = " ".join(str(exc).split()).split(". ")[0].rstrip(".")  # mps's goes on for 7000 characters
        raise ValueError(f"device {str(name)!r} is not available here (PyTorch {torch.__version__}: {reason}); "
                         "try cpu") from None
    return probe.device


def check_shape(name: str, x: torch.Tensor, shape: Sequence[int | str | None]) -> None:
    """Raise ``ValueError`` unless ``x`` has ``len(shape)`` dims matching ``shape``.

    ``shape`` entries are ints (exact size), or a letter / ``None`` (any size). Equal letters
    must have equal sizes, e.g. ``check_shape("pts", pts, ("N", 3))``.
    """
    expected = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"Expected {name} to be a tensor of shape {expected}; got {type(x).__name__}")
    ok = x.dim() == len(shape)
    sizes: dict[str, int] = {}
    if ok:
        for s, n in zip(shape, x.shape):
            if isinstance(s, int) and s != n:
                ok = False
            elif isinstance(s, str) and sizes.setdefault(s, n) != n:
                ok = False
    if not ok:
        raise ValueError(f"Expected {name} to have shape {expected}; got {tuple(x.shape)}")


def check_finite(name: str, x: torch.Tensor, unit: str = "") -> torch.Tensor:
    """``x`` itself, or ``ValueError`` naming it and counting its NaN and infinite values; ``unit``
    (e.g. "radians") completes "Expected theta to be finite radians"."""
    finite = x.isfinite()
    if not bool(finite.all()):
        raise ValueError(f"Expected {name} to be finite{' ' + unit if unit else ''}; {int((~finite).sum())} value(s) "
                         f"are NaN or infinite")
    return x


def as_float_tensor(name: str, x, like: torch.Tensor | None = None) -> torch.Tensor:
    """Convert a tensor, array, list or scalar of numbers to a floating tensor.

    Keeps a floating tensor's dtype and device; other inputs become ``like``'s dtype and
    device when given, else float32 on the CPU. Text ("0.7") and booleans are not numbers.
    """
    if isinstance(x, torch.Tensor):
        if x.is_floating_point():
            return x
        if x.dtype == torch.bool:
            raise ValueError(f"Expected {name} to be numeric; got a bool tensor")
        return x.to(like.dtype if like is not None else torch.float32)
    try:
        arr = np.asarray(x)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"Expected {name} to be numeric; got {type(x).__name__}") from exc
    if arr.dtype.kind not in "fiu":  # not bool, text or objects (np.asarray would parse "0.7")
        raise ValueError(f"Expected {name} to be numeric; got {type(x).__name__} of {arr.dtype}")
    if not isinstance(x, np.ndarray) and any(
            isinstance(v, (bool, np.bool_)) for v in np.asarray(x, dtype=object).ravel()):
        raise ValueError(f"Expected {name} to be numeric; got a bool in {type(x).__name__}")  # [1, True] was [1, 1]
    arr = arr.astype(np.float64)
    dtype = like.dtype if like is not None else torch.float32
    device = like.device if like is not None else None
    return torch.as_tensor(arr, dtype=dtype, device=device)


def to_grey(name: str, image, dtypes: Sequence[type | np.dtype], order: str = "BGR") -> np.ndarray:
    """Check a numpy image and return it grey, keeping its dtype.

    Args:
        name: the argument's name, for error messages.
        image: (H, W) grey, returned as it is, or (H, W, 3) in channel ``order``, converted with
            OpenCV's weights (float64 via float32).
        dtypes: the accepted dtypes, among uint8, uint16, float32 and float64.
        order: "BGR" (OpenCV's images) or "RGB" (this package's sequences).
    Returns:
        (H, W) of ``image``'s dtype.
    """
    codes = {"BGR": cv2.COLOR_BGR2GRAY, "RGB": cv2.COLOR_RGB2GRAY}
    if order not in codes:
        raise ValueError(f"Expected order 'BGR' or 'RGB'; got {order!r}")
    code = codes[order]
    if not isinstance(image, np.ndarray):
        raise ValueError(f"Expected {name} to be a numpy array; got {type(image).__name__}")
    if image.dtype not in dtypes:
        allowed = " or ".join(np.dtype(d).name for d in dtypes)
        raise ValueError(f"Expected {name} to have dtype {allowed}; got {image.dtype} (shape {image.shape})")
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        if image.dtype == np.float64:
            return cv2.cvtColor(image.astype(np.float32), code).astype(np.float64)
        return cv2.cvtColor(image, code)
    raise ValueError(f"Expected {name} to have shape (H, W) or (H, W, 3); got {image.shape}")


def describe_array(value) -> str:
    """An array's shape and dtype, or the type of anything else, for error messages."""
    if isinstance(value, np.ndarray):
        return f"shape {value.shape}, dtype {value.dtype}"
    return f"a {type(value).__name__}"


def check_pattern(pattern) -> tuple[int, int]:
    """A checkerboard's (columns, rows) of inner corners as ints, at least 3 x 3 (the fewest
    ``cv2.findChessboardCorners`` takes: fewer is a cv2.error). ValueError naming the value."""
    try:
        cols, rows = (int(p) for p in pattern)
        if [cols, rows] != list(pattern):  # 9.5 is not 9 corners
            raise ValueError
    except (TypeError, ValueError) as exc:
        raise ValueError(f"Expected pattern to be (columns, rows) of inner corners, two integers; got {pattern!r}"
                         ) from exc
    if cols < 3 or rows < 3:
        raise ValueError(f"Expected pattern to have at least 3 x 3 inner corners (the fewest OpenCV finds); "
                         f"got {pattern!r}")
    return cols, rows
