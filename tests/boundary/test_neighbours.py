"""The LE neighbour search: vesin on the LE triclinic lattice against an O(n²) minimum-image
search (every pair in both directions, as the graph uses them)."""

import numpy as np
import pytest

from gripdem.boundary import Box, brute_force_pairs, minimum_image
from gripdem.boundary import neighbour_pairs as half_pairs


def neighbour_pairs(pos, box, offset, cutoff):
    return half_pairs(pos, box, offset, cutoff, both_directions=True)


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
