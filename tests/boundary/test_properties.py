"""Property tests of the boundary math (hypothesis), numpy and torch."""

from fractions import Fraction

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gripdem.boundary import (
    Box,
    LeesEdwards,
    lattice_shift,
    minimum_image,
    rewrap_trajectory,
    sincos_decode,
    sincos_encode,
    unwrap_trajectory,
    wrap_coordinate,
    wrap_positions,
)

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

lengths = st.floats(0.5, 20.0, allow_nan=False)
boxes = st.builds(Box, lengths, lengths, lengths)


@st.composite
def box_and_offset(draw):
    """A non-cubic box and an LE offset, biased to the edges 0, +-lz/2 and lz."""
    box = draw(boxes)
    kind = draw(st.sampled_from(["random", "zero", "tiny", "half", "near_lz"]))
    if kind == "random":
        offset = draw(st.floats(-0.5, 0.5)) * box.lz
    elif kind == "zero":
        offset = 0.0
    elif kind == "tiny":
        offset = draw(st.sampled_from([1e-15, -1e-15, 1e-9])) * box.lz
    elif kind == "half":
        offset = draw(st.sampled_from([-0.5, 0.5 - 1e-12])) * box.lz
    else:  # an unwrapped offset just below lz: must behave like one just below 0
        offset = (1.0 - draw(st.floats(0.0, 1e-6))) * box.lz
    return box, offset


def position_in(box: Box):
    """A wrapped position, often exactly on a face (-l/2) or at 0."""

    def coord(length):
        return st.one_of(
            st.floats(-0.5 * length, 0.5 * length, exclude_max=True),
            st.sampled_from([-0.5 * length, 0.0, np.nextafter(0.5 * length, 0.0)]),
        )

    return st.tuples(coord(box.lx), coord(box.ly), coord(box.lz)).map(np.array)


def _near_half(values: np.ndarray, box: Box, rel: float = 1e-9) -> bool:
    return bool(np.any(np.abs(np.abs(values) - 0.5 * box.lengths) < rel * box.lengths))


@SETTINGS
@given(box_and_offset(), arrays(np.float64, (8, 3), elements=st.floats(-60, 60)))
def test_minimum_image_is_at_most_half_the_box(bo, vectors):
    box, offset = bo
    r = minimum_image(vectors, box, offset)
    assert np.all(r >= -0.5 * box.lengths - 1e-12 * box.lengths)
    assert np.all(r < 0.5 * box.lengths + 1e-12 * box.lengths)


@SETTINGS
@given(
    box_and_offset(),
    arrays(np.float64, (3,), elements=st.floats(-30, 30)),
    st.tuples(*(st.integers(-5, 5),) * 3),
)
def test_minimum_image_is_invariant_under_lattice_vectors(bo, vector, counts):
    box, offset = bo
    a, b, c = counts
    lattice = (
        a * np.array([box.lx, 0.0, offset])
        + b * np.array([0, box.ly, 0])
        + c * np.array([0, 0, box.lz])
    )
    r1 = minimum_image(vector, box, offset)
    r2 = minimum_image(vector + lattice, box, offset)
    assume(not _near_half(r1, box, 1e-8))
    np.testing.assert_allclose(r2, r1, atol=1e-9 * max(box.lengths.max(), 1.0))


@SETTINGS
@given(box_and_offset(), st.data())
def test_minimum_image_recovers_small_true_displacements(bo, data):
    """Wrap a and a+d at the same offset: the minimum image of the difference is d."""
    box, offset = bo
    a = data.draw(position_in(box))
    frac = data.draw(arrays(np.float64, (3,), elements=st.floats(-0.45, 0.45)))
    d = frac * box.lengths
    wa = wrap_positions(a, box, offset)
    wb = wrap_positions(a + d, box, offset)
    for w in (wa, wb):
        assert np.all(w >= -0.5 * box.lengths) and np.all(w < 0.5 * box.lengths)
    np.testing.assert_allclose(
        minimum_image(wb - wa, box, offset), d, atol=1e-9 * box.lengths.max()
    )
    # torch float64 and float32 agree
    rt = minimum_image(torch.tensor(wb - wa), box, offset)
    np.testing.assert_allclose(rt.numpy(), d, atol=1e-9 * box.lengths.max())
    rt32 = minimum_image(torch.tensor(wb - wa, dtype=torch.float32), box, offset)
    np.testing.assert_allclose(rt32.numpy(), d, atol=1e-5 * box.lengths.max())


@SETTINGS
@given(boxes, st.sampled_from([-0.5, 0.0, 0.25, 0.5 - 1e-15, -0.25]))
def test_sincos_round_trip_is_exact_at_faces_and_zero(box, frac):
    pos = frac * box.lengths
    for array in (pos, torch.tensor(pos)):
        back = np.asarray(sincos_decode(sincos_encode(array, box), box))
        err = np.array([wrap_coordinate(back[i] - pos[i], box.lengths[i]) for i in range(3)])
        np.testing.assert_allclose(err, 0.0, atol=1e-12 * box.lengths.max())
        assert np.all(back >= -0.5 * box.lengths) and np.all(back < 0.5 * box.lengths)


def test_sincos_plus_half_box_decodes_to_minus_half():
    box = Box(2.0, 3.0, 4.0)
    feats = sincos_encode(np.array([-1.0, -1.5, -2.0]), box)
    np.testing.assert_allclose(sincos_decode(feats, box), [-1.0, -1.5, -2.0])
    # atan2(0, -1) = +pi would give +l/2; the decoder folds it to -l/2
    feats = np.array([0.0, -1.0, 0.0, -1.0, 0.0, -1.0])
    np.testing.assert_array_equal(sincos_decode(feats, box), [-1.0, -1.5, -2.0])


@SETTINGS
@given(
    boxes,
    arrays(np.float64, (5, 3), elements=st.floats(-0.5, 0.4999)),
    st.floats(0.01, 100.0),
)
def test_sincos_decoder_is_scale_invariant_off_the_unit_circle(box, frac, scale):
    pos = frac * box.lengths
    feats = sincos_encode(pos, box) * scale
    feats_t = torch.tensor(feats)
    for decoded in (sincos_decode(feats, box), sincos_decode(feats_t, box).numpy()):
        err = decoded - pos
        err = np.stack([wrap_coordinate(err[:, i], box.lengths[i]) for i in range(3)], -1)
        np.testing.assert_allclose(err, 0.0, atol=1e-10 * box.lengths.max())
    # a zero pair decodes to 0, not NaN
    assert np.all(np.isfinite(sincos_decode(np.zeros(6), box)))


@pytest.mark.parametrize("frames", [0, 1, 1000, 123_457, 1_000_000])
def test_offsets_keep_full_precision_at_large_times(frames):
    """delta(t) at t up to 1e6 frame intervals equals the exact rational result to ~1 ulp of
    the product k*lx*t (float32 anywhere would be off by ~1e-8 relative)."""
    box = Box(3.2e-5, 3.2e-5, 3.2e-5)
    le = LeesEdwards(1000.0, time_origin=0.0)
    dt = 5e-6
    t = 1.1e-3 + frames * dt
    got = float(le.offset(box, np.array(t)))
    exact = Fraction(1000.0) * Fraction(3.2e-5) * Fraction(t)
    lz = Fraction(3.2e-5)
    exact_wrapped = exact - lz * ((exact / lz + Fraction(1, 2)).__floor__())
    ulp_of_product = np.spacing(1000.0 * 3.2e-5 * t)
    assert abs(got - float(exact_wrapped)) <= 4 * ulp_of_product
    assert -0.5 * box.lz <= got < 0.5 * box.lz
    # float32 arithmetic on the raw product loses it for large times
    if frames >= 123_457:
        naive = np.float32(1000.0) * np.float32(3.2e-5) * np.float32(t)
        naive = float(naive - np.float32(box.lz) * np.floor(naive / np.float32(box.lz) + 0.5))
        assert abs(naive - float(exact_wrapped)) > 1e3 * abs(got - float(exact_wrapped))


def _continuous_trajectory(rng, box, le, n_frames, n_particles, dt, t0):
    """A lattice-continuous trajectory under affine shear plus noise, starting in the box."""
    c = np.empty((n_frames, n_particles, 3))
    c[0] = (rng.random((n_particles, 3)) - 0.5) * box.lengths
    rate = 0.0 if le is None else le.sign * le.shear_rate
    for t in range(1, n_frames):
        step = rng.normal(0.0, 0.03, (n_particles, 3)) * box.lengths
        step[:, 2] += rate * c[t - 1, :, 0] * dt
        c[t] = c[t - 1] + step
    return c, t0 + dt * np.arange(n_frames)


@pytest.mark.parametrize("sign", [1, -1])
@pytest.mark.parametrize("as_torch", [False, True])
def test_wrap_then_unwrap_returns_the_continuous_trajectory(sign, as_torch):
    rng = np.random.default_rng(7 + sign)
    box = Box(2.0, 3.0, 5.0)
    le = LeesEdwards(shear_rate=3.0, sign=sign, time_origin=0.3)
    c, times = _continuous_trajectory(rng, box, le, 80, 40, 0.05, t0=12.345)
    offsets = le.offset(box, times)
    wrapped = rewrap_trajectory(c, box, offsets)
    crossings = np.abs(np.diff(lattice_shift(c, box)[..., 0], axis=0)).sum()
    assert crossings > 20  # the test exercises many LE crossings
    increments = np.diff(times) * le.image_velocity(box)
    data = torch.tensor(wrapped) if as_torch else wrapped
    back = np.asarray(unwrap_trajectory(data, box, offsets, increments))
    np.testing.assert_allclose(back, c, atol=1e-9)
    np.testing.assert_allclose(rewrap_trajectory(back, box, offsets), wrapped, atol=1e-9)


def test_wrap_then_unwrap_periodic():
    rng = np.random.default_rng(3)
    box = Box(1.0, 2.0, 3.0)
    c, _ = _continuous_trajectory(rng, box, None, 50, 30, 0.1, 0.0)
    wrapped = rewrap_trajectory(c, box)
    np.testing.assert_allclose(unwrap_trajectory(wrapped, box), c, atol=1e-10)
