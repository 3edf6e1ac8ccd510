"""numpy / torch dispatch shared by the boundary modules (private): every function takes numpy
arrays or torch tensors and returns the same kind.

torch is imported by the torch branches only: a caller with a tensor has imported it already,
and a numpy caller (the DEM, the importers, a sweep's controlling process, which computes
its jobs' dataset names) does not pay its import (about 1.2 s)."""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

Array = Any  # np.ndarray | torch.Tensor


def _is_torch(x: Array) -> bool:
    torch = sys.modules.get("torch")  # no tensor exists before torch is imported
    return torch is not None and isinstance(x, torch.Tensor)


def _floor(x: Array) -> Array:
    if _is_torch(x):
        import torch

        return torch.floor(x)
    return np.floor(x)


def _stack(parts: list, like: Array) -> Array:
    if _is_torch(like):
        import torch

        return torch.stack(parts, dim=-1)
    return np.stack(parts, axis=-1)


def _cumsum_last(x: Array) -> Array:
    """Cumulative sum along the last axis (same kind as x)."""
    if _is_torch(x):
        import torch

        return torch.cumsum(x, -1)
    return np.cumsum(x, -1)


def _as_offset(offset: Array | float | None, like: Array) -> Array:
    """Offset as an array of ``like``'s kind and dtype (after float64 wrapping upstream)."""
    if offset is None:
        offset = 0.0
    if _is_torch(like):
        import torch

        return torch.as_tensor(offset, dtype=like.dtype, device=like.device)
    return np.asarray(offset, dtype=like.dtype)


def _image_count(x: Array, length: float) -> Array:
    """Whole number n with ``x - n*length`` in ``[-length/2, length/2)`` (same kind as x)."""
    n = _floor(x / length + 0.5)
    rem = x - n * length
    # floor(x/l + 0.5) can be off by one when x/l + 0.5 rounds onto an integer: fold back.
    up = rem >= 0.5 * length
    down = rem < -0.5 * length
    if _is_torch(x):
        return n + up.to(n.dtype) - down.to(n.dtype)
    return n + up - down.astype(n.dtype)


def wrap_coordinate(x: Array, length: float) -> Array:
    """Wrap values into ``[-length/2, length/2)``, robust to values many lengths away."""
    return x - length * _image_count(x, length)
