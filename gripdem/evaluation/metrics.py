"""Evaluation metrics (docs/spec/evaluation.md#rmse), all through :mod:`gripdem.boundary`.

Layout: predicted and true positions are ``(windows, horizon, particles, 3)`` wrapped
Cartesian; ``offsets`` are the float64 LE offsets of the predicted frames ``(windows, horizon)``
(zeros for a periodic box). Works on numpy arrays and torch tensors.

RMSE = sqrt(sum_{w,n,t,c} r^2 / (w * n * t)) with r the LE-aware minimum-image difference
between truth and prediction at the same frame (so the frame's own offset applies).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from gripdem.boundary import Box, lattice_shift, minimum_image

Array = Any


def _offsets_like(offsets: Array | None, like: Array) -> Array | None:
    """``(windows, horizon)`` offsets -> broadcastable to ``like[..., 0]`` ``(w, h, n)``."""
    if offsets is None:
        return None
    if isinstance(like, torch.Tensor):
        off = torch.as_tensor(offsets, dtype=torch.float64, device=like.device)
    else:
        off = np.asarray(offsets, dtype=np.float64)
    return off[..., None]


def position_residuals(pred: Array, true: Array, box: Box, offsets: Array | None = None) -> Array:
    """Minimum-image ``true - pred`` per frame: ``(windows, horizon, particles, 3)``.

    Computed in float64 (the offsets are float64; float32 would lose ~1e-7 of the box)."""
    if isinstance(pred, torch.Tensor):
        diff = true.double() - pred.double()
    else:
        diff = np.asarray(true, np.float64) - np.asarray(pred, np.float64)
    return minimum_image(diff, box, _offsets_like(offsets, diff))


def _mean_sq(residuals: Array, axis) -> Array:
    sq = (residuals**2).sum(-1)
    if isinstance(sq, torch.Tensor):
        return sq.mean(dim=axis)
    return sq.mean(axis=axis)


def rmse(residuals: Array) -> float:
    """Paper RMSE over all windows, particles and steps: ``sqrt(sum r^2 / (w n t))``."""
    return float(_mean_sq(residuals, (0, 1, 2)) ** 0.5)


def rmse_per_step(residuals: Array) -> np.ndarray:
    """RMSE at each horizon step: ``(horizon,)``."""
    per = _mean_sq(residuals, (0, 2)) ** 0.5
    return np.asarray(per.detach().cpu() if isinstance(per, torch.Tensor) else per)


def crossing_mask(
    last_positions: Array, true: Array, box: Box, offsets: Array | None = None
) -> np.ndarray:
    """``(windows, particles)`` bool: the particle crosses an LE x face in the horizon.

    A crossing is a change of the x image count between consecutive true frames (from the last
    observed frame to the first target frame, and between target frames).
    """
    true = np.asarray(true.detach().cpu() if isinstance(true, torch.Tensor) else true)
    last = np.asarray(
        last_positions.detach().cpu()
        if isinstance(last_positions, torch.Tensor)
        else last_positions
    )
    frames = np.concatenate([last[:, None], true], axis=1)
    steps = frames[:, 1:] - frames[:, :-1]
    off = None if offsets is None else np.asarray(offsets, np.float64)[..., None]
    return (lattice_shift(steps, box, off)[..., 0] != 0).any(axis=1)


def rmse_split(residuals: Array, mask: np.ndarray) -> tuple[float, float, int]:
    """RMSE of the particles where ``mask`` ``(windows, particles)`` holds and of the rest,
    and the number of masked particle-windows (NaN where a group is empty)."""
    r = np.asarray(residuals.detach().cpu() if isinstance(residuals, torch.Tensor) else residuals)
    sq = (r**2).sum(-1).mean(1)  # (windows, particles): mean over steps
    count = int(mask.sum())
    inside = float(np.sqrt(sq[mask].mean())) if count else math.nan
    outside = float(np.sqrt(sq[~mask].mean())) if count < mask.size else math.nan
    return inside, outside, count


def summarize(
    pred: Array,
    true: Array,
    last_positions: Array,
    box: Box,
    diameter: float,
    offsets: Array | None = None,
    le: bool = False,
) -> dict[str, float]:
    """The scalar metrics of a set of windows: ``rmse``, ``rmse_over_d``, ``rmse_step/NN``,
    and for LE data ``rmse_crossers``, ``rmse_others``, ``n_crossers``."""
    res = position_residuals(pred, true, box, offsets)
    out = {"rmse": rmse(res)}
    out["rmse_over_d"] = out["rmse"] / diameter
    for step, value in enumerate(rmse_per_step(res), start=1):
        out[f"rmse_step/{step:03d}"] = float(value)
    if le:
        mask = crossing_mask(last_positions, true, box, offsets)
        out["rmse_crossers"], out["rmse_others"], out["n_crossers"] = rmse_split(res, mask)
    return out


def shown_in_tensorboard(key: str) -> bool:
    """Whether a validation/test metric (``stage/name``) goes to TensorBoard: values in
    diameters and ratios, the loss and the ensemble's calibration; never one tag per step of
    the horizon (``rmse_step/001``: those are one curve per forecaster) or metres."""
    name = key.split("/", 1)[-1]
    if "/" in name:
        return False
    if name == "loss":  # training's objective: for train and validation only
        return not key.startswith("test/")
    return (
        name.endswith("_over_d")
        or name.startswith("rmse_ratio_")
        or name in ("spread_skill", "rank_max_over_uniform", "rank_min_over_uniform")
    )
