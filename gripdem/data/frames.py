"""One simulation prepared once in memory, so that a window costs slicing, not recomputing.

A window of the exact frame (encoding ``unwrapped``) needs its lattice-continuous steps anchored
at its last observed frame, their normalisation, the graph at that frame and which particles
cross an LE face over its targets. All of it comes from per-simulation arrays computed once:

- the frame-to-frame steps of the whole simulation (minimum image with the later frame's offset)
  and, per particle, the number of x-face crossings before each frame: a window's steps anchored
  at frame ``A`` are ``step_s + (cells_s - cells_A) * increment_s`` along z
  (:func:`gripdem.boundary.lattice_continuous_steps`, the same numbers element by element);
- their normalisation in float32 (only particles whose anchored steps differ from the raw ones,
  LE crossers near the window, are normalised again per window);
- the graph of each frame from neighbour lists with a skin (:class:`gripdem.boundary.NeighbourList`)
  built in frame order: a frame's pairs are its list's pairs recomputed at that frame.

Shapes: positions ``(T, N, 3)`` float64 wrapped, times ``(T,)`` absolute; steps ``(N, T-1, 3)``.
"""

from __future__ import annotations

import numpy as np

from gripdem.boundary import (
    Boundary,
    NeighbourList,
    apply_lattice_shift,
    lattice_shift,
    le_cell,
    le_offset_increments,
    minimum_image,
)
from gripdem.data.graph import DEFAULT_ALPHA, Graph, graph_from_pairs
from gripdem.data.normalizer import Normalizer

#: skin of the neighbour lists behind the graphs, in units of the graph cut-off
GRAPH_SKIN_FRACTION = 0.12


class SimulationFrames:
    """One simulation's frames, steps and graphs (see the module doc).

    Args:
        positions: ``(T, N, 3)`` wrapped; times: ``(T,)`` absolute; boundary: the scene's.
        normalizer: the exact frame's channel statistics (steps are normalised with it).
        graph_cutoff: in length units; length_unit: the diameter (edge features' unit).
    """

    def __init__(
        self,
        positions: np.ndarray,
        times: np.ndarray,
        boundary: Boundary,
        normalizer: Normalizer,
        graph_cutoff: float,
        length_unit: float,
        graph_alpha: float = DEFAULT_ALPHA,
    ):
        self.positions = np.asarray(positions, dtype=np.float64)
        # particle-major copy: a window's frames of one particle are contiguous
        self.by_particle = np.ascontiguousarray(self.positions.transpose(1, 0, 2))
        self.times = np.asarray(times, dtype=np.float64)
        self.boundary = boundary
        self.offsets = boundary.offset(self.times)
        self.le = boundary.is_lees_edwards
        self.normalizer = normalizer
        self.length_unit = float(length_unit)
        self.graph_cutoff = float(graph_cutoff)
        self.graph_alpha = float(graph_alpha)
        box = boundary.box
        raw = np.moveaxis(self.positions[1:] - self.positions[:-1], 0, 1)  # (N, T-1, 3)
        later = self.offsets[None, 1:] if self.le else None
        shift = lattice_shift(raw, box, later)
        self.steps = apply_lattice_shift(raw, shift, box, later)
        self.normalized = normalizer.normalize(self.steps).astype(np.float32)
        crossings = (-shift[..., 0]).astype(np.int64)  # +1: out through +x
        self.crossed_step = crossings != 0  # (N, T-1)
        self.cells = np.concatenate(
            [np.zeros((len(crossings), 1), np.int64), np.cumsum(crossings, axis=1)], axis=1
        )  # (N, T): crossings before each frame
        self.increments = le_offset_increments(self.offsets, box) if self.le else None
        self._lists: list[NeighbourList] = []
        self._list_of_frame = np.full(len(self.times), -1, dtype=np.int64)

    @property
    def nbytes(self) -> int:
        arrays = (self.positions, self.by_particle, self.steps, self.normalized, self.cells)
        return sum(a.nbytes for a in arrays)

    # ---- steps ----------------------------------------------------------------------------
    def window_steps(self, start: int, stop: int, anchor: int) -> tuple[np.ndarray, np.ndarray]:
        """Steps of frames ``start .. stop-1`` anchored at frame ``anchor``: float64
        ``(N, stop-start-1, 3)`` and their normalised float32 copy."""
        steps = self.steps[:, start : stop - 1]
        normalized = self.normalized[:, start : stop - 1]
        if not self.le:
            return steps, normalized
        cells = self.cells[:, start : stop - 1] - self.cells[:, anchor, None]
        moved = np.flatnonzero(cells.any(axis=1))
        if moved.size == 0:
            return steps, normalized
        steps, normalized = steps.copy(), normalized.copy()
        fixed = steps[moved]
        fixed[..., 2] += cells[moved] * self.increments[start : stop - 1]
        steps[moved] = fixed
        normalized[moved] = self.normalizer.normalize(fixed).astype(np.float32)
        return steps, normalized

    def crossers(self, start: int, stop: int) -> np.ndarray:
        """``(N,)`` particles crossing an x face in a step of frames ``start .. stop-1``."""
        return self.crossed_step[:, start : stop - 1].any(axis=1)

    # ---- graphs -----------------------------------------------------------------------------
    def _prepare_lists(self) -> None:
        """Neighbour lists in frame order; each frame remembers the list that covers it."""
        box = self.boundary.box
        skin = GRAPH_SKIN_FRACTION * self.graph_cutoff
        nl = NeighbourList(box, self.graph_cutoff, skin, self.boundary.image_velocity)
        for t in range(len(self.times)):
            before = nl.builds
            nl.update(self.positions[t], float(self.offsets[t]), float(self.times[t]))
            if nl.builds != before:
                self._lists.append(_frozen(nl))
            self._list_of_frame[t] = len(self._lists) - 1

    def graph(self, frame: int) -> Graph:
        """The fixed graph of ``frame`` (pairs within the graph cut-off)."""
        if not self._lists:
            self._prepare_lists()
        nl = self._lists[self._list_of_frame[frame]]
        s = nl.state
        time = float(self.times[frame])
        delta = nl.unwrapped_offset(time)
        q = s.positions + minimum_image(self.positions[frame] - s.positions, nl.box, delta)
        vec = q[s.j] - q[s.i] + s.shift @ le_cell(nl.box, delta)
        keep = np.einsum("pc,pc->p", vec, vec) < self.graph_cutoff**2
        return graph_from_pairs(
            s.i[keep],
            s.j[keep],
            vec[keep],
            self.positions.shape[1],
            self.graph_alpha,
            self.length_unit,
        )


def _frozen(nl: NeighbourList) -> NeighbourList:
    """A copy of a list's current build (its state is replaced by the next build)."""
    copy = NeighbourList.__new__(NeighbourList)
    copy.__dict__.update(nl.__dict__)
    return copy


class FrameStore:
    """Simulations of a file prepared on first use (:class:`SimulationFrames`) and kept in memory
    up to ``memory_mb`` (least recently used dropped first). A simulation larger than the budget
    is not kept: :meth:`frames` returns None and the caller reads windows from the file."""

    def __init__(
        self,
        read_simulation,
        times: np.ndarray,
        boundary: Boundary,
        normalizer: Normalizer,
        graph_cutoff: float,
        length_unit: float,
        graph_alpha: float = DEFAULT_ALPHA,
        memory_mb: float = 2048.0,
        simulation_mb: float = 0.0,
    ):
        self.read_simulation = read_simulation  # sim -> (T, N, 3) positions
        self.times = times
        self.args = (boundary, normalizer, graph_cutoff, length_unit, graph_alpha)
        self.budget = memory_mb * 2**20
        # two copies of the positions, the steps and their float32 copy: ~3.6x the positions
        self.fits = simulation_mb * 3.6 * 2**20 <= self.budget
        self._frames: dict[int, SimulationFrames] = {}

    def use_normalizer(self, normalizer: Normalizer) -> None:
        """Normalise with other statistics from now on (prepared simulations are dropped)."""
        self.args = (self.args[0], normalizer, *self.args[2:])
        self._frames.clear()

    def frames(self, sim: int) -> SimulationFrames | None:
        if not self.fits:
            return None
        if sim in self._frames:
            self._frames[sim] = self._frames.pop(sim)  # most recently used last
            return self._frames[sim]
        prepared = SimulationFrames(self.read_simulation(sim), self.times[sim], *self.args)
        self._frames[sim] = prepared
        while sum(f.nbytes for f in self._frames.values()) > self.budget and len(self._frames) > 1:
            self._frames.pop(next(iter(self._frames)))
        return prepared

    def __getstate__(self) -> dict:
        """Workers start with an empty store (each prepares what it reads)."""
        return {**self.__dict__, "_frames": {}}
