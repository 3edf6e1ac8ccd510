"""The fixed graph of the models: the reference scripts' normalisation on the LE pair search."""

import numpy as np
import pytest

from gripdem.boundary import Box, brute_force_pairs, minimum_image
from gripdem.data.graph import DEFAULT_ALPHA, build_graph

BOX = Box(8.0, 7.0, 9.0)  # lengths in diameters; never cubic


def _configuration(box, n, seed):
    """Random positions with some exactly on the lower faces (and on two faces at once)."""
    rng = np.random.default_rng(seed)
    pos = (rng.random((n, 3)) - 0.5) * box.lengths
    pos[:15, 0] = -box.lx / 2
    pos[10:25, 2] = -box.lz / 2
    pos[20:30, 1] = -box.ly / 2
    pos[30:40, 0] = box.lx / 2 * (1 - 1e-15)  # just inside the +x face
    return pos


def test_normalisation_matches_the_reference_formula():
    offset, cutoff = 1.3, 2.0
    others = _configuration(BOX, 150, 4)
    far = np.linalg.norm(minimum_image(others, BOX, offset), axis=1) > cutoff + 0.1
    pos = np.concatenate([np.zeros((1, 3)), others[far]])  # particle 0 is isolated
    graph = build_graph(pos, BOX, offset, cutoff, length_unit=2.0)
    bi, bj, _ = brute_force_pairs(pos, BOX, offset, cutoff)
    n = len(pos)
    adjacency = np.eye(n)
    adjacency[bi, bj] = 1.0
    lam = adjacency.sum(axis=1) + DEFAULT_ALPHA
    expected = np.eye(n) / (1 + DEFAULT_ALPHA) + adjacency / np.sqrt(lam[:, None] * lam[None, :])
    np.testing.assert_allclose(graph.dense(), expected, rtol=1e-6)
    assert graph.n_edges == n + len(bi)
    # an isolated particle gets a bounded self weight, not 1/alpha
    assert not (bi == 0).any()
    assert graph.dense()[0, 0] == pytest.approx(2 / (1 + DEFAULT_ALPHA), rel=1e-6)
    assert graph.dense().max() < 2.01
    # edge features in the given length unit; self pairs at distance 0
    self_pairs = graph.edge_index[0] == graph.edge_index[1]
    assert self_pairs.sum() == n and (graph.edge_distance[self_pairs] == 0).all()
    assert (graph.edge_distance[~self_pairs] < cutoff / 2.0).all()
    np.testing.assert_allclose(
        np.linalg.norm(graph.edge_vector, axis=1), graph.edge_distance, rtol=1e-6
    )
    assert graph.edge_index.dtype == np.int64 and graph.edge_weight.dtype == np.float32


@pytest.mark.parametrize("gap", [-2.7e-5, -3.1e-6, 4.3e-6, 0.013])
def test_edge_gap_is_computed_in_float64(gap):
    """Contact overlaps of ~1e-5 d: the float32 distance minus 1 would be off by up to 6e-8
    (0.6 % of a 1e-5 overlap); the gap is taken in float64 before the cast. The pair sits
    across the LE x face of a shifted cell, metres as units (d = 2.5e-6 m)."""
    d = 2.5e-6
    box = Box(12.8 * d, 12.8 * d, 12.8 * d)
    offset = 0.3719 * box.lz
    a = np.array([0.5 * box.lx - 0.3 * d, 0.1 * d, 0.49 * box.lz])
    direction = np.array([0.6, 0.0, 0.8])
    b = a + (1.0 + gap) * d * direction
    b[0] -= box.lx  # wrap through +x: z shifted by the offset, then wrapped
    b[2] = (b[2] - offset + box.lz / 2) % box.lz - box.lz / 2
    graph = build_graph(np.stack([a, b]), box, offset, 1.5 * d, length_unit=d)
    pair = graph.edge_index[0] != graph.edge_index[1]
    assert pair.sum() == 2
    np.testing.assert_allclose(graph.edge_gap[pair], gap, rtol=1e-5)
    np.testing.assert_allclose(graph.edge_distance[pair], 1 + gap, rtol=1e-7)
    assert (graph.edge_gap[~pair] == -1).all()
