"""The neighbour list with a skin equals a brute-force LE minimum-image search at every frame,
across LE face crossings, offsets wrapping through the box and list rebuilds, and is reused
between rebuilds (lengths in diameters, a box that is not cubic)."""

from __future__ import annotations

import numpy as np
import pytest

from gripdem.boundary import (
    Boundary,
    Box,
    LeesEdwards,
    NeighbourList,
    brute_force_pairs,
    wrap_positions,
)

BOX = Box(8.0, 7.0, 9.0)
DT = 1.0


def sheared_frames(lees_edwards: bool, n=220, frames=80, noise=0.03, strain=0.02, seed=0):
    """Wrapped frames of particles moving with the affine flow (a cosine profile in a periodic
    box) plus a random walk, from a late absolute time, with each frame's wrapped offset."""
    rng = np.random.default_rng(seed)
    rate = strain / DT
    boundary = Boundary(BOX, LeesEdwards(rate, 1, 0.0) if lees_edwards else None)
    times = 1234.5 + DT * np.arange(frames)
    offsets = boundary.offset(times)
    cont = (rng.random((n, 3)) - 0.5) * BOX.lengths
    out = []
    for t in range(frames):
        if t:
            flow = np.zeros_like(cont)
            if lees_edwards:
                flow[:, 2] = rate * cont[:, 0] * DT
            else:
                flow[:, 2] = 0.05 * np.cos(2 * np.pi * cont[:, 0] / BOX.lx)
            cont = cont + flow + rng.normal(0.0, noise, cont.shape)
        out.append(wrap_positions(cont, BOX, offsets[t]))
    return np.stack(out), times, offsets, boundary


def as_set(i, j, vec):
    """``{(min, max): vector from min to max}``."""
    out = {}
    for a, b, v in zip(i.tolist(), j.tolist(), vec, strict=True):
        out[(a, b) if a < b else (b, a)] = v if a < b else -v
    return out


@pytest.mark.parametrize("lees_edwards", [True, False])
def test_pairs_equal_brute_force_at_every_frame(lees_edwards):
    frames, times, offsets, boundary = sheared_frames(lees_edwards)
    cutoff, skin = 1.3, 0.4
    nl = NeighbourList(BOX, cutoff, skin, boundary.image_velocity)
    crossed = 0
    for t in range(len(frames)):
        nl.update(frames[t], offsets[t], times[t])
        got = as_set(*nl.pairs(times[t]))
        want = as_set(*brute_force_pairs(frames[t], BOX, offsets[t], cutoff))
        assert got.keys() == want.keys(), f"frame {t}"
        for key, vec in got.items():
            np.testing.assert_allclose(vec, want[key], atol=1e-9, err_msg=f"frame {t} {key}")
        if t:
            crossed += int((np.abs(frames[t, :, 0] - frames[t - 1, :, 0]) > BOX.lx / 2).sum())
    assert crossed > 10  # particles crossed the x faces while the list was followed
    assert 1 < nl.builds < len(frames) // 2  # rebuilt, but reused between rebuilds


def test_offset_wrapping_through_the_box_keeps_the_images():
    """A fast shear: the wrapped offset jumps by lz several times between builds."""
    frames, times, offsets, boundary = sheared_frames(True, strain=0.3, noise=0.0, frames=30)
    assert (np.abs(np.diff(offsets)) > BOX.lz / 2).any()
    nl = NeighbourList(BOX, 1.3, 3.0 - 1.3 - 1e-9, boundary.image_velocity)
    for t in range(len(frames)):
        nl.update(frames[t], offsets[t], times[t])
        got = as_set(*nl.pairs(times[t]))
        want = as_set(*brute_force_pairs(frames[t], BOX, offsets[t], 1.3))
        assert got.keys() == want.keys()


def test_refuses_a_radius_of_half_the_box_or_more():
    with pytest.raises(ValueError, match="half the smallest box length"):
        NeighbourList(BOX, 3.0, 0.6)
    nl = NeighbourList(BOX, 1.0, 0.5)
    nl.build(np.zeros((2, 3)), 0.0, 0.0)
    with pytest.raises(ValueError, match="the list holds"):
        nl.pairs(0.0, cutoff=2.0)
