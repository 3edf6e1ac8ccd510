"""Physics-level evaluation of predicted trajectories beside the truth
(docs/spec/evaluation.md#physics).

Everything works on wrapped Cartesian positions with the LE-aware minimum image of
:mod:`gripdem.boundary`. Pair searches use :func:`gripdem.boundary.neighbour_pairs` (O(n)
cell lists on the triclinic Lees-Edwards cell, never an n x n matrix); for a cut-off below half
the smallest box length every pair has at most one image inside the cut-off, and that image is
the minimum image of docs/spec/conventions.md#minimum-image.

Layouts (as :mod:`gripdem.evaluation.metrics`): one frame ``(particles, 3)`` with a scalar offset, a
stack of frames ``(frames, particles, 3)`` with offsets ``(frames,)``, windows of predictions
``(windows, horizon, particles, 3)`` with offsets ``(windows, horizon)`` and last observed positions
``(windows, particles, 3)``. Offsets are the float64 LE offsets delta of each frame (zeros or
``None`` for a periodic box). Lengths come back in the positions' units; divide by the diameter for
"in diameters".
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gripdem.boundary import Box, displacement, unwrap_trajectory, wrap_coordinate
from gripdem.boundary import neighbour_pairs as find_pairs

Array = Any

#: pairs closer than ``OVERLAP_TOLERANCE * diameter`` count as overlapping
#: (docs/spec/evaluation.md#overlap): the soft-contact DEM truth has pairs slightly below d
OVERLAP_TOLERANCE = 0.98


def _np(x: Array) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float64)


def _frames(positions: Array, offsets: Array | float | None) -> tuple[np.ndarray, np.ndarray]:
    """Positions as ``(frames, particles, 3)`` float64 and offsets as ``(frames,)``."""
    pos = _np(positions)
    if pos.ndim == 2:
        pos = pos[None]
    if pos.ndim != 3 or pos.shape[-1] != 3:
        raise ValueError(
            f"positions must be (particles, 3) or (frames, particles, 3), got {pos.shape}"
        )
    off = np.zeros(pos.shape[0]) if offsets is None else _np(offsets).reshape(-1)
    if off.size == 1:
        off = np.full(pos.shape[0], float(off[0]))
    if off.shape != (pos.shape[0],):
        raise ValueError(f"offsets must be a scalar or ({pos.shape[0]},), got {off.shape}")
    return pos, off


def neighbour_pairs(
    positions: Array, box: Box, cutoff: float, offset: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs ``i < j`` of one frame ``(particles, 3)`` whose LE-aware minimum-image distance is
    below ``cutoff``; returns ``(i, j, distance)``, each pair once, O(n) work
    (:func:`gripdem.boundary.neighbour_pairs`).

    Requires ``cutoff < min(lx, ly, lz) / 2`` so that each pair has a single image in range.
    """
    limit = 0.5 * float(box.lengths.min())
    if not 0 < cutoff < limit:
        raise ValueError(
            f"pair cut-off must be in (0, min(box)/2) = (0, {limit:g}), got {cutoff!r}"
        )
    pos = _np(positions)
    if pos.ndim != 2 or pos.shape[-1] != 3:
        raise ValueError(f"positions of one frame must be (particles, 3), got {pos.shape}")
    i, j, vec = find_pairs(pos, box, offset, cutoff)
    distance = np.sqrt(np.einsum("pc,pc->p", vec, vec))
    return np.minimum(i, j), np.maximum(i, j), distance


def pair_distances(
    positions: Array, box: Box, cutoff: float, offsets: Array | float | None = None
) -> np.ndarray:
    """Minimum-image distances of all pairs below ``cutoff`` in every frame, concatenated
    (each pair once per frame). positions ``(particles, 3)`` or ``(frames, particles, 3)``."""
    pos, off = _frames(positions, offsets)
    return np.concatenate(
        [neighbour_pairs(p, box, cutoff, o)[2] for p, o in zip(pos, off, strict=True)]
    )


def overlap_fraction(
    positions: Array,
    box: Box,
    diameter: float,
    offsets: Array | float | None = None,
    tol: float = OVERLAP_TOLERANCE,
) -> float:
    """Fraction of particles (over all frames given) with a neighbour closer than
    ``tol * diameter``. positions ``(particles, 3)`` or ``(frames, particles, 3)``."""
    pos, off = _frames(positions, offsets)
    hits = 0
    for p, o in zip(pos, off, strict=True):
        i, j, _ = neighbour_pairs(p, box, tol * diameter, o)
        overlapping = np.zeros(p.shape[0], dtype=bool)
        overlapping[i] = True
        overlapping[j] = True
        hits += int(overlapping.sum())
    return hits / (pos.shape[0] * pos.shape[1])


def coordination_numbers(
    positions: Array, box: Box, cutoff: float, offset: float = 0.0
) -> np.ndarray:
    """Number of neighbours closer than ``cutoff`` of each particle of one frame:
    ``(particles,)`` int. (Contacts: a cut-off of about 1.02-1.05 d; a shell: the first
    minimum of g(r).)"""
    pos = _np(positions)
    i, j, _ = neighbour_pairs(pos, box, cutoff, offset)
    return np.bincount(i, minlength=pos.shape[0]) + np.bincount(j, minlength=pos.shape[0])


def coordination_number(
    positions: Array, box: Box, cutoff: float, offsets: Array | float | None = None
) -> float:
    """Mean coordination number over particles and frames (``2 * pairs / particles``)."""
    pos, off = _frames(positions, offsets)
    pairs = sum(neighbour_pairs(p, box, cutoff, o)[0].size for p, o in zip(pos, off, strict=True))
    return 2.0 * pairs / (pos.shape[0] * pos.shape[1])


def radial_distribution(
    positions: Array,
    box: Box,
    r_max: float,
    bins: int = 100,
    offsets: Array | float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """LE-aware radial distribution function g(r) averaged over frames.

    ``g(r_k) = 2 N_k / (F n (n-1)/V * 4/3 pi (r_{k+1}^3 - r_k^3))`` with ``N_k`` the pairs in
    bin k over F frames (g -> 1 for an ideal gas). Returns ``(bin_centres, g)``, ``(bins,)``
    each, for bins of equal width on ``[0, r_max)``.
    """
    pos, off = _frames(positions, offsets)
    n_frames, n = pos.shape[:2]
    edges = np.linspace(0.0, r_max, bins + 1)
    counts = np.histogram(pair_distances(pos, box, r_max, off), bins=edges)[0]
    shell = 4.0 / 3.0 * math.pi * (edges[1:] ** 3 - edges[:-1] ** 3)
    density = (n - 1) / box.volume
    g = 2.0 * counts / (n_frames * n * density * shell)
    return 0.5 * (edges[1:] + edges[:-1]), g


# --------------------------------------------------------------------------------------------
# quantities over the prediction horizon: windows (w, f, n, 3), last observed (w, n, 3)
# --------------------------------------------------------------------------------------------
def _windows(positions: Array, last_positions: Array, offsets: Array | None):
    pos, last = _np(positions), _np(last_positions)
    if pos.ndim != 4 or last.shape != (pos.shape[0],) + pos.shape[2:]:
        raise ValueError(
            f"expected positions (windows, horizon, particles, 3) and last positions "
            f"(windows, particles, 3), got {pos.shape} and {last.shape}"
        )
    off = np.zeros(pos.shape[:2]) if offsets is None else _np(offsets)
    if off.shape != pos.shape[:2]:
        raise ValueError(f"offsets must be (windows, horizon) = {pos.shape[:2]}, got {off.shape}")
    return pos, last, off


def frame_displacements(
    positions: Array, last_positions: Array, box: Box, offsets: Array | None = None
) -> np.ndarray:
    """Displacements between consecutive frames, the first from the last observed frame:
    ``(windows, horizon, particles, 3)``, each the minimum image with the LATER frame's offset
    (the displacement of the particle's image continuous with its earlier position)."""
    pos, last, off = _windows(positions, last_positions, offsets)
    frames = np.concatenate([last[:, None], pos], axis=1)
    return displacement(frames[:, 1:], frames[:, :-1], box, off[..., None])


def mean_squared_displacement(
    positions: Array,
    last_positions: Array,
    box: Box,
    offsets: Array | None = None,
    offset_increment: float = 0.0,
) -> np.ndarray:
    """MSD relative to the last observed frame at each horizon step: ``(horizon,)``.

    Displacements are lattice-continuous (:func:`gripdem.boundary.unwrap_trajectory`): the
    per-step minimum images summed, plus, for a particle that has crossed the LE x faces m
    times, m times the offset's growth per frame, because its image cell moves with the image
    velocity. ``offset_increment`` is that growth, unwrapped: ``Boundary.image_velocity *
    frame_interval`` (0 for a periodic box). Without it an LE crosser's displacement would
    lose the velocity jump it made at the face.
    """
    pos, last, off = _windows(positions, last_positions, offsets)
    w, f = pos.shape[:2]
    total = np.zeros(f)
    increments = np.full(f, float(offset_increment))
    for k in range(w):
        frames = np.concatenate([last[k, None], pos[k]], axis=0)
        frame_offsets = np.concatenate([[0.0], off[k]])  # the anchor's offset is not used
        cont = unwrap_trajectory(frames, box, frame_offsets, increments)
        total += ((cont[1:] - cont[0]) ** 2).sum(-1).sum(-1)
    return total / (w * pos.shape[2])


def velocity_profile(
    positions: Array,
    last_positions: Array,
    box: Box,
    offsets: Array | None = None,
    frame_interval: float = 1.0,
    bins: int = 16,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """z velocity against x, averaged over windows, horizon steps and particles in each x bin.

    Velocities are per-frame displacements (later frame's offset) over ``frame_interval``
    (leave 1 for length per frame); x is the middle of each step, wrapped. Returns
    ``(bin_centres, mean_vz, counts)``, ``(bins,)`` each (NaN where a bin is empty).
    """
    pos, last, off = _windows(positions, last_positions, offsets)
    steps = frame_displacements(pos, last, box, off)
    earlier = np.concatenate([last[:, None], pos[:, :-1]], axis=1)
    mid_x = wrap_coordinate(earlier[..., 0] + 0.5 * steps[..., 0], box.lx).reshape(-1)
    vz = steps[..., 2].reshape(-1) / frame_interval
    edges = np.linspace(-0.5 * box.lx, 0.5 * box.lx, bins + 1)
    counts = np.histogram(mid_x, bins=edges)[0]
    sums = np.histogram(mid_x, bins=edges, weights=vz)[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    return 0.5 * (edges[1:] + edges[:-1]), mean, counts


def velocity_profile_error(pred_profile: Array, true_profile: Array) -> float:
    """RMS difference of two binned profiles over the bins where both are defined."""
    p, t = _np(pred_profile), _np(true_profile)
    ok = np.isfinite(p) & np.isfinite(t)
    return float(np.sqrt(np.mean((p[ok] - t[ok]) ** 2))) if ok.any() else math.nan


PROFILE_KINDS = ("cosine", "linear")


def fit_profile(x: Array, vz: Array, box: Box, kind: str) -> tuple[float, float]:
    """Least-squares imposed profile on binned (or raw) values, NaNs ignored:
    ``cosine``: ``vz = A cos(2 pi x / lx) + B``; ``linear``: ``vz = S x + B``. Returns
    ``(A or S, B)``."""
    x, vz = _np(x), _np(vz)
    ok = np.isfinite(vz)
    basis = profile_basis(x[ok], box, kind)
    coeffs = np.linalg.lstsq(basis, vz[ok], rcond=None)[0]
    return float(coeffs[0]), float(coeffs[1])


def profile_basis(x: Array, box: Box, kind: str) -> np.ndarray:
    """``(len(x), 2)`` basis of an imposed profile (see :func:`fit_profile`)."""
    x = _np(x)
    if kind == "cosine":
        return np.stack([np.cos(2 * np.pi * x / box.lx), np.ones_like(x)], -1)
    if kind == "linear":
        return np.stack([x, np.ones_like(x)], -1)
    raise ValueError(f"profile kind must be one of {PROFILE_KINDS}, got {kind!r}")
