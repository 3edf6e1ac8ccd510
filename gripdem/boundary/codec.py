"""The sin/cos position codec (docs/spec/conventions.md#sincos): per axis with that axis's own
length; decoding by atan2 (correct in all quadrants and for pairs off the unit circle)."""

from __future__ import annotations

import math

import numpy as np

from gripdem.boundary._array import Array, _is_torch, _stack, wrap_coordinate
from gripdem.boundary.cell import Box


def sincos_encode(positions: Array, box: Box) -> Array:
    """``(..., 3)`` positions -> ``(..., 6)`` features
    ``[sin θx, cos θx, sin θy, cos θy, sin θz, cos θz]`` with ``θ = 2π·p/l`` per axis."""
    lengths = box.lengths
    if _is_torch(positions):
        import torch

        lengths_t = torch.as_tensor(lengths, dtype=positions.dtype, device=positions.device)
        angle = 2 * math.pi * positions / lengths_t
        out = torch.stack([torch.sin(angle), torch.cos(angle)], dim=-1)
    else:
        angle = 2 * np.pi * positions / lengths
        out = np.stack([np.sin(angle), np.cos(angle)], axis=-1)
    return out.reshape(*positions.shape[:-1], 6)


def sincos_decode(features: Array, box: Box) -> Array:
    """``(..., 6)`` features -> ``(..., 3)`` positions in ``[-l/2, l/2)``.

    Uses atan2 on each (sin, cos) pair: correct in all four quadrants and for pairs off the
    unit circle (only the direction counts). A pair at the origin decodes to 0.
    """
    pairs = features.reshape(*features.shape[:-1], 3, 2)
    lengths = box.lengths
    if _is_torch(features):
        import torch

        angle = torch.atan2(pairs[..., 0], pairs[..., 1])
        lengths_t = torch.as_tensor(lengths, dtype=features.dtype, device=features.device)
        pos = angle * lengths_t / (2 * math.pi)
    else:
        angle = np.arctan2(pairs[..., 0], pairs[..., 1])
        pos = angle * lengths / (2 * np.pi)
    return _stack([wrap_coordinate(pos[..., i], float(lengths[i])) for i in range(3)], pos)
