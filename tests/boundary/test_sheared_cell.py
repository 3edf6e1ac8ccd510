"""``wrap_into_sheared_cell``: positions moved into the tilted LE cell a triclinic engine uses."""

import numpy as np
import torch

from gripdem.boundary import Box, minimum_image, wrap_into_sheared_cell, wrap_positions

BOX = Box(2.0, 3.0, 5.0)


def test_positions_land_in_the_tilted_cell_as_the_same_lattice_points():
    rng = np.random.default_rng(0)
    positions = (rng.random((200, 3)) - 0.5) * 7 * BOX.lengths  # many images away
    offsets = rng.uniform(-BOX.lz / 2, BOX.lz / 2, (200,))
    inside = wrap_into_sheared_cell(positions, BOX, offsets)
    v = (inside[:, 0] + BOX.lx / 2) / BOX.lx
    w = (inside[:, 1] + BOX.ly / 2) / BOX.ly
    u = (inside[:, 2] + BOX.lz / 2 - v * offsets) / BOX.lz
    for frac in (u, v, w):
        assert ((frac >= 0) & (frac < 1)).all()
    # the same point of the LE lattice: wrapping returns gripdem's wrapped position
    wrapped = wrap_positions(positions, BOX, offsets)
    np.testing.assert_allclose(wrap_positions(inside, BOX, offsets), wrapped, atol=1e-12)
    assert np.abs(minimum_image(inside - wrapped, BOX, offsets)).max() < 1e-12
    as_torch = wrap_into_sheared_cell(torch.from_numpy(positions), BOX, torch.from_numpy(offsets))
    np.testing.assert_allclose(as_torch.numpy(), inside, atol=1e-12)
