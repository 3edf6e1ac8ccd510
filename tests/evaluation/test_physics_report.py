"""The physics report (truth, model and baselines side by side) against answers known by
construction: a lattice's g(r), invariance under an LE-consistent shift, and hand-computed
aggregates of flows built from an exact affine shear plus known drifts."""

import math

import numpy as np
import pytest

from gripdem.boundary import Boundary, Box, LeesEdwards, rewrap_trajectory, wrap_positions
from gripdem.evaluation.physics import coordination_number, radial_distribution
from gripdem.evaluation.physics_report import bootstrap_rmse, physics_report
from gripdem.evaluation.predictions import Predictions

DT = 0.05


def test_radial_distribution_of_a_lattice_peaks_at_the_lattice_spacing():
    spacing, cells = 0.5, 6
    box = Box(spacing * cells, spacing * cells, spacing * cells)
    grid = np.stack(np.meshgrid(*[np.arange(cells)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5
    positions = grid * spacing - box.lengths / 2
    r, g = radial_distribution(positions, box, 1.2 * spacing, bins=24)
    assert r[np.argmax(g)] == pytest.approx(spacing, abs=spacing / 24)
    assert np.all(g[r < 0.9 * spacing] == 0)
    # six neighbours at the spacing: coordination from the lattice, by hand
    assert coordination_number(positions, box, 1.01 * spacing) == pytest.approx(6.0)


def test_gr_and_coordination_are_invariant_under_an_le_consistent_shift():
    box = Box(4.0, 3.0, 5.0)
    le = LeesEdwards(shear_rate=3.0, sign=1, time_origin=0.0)
    delta = float(le.offset(box, np.array([0.71]))[0])
    rng = np.random.default_rng(3)
    positions = (rng.random((400, 3)) - 0.5) * box.lengths
    # translate the whole configuration (particles leave through every face) and rewrap with
    # the same offset: the same LE lattice of images, so the same pair distances
    shifted = wrap_positions(positions + np.array([1.7, -2.2, 3.1]), box, delta)
    assert np.abs(shifted - positions).max() > 1.0
    r, g = radial_distribution(positions, box, 1.4, 28, delta)
    _, g_shifted = radial_distribution(shifted, box, 1.4, 28, delta)
    np.testing.assert_allclose(g_shifted, g, rtol=1e-12)
    assert coordination_number(shifted, box, 0.6, delta) == coordination_number(
        positions, box, 0.6, delta
    )


def affine_predictions(le: bool, drift: float = 0.0, w: int = 2, n: int = 60, horizon: int = 5):
    """Truth: exact affine shear ``u_z = strain * x`` (LE) or rest (periodic) plus a constant x
    velocity per particle (so particles cross the x faces); model: the truth plus ``drift`` in y
    per step; baselines: the truth itself and 'stay'."""
    box = Box(4.0, 3.0, 5.0)
    le_params = LeesEdwards(shear_rate=2.0, sign=1, time_origin=0.0) if le else None
    boundary = Boundary(box, le_params)
    strain = boundary.image_velocity * DT / box.lx
    rng = np.random.default_rng(1)
    start = (rng.random((w, n, 3)) - 0.5) * box.lengths
    vx = rng.normal(0.0, 0.4, (w, n))
    frames = [start]
    for _ in range(horizon):
        prev = frames[-1]
        dx = vx * DT
        step = np.stack([dx, np.zeros_like(dx), strain * (prev[..., 0] + 0.5 * dx)], -1)
        frames.append(prev + step)
    continuous = np.stack(frames, 1)  # (W, f+1, N, 3)
    times = 1.3 + DT * np.arange(horizon + 1)[None, :] + np.zeros((w, 1))
    offsets = boundary.offset(times)
    wrapped = np.stack(
        [rewrap_trajectory(c, box, o) for c, o in zip(continuous, offsets, strict=True)]
    )
    moved = continuous + drift * np.arange(horizon + 1)[None, :, None, None] * np.array([0, 1, 0])
    model = np.stack([rewrap_trajectory(c, box, o) for c, o in zip(moved, offsets, strict=True)])
    truth = wrapped[:, 1:]
    return Predictions(
        pred_positions=model[:, 1:],
        true_positions=truth,
        last_positions=wrapped[:, 0],
        times=times[:, 1:],
        boundary=boundary,
        radius=0.05,
        baselines={"echo": truth.copy(), "stay": np.repeat(wrapped[:, :1], horizon, 1)},
    ), vx


@pytest.mark.parametrize("le", [True, False])
def test_report_aggregates_match_hand_computed_values(le):
    drift = 0.02
    p, vx = affine_predictions(le, drift)
    report = physics_report(p)
    m, c = report.metrics, report.curves
    d, f = p.diameter, p.horizon
    # non-affine displacement of the truth: its own x drift (the shear is the mean flow)
    x_drift = f * DT * vx / d
    assert m["truth/non_affine_rms_over_d"] == pytest.approx(math.sqrt((x_drift**2).mean()))
    expected = math.sqrt((x_drift**2).mean() + (f * drift / d) ** 2)
    assert m["model/non_affine_rms_over_d"] == pytest.approx(expected, rel=1e-9)
    steps = np.arange(1, f + 1)
    np.testing.assert_allclose(
        c["model/non_affine_msd"],
        (steps * DT / d) ** 2 * (vx**2).mean() + (steps * drift / d) ** 2,
        rtol=1e-9,
    )
    # a baseline equal to the truth scores zero distance on every comparison
    assert m["echo/gr_distance"] == 0.0 and m["echo/profile_error_over_d"] == 0.0
    assert m["echo/coordination_contact"] == m["truth/coordination_contact"]
    assert m["echo/overlap_fraction"] == m["truth/overlap_fraction"]
    # the model's drift moves every particle alike: the structure is the truth's
    assert m["model/gr_distance"] == pytest.approx(0.0, abs=1e-12)
    if le:  # staying put is far from the sheared flow
        assert m["stay/non_affine_rms_over_d"] > m["truth/non_affine_rms_over_d"]
        assert m["crossers/n"] > 0
        assert m["crossers/echo/rmse_over_d"] == 0.0
        crossers = m["crossers/model/rmse_over_d"]
        # every model frame is off by j * drift in y: RMSE over the horizon, by hand
        assert crossers == pytest.approx(drift * math.sqrt((steps**2).mean()) / d, rel=1e-9)
        assert m["crossers/model/ci_low_over_d"] == pytest.approx(crossers, rel=1e-9)
        assert m["crossers/model/ci_high_over_d"] == pytest.approx(crossers, rel=1e-9)
    else:
        assert not any(k.startswith("crossers/") for k in m)


def test_bootstrap_interval_brackets_the_rmse():
    rng = np.random.default_rng(0)
    squared = rng.exponential(1.0, 400)
    value, low, high = bootstrap_rmse(squared)
    assert value == pytest.approx(math.sqrt(squared.mean()))
    assert low < value < high
    # the interval of n units shrinks like 1/sqrt(n)
    _, low_4, high_4 = bootstrap_rmse(np.tile(squared, 4))
    assert (high_4 - low_4) == pytest.approx((high - low) / 2, rel=0.25)
    assert all(math.isnan(v) for v in bootstrap_rmse(np.array([])))


def test_command_line_reports_a_predictions_file(tmp_path, capsys):
    """``python -m gripdem.physics_report``: the table names every set, the JSON holds the same
    scalars as the report, the figure is written."""
    import json

    from gripdem.evaluation.predictions import write_predictions
    from gripdem.physics_report import main

    p, _ = affine_predictions(le=True, drift=0.02)
    path = write_predictions(tmp_path / "predictions.h5", p)
    figure, scalars = tmp_path / "physics.png", tmp_path / "physics.json"
    assert main([str(path), "--figure", str(figure), "--json", str(scalars)]) == 0
    out = capsys.readouterr().out
    for name in ("truth", "model", "echo", "stay"):
        assert f"| {name} |" in out
    assert "LE crossers (n = " in out
    assert figure.stat().st_size > 10_000
    expected = physics_report(p).metrics
    assert json.loads(scalars.read_text()) == pytest.approx(expected)
