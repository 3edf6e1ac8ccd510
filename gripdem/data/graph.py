"""The fixed interaction graph at the last observed frame (docs/spec/model.md#fixed-graph), as a
sparse edge list.

Neighbours: every pair whose LE-aware minimum-image centre distance is below the cut-off D
(default 3 particle diameters), found in O(n) by :func:`gripdem.boundary.neighbour_pairs`
(``vesin`` on the triclinic lattice of the Lees-Edwards images) and kept in both directions.

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

from gripdem.boundary import Box, neighbour_pairs

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
    i, j, vec = neighbour_pairs(positions, box, offset, cutoff, n_threads)
    return graph_from_pairs(i, j, vec, len(positions), alpha, length_unit)


def graph_from_pairs(
    i: np.ndarray,
    j: np.ndarray,
    vectors: np.ndarray,
    n_nodes: int,
    alpha: float = DEFAULT_ALPHA,
    length_unit: float = 1.0,
) -> Graph:
    """The fixed graph from each pair once: ``i``, ``j`` ``(P,)`` and minimum-image vectors
    ``r_j - r_i`` ``(P, 3)`` float64 (from :func:`gripdem.boundary.neighbour_pairs` or a
    :class:`gripdem.boundary.NeighbourList`); adds the reverse pairs and the self pairs."""
    i, j = np.concatenate([i, j]), np.concatenate([j, i])
    vec = np.concatenate([vectors, -vectors])
    self_w, pair_w = fixed_graph_weights(i, j, n_nodes, alpha)
    nodes = np.arange(n_nodes, dtype=np.int64)
    vec = np.concatenate([np.zeros((n_nodes, 3)), vec]) / length_unit
    distance = np.sqrt(np.einsum("ec,ec->e", vec, vec))
    return Graph(
        edge_index=np.stack([np.concatenate([nodes, i]), np.concatenate([nodes, j])]),
        edge_weight=np.concatenate([self_w, pair_w]).astype(np.float32),
        edge_vector=vec.astype(np.float32),
        edge_distance=distance.astype(np.float32),
        edge_gap=(distance - 1.0).astype(np.float32),
        n_nodes=n_nodes,
    )
