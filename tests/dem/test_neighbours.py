"""Neighbour lists: cell list == brute force == vesin's triclinic LE cell; history transfer;
the skin rule never misses an interacting pair during a sheared run."""

from __future__ import annotations

import numpy as np
import pytest

from gripdem.boundary import Box, apply_lattice_shift, minimum_image, wrap_positions
from gripdem.dem.engine import Simulation
from gripdem.dem.neighbours import PairList, brute_force_pairs, build_pairs, transfer_history
from gripdem.dem.packing import random_packing
from gripdem.dem.scenes import initial_velocities

D = 2.5e-6


def _as_set(pairs: PairList) -> set:
    return {
        (int(a), int(b), *map(int, s))
        for a, b, s in zip(pairs.i, pairs.j, pairs.shift, strict=True)
    }


@pytest.mark.parametrize(
    "box", [Box(3.2e-5, 3.2e-5, 3.2e-5), Box(2.0e-5, 3.0e-5, 4.1e-5), Box(1.0e-5, 1.2e-5, 1.1e-5)]
)  # the last: all-pairs fallback
@pytest.mark.parametrize("delta_frac", [0.0, 0.115, -0.41, 0.4999, -0.5])
def test_cell_list_equals_brute_force(box, delta_frac):
    rng = np.random.default_rng(7)
    delta = delta_frac * box.lz
    pos = wrap_positions((rng.random((700, 3)) - 0.5) * box.lengths, box, delta)
    pairs = build_pairs(pos, box, delta, 3.5e-6)
    assert _as_set(pairs) == brute_force_pairs(pos, box, delta, 3.5e-6)
    assert len(_as_set(pairs)) == len(pairs)  # no duplicates
    assert np.all(pairs.i < pairs.j) and np.all(np.diff(pairs.i) >= 0)
    # stored shifts reproduce the minimum image of boundary.py
    r = apply_lattice_shift(pos[pairs.i] - pos[pairs.j], pairs.shift, box, delta)
    np.testing.assert_allclose(
        r, minimum_image(pos[pairs.i] - pos[pairs.j], box, delta), atol=1e-18
    )


def test_cell_list_matches_vesin_triclinic_le_cell():
    vesin = pytest.importorskip("vesin")
    box = Box(2.4e-5, 2.0e-5, 2.8e-5)
    delta = 0.31 * box.lz
    rng = np.random.default_rng(3)
    pos = wrap_positions((rng.random((900, 3)) - 0.5) * box.lengths, box, delta)
    cell = np.array([[box.lx, 0.0, delta], [0.0, box.ly, 0.0], [0.0, 0.0, box.lz]])
    i, j, s = vesin.NeighborList(cutoff=3.5e-6, full_list=False).compute(
        pos, cell, periodic=True, quantities="ijS"
    )
    ours = _as_set(build_pairs(pos, box, delta, 3.5e-6))
    # vesin: vector = x_j - x_i + S @ cell; ours: r_ij = x_i - x_j - n @ cell (so n = S)
    theirs = set()
    for a, b, sh in zip(i, j, s, strict=True):
        a, b, sh = (int(a), int(b), sh) if a < b else (int(b), int(a), -sh)
        theirs.add((a, b, *map(int, sh)))
    assert ours == theirs


def test_history_follows_the_particle_pair():
    old = PairList(
        np.array([0, 0, 1, 2]), np.array([1, 3, 2, 3]), np.zeros((4, 3), np.int64), 0.0, 0
    )
    hist = np.arange(12.0).reshape(4, 3)
    new = PairList(
        np.array([0, 1, 2, 2]),
        np.array([3, 2, 3, 4]),
        np.array([[0, 0, 0], [1, 0, -1], [0, 0, 0], [0, 0, 0]]),
        0.1,
        10,
    )
    out = transfer_history(old, hist, new, n=5)
    np.testing.assert_array_equal(out, [hist[1], hist[2], hist[3], [0.0, 0.0, 0.0]])


@pytest.mark.parametrize("scene", ["lebc", "pbc"])
def test_list_never_misses_an_interacting_pair(make_config, scene):
    """After rebuilds driven by motion and by delta, every pair within the interaction range
    (contact + cohesion gap) is in the list, with the shift that gives its separation."""
    cfg = make_config(scene, particles=300, skin_d=0.05)  # small skin: frequent rebuilds
    pos = random_packing(300, cfg.box, D, np.random.default_rng(0))
    sim = Simulation(cfg, pos, initial_velocities(cfg, pos))
    reach = D + cfg.interaction_gap
    for _ in range(10):
        sim.run(997)
        p, _, _ = sim._backend.kinematics()  # internal order, as sim.pairs; not wrapped
        delta = sim.pairs.delta + sim.boundary.image_velocity * (sim.step - sim.pairs.step) * sim.dt
        listed = {
            (a, b): sh for a, b, sh in zip(sim.pairs.i, sim.pairs.j, sim.pairs.shift, strict=True)
        }
        wrapped = wrap_positions(p, cfg.box, delta)
        for a, b, *_ in brute_force_pairs(wrapped, cfg.box, delta, reach):
            assert (a, b) in listed, f"pair {(a, b)} within reach is missing from the list"
            r = apply_lattice_shift(p[a] - p[b], listed[(a, b)], cfg.box, delta)
            assert np.linalg.norm(r) < reach
    assert sim.rebuilds > 3
