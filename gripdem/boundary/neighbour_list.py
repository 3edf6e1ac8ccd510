"""A neighbour list with a skin (Verlet list) for a sequence of frames, Lees-Edwards aware.

Pairs within ``cutoff + skin`` are found once (:func:`gripdem.boundary.neighbours.le_cell`, vesin
on the triclinic LE lattice) with the integer image shift ``n`` of every pair; later frames
recompute each listed pair's vector from the current positions and offset, exactly, and keep the
pairs within ``cutoff``. Nothing is searched again until a pair outside the list could have come
within the cut-off (docs/spec/dem.md#numerical-traps, as the DEM's list):

    2 * max_i |D_i| + |strain since the build| * (cutoff + skin) >= skin  ->  rebuild

``D_i`` is particle i's displacement since the build relative to the affine flow of the sheared
cell (the whole displacement in a periodic box), the strain term the relative motion the affine
flow gives two particles up to ``cutoff + skin`` apart.

Positions between builds are followed as physical lattice images (``q``): the image of the new
wrapped position nearest the previous one, in the LE lattice of the current, *unwrapped* offset
``delta_b + image_velocity * (t - t_b)`` (continuous in time, so a listed image index ``n`` keeps
naming the same physical image even when the wrapped offset jumps by ``lz``). A pair's vector is
``q_j - q_i + n @ cell(delta)``, the minimum image while the pair is within the cut-off.

Shapes: positions ``(N, 3)`` float64 wrapped into the box; pairs ``i < j`` is not assumed, each
pair appears once (vesin's half list).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gripdem.boundary.cell import Box
from gripdem.boundary.images import minimum_image
from gripdem.boundary.neighbours import le_cell, neighbour_pairs_with_shifts


@dataclass
class ListState:
    """One build: positions and offset at the build, the pairs and their image shifts."""

    positions: np.ndarray  # (N, 3) wrapped positions at the build
    offset: float  # wrapped LE offset at the build
    time: float  # absolute time of the build
    i: np.ndarray  # (P,) int64
    j: np.ndarray  # (P,) int64
    shift: np.ndarray  # (P, 3) float64 whole numbers: vector = q_j - q_i + shift @ cell


class NeighbourList:
    """Pairs within ``cutoff`` of a sequence of frames from a list within ``cutoff + skin``.

    Args:
        box: the orthorhombic box.
        cutoff, skin: lengths (same units as the positions); ``cutoff + skin`` must be below half
            the smallest box length.
        image_velocity: z velocity of the +x image cell (``Boundary.image_velocity``; 0 when
            periodic), which also sets the affine flow ``u_z = image_velocity * x / lx``.
    """

    def __init__(self, box: Box, cutoff: float, skin: float, image_velocity: float = 0.0):
        if not (cutoff > 0 and skin >= 0):
            raise ValueError(f"neighbour list needs cutoff > 0 and skin >= 0, got {cutoff}, {skin}")
        if 2 * (cutoff + skin) >= float(box.lengths.min()):
            raise ValueError(
                f"neighbour list radius {cutoff + skin:g} (cut-off + skin) must be below half the "
                f"smallest box length {box.lengths.min():g}"
            )
        self.box = box
        self.cutoff = float(cutoff)
        self.skin = float(skin)
        self.image_velocity = float(image_velocity)
        self.state: ListState | None = None
        self.q: np.ndarray | None = None  # (N, 3) physical images since the build
        self.builds = 0

    # ---- building and following ---------------------------------------------------------
    def build(self, positions: np.ndarray, offset: float, time: float) -> None:
        """Search all pairs within ``cutoff + skin`` at this frame."""
        positions = np.ascontiguousarray(positions, dtype=np.float64)
        i, j, shift = neighbour_pairs_with_shifts(
            positions, self.box, offset, self.cutoff + self.skin
        )
        self.state = ListState(positions.copy(), float(offset), float(time), i, j, shift)
        self.q = positions.copy()
        self.builds += 1

    def unwrapped_offset(self, time: float) -> float:
        """The offset at ``time`` continued from the build's, without wrapping."""
        return self.state.offset + self.image_velocity * (float(time) - self.state.time)

    def follow(self, positions: np.ndarray, time: float) -> np.ndarray:
        """Physical images ``q`` of this frame's wrapped positions: the image nearest the
        previous frame's (each particle moves less than half a box per frame)."""
        delta = self.unwrapped_offset(time)
        return self.q + minimum_image(np.asarray(positions, np.float64) - self.q, self.box, delta)

    def strain(self, time: float) -> float:
        """Strain of the affine flow since the build (0 in a periodic box)."""
        return self.image_velocity * (float(time) - self.state.time) / self.box.lx

    def stale(self, q: np.ndarray, time: float) -> bool:
        """Could a pair outside the list be within the cut-off at ``q`` (see module doc)?"""
        moved = q - self.state.positions
        gamma = self.strain(time)
        if gamma:
            x_mid = 0.5 * (q[:, 0] + self.state.positions[:, 0])
            moved[:, 2] -= gamma * x_mid
        largest = float(np.sqrt(np.einsum("nc,nc->n", moved, moved).max())) if len(q) else 0.0
        return 2.0 * largest + abs(gamma) * (self.cutoff + self.skin) >= self.skin

    def update(self, positions: np.ndarray, offset: float, time: float) -> None:
        """Move the list to a new frame (wrapped positions, wrapped offset, absolute time),
        rebuilding it when it has gone stale."""
        if self.state is None:
            self.build(positions, offset, time)
            return
        q = self.follow(positions, time)
        if self.stale(q, time):
            self.build(positions, offset, time)
        else:
            self.q = q

    # ---- the pairs of the current frame ---------------------------------------------------
    def vectors(self, time: float, q: np.ndarray | None = None) -> np.ndarray:
        """``(P, 3)`` vectors ``r_j - r_i`` of every listed pair at the current frame (or at the
        physical images ``q`` of the same time)."""
        q = self.q if q is None else q
        cell = le_cell(self.box, self.unwrapped_offset(time))
        s = self.state
        return q[s.j] - q[s.i] + s.shift @ cell

    def pairs(self, time: float, cutoff: float | None = None):
        """``(i, j, vectors)`` of the listed pairs within ``cutoff`` (default the list's) at the
        current frame, each pair once."""
        cutoff = self.cutoff if cutoff is None else float(cutoff)
        if cutoff > self.cutoff:
            raise ValueError(f"asked for pairs within {cutoff:g}, the list holds {self.cutoff:g}")
        vec = self.vectors(time)
        keep = np.einsum("pc,pc->p", vec, vec) < cutoff * cutoff
        return self.state.i[keep], self.state.j[keep], vec[keep]
