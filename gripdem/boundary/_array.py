"""numpy / torch dispatch shared by the boundary modules (private): every function takes numpy
arrays or torch tensors and returns the same kind."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

Array = Any  # np.ndarray | torch.Tensor


def _is_torch(x: Array) -> bool:
    return isinstance(x, torch.Tensor)


def _floor(x: Array) -> Array:
    return torch.floor(x) if _is_torch(x) else np.floor(x)


def _stack(parts: list, like: Array) -> Array:
    return torch.stack(parts, dim=-1) if _is_torch(like) else np.stack(parts, axis=-1)


def _as_offset(offset: Array | float | None, like: Array) -> Array:
    """Offset as an array of ``like``'s kind and dtype (after float64 wrapping upstream)."""
    if offset is None:
        offset = 0.0
    if _is_torch(like):
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
