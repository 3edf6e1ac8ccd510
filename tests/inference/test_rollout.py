"""Chained rollouts: an untrained model (exactly constant velocity) chained on its own
predictions must equal the one-shot constant-velocity rollout, across LE crossings, beyond the
data's end, for any link length; a diverging model is flagged, never crashes."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import torch

from gripdem.data.dataset_io import read_meta
from gripdem.inference.checkpoint import load_model
from gripdem.inference.rollout import rollout
from gripdem.inference.stepper import StepperSettings
from gripdem.models.baselines import constant_velocity


def observed_window(path, model, start=2):
    meta = read_meta(path)
    k = int(model.hparams.history_len)
    with h5py.File(path) as h5:
        positions = h5["positions"][:, start : start + k + 1]
        times = h5["times"][:, start : start + k + 1]
    return meta, positions, times


@pytest.mark.parametrize("scene", ["le", "pbc"])
@pytest.mark.parametrize("step", [None, 1, 3])
def test_chained_untrained_model_is_the_one_shot_constant_velocity_rollout(request, scene, step):
    path = request.getfixturevalue(f"{scene}_file")
    meta = read_meta(path)
    model = load_model(request.getfixturevalue(f"{scene}_checkpoint"), meta)
    meta, observed, times = observed_window(path, model)
    frames = 47  # beyond the file's 40 frames: times continue at the frame interval
    settings = StepperSettings(link=step, contact_correction=False)
    run = rollout(model, meta, observed, times, frames, settings, check_overlap=False)
    assert run.positions.shape == (3, observed.shape[1] + frames, 24, 3)
    assert np.allclose(np.diff(run.times, axis=1), meta.frame_interval, rtol=1e-9)
    in_off = meta.boundary.offset(times)
    out_off = meta.boundary.offset(run.times[:, observed.shape[1] :])
    cv = constant_velocity(torch.from_numpy(observed), in_off, out_off, meta.box).numpy()
    assert np.abs(run.predicted - cv).max() < 1e-12 * meta.box.lengths.max()
    moves = run.positions[:, 1:, :, 0] - run.positions[:, :-1, :, 0]
    assert (np.abs(moves) > 0.5 * meta.box.lx).sum() > 20  # many x-face (LE) crossings
    assert run.divergence.first == {} and run.divergence.stopped is None


def test_divergence_is_flagged_and_the_rollout_ends_cleanly(le_file, le_checkpoint):
    meta = read_meta(le_file)
    model = load_model(le_checkpoint, meta)
    _, observed, times = observed_window(le_file, model)
    g = torch.Generator().manual_seed(0)
    with torch.no_grad():  # a runaway model: huge, particle-dependent velocity changes
        for p in model.parameters():  # (a uniform shift would be removed by the zero-mean head)
            p.add_(3.0 * torch.randn(p.shape, generator=g, dtype=p.dtype))
    raw = StepperSettings(contact_correction=False)  # the model's own frames are judged
    run = rollout(model, meta, observed, times, 12, raw, overlap_margin=0.05)
    assert run.n_predicted == 12 and np.isfinite(run.positions).all()
    assert run.divergence.first["escaped"] == 1
    assert run.divergence.first["overlap"] >= 1
    assert len(run.divergence.overlap) == 12 and max(run.divergence.escaped) > 0
    with torch.no_grad():
        for p in model.parameters():
            p.fill_(float("nan"))
    run = rollout(model, meta, observed, times, 12, raw)
    assert run.divergence.first == {"non_finite": 1}
    assert "non-finite" in run.divergence.stopped
    assert run.n_predicted == 0 and np.isfinite(run.positions).all()
    assert "rollout stopped" in run.divergence.lines(0.05)[0]


def test_link_length_must_fit_the_horizon(le_file, le_checkpoint):
    meta = read_meta(le_file)
    model = load_model(le_checkpoint, meta)
    _, observed, times = observed_window(le_file, model)
    with pytest.raises(ValueError, match="link must lie in 1..5"):
        rollout(model, meta, observed, times, 10, StepperSettings(link=6))
