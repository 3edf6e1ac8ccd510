"""Scores of an ensemble forecast: the fair CRPS (docs/spec/long-rollouts.md#crps), the spread/skill
ratio (docs/spec/long-rollouts.md#spread-skill) and the rank histogram
(docs/spec/long-rollouts.md#rank-histogram), for ensembles of any size (a point forecast is an
ensemble of one).

Everything is computed from *residuals*: ``r_m = y - x_m``, the LE-aware minimum-image
difference between the truth ``y`` and member ``m``'s prediction ``x_m`` at the same frame
(:func:`gripdem.evaluation.metrics.position_residuals`). Since positions enter only through
differences, ``|x_m - y| = |r_m|``, ``|x_i - x_j| = |r_i - r_j|``, the ensemble mean's error is
``mean_m r_m`` and the truth's rank among the members is the number of members with ``r_m > 0``
(members below the truth). Scores are per coordinate (particle, axis, frame) and averaged.

Shapes: members first, ``(M, ...)``; the trailing layout of the evaluation is
``(windows, horizon, particles, 3)``, so ``(M, W, f, N, 3)``. Works on torch tensors (the
training loss differentiates :func:`fair_crps`) and numpy arrays (converted).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from gripdem.boundary import minimum_image, wrap_positions

Array = Any


def _tensor(x: Array) -> torch.Tensor:
    return x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x, np.float64))


def pairwise_abs_sum(members: torch.Tensor) -> torch.Tensor:
    """``sum_{i != j} |x_i - x_j|`` over the first axis (both orders), elementwise over the
    rest: from the sorted members, ``2 sum_k (2k - M + 1) x_(k)`` (O(M log M), no M x M
    tensor)."""
    m = members.shape[0]
    if m == 1:
        return torch.zeros_like(members[0])
    if m == 2:
        return 2 * (members[0] - members[1]).abs()
    ordered = members.sort(dim=0).values
    weight = 2 * torch.arange(m, dtype=members.dtype, device=members.device) - (m - 1)
    return 2 * torch.tensordot(weight, ordered, dims=([0], [0]))


def fair_crps(members: Array, truth: Array | float = 0.0) -> torch.Tensor:
    """The fair CRPS of members ``(M, ...)`` for the truth (``...``), elementwise:
    ``mean_i |x_i - y| - sum_{i != j} |x_i - x_j| / (2 M (M - 1))``; for ``M = 1`` the absolute
    error. Unbiased for the CRPS of the distribution the members are drawn from (so a model
    trained on it gains nothing from too few members). ``members`` may be residuals with
    ``truth = 0``."""
    x = _tensor(members)
    m = x.shape[0]
    skill = (x - truth).abs().mean(dim=0)
    if m == 1:
        return skill
    return skill - pairwise_abs_sum(x) / (2 * m * (m - 1))


def crps_per_step(residuals: Array) -> np.ndarray:
    """Mean fair CRPS per horizon step ``(f,)`` of residuals ``(M, W, f, N, 3)`` (or
    ``(W, f, N, 3)`` for a point forecast: the mean absolute error per coordinate)."""
    r = _tensor(residuals)
    if r.ndim == 4:
        r = r[None]
    return fair_crps(r).mean(dim=(0, 2, 3)).cpu().numpy()


def spread_skill_per_step(residuals: Array) -> np.ndarray:
    """Spread/skill per horizon step ``(f,)`` of member residuals ``(M, W, f, N, 3)``,
    ``M >= 2``: ``sqrt((M + 1) / M) * sqrt(mean unbiased member variance)`` over the RMSE of the
    ensemble mean, both per coordinate; 1 for a calibrated ensemble of ``M`` members."""
    r = _tensor(residuals)
    m = r.shape[0]
    if m < 2:
        raise ValueError(f"the spread/skill ratio needs at least 2 members, got {m}")
    spread = r.var(dim=0, unbiased=True).mean(dim=(0, 2, 3))
    skill = (r.mean(dim=0) ** 2).mean(dim=(0, 2, 3))
    ratio = math.sqrt((m + 1) / m) * torch.sqrt(spread / skill.clamp_min(1e-300))
    return ratio.cpu().numpy()


def rank_histogram(residuals: Array, steps: slice | None = None) -> np.ndarray:
    """Frequencies ``(M + 1,)`` (summing to 1) of the truth's rank among the members, pooled
    over windows, the horizon steps in ``steps`` (all by default), particles and axes. Rank
    ``k``: ``k`` members lie below the truth (``r_m > 0``); flat, ``1 / (M + 1)`` per bin, for
    a calibrated ensemble."""
    r = _tensor(residuals)
    if steps is not None:
        r = r[:, :, steps]
    m = r.shape[0]
    ranks = (r > 0).sum(dim=0).flatten()
    counts = torch.bincount(ranks, minlength=m + 1).double()
    return (counts / counts.sum()).cpu().numpy()


def rank_flatness(histogram: np.ndarray) -> tuple[float, float]:
    """The largest and the smallest bin of a rank histogram relative to uniform (1, 1 when
    flat; an under-dispersed ensemble piles the truth into the end bins: max >> 1)."""
    uniform = 1.0 / len(histogram)
    return float(np.max(histogram) / uniform), float(np.min(histogram) / uniform)


def ensemble_mean_and_spread(members: np.ndarray, box, offsets: np.ndarray | None = None):
    """The mean and the spread of members' wrapped positions ``(M, ..., N, 3)`` at frames with
    LE ``offsets`` ``(...)`` (None: periodic): the mean position ``(..., N, 3)`` (member 0 moved
    by the mean minimum-image displacement of every member from it, wrapped) and the spread per
    particle ``(..., N)``, ``sqrt`` of the unbiased member variance summed over the axes."""
    x = np.asarray(members, np.float64)
    off = None if offsets is None else np.asarray(offsets, np.float64)[..., None]
    rel = minimum_image(x - x[0], box, off)
    mean = wrap_positions(x[0] + rel.mean(axis=0), box, off)
    if len(x) == 1:
        return mean, np.zeros(x.shape[1:-1])
    return mean, np.sqrt(rel.var(axis=0, ddof=1).sum(axis=-1))
