"""Baselines are exact where their assumption holds; metrics equal a slow reference."""

import math

import numpy as np
import pytest
import torch

from gripdem.boundary import Box, LeesEdwards, minimum_image, rewrap_trajectory
from gripdem.evaluation.metrics import (
    crossing_mask,
    position_residuals,
    rmse,
    rmse_per_step,
    summarize,
)
from gripdem.models.baselines import constant_velocity, mean_flow, predict_baseline, stay

BOX = Box(2.0, 2.5, 3.0)
LE = LeesEdwards(shear_rate=2.0, sign=1, time_origin=0.1)
DT = 0.05


def windows_of(continuous, times, n_in):
    """Split continuous trajectories ``(windows, frames, n, 3)`` into wrapped observed and
    target frames with their offsets."""
    offsets = LE.offset(BOX, times)
    wrapped = np.stack(
        [rewrap_trajectory(c, BOX, o) for c, o in zip(continuous, offsets, strict=True)]
    )
    return (
        torch.tensor(wrapped[:, :n_in]),
        torch.tensor(wrapped[:, n_in:]),
        torch.tensor(offsets[:, :n_in]),
        torch.tensor(offsets[:, n_in:]),
    )


def test_constant_velocity_is_exact_on_ballistic_motion_across_le_faces():
    rng = np.random.default_rng(0)
    w, n, n_in, horizon = 3, 60, 4, 12
    start = (rng.random((w, 1, n, 3)) - 0.5) * BOX.lengths
    velocity = rng.normal(0, 0.08, (w, 1, n, 3)) * BOX.lengths
    steps = np.arange(n_in + horizon)[None, :, None, None]
    continuous = start + steps * velocity  # ballistic in lattice-continuous coordinates
    times = 3.7 + DT * np.arange(n_in + horizon)[None, :] + np.zeros((w, 1))
    observed, target, obs_off, tgt_off = windows_of(continuous, times, n_in)
    pred = constant_velocity(observed, obs_off, tgt_off, BOX)
    mask = crossing_mask(observed[:, -1], target, BOX, tgt_off)
    assert mask.sum() > 20  # many particles cross an LE face inside the horizon
    res = position_residuals(pred, target, BOX, tgt_off)
    assert rmse(res) < 1e-10
    # stepping a fixed velocity in wrapped space (forgetting the velocity jump) is not exact
    naive = observed[:, -1:] + torch.arange(1, horizon + 1)[None, :, None, None] * (
        observed[:, -1:] - observed[:, -2:-1]
    )
    assert rmse(position_residuals(naive, target, BOX, tgt_off)) > 1e-2


@pytest.mark.parametrize("profile", ["linear", "cosine"])
def test_mean_flow_is_exact_on_the_imposed_profile(profile):
    rng = np.random.default_rng(1)
    w, n, n_in, horizon = 2, 80, 6, 5
    x = (rng.random((w, 1, n)) - 0.5) * BOX.lx
    u = 0.3 * x + 0.05 if profile == "linear" else 0.2 * np.cos(2 * np.pi * x / BOX.lx) - 0.02
    frames = np.arange(n_in + horizon)[None, :, None]
    pos = np.zeros((w, n_in + horizon, n, 3))
    pos[..., 0] = x
    pos[..., 1] = (rng.random((w, 1, n)) - 0.5) * BOX.ly
    pos[..., 2] = (rng.random((w, 1, n)) - 0.5) * BOX.lz + frames * u
    pos[..., 2] -= BOX.lz * np.floor(pos[..., 2] / BOX.lz + 0.5)
    zeros = torch.zeros(w, n_in), torch.zeros(w, horizon)
    pred = mean_flow(torch.tensor(pos[:, :n_in]), *zeros, BOX, profile)
    res = position_residuals(pred, torch.tensor(pos[:, n_in:]), BOX)
    assert rmse(res) < 1e-10


def test_stay_is_exact_on_static_particles_and_dispatch():
    rng = np.random.default_rng(2)
    pos = torch.tensor((rng.random((2, 1, 10, 3)) - 0.5) * BOX.lengths).expand(-1, 7, -1, -1)
    off = torch.zeros(2, 4), torch.zeros(2, 3)
    torch.testing.assert_close(stay(pos[:, :4], 3), pos[:, 4:])
    torch.testing.assert_close(
        predict_baseline("stay", pos[:, :4], *off, BOX, "linear"), pos[:, 4:]
    )
    with pytest.raises(ValueError, match="baseline must be one of"):
        predict_baseline("oracle", pos[:, :4], *off, BOX, "linear")


def slow_reference_rmse(pred, true, offsets):
    """The formula of docs/spec/evaluation.md#rmse with Python loops, one particle at a time."""
    total, count = 0.0, 0
    for s in range(pred.shape[0]):
        for t in range(pred.shape[1]):
            delta = float(offsets[s, t])
            for i in range(pred.shape[2]):
                r = [true[s, t, i, c] - pred[s, t, i, c] for c in range(3)]
                if r[0] >= BOX.lx / 2:
                    r[0] -= BOX.lx
                    r[2] -= delta
                elif r[0] < -BOX.lx / 2:
                    r[0] += BOX.lx
                    r[2] += delta
                r[1] -= BOX.ly * math.floor(r[1] / BOX.ly + 0.5)
                r[2] -= BOX.lz * math.floor(r[2] / BOX.lz + 0.5)
                total += sum(v * v for v in r)
                count += 1
    return math.sqrt(total / count)


def test_rmse_equals_a_slow_reference_on_random_le_data():
    rng = np.random.default_rng(3)
    shape = (3, 4, 25, 3)
    true = (rng.random(shape) - 0.5) * BOX.lengths
    pred = (rng.random(shape) - 0.5) * BOX.lengths
    offsets = LE.offset(BOX, 5.0 + DT * rng.integers(0, 1000, (3, 4)))
    expected = slow_reference_rmse(pred, true, offsets)
    assert rmse(position_residuals(pred, true, BOX, offsets)) == pytest.approx(expected, rel=1e-12)
    got_t = rmse(position_residuals(torch.tensor(pred), torch.tensor(true), BOX, offsets))
    assert got_t == pytest.approx(expected, rel=1e-12)


def test_summary_keys_and_per_step_values():
    rng = np.random.default_rng(4)
    true = (rng.random((2, 3, 8, 3)) - 0.5) * BOX.lengths
    pred = true.copy()
    pred[:, 2, :, 1] += 0.1  # only step 3 is wrong, by 0.1 in y
    offsets = LE.offset(BOX, 1.0 + DT * np.arange(3))[None].repeat(2, 0)
    out = summarize(pred, true, true[:, 0], BOX, diameter=0.05, offsets=offsets, le=True)
    assert out["rmse_step/001"] == pytest.approx(0.0, abs=1e-12)
    assert out["rmse_step/003"] == pytest.approx(0.1)
    assert out["rmse"] == pytest.approx(0.1 / math.sqrt(3))
    assert out["rmse_over_d"] == pytest.approx(out["rmse"] / 0.05)
    assert {"rmse_crossers", "rmse_others", "n_crossers"} <= set(out)
    np.testing.assert_allclose(
        rmse_per_step(position_residuals(pred, true, BOX, offsets)), [0, 0, 0.1], atol=1e-12
    )
    # residuals stay within half a box per axis
    assert np.all(np.abs(minimum_image(true - pred, BOX)) <= BOX.lengths / 2)
