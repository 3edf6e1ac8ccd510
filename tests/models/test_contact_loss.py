"""The contact term of the loss (gripdem.models.contact_loss) on pairs placed by hand: the overlap
of a pair that straddles a sheared face, measured through the LE image at the frame's offset;
nothing for self pairs, touching or resting pairs; a gradient that pushes overlapping pairs
apart."""

from __future__ import annotations

import pytest
import torch

from gripdem.boundary import Boundary, Box, LeesEdwards, wrap_positions
from gripdem.models.contact_loss import RESTING_OVERLAP, contact_term, pair_overlaps

D = 2.5e-6
BOX = Box(8 * D, 7 * D, 9 * D)
LE = Boundary(BOX, LeesEdwards(1e4, sign=1, time_origin=0.0))
OFFSET = 2.3 * D  # the frame's LE offset: a pair across the x face meets its shifted image


def pair_across_the_face(gap: float) -> torch.Tensor:
    """Two particles ``(1, 1, 2, 3)`` whose images are ``gap`` diameters apart along x across the
    +x face (in the cell's image at the frame's offset), wrapped into the box."""
    first = torch.tensor([0.5 * BOX.lx - 0.25 * D, 0.1 * D, -1.0 * D], dtype=torch.float64)
    image = first + torch.tensor([gap * D, 0.0, 0.0], dtype=torch.float64)
    both = torch.stack([first, image])
    return wrap_positions(both, BOX, torch.tensor(OFFSET, dtype=torch.float64))[None, None]


EDGES = torch.tensor([[0, 1, 0], [1, 0, 0]])  # both directions and a self pair
OFFSETS = torch.tensor([[OFFSET]], dtype=torch.float64)


@pytest.mark.parametrize(("gap", "overlap"), [(0.9, 0.1 - RESTING_OVERLAP), (1.0, 0.0), (1.3, 0.0)])
def test_pair_overlap_across_a_sheared_face(gap, overlap):
    positions = pair_across_the_face(gap)
    assert positions[0, 0, 1, 0] < 0  # the second particle was wrapped through the x face
    got = pair_overlaps(positions, EDGES, OFFSETS, LE, D)  # (1 frame, 2 pairs)
    assert got.shape == (1, 2)
    torch.testing.assert_close(got / D, torch.full((1, 2), overlap, dtype=torch.float64))
    resting = pair_overlaps(
        pair_across_the_face(1.0 - 0.5 * RESTING_OVERLAP), EDGES, OFFSETS, LE, D
    )
    assert float(resting.max()) == 0.0  # the DEM's own resting contacts cost nothing


def test_the_gradient_pushes_an_overlapping_pair_apart():
    positions = pair_across_the_face(0.9).requires_grad_(True)
    unit = torch.tensor(1e-3 * D, dtype=torch.float64)
    cv = torch.tensor(1.0, dtype=torch.float64)
    term = contact_term(positions, EDGES, OFFSETS, LE, D, unit, cv)
    assert float(term.detach()) == pytest.approx(((0.1 - RESTING_OVERLAP) / 1e-3) ** 2, rel=1e-9)
    term.backward()
    grad = positions.grad[0, 0]
    assert grad[0, 0] > 0 and grad[1, 0] < 0  # descent moves the first -x, its image +x
    torch.testing.assert_close(grad[0], -grad[1])  # equal and opposite
