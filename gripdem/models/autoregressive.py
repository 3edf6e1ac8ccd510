"""Linear autoregressive baseline (docs/spec/evaluation.md#baselines): the strongest predictor
without interactions.

Per particle (one set of coefficients shared by all particles), a ridge regression of the next
frame-to-frame displacement on the last ``lags`` displacements and ``sin``/``cos`` of the
particle's x (the periodic drive is a cosine of x), fitted once on the training windows.

LE-exact by construction: the regression works on flow-relative displacements (the LE cell's
affine flow ``strain * x`` removed from z, :func:`gripdem.boundary.remove_affine_flow`), which do
not depend on the LE image a particle is followed in; a rollout adds the affine flow back in
lattice-continuous coordinates and wraps each predicted frame with its own offset, so crossings
get the LE shift and the velocity jump exactly as the constant-velocity baseline does.

Features of a step, in this order: ``[r_{s-1} (3), ..., r_{s-L} (3), sin θ_s, cos θ_s, 1]``
with ``r`` the flow-relative displacements and ``θ_s = 2π x_s / lx`` at the start of the step.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from gripdem.boundary import (
    Boundary,
    add_affine_flow,
    affine_flow_strain,
    lattice_continuous_steps,
    remove_affine_flow,
    step_start_x,
    wrap_positions,
)


def _flow_relative_steps(positions, box, offsets, strain: float):
    """positions ``(..., N, T, 3)`` wrapped, offsets ``(..., 1, T)`` or None -> flow-relative
    steps ``(..., N, T-1, 3)`` anchored at the last frame, and the continuous x at each step's
    start ``(..., N, T-1)``."""
    steps = lattice_continuous_steps(positions, box, offsets, anchor=-1)
    x_start = step_start_x(steps, positions[..., -1, 0])
    return remove_affine_flow(steps, x_start, strain), x_start


def _features(lagged: list, x, lx: float):
    """``[lag 1 (3), ..., lag L (3), sin, cos, 1]`` along the last axis."""
    theta = 2 * math.pi * x / lx
    if isinstance(x, torch.Tensor):
        trig = [
            torch.sin(theta)[..., None],
            torch.cos(theta)[..., None],
            torch.ones_like(x)[..., None],
        ]
        return torch.cat(lagged + trig, dim=-1)
    trig = [np.sin(theta)[..., None], np.cos(theta)[..., None], np.ones_like(x)[..., None]]
    return np.concatenate(lagged + trig, axis=-1)


@dataclass(frozen=True)
class LinearAR:
    """Fitted coefficients (plain floats: stored in a model's hyperparameters).

    weights: ``(3 * lags + 3, 3)`` row-major nested tuples (features x output xyz); strain: the
    affine flow per frame (LE) or 0; lx: box length along x (for the sin/cos features).
    """

    lags: int
    strain: float
    lx: float
    weights: tuple[tuple[float, ...], ...]
    ridge: float
    n_samples: int

    @property
    def n_features(self) -> int:
        return 3 * self.lags + 3

    @classmethod
    def fit(
        cls,
        trajectories: Iterable[tuple[np.ndarray, np.ndarray | None]],
        boundary: Boundary,
        frame_interval: float,
        lags: int,
        ridge: float = 1e-6,
    ) -> LinearAR:
        """Least squares over every step of ``trajectories``: pairs of wrapped positions
        ``(N, T, 3)`` and their frame offsets ``(T,)`` (None for a periodic box).

        ``ridge`` is relative: the penalty is ``ridge * diag(X^T X)`` (scale-free)."""
        if lags < 1:
            raise ValueError(f"linear AR baseline needs lags >= 1, got {lags}")
        strain = affine_flow_strain(boundary, frame_interval)
        box = boundary.box
        n_feat = 3 * lags + 3
        xtx, xty, count = np.zeros((n_feat, n_feat)), np.zeros((n_feat, 3)), 0
        for positions, offsets in trajectories:
            positions = np.asarray(positions, np.float64)
            if positions.shape[-2] < lags + 2:
                continue
            off = None if offsets is None else np.asarray(offsets, np.float64)[None, :]
            rel, x_start = _flow_relative_steps(positions, box, off, strain)
            s = rel.shape[-2]
            lagged = [rel[:, lags - k : s - k] for k in range(1, lags + 1)]
            x = _features(lagged, x_start[:, lags:], box.lx).reshape(-1, n_feat)
            y = rel[:, lags:].reshape(-1, 3)
            xtx += x.T @ x
            xty += x.T @ y
            count += len(y)
        if count < n_feat:
            raise ValueError(
                f"linear AR baseline: {count} training steps for {n_feat} coefficients "
                f"(lags {lags}); the training windows are too short"
            )
        penalty = ridge * np.diag(np.diag(xtx))
        weights = np.linalg.solve(xtx + penalty, xty)
        if not np.isfinite(weights).all():
            raise FloatingPointError("linear AR baseline: non-finite coefficients")
        return cls(
            int(lags),
            float(strain),
            float(box.lx),
            tuple(tuple(float(v) for v in row) for row in weights),
            float(ridge),
            int(count),
        )

    def rollout_steps(
        self,
        observed: torch.Tensor,
        observed_offsets: torch.Tensor | None,
        horizon: int,
        boundary: Boundary,
        relative: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """The filter's steps over the horizon, lattice-continuous in the image cell of the
        last observed frame (the exact frame of :mod:`gripdem.models.decoder_modes`).

        observed ``(windows, K+1, particles, 3)`` wrapped (K >= lags), observed_offsets
        ``(windows, K+1)`` float64 (ignored in a periodic box) -> ``(windows, particles,
        horizon, 3)`` float64; the first step goes from the last observed frame. ``relative``:
        the observed flow-relative steps ``(windows, particles, K, 3)`` float64 when the caller
        has them (with this filter's strain), else computed here."""
        observed = torch.as_tensor(observed).double().transpose(1, 2)  # (W, N, K+1, 3)
        if observed.shape[2] - 1 < self.lags:
            raise ValueError(
                f"linear AR baseline fitted with {self.lags} lags needs at least that many "
                f"observed steps, got {observed.shape[2] - 1}"
            )
        rel = relative
        if rel is None:
            obs_off = None
            if boundary.is_lees_edwards:
                obs_off = torch.as_tensor(observed_offsets, dtype=torch.float64)[:, None, :]
            rel, _ = _flow_relative_steps(observed, boundary.box, obs_off, self.strain)
        weights = torch.tensor(self.weights, dtype=torch.float64, device=observed.device)
        lags = self.lags
        # the lag weights in time order (oldest lag first), so that each step's features are a
        # window of one buffer of the steps (a strided view: nothing copied per step); the
        # same product as the fit's features (lag 1 first), summed in another order
        by_time = weights[: 3 * lags].reshape(lags, 3, 3).flip(0).reshape(3 * lags, 3)
        sin_w, cos_w, bias = weights[3 * lags], weights[3 * lags + 1], weights[3 * lags + 2]
        buffer = torch.empty(rel.shape[:-2] + (lags + horizon, 3), dtype=torch.float64,
                             device=observed.device)  # fmt: skip
        buffer[..., :lags, :] = rel[..., -lags:, :]
        x = observed[..., -1, 0]
        x_start = torch.empty_like(buffer[..., lags:, 0])  # each step's starting x
        theta_scale = 2 * math.pi / self.lx
        for s in range(horizon):
            theta = theta_scale * x
            step_rel = buffer[..., s : s + lags, :].flatten(-2) @ by_time + bias
            step_rel += torch.sin(theta)[..., None] * sin_w
            step_rel += torch.cos(theta)[..., None] * cos_w
            buffer[..., lags + s, :] = step_rel
            x_start[..., s] = x
            x = x + step_rel[..., 0]  # the affine flow is along z: x moves as relative
        return add_affine_flow(buffer[..., lags:, :], x_start, self.strain)

    def predict(
        self,
        observed: torch.Tensor,
        observed_offsets: torch.Tensor,
        target_offsets: torch.Tensor,
        boundary: Boundary,
    ) -> torch.Tensor:
        """Roll the filter out over the horizon.

        observed ``(windows, K+1, particles, 3)`` wrapped (K >= lags), observed_offsets
        ``(windows, K+1)`` and target_offsets ``(windows, f)`` float64 -> predicted wrapped
        positions ``(windows, f, particles, 3)`` float64."""
        observed = torch.as_tensor(observed).double()
        tgt_off = torch.as_tensor(target_offsets, dtype=torch.float64)
        steps = self.rollout_steps(observed, observed_offsets, tgt_off.shape[1], boundary)
        continuous = observed[:, -1, :, None] + torch.cumsum(steps, dim=2)  # (W, N, f, 3)
        le = boundary.is_lees_edwards
        wrapped = wrap_positions(
            continuous.transpose(1, 2), boundary.box, tgt_off[..., None] if le else None
        )
        return wrapped

    def to_dict(self) -> dict[str, Any]:
        return {
            "lags": self.lags,
            "strain": self.strain,
            "lx": self.lx,
            "weights": [list(row) for row in self.weights],
            "ridge": self.ridge,
            "n_samples": self.n_samples,
        }

    @classmethod
    def from_dict(cls, state: dict[str, Any]) -> LinearAR:
        return cls(
            int(state["lags"]),
            float(state["strain"]),
            float(state["lx"]),
            tuple(tuple(float(v) for v in row) for row in state["weights"]),
            float(state["ridge"]),
            int(state["n_samples"]),
        )


def fit_on_training_frames(datamodule, lags: int, ridge: float = 1e-6) -> LinearAR:
    """The linear AR baseline fitted on the frames that a set-up
    :class:`~gripdem.data.datamodule.TrajectoryDataModule`'s training windows cover
    (docs/spec/evaluation.md#baselines)."""
    return LinearAR.fit(
        datamodule.training_trajectories(overlap=lags + 1),
        datamodule.meta.boundary,
        datamodule.meta.frame_interval,
        lags,
        ridge,
    )
