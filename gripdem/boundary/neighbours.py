"""The one LE-aware neighbour search: every pair of one frame closer than a cut-off, in O(n).

``vesin`` (cell lists) on the triclinic lattice of the Lees-Edwards images, cell vectors
``(lx, 0, delta), (0, ly, 0), (0, 0, lz)`` with delta of that frame (a periodic box is the case
delta = 0): its neighbour set equals a brute-force LE minimum-image search exactly
(docs/spec/conventions.md#minimum-image). The graph of the models, the physics report, the rollout
checks and the in-memory stepper all call :func:`neighbour_pairs`; :func:`brute_force_pairs` is the
O(n²) reference for tests.
"""

from __future__ import annotations

import numpy as np

from gripdem.boundary.cell import Box
from gripdem.boundary.images import minimum_image

#: smallest search radius handed to vesin, as a fraction of the smallest box length (vesin
#: refuses cut-offs far below the box size: too many cells); shorter cut-offs search this far
#: and keep the pairs within the cut-off
MIN_SEARCH_FRACTION = 1e-3


def le_cell(box: Box, offset: float = 0.0) -> np.ndarray:
    """Rows are the triclinic Lees-Edwards cell vectors ``(lx,0,delta), (0,ly,0), (0,0,lz)``."""
    return np.array([[box.lx, 0.0, float(offset)], [0.0, box.ly, 0.0], [0.0, 0.0, box.lz]])


def neighbour_pairs(
    positions: np.ndarray,
    box: Box,
    offset: float,
    cutoff: float,
    n_threads: int = 1,
    both_directions: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each pair ``(i, j)``, ``i != j``, with LE minimum-image distance ``< cutoff``, once
    (``both_directions``: then every pair again as ``(j, i)`` with the opposite vector, after
    all the first ones).

    positions ``(N, 3)`` float64 wrapped; ``offset`` the frame's LE offset delta (0 if
    periodic). Returns int64 ``i``, ``j`` ``(P,)`` and the float64 minimum-image vectors
    ``r_j - r_i`` ``(P, 3)``. A cut-off of half the smallest box length or more (several
    images of a pair could lie within it) keeps each pair once, with the minimum image of
    docs/spec/conventions.md#minimum-image.
    """
    positions = np.ascontiguousarray(positions, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise ValueError(f"positions must have shape (N, 3), got {positions.shape}")
    if not cutoff > 0:
        raise ValueError(f"neighbour cut-off must be positive, got {cutoff!r}")
    offset = float(offset)
    radius = max(float(cutoff), MIN_SEARCH_FRACTION * float(box.lengths.min()))
    nl = _vesin_list(radius, n_threads)
    i, j, vec = nl.compute(positions, le_cell(box, offset), True, "ijD")
    i, j = i.astype(np.int64), j.astype(np.int64)
    if 2 * cutoff >= min(box.lx, box.ly, box.lz):
        # More than one image of a pair (or a particle's own image) can lie within the
        # cut-off: keep each pair once, with the minimum image of
        # docs/spec/conventions.md#minimum-image, if that is within it.
        keep = i != j
        i, j = i[keep], j[keep]
        lo, hi = np.minimum(i, j), np.maximum(i, j)
        _, first = np.unique(lo * len(positions) + hi, return_index=True)
        i, j = lo[first], hi[first]
        vec = minimum_image(positions[j] - positions[i], box, offset)
    # Otherwise every lattice vector is longer than 2*cutoff, so each pair has one image within
    # the cut-off and it is the minimum image: vesin's vectors are the answer as they are.
    if radius > cutoff or 2 * cutoff >= min(box.lx, box.ly, box.lz):
        keep = np.einsum("pc,pc->p", vec, vec) < cutoff * cutoff
        i, j, vec = i[keep], j[keep], vec[keep]
    if both_directions:
        return np.concatenate([i, j]), np.concatenate([j, i]), np.concatenate([vec, -vec])
    return i, j, vec


def _vesin_list(radius: float, n_threads: int):
    """vesin's half neighbour list of ``radius``. vesin is imported here, not with the module:
    it imports torch where torch is installed (about 1.2 s), which a caller that only names
    files or configs (a sweep's controlling process, the DEM's workers) does not need."""
    import vesin

    return vesin.NeighborList(cutoff=radius, full_list=False, n_threads=n_threads)


def neighbour_pairs_with_shifts(
    positions: np.ndarray, box: Box, offset: float, cutoff: float, n_threads: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each pair within ``cutoff`` once, with its lattice image: ``(i, j, shift)`` with int64
    ``i``, ``j`` ``(P,)`` and float64 whole-number ``shift`` ``(P, 3)`` such that the minimum
    image vector is ``r_j - r_i + shift @ le_cell(box, offset)``. Needs ``cutoff`` below half the
    smallest box length (one image per pair); :class:`gripdem.boundary.NeighbourList` keeps the
    shifts to recompute the vectors at later frames."""
    positions = np.ascontiguousarray(positions, dtype=np.float64)
    if not 0 < 2 * cutoff < float(box.lengths.min()):
        raise ValueError(
            f"a pair search with image shifts needs 0 < cut-off < half the smallest box length "
            f"({0.5 * box.lengths.min():g}), got {cutoff!r}"
        )
    radius = max(float(cutoff), MIN_SEARCH_FRACTION * float(box.lengths.min()))
    nl = _vesin_list(radius, n_threads)
    i, j, shift, vec = nl.compute(positions, le_cell(box, float(offset)), True, "ijSD")
    keep = np.einsum("pc,pc->p", vec, vec) < cutoff * cutoff
    return i[keep].astype(np.int64), j[keep].astype(np.int64), shift[keep].astype(np.float64)


def brute_force_pairs(
    positions: np.ndarray, box: Box, offset: float, cutoff: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """O(n²) reference: every ordered pair ``(i, j)``, ``i != j``, within the cut-off (both
    directions), minimum image of every pair (numpy)."""
    positions = np.asarray(positions, dtype=np.float64)
    vec = minimum_image(positions[None, :, :] - positions[:, None, :], box, float(offset))
    dist2 = np.einsum("ijc,ijc->ij", vec, vec)
    np.fill_diagonal(dist2, np.inf)
    i, j = np.nonzero(dist2 < cutoff * cutoff)
    return i.astype(np.int64), j.astype(np.int64), vec[i, j]
