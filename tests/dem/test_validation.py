"""The validation report on the cached tiny datasets (issue 3), and that it catches bad data."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from gripdem.boundary import wrap_positions
from gripdem.data.dataset_io import read_dataset
from gripdem.dem.validation import report_paths, validate_trajectories


@pytest.fixture(params=["pbc", "lebc"])
def tiny(request, tiny_pbc_path, tiny_lebc_path):
    return {"pbc": tiny_pbc_path, "lebc": tiny_lebc_path}[request.param]


def test_tiny_dataset_is_valid_and_has_its_report(tiny):
    data = read_dataset(tiny)
    assert data.positions.shape == (3, 61, 400, 3)
    assert data.velocities is not None and np.isfinite(data.velocities).all()
    assert data.times[0, 0] > 0  # absolute frame times after the spin-up
    assert data.provenance["generator"] == "gripdem.dem"
    json_path, png_path = report_paths(tiny)
    report = json.loads(json_path.read_text())
    assert png_path.stat().st_size > 1000 and png_path.read_bytes()[:4] == b"\x89PNG"
    assert report["passed"], report["checks"]
    assert report["max_overlap_frames_d"] < 0.02
    assert report["max_overlap_all_steps_d"] < 0.02
    assert report["velocity_profile"]["fit_r2"] > 0.95
    assert report["nonaffine_rms_window_d"] > 0.005  # motion relative to the mean flow
    if data.boundary.is_lees_edwards:
        assert report["checks"]["le_crossings_present"]
        assert report["x_crossings_total"] > 0
        assert report["velocity_profile"]["slope_over_shear_rate"] == pytest.approx(1, abs=0.1)
        assert abs(data.offsets()[0, 0]) > 0  # the LE offset of frame 0 is not zero


def test_report_recomputed_from_the_file_matches(tiny):
    report = json.loads(report_paths(tiny)[0].read_text())
    again = validate_trajectories(read_dataset(tiny))
    for key in ("max_overlap_frames_d", "nonaffine_rms_window_d", "x_crossings_total"):
        assert again[key] == pytest.approx(report[key])


def test_checks_fail_on_bad_data(tiny_lebc_path):
    data = read_dataset(tiny_lebc_path)
    # an overlapping pair: particle 1 put half a diameter from particle 0 in one frame
    pos = data.positions.copy()
    moved = pos[0, 5, 0] + np.array([0.5 * data.diameter, 0, 0])
    pos[0, 5, 1] = wrap_positions(moved, data.box, data.offsets()[0, 5])
    report = validate_trajectories(replace(data, positions=pos))
    assert report["max_overlap_frames_d"] == pytest.approx(0.5, abs=0.01)
    assert not report["checks"]["max_overlap_below_2pct_d"] and not report["passed"]
    # frozen particles: no flow profile, no motion, no crossings
    frozen = np.repeat(data.positions[:, :1], data.n_frames, axis=1)
    report = validate_trajectories(replace(data, positions=frozen))
    assert not report["checks"]["nonaffine_motion_measurable"]
    assert not report["checks"]["le_crossings_present"]
    assert not report["passed"]
    nan = data.positions.copy()
    nan[0, 3, 7, 1] = np.nan
    assert validate_trajectories(replace(data, positions=nan))["passed"] is False
