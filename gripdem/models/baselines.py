"""Baselines evaluated on the same windows as every model (docs/spec/evaluation.md#baselines).

All take the observed frames of each window, ``observed`` ``(windows, frames_in, particles, 3)``
wrapped Cartesian (float64 recommended), and the float64 LE offsets of the observed and of the
predicted frames, and return predictions ``(windows, horizon, particles, 3)`` wrapped.

- ``stay``: every particle stays at its last observed position.
- ``constant_velocity``: the last observed frame-to-frame displacement (minimum image with the
  later frame's offset), extrapolated in lattice-continuous coordinates and wrapped with each
  predicted frame's own offset, so a particle crossing an LE face gets the z shift and the
  velocity jump (docs/spec/conventions.md#crossing).
- ``linear_ar``: the per-particle linear autoregressive filter fitted on the training windows
  (:mod:`gripdem.models.autoregressive`), LE-exact like constant velocity.
- ``mean_flow``: the imposed profile (``cosine``: u_z = A cos(2 pi x / lx) + B for the periodic
  scene, ``linear``: u_z = S x + B for the LE scene) fitted by least squares on the observed
  displacements of each window; particles advance along z at the fitted u_z(x).
"""

from __future__ import annotations

import math

import torch

from gripdem.boundary import Boundary, Box, displacement, wrap_positions
from gripdem.models.autoregressive import LinearAR

BASELINES = ("stay", "constant_velocity", "linear_ar", "mean_flow")
PROFILES = ("cosine", "linear")


def _t(x) -> torch.Tensor:
    return x if isinstance(x, torch.Tensor) else torch.as_tensor(x)


def stay(observed, horizon: int) -> torch.Tensor:
    last = _t(observed)[:, -1]
    return last.unsqueeze(1).expand(-1, horizon, -1, -1).clone()


def constant_velocity(observed, observed_offsets, target_offsets, box: Box) -> torch.Tensor:
    """observed_offsets ``(windows, frames_in)``, target_offsets ``(windows, horizon)``."""
    observed = _t(observed)
    obs_off = _t(observed_offsets).to(torch.float64)
    tgt_off = _t(target_offsets).to(torch.float64)
    before, last = observed[:, -2], observed[:, -1]
    velocity = displacement(last, before, box, obs_off[:, -1, None])
    horizon = tgt_off.shape[1]
    steps = torch.arange(2, horizon + 2, dtype=observed.dtype, device=observed.device)
    continuous = before[:, None] + steps[None, :, None, None] * velocity[:, None]
    return wrap_positions(continuous, box, tgt_off[..., None])


def frame_displacements(observed, observed_offsets, box: Box) -> torch.Tensor:
    """Minimum-image displacements between consecutive observed frames (later frame's
    offset): ``(windows, frames_in - 1, particles, 3)``."""
    observed = _t(observed)
    off = _t(observed_offsets).to(torch.float64)
    return displacement(observed[:, 1:], observed[:, :-1], box, off[:, 1:, None])


def _profile_basis(x: torch.Tensor, box: Box, profile: str) -> torch.Tensor:
    if profile == "cosine":
        return torch.stack([torch.cos(2 * math.pi * x / box.lx), torch.ones_like(x)], -1)
    if profile == "linear":
        return torch.stack([x, torch.ones_like(x)], -1)
    raise ValueError(f"mean-flow profile must be one of {PROFILES}, got {profile!r}")


def fit_mean_flow(observed, observed_offsets, box: Box, profile: str) -> torch.Tensor:
    """Least-squares profile coefficients per window ``(windows, 2)``, z displacement per frame
    as a function of x (x taken at the middle of each step)."""
    observed = _t(observed).to(torch.float64)
    steps = frame_displacements(observed, observed_offsets, box)
    mid_x = observed[:, :-1, :, 0] + 0.5 * steps[..., 0]
    mid_x = mid_x - box.lx * torch.round(mid_x / box.lx)
    basis = _profile_basis(mid_x, box, profile).reshape(observed.shape[0], -1, 2)
    target = steps[..., 2].reshape(observed.shape[0], -1, 1)
    return torch.linalg.lstsq(basis, target).solution.squeeze(-1)


def mean_flow(observed, observed_offsets, target_offsets, box: Box, profile: str) -> torch.Tensor:
    observed = _t(observed)
    coeffs = fit_mean_flow(observed, observed_offsets, box, profile).to(observed.dtype)
    last = observed[:, -1]
    per_frame = (_profile_basis(last[..., 0], box, profile) * coeffs[:, None]).sum(-1)
    horizon = _t(target_offsets).shape[1]
    steps = torch.arange(1, horizon + 1, dtype=observed.dtype, device=observed.device)
    pred = last[:, None].expand(-1, horizon, -1, -1).clone()
    pred[..., 2] = pred[..., 2] + steps[None, :, None] * per_frame[:, None]
    return wrap_positions(pred, box)


def predict_baseline(
    name: str,
    observed,
    observed_offsets,
    target_offsets,
    box: Box,
    profile: str,
    linear_ar: LinearAR | None = None,
    boundary: Boundary | None = None,
) -> torch.Tensor:
    """Dispatch by name (one of :data:`BASELINES`); ``linear_ar`` needs the fitted filter and
    the boundary."""
    if name == "stay":
        return stay(observed, _t(target_offsets).shape[1])
    if name == "constant_velocity":
        return constant_velocity(observed, observed_offsets, target_offsets, box)
    if name == "mean_flow":
        return mean_flow(observed, observed_offsets, target_offsets, box, profile)
    if name == "linear_ar":
        if linear_ar is None or boundary is None:
            raise ValueError("baseline 'linear_ar' needs the fitted filter and the boundary")
        return linear_ar.predict(_t(observed), observed_offsets, target_offsets, boundary)
    raise ValueError(f"baseline must be one of {BASELINES}, got {name!r}")
