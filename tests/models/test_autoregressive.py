"""The linear autoregressive baseline: exact on trajectories that are linear filters of their
past (LE crossers included), fitted on the training frames only, stored and restored."""

import numpy as np
import pytest
import torch

from gripdem.boundary import (
    Boundary,
    Box,
    LeesEdwards,
    add_affine_flow,
    affine_flow_strain,
    minimum_image,
    wrap_positions,
)
from gripdem.data.datamodule import TrajectoryDataModule
from gripdem.data.dataset_io import write_dataset
from gripdem.data.encodings import x_face_crossings
from gripdem.data.schema import TrajectoryData
from gripdem.models.autoregressive import LinearAR, fit_on_training_frames

BOX = Box(1.0e-5, 1.2e-5, 0.9e-5)
DT = 5e-6
LAGS = 3


def filter_trajectories(lees_edwards: bool, n_sims=3, n_frames=40, n=30, seed=0):
    """Flow-relative steps r_s = sum_k A_k r_{s-k} + b sin(theta_s) + c cos(theta_s) + e: per
    axis an AR(3) with the roots 0.97 exp(+-i omega) and -0.5 (bounded, slowly decaying, and
    three independent lags), large enough to cross every face; the LE cell's affine flow is added in
    lattice-continuous coordinates and each frame wrapped with its own offset. Returns the
    data and the true coefficients (3 * LAGS + 3, 3)."""
    rng = np.random.default_rng(seed)
    le = LeesEdwards(4000.0, sign=1, time_origin=1e-4) if lees_edwards else None
    boundary = Boundary(BOX, le)
    strain = affine_flow_strain(boundary, DT)
    weights = np.zeros((3 * LAGS + 3, 3))
    for axis, omega in enumerate((0.3, 0.5, 0.7)):
        pair = 0.97 * np.exp(1j * omega)
        poly = np.real(np.poly([pair, np.conj(pair), -0.5]))  # z^3 + p1 z^2 + p2 z + p3
        for lag in range(LAGS):
            weights[3 * lag + axis, axis] = -poly[lag + 1]
    weights[9] = [0.004, -0.002, 0.006]  # sin
    weights[10] = [-0.002, 0.004, 0.002]  # cos
    weights[11] = [0.0002, 0.0, -0.0004]  # constant
    weights[9:] *= BOX.lx
    times = 2e-3 + DT * np.arange(n_frames)[None, :] + 11 * DT * np.arange(n_sims)[:, None]
    offsets = boundary.offset(times)
    positions = np.empty((n_sims, n_frames, n, 3))
    for s in range(n_sims):
        pos = (rng.random((n, 3)) - 0.5) * BOX.lengths
        lagged = [rng.normal(0, 0.05, (n, 3)) * BOX.lx for _ in range(LAGS)]  # r_{-1..-L}
        positions[s, 0] = wrap_positions(pos, BOX, offsets[s, 0])
        for t in range(1, n_frames):
            theta = 2 * np.pi * pos[:, 0] / BOX.lx
            feats = np.concatenate(
                lagged + [np.sin(theta)[:, None], np.cos(theta)[:, None], np.ones((n, 1))], 1
            )
            r = feats @ weights
            assert np.abs(r).max() < 0.3 * BOX.lx  # minimum images stay unambiguous
            step = add_affine_flow(r[:, None], pos[:, 0, None], strain)[:, 0]
            pos = pos + step
            lagged = [r] + lagged[:-1]
            positions[s, t] = wrap_positions(pos, BOX, offsets[s, t])
    data = TrajectoryData(positions, times, boundary, radius=2e-7)
    return data, weights


@pytest.mark.parametrize("lees_edwards", [True, False])
def test_fit_recovers_the_filter_and_predicts_exactly(tmp_path, lees_edwards):
    data, weights = filter_trajectories(lees_edwards)
    path = write_dataset(tmp_path / "filter.h5", data)
    dm = TrajectoryDataModule(
        path,
        split="12-8",
        history_len=LAGS + 2,
        protocol="sims",
        encoding="unwrapped",
        eval_stride=3,
    )
    dm.setup("fit")
    ar = fit_on_training_frames(dm, LAGS, ridge=0.0)
    fitted = np.array(ar.weights)
    np.testing.assert_allclose(fitted[:9], weights[:9], rtol=1e-8, atol=1e-10)  # lags
    np.testing.assert_allclose(fitted[9:], weights[9:], rtol=1e-6, atol=1e-10 * BOX.lx)
    crossers, worst = 0, 0.0
    for batch in dm.test_dataloader():
        pred = ar.predict(
            batch.input_positions.transpose(1, 2),
            batch.input_offsets,
            batch.target_offsets,
            dm.meta.boundary,
        )
        truth = batch.target_positions.transpose(1, 2)
        diff = minimum_image(pred - truth, BOX, batch.target_offsets[..., None])
        worst = max(worst, float(diff.abs().max()) / BOX.lx)
        # particles crossing an x face in the horizon (the batch's mask is the LE crossers',
        # all False in a periodic box)
        window = torch.cat([batch.last_positions[:, :, None], batch.target_positions], dim=2)
        offsets = torch.cat([batch.input_offsets[:, -1:], batch.target_offsets], dim=1)
        crossers += int(x_face_crossings(window, BOX, offsets).sum())
    assert worst < 1e-8
    assert crossers >= 20


def test_fit_uses_the_training_simulations_only(tmp_path):
    data, _ = filter_trajectories(True)
    noisy = data.positions.copy()
    noisy[2] = wrap_positions(  # garbage in the test simulation must not change the fit
        noisy[2] + np.random.default_rng(1).normal(0, 0.1 * BOX.lx, noisy[2].shape),
        BOX,
        data.offsets()[2][:, None],
    )
    paths = []
    for name, pos in (("clean", data.positions), ("noisy", noisy)):
        variant = TrajectoryData(pos, data.times, data.boundary, radius=data.radius)
        paths.append(write_dataset(tmp_path / f"{name}.h5", variant))
    fits = []
    for path in paths:
        dm = TrajectoryDataModule(path, split="12-8", history_len=5, protocol="sims")
        dm.setup("fit")
        assert dm.plan.test.sims == (2,)
        fits.append(fit_on_training_frames(dm, LAGS).weights)
    assert fits[0] == fits[1]


def test_round_trip_and_clear_errors(tmp_path):
    data, _ = filter_trajectories(False, n_sims=3, n_frames=20)
    path = write_dataset(tmp_path / "f.h5", data)
    dm = TrajectoryDataModule(path, split="6-4", history_len=4, protocol="sims")
    dm.setup("fit")
    ar = fit_on_training_frames(dm, 2)
    assert LinearAR.from_dict(ar.to_dict()) == ar and ar.n_features == 9
    with pytest.raises(ValueError, match="lags >= 1"):
        fit_on_training_frames(dm, 0)
    with pytest.raises(ValueError, match="too short"):
        fit_on_training_frames(dm, 18)
    batch = next(iter(dm.test_dataloader()))
    short = batch.input_positions[:, :, -2:].transpose(1, 2)
    with pytest.raises(ValueError, match="at least that many"):
        ar.predict(short, batch.input_offsets[:, -2:], batch.target_offsets, dm.meta.boundary)
    assert torch.isfinite(
        ar.predict(
            batch.input_positions.transpose(1, 2),
            batch.input_offsets,
            batch.target_offsets,
            dm.meta.boundary,
        )
    ).all()
