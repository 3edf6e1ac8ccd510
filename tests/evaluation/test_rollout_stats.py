"""Rollout statistics on hand-built trajectories with known answers: a lattice (no overlap, known
pair distances, identical structure), an exact affine shear across the LE faces (known slope,
zero drift, zero non-affine motion) and a uniform drift (found as the profile's constant)."""

from __future__ import annotations

import numpy as np
import pytest

from gripdem.boundary import Boundary, Box, LeesEdwards, wrap_positions
from gripdem.evaluation.rollout_stats import block_statistics

D = 1.0
SPACING = 1.1
BOX = Box(8 * SPACING, 7 * SPACING, 9 * SPACING)


def lattice() -> np.ndarray:
    grid = np.stack(np.meshgrid(*(np.arange(k) for k in (8, 7, 9)), indexing="ij"), -1)
    return (grid.reshape(-1, 3) + 0.5) * SPACING - 0.5 * BOX.lengths


def affine_trajectory(frames: int, strain: float, drift: float = 0.0):
    """The lattice carried by the exact affine shear ``u_z = strain * x`` per frame (plus a
    uniform ``drift`` per frame along z), lattice-continuous, wrapped with each frame's offset."""
    rate = strain  # frame interval 1
    boundary = Boundary(BOX, LeesEdwards(rate, 1, 0.0))
    times = 100.0 + np.arange(frames + 1)
    start = lattice()
    cont = np.repeat(start[None], frames + 1, axis=0)
    t = np.arange(frames + 1)[:, None]
    cont[..., 2] = start[None, :, 2] + (rate * start[None, :, 0] + drift) * t
    offsets = boundary.offset(times)
    wrapped = np.stack([wrap_positions(c, BOX, o) for c, o in zip(cont, offsets, strict=True)])
    return wrapped, times, boundary


def test_a_lattice_has_no_overlap_and_the_same_structure_as_itself():
    boundary = Boundary(BOX)
    frames = np.repeat(lattice()[None], 21, axis=0)
    times = np.arange(21.0)
    stats = block_statistics(frames, frames, times, boundary, D, block=10, gr_every=2)
    assert len(stats["blocks"]) == 2
    for row in stats["blocks"]:
        assert row["model/overlap_max"] == 0.0 and row["gr_l1"] == 0.0
        assert row["model/coordination"] == 0.0  # nearest neighbours at 1.1 d, contact < 1.01 d
        assert row["model/rms_step_over_d"] == 0.0


def test_known_pair_distances_enter_the_histogram():
    """A lattice against the same lattice compressed to spacing 0.97 d: every particle then
    overlaps (below 0.98 d) and the structures share nothing below 1.1 d."""
    boundary = Boundary(BOX)
    frames = np.repeat(lattice()[None], 6, axis=0)
    squeezed = frames.copy()
    squeezed[:, :, 0] *= 0.97 / SPACING  # x spacing 0.97 d (the box is kept: a gap at the face)
    stats = block_statistics(squeezed, frames, np.arange(6.0), boundary, D, block=5, gr_every=1)
    row = stats["blocks"][0]
    assert row["model/overlap_max"] == 1.0 and row["truth/overlap_max"] == 0.0
    assert row["gr_l1"] > 0.3


@pytest.mark.parametrize("drift", [0.0, 0.013])
def test_exact_affine_shear_has_the_imposed_slope_and_no_non_affine_motion(drift):
    strain = 0.02
    frames, times, boundary = affine_trajectory(120, strain, drift)
    crossings = (np.abs(np.diff(frames[..., 0], axis=0)) > BOX.lx / 2).sum()
    moved_z = np.abs(np.diff(frames[..., 2], axis=0)) > BOX.lz / 2
    assert crossings == 0 and moved_z.any()  # z faces crossed; positions move only along z
    stats = block_statistics(frames, frames, times, boundary, D, block=50, gr_every=10)
    for row in stats["blocks"]:
        np.testing.assert_allclose(row["truth/profile"], strain, rtol=1e-9)
        np.testing.assert_allclose(row["truth/drift_over_d"], drift, atol=1e-9)
        for lag in (1, 10, 100):
            value = row[f"truth/msd_{lag}_over_d2"]
            assert np.isnan(value) or value < 1e-18
        assert row["truth/rms_non_affine_over_d"] < 1e-9
        assert row["step_w1"] == 0.0 or np.isnan(row["step_w1"])


def test_diffusion_coefficients_of_sheared_random_walks():
    """Random walks with step variances (sx^2, sy^2, sz^2) per frame in an exact shear flow
    (each z-step is the flow at the step's middle x plus the walk's): the non-affine MSD grows as
    L s^2 per axis, so D = s^2 / 2 (d^2 per frame), the flow removed with the truth's profile."""
    from gripdem.evaluation.rollout_stats import diffusion_coefficients

    frames, rate = 1200, 0.01
    boundary = Boundary(BOX, LeesEdwards(rate, 1, 0.0))
    times = 100.0 + np.arange(frames + 1)
    rng = np.random.default_rng(0)
    sigma = np.array([0.02, 0.01, 0.03])
    noise = rng.normal(size=(frames, len(lattice()), 3)) * sigma
    cont = [lattice()]
    for step in noise:
        x_mid = cont[-1][:, 0] + 0.5 * step[:, 0]
        cont.append(cont[-1] + step + np.stack([0 * x_mid, 0 * x_mid, rate * x_mid], -1))
    offsets = boundary.offset(times)
    moved = np.stack([wrap_positions(c, BOX, o) for c, o in zip(cont, offsets, strict=True)])
    measured = diffusion_coefficients(moved, moved, times, boundary, D)
    np.testing.assert_allclose(measured, sigma**2 / 2, rtol=0.15)
    with pytest.raises(ValueError, match="needs 1000 frames"):
        diffusion_coefficients(moved[:500], moved[:500], times[:500], boundary, D)
