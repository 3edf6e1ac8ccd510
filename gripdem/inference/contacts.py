"""Contact correction of a predicted frame: pairs closer than a contact distance are pushed apart.

Rigid-ish DEM particles never overlap by more than ~1e-4 d (the soft contacts of the built-in
DEM: ~1e-5 d), and a model's frame that packs particles into each other is outside everything
it was trained on and explodes when handed back to a DEM
(docs/spec/long-rollouts.md#overlaps-first). After each predicted frame the overlapping pairs of the
neighbour list are pushed apart along their centre line, each particle by half the overlap
(Gauss-Seidel sweeps over the candidate pairs, compiled with numba), until no pair is closer than
``distance * (1 - tolerance)`` or ``sweeps`` are done. Every push moves two particles by opposite
amounts: the centre of mass does not move, so a correction cannot make the suspension drift.

Positions are the neighbour list's physical images ``q (N, 3)``; the list gives each pair's
image shift. Candidates are the listed pairs within ``CANDIDATE_MARGIN`` contact distances,
chosen again whenever a particle has been pushed far enough for an outside pair to touch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from gripdem.boundary import NeighbourList, le_cell

#: candidate pairs: within this factor of the contact distance when chosen
CANDIDATE_MARGIN = 1.05
#: overlaps left by the correction, as a fraction of the contact distance (the built-in DEM's
#: own reach ~1e-5-1e-4 d)
CORRECTION_TOLERANCE = 1e-4


@dataclass
class Correction:
    """What one correction did: pairs overlapping (beyond the tolerance) before and after, the
    largest overlap before and after (in units of the contact distance), the sweeps used and
    the RMS push (length units)."""

    overlapping_before: int
    overlapping_after: int
    worst_before: float
    worst_after: float
    sweeps: int
    rms_push: float


@numba.njit(cache=True)
def _select(q, i, j, cell_part, radius):
    """Indices of the pairs closer than ``radius``."""
    keep = np.empty(i.shape[0], dtype=np.int64)
    count = 0
    r2 = radius * radius
    for p in range(i.shape[0]):
        a, b = i[p], j[p]
        rx = q[b, 0] - q[a, 0] + cell_part[p, 0]
        ry = q[b, 1] - q[a, 1] + cell_part[p, 1]
        rz = q[b, 2] - q[a, 2] + cell_part[p, 2]
        if rx * rx + ry * ry + rz * rz < r2:
            keep[count] = p
            count += 1
    return keep[:count]


@numba.njit(cache=True)
def _sweep(q, i, j, cell_part, pairs, distance, slack, moved, limit, apply):
    """One Gauss-Seidel sweep over ``pairs``: each pair overlapping by more than ``slack`` is
    pushed apart to ``distance``, half each way, at once (only counted when not ``apply``).
    Returns (overlapping pairs found, largest overlap found, a particle's accumulated push
    exceeded ``limit``)."""
    found = 0
    worst = 0.0
    far = False
    for p in pairs:
        a, b = i[p], j[p]
        rx = q[b, 0] - q[a, 0] + cell_part[p, 0]
        ry = q[b, 1] - q[a, 1] + cell_part[p, 1]
        rz = q[b, 2] - q[a, 2] + cell_part[p, 2]
        dist = np.sqrt(rx * rx + ry * ry + rz * rz)
        overlap = distance - dist
        if overlap > worst:
            worst = overlap
        if overlap > slack:
            found += 1
            if not apply:
                continue
            scale = 0.5 * overlap / max(dist, 1e-12 * distance)
            push = (scale * rx, scale * ry, scale * rz)
            for axis in range(3):
                q[b, axis] += push[axis]
                q[a, axis] -= push[axis]
                moved[b, axis] += push[axis]
                moved[a, axis] -= push[axis]
            for c in (a, b):
                if moved[c, 0] ** 2 + moved[c, 1] ** 2 + moved[c, 2] ** 2 > limit:
                    far = True
    return found, worst, far


def push_apart(
    nl: NeighbourList,
    time: float,
    distance: float,
    sweeps: int = 20,
    tolerance: float = CORRECTION_TOLERANCE,
) -> Correction:
    """Push overlapping pairs of ``nl``'s current frame apart in place (``nl.q`` moves); see the
    module doc. ``distance`` in length units (the diameter for touching spheres). The caller
    checks that the list itself is still valid afterwards (``nl.stale``)."""
    s = nl.state
    q = nl.q
    start = q.copy()
    cell_part = s.shift @ le_cell(nl.box, nl.unwrapped_offset(time))
    slack = tolerance * distance
    margin = (CANDIDATE_MARGIN - 1.0) * distance
    pairs = _select(q, s.i, s.j, cell_part, CANDIDATE_MARGIN * distance)
    moved = np.zeros_like(q)
    limit = 0.25 * margin * margin
    # each sweep counts the overlaps it meets and pushes them apart; the first sweep's count is
    # the frame's overlaps before the correction, a sweep that meets none ends it
    before, worst_before, far = _sweep(
        q, s.i, s.j, cell_part, pairs, distance, slack, moved, limit, True
    )
    after, worst_after, done = before, worst_before, 1
    while after and done <= sweeps:
        if far:  # an outside pair may touch now: choose the candidates again
            pairs = _select(q, s.i, s.j, cell_part, CANDIDATE_MARGIN * distance)
            moved[:] = 0.0
        after, worst_after, far = _sweep(
            q, s.i, s.j, cell_part, pairs, distance, slack, moved, limit, True
        )
        done += 1
    worst_before, worst_after = max(worst_before, 0.0) / distance, max(worst_after, 0.0) / distance
    shift = q - start
    rms = float(np.sqrt(np.einsum("nc,nc->n", shift, shift).mean())) if len(q) else 0.0
    return Correction(before, after, worst_before, worst_after, done, rms)
