"""The fixed graph: vesin on the LE triclinic lattice against an O(n²) minimum-image search."""

import numpy as np
import pytest

from gripdem.boundary import Box, minimum_image
from gripdem.data.graph import (
    DEFAULT_ALPHA,
    brute_force_pairs,
    build_graph,
    neighbour_pairs,
)

BOX = Box(8.0, 7.0, 9.0)  # lengths in diameters; never cubic
SMALL = Box(4.0, 4.5, 5.0)  # cut-off 3 > l/2: several images of a pair lie within it


def _configuration(box, n, seed):
    """Random positions with some exactly on the lower faces (and on two faces at once)."""
    rng = np.random.default_rng(seed)
    pos = (rng.random((n, 3)) - 0.5) * box.lengths
    pos[:15, 0] = -box.lx / 2
    pos[10:25, 2] = -box.lz / 2
    pos[20:30, 1] = -box.ly / 2
    pos[30:40, 0] = box.lx / 2 * (1 - 1e-15)  # just inside the +x face
    return pos


def _offsets(box):
    lz = box.lz
    return [0.0, 1e-13, -1e-13, 0.37 * lz, -lz / 2, lz / 2 * (1 - 1e-15), lz - 1e-12, 3.3 * lz]


@pytest.mark.parametrize("box,cutoff", [(BOX, 3.0), (BOX, 1.7), (SMALL, 3.0)])
@pytest.mark.parametrize("seed", [0, 1])
def test_edges_equal_brute_force_minimum_image(box, cutoff, seed):
    pos = _configuration(box, 250, seed)
    n = len(pos)
    for offset in _offsets(box):
        i, j, vec = neighbour_pairs(pos, box, offset, cutoff)
        bi, bj, bvec = brute_force_pairs(pos, box, offset, cutoff)
        key, want = i * n + j, bi * n + bj
        assert len(np.unique(key)) == len(key), "a pair appears twice"
        order, border = np.argsort(key), np.argsort(want)
        np.testing.assert_array_equal(key[order], want[border], err_msg=f"offset {offset}")
        got, ref = vec[order], bvec[border]
        # the same minimum image; at an exact tie (|r| = l/2 on an axis) either image of the
        # pair has the same length
        np.testing.assert_allclose(
            np.linalg.norm(got, axis=1), np.linalg.norm(ref, axis=1), rtol=0, atol=1e-12
        )
        tied = np.isclose(np.abs(ref), box.lengths / 2, rtol=0, atol=1e-12).any(axis=1)
        np.testing.assert_allclose(got[~tied], ref[~tied], rtol=0, atol=1e-12)
        assert (np.linalg.norm(vec, axis=1) < cutoff).all()


def test_vectors_are_minimum_images_of_the_frame():
    pos = _configuration(BOX, 200, 3)
    offset = 2.2
    i, j, vec = neighbour_pairs(pos, BOX, offset, 3.0)
    np.testing.assert_allclose(vec, minimum_image(pos[j] - pos[i], BOX, offset), atol=1e-12)


def test_le_pair_across_the_x_face_uses_the_offset():
    """Two particles placed by hand: close only through the sheared +x image."""
    offset = 2.0
    pos = np.array([[3.9, 0.0, 1.0], [-3.9, 0.0, 1.0 - offset], [-3.9, 0.0, 1.0]])
    i, j, vec = neighbour_pairs(pos, BOX, offset, 0.5)
    pairs = dict(zip(zip(i.tolist(), j.tolist(), strict=True), vec, strict=True))
    assert set(pairs) == {(0, 1), (1, 0)}
    np.testing.assert_allclose(pairs[(0, 1)], [0.2, 0.0, 0.0], atol=1e-12)


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
