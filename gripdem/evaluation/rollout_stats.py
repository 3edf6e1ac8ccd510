"""Statistics of a long rollout beside the truth, per block of frames (definitions:
docs/spec/long-rollouts.md#rollout-statistics).

Over long times no forecaster beats the mean on RMSE; a surrogate must keep the statistics of
the flow. For two trajectories of the same scene, ``model`` and ``truth`` ``(T, N, 3)`` wrapped
(frame 0 the last observed frame, identical in both), per block of ``block`` frames:

- ``overlap``: fraction of particles with a neighbour closer than 0.98 d (every frame; the
  block's maximum);
- ``gr_l1``: the pair-distance histogram over 0-3 d in 0.05 d bins, summed over the block's
  frames (every ``gr_every``-th), ``sum |h_model - h_truth| / sum h_truth``;
- ``coordination``: neighbours closer than 1.01 d per particle;
- ``profile`` and ``drift``: least squares of the per-frame z-steps against ``[cos(2 pi x / lx),
  1]`` (periodic: the amplitude) or ``[x - mean x, 1]`` (Lees-Edwards: the slope), the constant
  being the uniform drift; steps are LE-aware minimum images with the later frame's offset,
  ``x`` the middle of the step;
- ``non_affine``: the z-step minus the truth's fitted profile of the block (x and y steps as
  they are); its ``msd`` at lags 1, 10, 100 frames (mean squared sum of L consecutive steps,
  starting in the block), its RMS (``rms_non_affine``), the RMS of the whole step (``rms_step``)
  and ``step_w1``: the Wasserstein-1 distance between the model's and the truth's distributions
  of per-frame non-affine z-steps, over the truth's RMS.

Over the whole rollout (at least ``DIFFUSION_LAGS[1]`` frames): the self-diffusion coefficient
per axis, ``D_a`` = half the slope of the non-affine MSD along ``a`` against the lag, fitted
between lags 200 and 1000 frames (docs/spec/long-rollouts.md#self-diffusion; d² per frame interval),
the flow removed with the truth's profile fitted over the whole rollout.

Lengths in diameters; per-block values are lists (one entry per block), ratios are model/truth.
The same function gives the noise floor: two independent DEM simulations as ``model`` and
``truth``.
"""

from __future__ import annotations

import math

import numpy as np

from gripdem.boundary import Boundary, NeighbourList, displacement, neighbour_pairs

#: the surrogate's targets over a long rollout (docs/explanation/surrogate.md#targets), stated
#: once: the largest relative deviation from the truth's statistic (``coordination``: contacts
#: within 1.01 d; ``msd``: non-affine MSD at every lag; ``rms_non_affine``: the RMS non-affine
#: step; ``diffusion``: D per axis; ``profile``: the mean-flow amplitude), the largest g(r) L1
#: distance (``gr_l1``), the largest overlapping fraction of particles in any frame
#: (``overlap``), and the bands of the hand-back's fluctuation kinetic energy, an ensemble's
#: spread/skill and its rank histogram (bins over uniform)
SURROGATE_TARGETS = {
    "coordination": 0.03,
    "msd": 0.15,
    "rms_non_affine": 0.10,
    "diffusion": 0.20,
    "profile": 0.03,
    "gr_l1": 0.02,
    "overlap": 0.01,
    "handback": (0.8, 1.25),
    "spread_skill": (0.8, 1.2),
    "rank_over_uniform": (0.5, 1.5),
}
OVERLAP_FACTOR = 0.98
CONTACT_FACTOR = 1.01
GR_MAX_D, GR_BIN_D = 3.0, 0.05
LAGS = (1, 10, 100)
#: the lag range (frames) of the self-diffusion fit
DIFFUSION_LAGS = (200, 1000)
PROFILES = {"periodic": "cosine", "lees_edwards": "linear"}


def frame_steps(positions: np.ndarray, offsets: np.ndarray, boundary: Boundary):
    """Per-frame steps ``(T-1, N, 3)`` (minimum image, later offset) and their middle x."""
    steps = displacement(positions[1:], positions[:-1], boundary.box, offsets[1:, None])
    return steps, positions[:-1, :, 0] + 0.5 * steps[..., 0]


def profile_basis(x: np.ndarray, boundary: Boundary) -> np.ndarray:
    """``(..., 2)``: the imposed profile's shape and a constant."""
    if boundary.is_lees_edwards:
        return np.stack([x, np.ones_like(x)], -1)
    return np.stack([np.cos(2 * np.pi * x / boundary.box.lx), np.ones_like(x)], -1)


def fit_profile(steps: np.ndarray, x_mid: np.ndarray, boundary: Boundary) -> np.ndarray:
    """Least-squares ``(shape coefficient, drift)`` of the z-steps over all given steps."""
    basis = profile_basis(x_mid.reshape(-1), boundary)
    return np.linalg.lstsq(basis, steps[..., 2].reshape(-1), rcond=None)[0]


def _overlaps(positions, times, offsets, boundary, diameter) -> np.ndarray:
    """Per frame: fraction of particles with a neighbour closer than 0.98 d."""
    nl = NeighbourList(
        boundary.box, OVERLAP_FACTOR * diameter, 0.3 * diameter, boundary.image_velocity
    )
    out = np.empty(len(positions))
    for t in range(len(positions)):
        nl.update(positions[t], float(offsets[t]), float(times[t]))
        i, j, _ = nl.pairs(float(times[t]))
        touched = np.zeros(positions.shape[1], dtype=bool)
        touched[i] = touched[j] = True
        out[t] = touched.mean()
    return out


def _structure(positions, offsets, frames, boundary, diameter):
    """Pair-distance histogram (0-3 d) summed over ``frames`` and the contact coordination."""
    edges = np.arange(0.0, GR_MAX_D + 0.5 * GR_BIN_D, GR_BIN_D)
    hist = np.zeros(len(edges) - 1)
    contacts = 0
    for t in frames:
        _, _, vec = neighbour_pairs(
            positions[t], boundary.box, float(offsets[t]), GR_MAX_D * diameter
        )
        dist = np.sqrt(np.einsum("pc,pc->p", vec, vec)) / diameter
        hist += np.histogram(dist, bins=edges)[0]
        contacts += int((dist < CONTACT_FACTOR).sum())
    coordination = 2.0 * contacts / (len(frames) * positions.shape[1])
    return hist, coordination


def lag_msd(non_affine: np.ndarray, starts, lag: int) -> float:
    """Mean squared sum of ``lag`` consecutive steps ``(S, N, 3)``, from each of ``starts``."""
    total = np.concatenate([np.zeros_like(non_affine[:1]), np.cumsum(non_affine, axis=0)])
    starts = [s for s in starts if s + lag <= len(non_affine)]
    if not starts:
        return math.nan
    sums = total[np.array(starts) + lag] - total[np.array(starts)]
    return float(np.mean(np.einsum("snc,snc->sn", sums, sums)))


def _w1(a: np.ndarray, b: np.ndarray, quantiles: int = 200) -> float:
    q = np.linspace(0.0, 1.0, quantiles)
    return float(np.mean(np.abs(np.quantile(a, q) - np.quantile(b, q))))


def block_statistics(
    model: np.ndarray,
    truth: np.ndarray,
    times: np.ndarray,
    boundary: Boundary,
    diameter: float,
    block: int = 100,
    gr_every: int = 2,
) -> dict:
    """Per-block statistics of ``model`` beside ``truth`` (see the module doc)."""
    if model.shape != truth.shape:
        raise ValueError(f"model {model.shape} and truth {truth.shape} must have the same shape")
    d = diameter
    offsets = boundary.offset(times)
    out: dict = {"block": block, "frames": len(model) - 1, "blocks": []}
    sets = {"model": model, "truth": truth}
    steps = {k: frame_steps(v, offsets, boundary) for k, v in sets.items()}
    overlap = {k: _overlaps(v, times, offsets, boundary, d) for k, v in sets.items()}
    na = {}
    n_blocks = (len(model) - 1 + block - 1) // block
    for b in range(n_blocks):
        lo, hi = b * block, min((b + 1) * block, len(model) - 1)  # steps lo..hi-1
        row: dict = {"frames": [lo + 1, hi]}
        fits = {k: fit_profile(s[lo:hi], x[lo:hi], boundary) for k, (s, x) in steps.items()}
        gr_frames = list(range(lo + 1, hi + 1, gr_every))
        structure = {k: _structure(v, offsets, gr_frames, boundary, d) for k, v in sets.items()}
        for k, (s, x) in steps.items():
            flow = profile_basis(x[lo:hi], boundary) @ fits["truth"]
            rel = s[lo:hi].copy()
            rel[..., 2] -= flow
            na[k] = rel / d
            row[f"{k}/overlap_max"] = float(overlap[k][lo + 1 : hi + 1].max())
            row[f"{k}/profile"] = float(fits[k][0])
            row[f"{k}/drift_over_d"] = float(fits[k][1] / d)
            row[f"{k}/coordination"] = structure[k][1]
            row[f"{k}/rms_step_over_d"] = float(np.sqrt(np.mean(np.sum(s[lo:hi] ** 2, -1)))) / d
            row[f"{k}/rms_non_affine_over_d"] = float(np.sqrt(np.mean(np.sum(na[k] ** 2, -1))))
        for k in sets:  # lags reach beyond the block: all steps, relative to the block's flow
            full = steps[k][0].copy()
            full[..., 2] -= profile_basis(steps[k][1], boundary) @ fits["truth"]
            for lag in LAGS:
                row[f"{k}/msd_{lag}_over_d2"] = lag_msd(full / d, range(lo, hi), lag)
        h_m, h_t = structure["model"][0], structure["truth"][0]
        row["gr_l1"] = float(np.abs(h_m - h_t).sum() / max(h_t.sum(), 1.0))
        truth_rms = row["truth/rms_non_affine_over_d"]
        w1 = _w1(na["model"][..., 2].ravel(), na["truth"][..., 2].ravel())
        row["step_w1"] = w1 / truth_rms if truth_rms > 0 else (0.0 if w1 == 0 else math.inf)
        for name in (
            "profile",
            "coordination",
            "rms_step_over_d",
            "rms_non_affine_over_d",
            *(f"msd_{lag}_over_d2" for lag in LAGS),
        ):
            t_value = row[f"truth/{name}"]
            row[f"ratio/{name}"] = row[f"model/{name}"] / t_value if t_value else math.nan
        out["blocks"].append(row)
    out["overlap_per_frame"] = {k: v.tolist() for k, v in overlap.items()}
    return out


def diffusion_coefficients(
    positions: np.ndarray,
    truth: np.ndarray,
    times: np.ndarray,
    boundary: Boundary,
    diameter: float,
    lags: tuple[int, int] = DIFFUSION_LAGS,
    lag_step: int = 50,
    start_step: int = 10,
) -> np.ndarray:
    """Self-diffusion coefficient per axis ``(3,)`` of ``positions`` ``(T, N, 3)`` in d² per
    frame interval: half the least-squares slope of the non-affine MSD per axis against the lag
    over ``lags`` (every ``lag_step`` frames; starts every ``start_step`` frames), the flow removed
    with ``truth``'s profile fitted over all frames (see the module doc)."""
    offsets = boundary.offset(times)
    steps, x_mid = frame_steps(positions, offsets, boundary)
    fit = fit_profile(*frame_steps(truth, offsets, boundary), boundary)
    steps = steps / diameter
    steps[..., 2] -= profile_basis(x_mid, boundary) @ fit / diameter
    if len(steps) < lags[1]:
        raise ValueError(
            f"the diffusion fit needs {lags[1]} frames (lags {lags[0]}-{lags[1]}), got {len(steps)}"
        )
    path = np.concatenate([np.zeros_like(steps[:1]), np.cumsum(steps, axis=0)])
    lag_values = np.arange(lags[0], lags[1] + 1, lag_step)
    msd = np.empty((len(lag_values), 3))
    for row, lag in enumerate(lag_values):
        starts = np.arange(0, len(steps) - lag + 1, start_step)
        moved = path[starts + lag] - path[starts]
        msd[row] = (moved**2).mean(axis=(0, 1))
    slope = np.polyfit(lag_values.astype(float), msd, 1)[0]
    return slope / 2.0


def profile_kind(boundary: Boundary) -> str:
    return PROFILES[boundary.kind]
