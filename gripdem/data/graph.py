"""The fixed interaction graph at the last observed frame (SPEC §5), as a sparse edge list.

Neighbours: every pair whose LE-aware minimum-image centre distance is below the cut-off D
(default 3 particle diameters). Found in O(n) with ``vesin`` on the triclinic lattice of the
Lees-Edwards images, cell vectors ``(lx, 0, δ), (0, ly, 0), (0, 0, lz)`` with δ of that frame
(a periodic box is the case δ = 0). :func:`brute_force_pairs` is the O(n²) reference.

Normalisation exactly as the authors' scripts: ``A_ij = 1`` for neighbours and for ``i = j``
(distance 0), ``Λ_ii = Σ_k A_ik + α``, ``G_fixed = I/(1+α) + Λ^-1/2 A Λ^-1/2`` (α = 0.001).
An isolated particle gets the bounded self weight ``1/(1+α) + 1/(1+α)``, never ``1/α``.

Edge list convention: ``edge_index[0] = i`` (the row of ``G``: the particle that receives),
``edge_index[1] = j`` (its neighbour), so a graph operation is
``out[i] += edge_weight[e] * feature[j]``. Every particle has its self pair ``(i, i)`` in the
list, carrying the whole diagonal of ``G_fixed``. ``edge_vector`` is the minimum-image vector
``r_j - r_i`` and ``edge_distance`` its length, both in units of ``length_unit`` (the particle
diameter in the DataModule), float32. ``edge_gap`` is the surface gap ``distance - 1`` of spheres
whose diameter is the length unit, computed in float64 before the cast: contact overlaps are
~1e-5 d, below float32's resolution of a distance near 1 (6e-8) by only a factor of 200.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import vesin

from gripdem.boundary import Box, minimum_image

#: the paper's α in Λ_ii = Σ_k A_ik + α
DEFAULT_ALPHA = 0.001


@dataclass(frozen=True)
class Graph:
    """Sparse ``G_fixed`` of one frame: ``E`` edges including ``N`` self pairs."""

    edge_index: np.ndarray  # (2, E) int64, rows i (receiver) and j (neighbour)
    edge_weight: np.ndarray  # (E,) float32, G_fixed[i, j]
    edge_vector: np.ndarray  # (E, 3) float32, minimum-image r_j - r_i / length_unit
    edge_distance: np.ndarray  # (E,) float32, |edge_vector|
    edge_gap: np.ndarray  # (E,) float32, |edge_vector| - 1 from float64 (surface gap)
    n_nodes: int

    @property
    def n_edges(self) -> int:
        return int(self.edge_index.shape[1])

    @property
    def nbytes(self) -> int:
        return sum(
            a.nbytes
            for a in (
                self.edge_index,
                self.edge_weight,
                self.edge_vector,
                self.edge_distance,
                self.edge_gap,
            )
        )

    def dense(self) -> np.ndarray:
        """``(N, N)`` float64 G_fixed (for tests and small systems only)."""
        g = np.zeros((self.n_nodes, self.n_nodes))
        np.add.at(g, (self.edge_index[0], self.edge_index[1]), self.edge_weight)
        return g


def _lattice(box: Box, offset: float) -> np.ndarray:
    """Rows are the LE lattice vectors (lx, 0, δ), (0, ly, 0), (0, 0, lz)."""
    return np.array([[box.lx, 0.0, offset], [0.0, box.ly, 0.0], [0.0, 0.0, box.lz]])


def neighbour_pairs(
    positions: np.ndarray, box: Box, offset: float, cutoff: float, n_threads: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All ordered pairs ``i != j`` with LE minimum-image distance ``< cutoff``, in O(n).

    positions ``(N, 3)`` float64 wrapped; ``offset`` the frame's LE offset δ (0 if periodic).
    Returns ``(i, j, vector)`` with int64 ``(P,)`` indices and ``(P, 3)`` float64
    minimum-image vectors ``r_j - r_i`` (both directions of every pair).
    """
    positions = np.ascontiguousarray(positions, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise ValueError(f"positions must have shape (N, 3), got {positions.shape}")
    if not cutoff > 0:
        raise ValueError(f"graph cut-off must be positive, got {cutoff!r}")
    offset = float(offset)
    nl = vesin.NeighborList(cutoff=float(cutoff), full_list=False, n_threads=n_threads)
    i, j, vec = nl.compute(positions, _lattice(box, offset), True, "ijD")
    i, j = i.astype(np.int64), j.astype(np.int64)
    if 2 * cutoff >= min(box.lx, box.ly, box.lz):
        # More than one image of a pair (or a particle's own image) can lie within the
        # cut-off: keep each pair once, with the SPEC's minimum image, if that is within it.
        keep = i != j
        i, j = i[keep], j[keep]
        lo, hi = np.minimum(i, j), np.maximum(i, j)
        _, first = np.unique(lo * len(positions) + hi, return_index=True)
        i, j = lo[first], hi[first]
        vec = minimum_image(positions[j] - positions[i], box, offset)
        keep = np.einsum("pc,pc->p", vec, vec) < cutoff * cutoff
        i, j, vec = i[keep], j[keep], vec[keep]
    # Otherwise every lattice vector is longer than 2*cutoff, so each pair has one image within
    # the cut-off and it is the minimum image: vesin's vectors are the answer as they are.
    return np.concatenate([i, j]), np.concatenate([j, i]), np.concatenate([vec, -vec])


def brute_force_pairs(
    positions: np.ndarray, box: Box, offset: float, cutoff: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """O(n²) reference for :func:`neighbour_pairs`: minimum image of every pair (numpy)."""
    positions = np.asarray(positions, dtype=np.float64)
    vec = minimum_image(positions[None, :, :] - positions[:, None, :], box, float(offset))
    dist2 = np.einsum("ijc,ijc->ij", vec, vec)
    np.fill_diagonal(dist2, np.inf)
    i, j = np.nonzero(dist2 < cutoff * cutoff)
    return i.astype(np.int64), j.astype(np.int64), vec[i, j]


def fixed_graph_weights(
    i: np.ndarray, j: np.ndarray, n_nodes: int, alpha: float = DEFAULT_ALPHA
) -> tuple[np.ndarray, np.ndarray]:
    """G_fixed on ``[self pairs, then (i, j) pairs]``: returns ``(self_weight (N,),
    pair_weight (P,))`` in float64. ``(i, j)`` must hold both directions of every pair."""
    lam = np.bincount(i, minlength=n_nodes).astype(np.float64) + 1.0 + alpha  # + A_ii = 1
    inv_sqrt = 1.0 / np.sqrt(lam)
    self_weight = 1.0 / (1.0 + alpha) + inv_sqrt * inv_sqrt
    return self_weight, inv_sqrt[i] * inv_sqrt[j]


def build_graph(
    positions: np.ndarray,
    box: Box,
    offset: float,
    cutoff: float,
    alpha: float = DEFAULT_ALPHA,
    length_unit: float = 1.0,
    n_threads: int = 1,
) -> Graph:
    """The fixed graph of one frame: ``positions (N, 3)`` wrapped, ``offset`` its LE offset,
    ``cutoff`` in metres; edge vectors and distances are divided by ``length_unit``."""
    n = len(positions)
    i, j, vec = neighbour_pairs(positions, box, offset, cutoff, n_threads)
    self_w, pair_w = fixed_graph_weights(i, j, n, alpha)
    nodes = np.arange(n, dtype=np.int64)
    vec = np.concatenate([np.zeros((n, 3)), vec]) / length_unit
    distance = np.sqrt(np.einsum("ec,ec->e", vec, vec))
    return Graph(
        edge_index=np.stack([np.concatenate([nodes, i]), np.concatenate([nodes, j])]),
        edge_weight=np.concatenate([self_w, pair_w]).astype(np.float32),
        edge_vector=vec.astype(np.float32),
        edge_distance=distance.astype(np.float32),
        edge_gap=(distance - 1.0).astype(np.float32),
        n_nodes=n,
    )
