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

Where pairs end: a moved pair ends at ``distance * (1 - overlap)``; ``overlap`` 0 is exact
touching, and :func:`resting_overlap` measures the data's own resting contacts (the stepper's
``contact_overlap=None``): the DEM's touching pairs sit a few 1e-5 d inside contact, and pairs
placed exactly at the contact distance are a different microstructure (in a g(r) binned at the
contact distance, they fall on the other side of the bin edge).

Captured contacts (``capture > 0``; off by default): the DEM's particles are cohesive (van der
Waals below a gap of 0.1 d, at its strongest below the regularisation gap 0.002 d), so a pair
that comes that close snaps shut and stays in contact until a force pulls it apart; a model's
small position errors leave pairs hovering at small gaps and open contacts at random instead
(the contact-number deficit of long rollouts, docs/how-to/ensembles.md#microstructure). With
``capture``, every pair whose gap is below ``capture`` contact distances is pulled into contact
(to the same end point as a push), half each way, once, in the first sweep; a pair that the model
moved further apart within one frame is let go (the contact breaks, as one that the flow pulls
apart does in the DEM). Pulls are pairwise like pushes (the centre of mass stays put), and the push
sweeps that follow remove any overlap a pull made, to the same tolerance. One pull per frame,
not pulls to convergence: closing every opened contact in every sweep froze the measured
suspension into a gel (coordination +20-30 %, the mean flow lost).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from gripdem.boundary import NeighbourList, le_cell

#: candidate pairs: within this factor of the contact distance when chosen. A speed setting:
#: while no particle is pushed more than half the margin within a sweep (a model's frames:
#: pushes ~1e-4 d), no pair outside it can touch and the result is the same bit for bit at any
#: margin (the shipped models' 2000-frame rollouts: identical at 1.01 and 1.05); 1.01
#: against 1.05: 22 % fewer candidates, 8 % less correction time at 2000 particles
CANDIDATE_MARGIN = 1.01
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
    #: pairs pulled into contact (capture, first sweep)
    pulled: int = 0
    #: how far the correction moved each particle ``(N, 3)`` (length units)
    moves: np.ndarray | None = None


@numba.njit(cache=True)
def _select(q, i, j, shift, cell, radius):
    """The pairs closer than ``radius``, compacted: their particles ``a``, ``b`` and their
    image parts ``shift @ cell`` (contiguous, so that the sweeps read them in order)."""
    count = 0
    keep = np.empty(i.shape[0], dtype=np.int64)
    part = np.empty((i.shape[0], 3))
    r2 = radius * radius
    for p in range(i.shape[0]):
        a, b = i[p], j[p]
        px = shift[p, 0] * cell[0, 0] + shift[p, 1] * cell[1, 0] + shift[p, 2] * cell[2, 0]
        py = shift[p, 0] * cell[0, 1] + shift[p, 1] * cell[1, 1] + shift[p, 2] * cell[2, 1]
        pz = shift[p, 0] * cell[0, 2] + shift[p, 1] * cell[1, 2] + shift[p, 2] * cell[2, 2]
        rx = q[b, 0] - q[a, 0] + px
        ry = q[b, 1] - q[a, 1] + py
        rz = q[b, 2] - q[a, 2] + pz
        if rx * rx + ry * ry + rz * rz < r2:
            keep[count] = p
            part[count, 0], part[count, 1], part[count, 2] = px, py, pz
            count += 1
    return i[keep[:count]], j[keep[:count]], part[:count].copy()


def resting_overlap(nl: NeighbourList, time: float, distance: float, tolerance: float) -> float:
    """The median overlap (a fraction of ``distance``) of the pairs of ``nl``'s current frame
    that overlap by less than ``tolerance`` (the resting contacts a correction leaves alone;
    the built-in DEM's sit ~1e-5-1e-4 d inside contact, where elastic repulsion balances
    cohesion); 0 when no pair does."""
    _, _, vec = nl.pairs(time, distance)
    overlaps = 1.0 - np.sqrt(np.einsum("pc,pc->p", vec, vec)) / distance
    resting = overlaps[(overlaps > 0) & (overlaps < tolerance)]
    return float(np.median(resting)) if len(resting) else 0.0


@numba.njit(cache=True)
def _sweep(q, i, j, cell_part, capture, distance, target, slack, moved, limit):
    """One Gauss-Seidel sweep over the candidate pairs (:func:`_select`'s arrays, in order):
    each pair overlapping ``distance`` by more than ``slack`` is pushed apart to ``target``,
    half each way, at once; a pair farther than ``target`` with a gap below ``capture`` is
    pulled to ``target`` the same way. Returns (overlapping pairs found, largest overlap found,
    a particle's accumulated move exceeded ``limit``, pairs pulled)."""
    found = 0
    pulled = 0
    worst = 0.0
    far = False
    for p in range(i.shape[0]):
        a, b = i[p], j[p]
        rx = q[b, 0] - q[a, 0] + cell_part[p, 0]
        ry = q[b, 1] - q[a, 1] + cell_part[p, 1]
        rz = q[b, 2] - q[a, 2] + cell_part[p, 2]
        dist = np.sqrt(rx * rx + ry * ry + rz * rz)
        overlap = distance - dist
        if overlap > worst:
            worst = overlap
        move = overlap > slack
        if move:
            found += 1
        elif capture > 0.0 and dist - target > 1e-9 * distance and -overlap < capture:
            move = True
            pulled += 1
        if move:
            scale = 0.5 * (target - dist) / max(dist, 1e-12 * distance)
            push = (scale * rx, scale * ry, scale * rz)
            for axis in range(3):
                q[b, axis] += push[axis]
                q[a, axis] -= push[axis]
                moved[b, axis] += push[axis]
                moved[a, axis] -= push[axis]
            for c in (a, b):
                if moved[c, 0] ** 2 + moved[c, 1] ** 2 + moved[c, 2] ** 2 > limit:
                    far = True
    return found, worst, far, pulled


@numba.njit(cache=True)
def _correct(q, i, j, shift, cell, reach, capture, distance, target, slack, limit, sweeps):
    """The sweeps of :func:`push_apart` (lengths in position units), in one compiled call.
    Returns (overlaps before, worst before, pulled, overlaps after, worst after, sweeps)."""
    a, b, part = _select(q, i, j, shift, cell, reach)
    moved = np.zeros_like(q)
    before, worst_before, far, pulled = _sweep(
        q, a, b, part, capture, distance, target, slack, moved, limit
    )
    after, worst_after, done = before, worst_before, 1
    while after and done <= sweeps:
        if far:  # an outside pair may touch now: choose the candidates again
            a, b, part = _select(q, i, j, shift, cell, reach)
            moved[:] = 0.0
        after, worst_after, far, _ = _sweep(
            q, a, b, part, 0.0, distance, target, slack, moved, limit
        )
        done += 1
    return before, worst_before, pulled, after, worst_after, done


def push_apart(
    nl: NeighbourList,
    time: float,
    distance: float,
    sweeps: int = 20,
    tolerance: float = CORRECTION_TOLERANCE,
    capture: float = 0.0,
    overlap: float = 0.0,
) -> Correction:
    """Push overlapping pairs of ``nl``'s current frame apart in place (``nl.q`` moves), and
    with ``capture`` > 0 (contact distances) pull pairs closer than that into contact first;
    see the module doc. ``distance`` in length units (the diameter for touching spheres);
    moved pairs end ``overlap`` (a fraction of ``distance``, below ``tolerance``) inside it.
    The caller checks that the list itself is still valid afterwards (``nl.stale``)."""
    s = nl.state
    q = nl.q
    start = q.copy()
    cell = le_cell(nl.box, nl.unwrapped_offset(time))
    reach = CANDIDATE_MARGIN + max(capture, 0.0)
    margin = (reach - 1.0) * distance
    # each sweep counts the overlaps it meets and pushes them apart; the first sweep's count is
    # the frame's overlaps before the correction, a sweep that meets none ends it; captured
    # pairs are pulled in the first sweep only, later sweeps push
    before, worst_before, pulled, after, worst_after, done = _correct(
        q, s.i, s.j, s.shift, cell, reach * distance, capture * distance, distance,
        (1.0 - overlap) * distance, tolerance * distance, 0.25 * margin * margin, sweeps,
    )  # fmt: skip
    worst_before, worst_after = max(worst_before, 0.0) / distance, max(worst_after, 0.0) / distance
    moves = q - start
    rms = float(np.sqrt(np.einsum("nc,nc->n", moves, moves).mean())) if len(q) else 0.0
    return Correction(before, after, worst_before, worst_after, done, rms, pulled, moves)
