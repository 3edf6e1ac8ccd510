"""Encodings on LE data with many crossings: round trips, VCT channels, normalisation."""

import numpy as np
import pytest
import torch

from gripdem.boundary import minimum_image, sincos_encode
from gripdem.data.encodings import ENCODINGS, make_encoding, step_lattice_shifts, x_face_crossings
from gripdem.data.normalizer import Normalizer


def _window(data, sim=0):
    """``(N, T, 3)`` positions and ``(T,)`` offsets of one simulation."""
    return data.positions[sim].transpose(1, 0, 2), data.offsets()[sim]


def _max_error(decoded, truth, box, offsets):
    """Largest LE minimum-image difference per axis, in box units (decoded frames vs truth)."""
    diff = minimum_image(np.asarray(decoded) - truth, box, np.asarray(offsets)[None, :])
    return np.abs(diff).max() / box.lx


def test_test_data_crosses_every_face_often(le_data):
    pos, offs = _window(le_data)
    shift, _ = step_lattice_shifts(pos, le_data.box, offs)
    crossings = (shift != 0).reshape(-1, 3).sum(axis=0)
    assert (crossings >= 30).all(), crossings
    assert le_data.times[0, 0] > 0 and abs(offs[0]) > 0.05 * le_data.box.lz


@pytest.mark.parametrize("name", sorted(ENCODINGS))
@pytest.mark.parametrize("backend", ["numpy", "torch"])
@pytest.mark.parametrize("lees_edwards", [True, False])
def test_encode_decode_round_trip(name, backend, lees_edwards, le_data, trajectories):
    data = (
        le_data if lees_edwards else trajectories(n_frames=60, n_particles=32, lees_edwards=False)
    )
    enc = make_encoding(name, data.boundary)
    pos, offs = _window(data)
    for k in (0, 7, 30):  # decode every horizon from several last observed frames (anchors)
        deltas = enc.encode(pos, offs, anchor=k)
        assert deltas.shape == (32, 59, enc.n_channels) == (32, 59, len(enc.channel_names))
        last, future, fut_offs = pos[:, k], deltas[:, k:], offs[k + 1 :]
        if backend == "torch":
            last, future = torch.from_numpy(last), torch.from_numpy(future)
            fut_offs = torch.from_numpy(fut_offs)
        decoded = enc.decode(last, future, fut_offs)
        assert type(decoded) is type(last) and decoded.shape == (32, 59 - k, 3)
        decoded = np.asarray(decoded)
        assert _max_error(decoded, pos[:, k + 1 :], data.box, offs[k + 1 :]) < 1e-9
        # and the result is wrapped into the box, per axis
        assert (np.abs(decoded) <= data.box.lengths / 2 + 1e-12 * data.box.lengths).all()


def test_round_trip_with_batch_axes_and_float32_deltas(le_data):
    enc = make_encoding("unwrapped", le_data.boundary)
    pos, offs = _window(le_data)
    batch_pos = torch.from_numpy(np.stack([pos[:, :20], pos[:, 20:40]]))  # (2, N, 20, 3)
    batch_off = torch.from_numpy(np.stack([offs[:20], offs[20:40]]))
    deltas = enc.encode(batch_pos, batch_off).float()
    decoded = enc.decode(batch_pos[:, :, 0], deltas, batch_off[:, 1:])
    assert decoded.dtype == torch.float64 and decoded.shape == (2, 32, 19, 3)
    for b in range(2):
        assert (
            _max_error(
                decoded[b].numpy(),
                batch_pos[b, :, 1:].numpy(),
                le_data.box,
                batch_off[b, 1:].numpy(),
            )
            < 1e-6
        )


def test_vct_channels_real_plus_shift_is_the_plain_difference(le_data):
    pos, offs = _window(le_data)
    vct = make_encoding("vct", le_data.boundary).encode(pos, offs)
    plain = make_encoding("sincos", le_data.boundary).encode(pos, offs)
    np.testing.assert_array_equal(vct[..., :4], plain[..., :4])
    np.testing.assert_allclose(vct[..., 4:6] + vct[..., 6:8], plain[..., 4:6], rtol=0, atol=1e-14)
    # shift channels: exactly zero except at steps that cross an x (LE) face
    shift, disp = step_lattice_shifts(pos, le_data.box, offs)
    crossed = shift[..., 0] != 0
    assert crossed.sum() >= 30
    assert (vct[~crossed][:, 6:8] == 0).all()
    # nonzero at crossings, unless the offset of that frame is a whole box length (delta = 0)
    moved = crossed & (np.abs(offs[1:]) > 0.01 * le_data.box.lz)[None, :]
    assert moved.sum() >= 25
    assert (np.abs(vct[moved][:, 6:8]).max(axis=-1) > 1e-3).all()
    # the real z pair is the difference to the image continuous with the previous frame
    continuous = pos[:, :-1] + disp
    real = (
        sincos_encode(continuous, le_data.box)[..., 4:6]
        - sincos_encode(pos[:, :-1], le_data.box)[..., 4:6]
    )
    np.testing.assert_allclose(vct[..., 4:6], real, rtol=0, atol=1e-14)


def test_vct_shift_channels_vanish_in_a_periodic_box(trajectories):
    data = trajectories(n_frames=30, lees_edwards=False)
    pos, offs = _window(data)
    vct = make_encoding("vct", data.boundary).encode(pos, offs)
    assert (vct[..., 6:8] == 0).all()
    np.testing.assert_array_equal(vct[..., :6], make_encoding("sincos", data.boundary).encode(pos))


def test_vct_exact_shift_ignores_the_shift_channels(le_data):
    enc = make_encoding("vct", le_data.boundary)
    pos, offs = _window(le_data)
    deltas = enc.encode(pos, offs)
    garbage = deltas.copy()
    garbage[..., 6:8] = 0.3  # the exact variant must not read these
    decoded = enc.decode(pos[:, 3], garbage[:, 3:], offs[4:], exact_shift=True)
    assert _max_error(decoded, pos[:, 4:], le_data.box, offs[4:]) < 1e-9
    learned = enc.decode(pos[:, 3], garbage[:, 3:], offs[4:])
    assert _max_error(learned, pos[:, 4:], le_data.box, offs[4:]) > 0.1
    with pytest.raises(ValueError, match="offsets"):
        enc.decode(pos[:, 3], deltas[:, 3:], None, exact_shift=True)


def test_sincos_deltas_are_small_at_the_default_frame_interval(trajectories):
    """At the default frame interval a particle moves ~0.01 d per frame: raw deltas ~1e-3."""
    data = trajectories(n_frames=10)
    pos, offs = _window(data)
    slow = pos[:, :1] + 0.01 * data.diameter * np.arange(10)[None, :, None]
    deltas = make_encoding("sincos", data.boundary).encode(slow)
    assert 1e-4 < np.abs(deltas).max() < 1e-2


def test_x_face_crossings(le_data):
    pos, offs = _window(le_data)
    mask = x_face_crossings(pos[:, 10:20], le_data.box, offs[10:20])
    jumps = np.abs(np.diff(pos[:, 10:20, 0], axis=1)) > le_data.box.lx / 2
    np.testing.assert_array_equal(mask, jumps.any(axis=1))
    assert mask.dtype == bool and mask.shape == (32,)


def test_unknown_encoding_is_a_clear_error(le_data):
    with pytest.raises(ValueError, match="expected one of"):
        make_encoding("polar", le_data.boundary)


def test_normalizer_fit_round_trip_and_state():
    rng = np.random.default_rng(0)
    x = rng.normal([1e-3, -2e-3, 0.0], [1e-3, 5e-4, 0.0], size=(1000, 3))
    whole = Normalizer.fit([x], "unwrapped")
    chunked = Normalizer.fit([x[:100], x[100:101], x[101:]], "unwrapped")
    np.testing.assert_allclose(chunked.mean, x.mean(axis=0), rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(chunked.std[:2], x.std(axis=0)[:2], rtol=1e-10)
    assert whole.std[2] == 1.0 and chunked.count == 1000  # a constant channel keeps std 1
    restored = Normalizer.from_dict(chunked.to_dict())
    assert restored == chunked
    assert all(type(v) is float for v in chunked.to_dict()["mean"] + chunked.to_dict()["std"])
    z = restored.normalize(torch.from_numpy(x).float())
    assert z.dtype == torch.float32 and abs(float(z[:, 0].std()) - 1) < 1e-3
    np.testing.assert_allclose(restored.denormalize(restored.normalize(x)), x, atol=1e-15)
    assert Normalizer.identity(8).normalize(x[:, :1].repeat(8, 1)).shape == (1000, 8)
