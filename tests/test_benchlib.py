"""The benchmarks' tiling of a trajectory into a larger box (``experiments/benchmarks/benchlib``):
the larger states must be the same physics, or every figure measured on them is wrong (a
tiled history once carried box-length steps for particles crossing a face)."""

from __future__ import annotations

import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from gripdem.boundary import lattice_continuous_steps, neighbour_pairs
from gripdem.data.dataset_io import read_meta

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments" / "benchmarks"))
from benchlib import tile_frames  # noqa: E402


def steps_of(positions, boundary, times):
    offsets = boundary.offset(times)[None, :] if boundary.is_lees_edwards else None
    return lattice_continuous_steps(np.moveaxis(positions, 0, -2), boundary.box, offsets, -1)


@pytest.mark.parametrize("scene", ["pbc", "lebc"])
@pytest.mark.parametrize("factor", [4, 16])
def test_a_tiled_history_has_the_same_steps_and_no_new_contacts(request, scene, factor):
    path = request.getfixturevalue(f"tiny_{scene}_path")
    meta = read_meta(path)
    with h5py.File(path) as h5:  # late frames: LE offsets have wrapped through the box
        positions = np.asarray(h5["positions"][0, -21:], np.float64)
        times = np.asarray(h5["times"][0, -21:], np.float64)
    tiled, big = tile_frames(positions, meta.boundary, factor, times)
    assert tiled.shape == (21, factor * meta.n_particles, 3)
    assert big.box.volume == pytest.approx(factor * meta.box.volume)
    small, large = steps_of(positions, meta.boundary, times), steps_of(tiled, big, times)
    n = meta.n_particles
    for copy in range(factor):  # every copy moves exactly as the original
        np.testing.assert_allclose(
            large[copy * n : (copy + 1) * n], small, atol=1e-12 * meta.box.lx
        )
    for t in (0, -1):  # the same pairs, factor times over
        offset = float(big.offset(times[t])) if big.is_lees_edwards else 0.0
        base = float(meta.boundary.offset(times[t])) if big.is_lees_edwards else 0.0
        i, _, _ = neighbour_pairs(tiled[t], big.box, offset, 1.01 * meta.diameter)
        i0, _, _ = neighbour_pairs(positions[t], meta.box, base, 1.01 * meta.diameter)
        assert len(i) == factor * len(i0)
