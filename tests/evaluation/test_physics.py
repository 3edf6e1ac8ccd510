"""Physics-level evaluation against independent brute-force references (O(n^2) loops over the
minimum-image rule of docs/spec/conventions.md#minimum-image) and against motions whose answer is
known in closed form."""

import math

import numpy as np
import pytest

from gripdem.boundary import Box, LeesEdwards, rewrap_trajectory
from gripdem.evaluation.physics import (
    coordination_number,
    coordination_numbers,
    fit_profile,
    frame_displacements,
    mean_squared_displacement,
    neighbour_pairs,
    overlap_fraction,
    pair_distances,
    radial_distribution,
    velocity_profile,
    velocity_profile_error,
)

BOX = Box(2.0, 2.5, 3.0)
LE = LeesEdwards(shear_rate=2.0, sign=1, time_origin=0.1)
DT = 0.05


def brute_min_image(a, b, box, delta):
    """The rule of docs/spec/conventions.md#minimum-image written out with scalar if-tests and a
    while loop (no numpy tricks)."""
    rx, ry, rz = (float(a[k] - b[k]) for k in range(3))
    if rx >= box.lx / 2:
        rx, rz = rx - box.lx, rz - delta
    elif rx < -box.lx / 2:
        rx, rz = rx + box.lx, rz + delta
    for length, idx in ((box.ly, 1), (box.lz, 2)):
        value = ry if idx == 1 else rz
        while value >= length / 2:
            value -= length
        while value < -length / 2:
            value += length
        if idx == 1:
            ry = value
        else:
            rz = value
    return math.sqrt(rx * rx + ry * ry + rz * rz)


def brute_distances(pos, box, delta):
    n = len(pos)
    return {
        (i, j): brute_min_image(pos[i], pos[j], box, delta)
        for i in range(n)
        for j in range(i + 1, n)
    }


def random_frame(n, seed):
    """Uniform positions in the box and the generator that made them."""
    rng = np.random.default_rng(seed)
    pos = (rng.random((n, 3)) - 0.5) * BOX.lengths
    return pos, rng


@pytest.mark.parametrize("delta", [0.0, 0.37, -1.49, 1.2])
def test_neighbour_pairs_equal_brute_force(delta):
    pos, _ = random_frame(100, 0)
    pos[0] = [0.5 * BOX.lx - 1e-3, 0.0, 1.4]  # a particle on the +x face ...
    pos[1] = [-0.5 * BOX.lx, 0.01, wrap(1.4 + 0.05 - delta)]  # ... its neighbour via the image
    cutoff = 0.6
    i, j, d = neighbour_pairs(pos, BOX, cutoff, delta)
    ref = {k: v for k, v in brute_distances(pos, BOX, delta).items() if v < cutoff}
    got = dict(zip(zip(i.tolist(), j.tolist(), strict=True), d.tolist(), strict=True))
    assert (0, 1) in ref
    assert got.keys() == ref.keys()
    np.testing.assert_allclose([got[k] for k in ref], list(ref.values()), rtol=1e-12)


def wrap(z):
    return z - BOX.lz * math.floor(z / BOX.lz + 0.5)


def test_neighbour_pairs_refuse_a_cutoff_beyond_half_the_box():
    pos, _ = random_frame(10, 1)
    with pytest.raises(ValueError, match="cut-off"):
        neighbour_pairs(pos, BOX, 1.0)  # min(box)/2 = 1.0


def test_overlap_fraction_and_coordination_equal_brute_force():
    delta = 0.9
    frames = []
    for seed in range(3):
        pos, rng = random_frame(100, seed)
        frames.append(pos)
    pos = np.stack(frames)
    diameter = 0.2
    ref_overlap = 0
    ref_coord = []
    for frame in pos:
        dist = brute_distances(frame, BOX, delta)
        close = {k for k, v in dist.items() if v < 0.98 * diameter}
        ref_overlap += len({i for pair in close for i in pair})
        counts = np.zeros(len(frame), int)
        for (a, b), v in dist.items():
            if v < 0.35:
                counts[a] += 1
                counts[b] += 1
        ref_coord.append(counts)
    assert ref_overlap > 0
    frac = overlap_fraction(pos, BOX, diameter, np.full(3, delta))
    assert frac == pytest.approx(ref_overlap / pos[..., 0].size, abs=0)
    np.testing.assert_array_equal(coordination_numbers(pos[1], BOX, 0.35, delta), ref_coord[1])
    assert coordination_number(pos, BOX, 0.35, delta) == pytest.approx(np.mean(ref_coord))
    # a tolerance of 0 counts nothing
    assert overlap_fraction(pos, BOX, diameter, delta, tol=1e-9) == 0.0


def test_radial_distribution_equals_brute_force_histogram_and_ideal_gas_is_one():
    pos, _ = random_frame(100, 4)
    delta, r_max, bins = -0.6, 0.9, 30
    r, g = radial_distribution(pos, BOX, r_max, bins, delta)
    dist = np.array(list(brute_distances(pos, BOX, delta).values()))
    edges = np.linspace(0, r_max, bins + 1)
    counts = np.histogram(dist[dist < r_max], edges)[0]
    shell = 4 / 3 * np.pi * np.diff(edges**3)
    np.testing.assert_allclose(g, 2 * counts / (100 * 99 / BOX.volume * shell), rtol=1e-12)
    np.testing.assert_allclose(r, 0.5 * (edges[1:] + edges[:-1]))
    # many uncorrelated frames: g(r) -> 1 (beyond the first, noisy bins)
    rng = np.random.default_rng(5)
    gas = (rng.random((40, 300, 3)) - 0.5) * BOX.lengths
    _, g_gas = radial_distribution(gas, BOX, r_max, 9, rng.random(40))
    assert np.all(np.abs(g_gas[3:] - 1) < 0.05)
    assert pair_distances(gas[:2], BOX, 0.5).max() < 0.5


def le_ballistic(w=3, n=80, n_in=1, horizon=12, seed=0, speed=0.08):
    """LE ballistic motion in lattice-continuous coordinates, wrapped at each frame's offset."""
    rng = np.random.default_rng(seed)
    start = (rng.random((w, 1, n, 3)) - 0.5) * BOX.lengths
    velocity = rng.normal(0, speed, (w, 1, n, 3)) * BOX.lengths
    steps = np.arange(n_in + horizon)[None, :, None, None]
    continuous = start + steps * velocity
    times = 3.7 + DT * np.arange(n_in + horizon)[None, :] + np.zeros((w, 1))
    offsets = LE.offset(BOX, times)
    wrapped = np.stack(
        [rewrap_trajectory(c, BOX, o) for c, o in zip(continuous, offsets, strict=True)]
    )
    last = wrapped[:, n_in - 1]
    return wrapped[:, n_in:], last, offsets[:, n_in:], velocity[:, 0]


def test_msd_of_ballistic_motion_across_le_faces_is_vt_squared():
    target, last, offsets, velocity = le_ballistic()
    horizon = target.shape[1]
    increment = LE.image_velocity(BOX) * DT
    msd = mean_squared_displacement(target, last, BOX, offsets, increment)
    t = np.arange(1, horizon + 1)
    expected = (velocity**2).sum(-1).mean() * t**2
    np.testing.assert_allclose(msd, expected, rtol=1e-10)
    # crossers exist, and summing per-step minimum images without the image-cell motion is wrong
    crossed = (
        np.abs(np.diff(np.concatenate([last[:, None], target], 1)[..., 0], axis=1)) > BOX.lx / 2
    ).any(1)
    assert crossed.sum() > 10
    naive = mean_squared_displacement(target, last, BOX, offsets, 0.0)
    assert np.abs(naive - expected).max() > 1e-2 * expected.max()
    # frame displacements are the ballistic velocity in x and y, and in z for non-crossers
    steps = frame_displacements(target, last, BOX, offsets)
    ballistic = np.broadcast_to(velocity[:, None], steps.shape)
    np.testing.assert_allclose(steps[..., :2], ballistic[..., :2], atol=1e-9)
    np.testing.assert_allclose(
        steps[..., 2].transpose(0, 2, 1)[~crossed],
        ballistic[..., 2].transpose(0, 2, 1)[~crossed],
        atol=1e-9,
    )


@pytest.mark.parametrize("kind", ["linear", "cosine"])
def test_velocity_profile_recovers_an_affine_flow(kind):
    rng = np.random.default_rng(6)
    w, n, horizon = 2, 400, 5
    x = (rng.random((w, n)) - 0.5) * BOX.lx
    rate = 0.4
    u = rate * x if kind == "linear" else 0.3 * np.cos(2 * np.pi * x / BOX.lx) + 0.05
    last = np.stack(
        [x, (rng.random((w, n)) - 0.5) * BOX.ly, (rng.random((w, n)) - 0.5) * BOX.lz], -1
    )
    t = np.arange(1, horizon + 1)[None, :, None]
    target = np.repeat(last[:, None], horizon, 1)
    target[..., 2] = target[..., 2] + t * u[:, None] * DT
    target[..., 2] -= BOX.lz * np.floor(target[..., 2] / BOX.lz + 0.5)
    centres, vz, counts = velocity_profile(target, last, BOX, None, DT, bins=8)
    assert counts.sum() == w * n * horizon
    edges = np.linspace(-BOX.lx / 2, BOX.lx / 2, 9)
    which = np.digitize(x.reshape(-1), edges) - 1
    expected = [u.reshape(-1)[which == b].mean() for b in range(8)]
    np.testing.assert_allclose(vz, expected, rtol=1e-9)
    a, b = fit_profile(x.reshape(-1), u.reshape(-1), BOX, kind)
    assert (a, b) == pytest.approx((rate, 0.0) if kind == "linear" else (0.3, 0.05), abs=1e-12)
    assert velocity_profile_error(vz, vz) == 0.0
    assert velocity_profile_error(vz + 0.1, vz) == pytest.approx(0.1)
    assert np.isnan(velocity_profile_error([np.nan], [1.0]))
    assert centres.shape == (8,)
