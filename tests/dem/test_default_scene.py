"""Slow tier: one default simulation per scene (2000 particles x 201 frames after a 1.1 ms
spin-up) passes every validation check, within the time budget of docs/spec/dem.md#step-and-cost."""

from __future__ import annotations

import time

import numpy as np
import pytest

from gripdem.dem.scenes import generate
from gripdem.dem.validation import validate_trajectories


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["lebc", "pbc"])
def test_default_simulation_is_valid_and_fast(make_config, scene):
    cfg = make_config(scene, "default", sims=1)
    start = time.perf_counter()
    data, results = generate(cfg, progress=False)
    wall = time.perf_counter() - start
    report = validate_trajectories(data)
    assert report["passed"], report["checks"]
    assert data.positions.shape == (1, 201, 2000, 3)
    assert results[0].max_overlap < 0.02
    assert report["velocity_profile"]["fit_r2"] > 0.98
    if scene == "lebc":
        assert report["x_crossings_per_frame"] > 0.05  # a few crossers per 10-frame window
    # 10 minutes for the whole default dataset on 2 cores leaves ~3 min per simulation
    assert wall < 180, f"one default simulation took {wall:.0f} s"


@pytest.mark.slow
def test_worker_processes_do_not_change_the_data(make_config):
    cfg = make_config("lebc", sims=2, frames=11)
    serial, _ = generate(cfg, progress=False, workers=1)
    parallel, _ = generate(cfg, progress=False, workers=2)
    np.testing.assert_array_equal(serial.positions, parallel.positions)
    np.testing.assert_array_equal(serial.velocities, parallel.velocities)
