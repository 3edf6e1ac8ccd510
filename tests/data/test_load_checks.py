"""A dataset is checked once, at load, on the path the runner takes (the DataModule's
``read_meta``): finite positions (the first bad simulation, frame and particle named),
plausible units, absurd declared sizes refused before reading, splits that fit the data."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from gripdem.boundary import Boundary, Box
from gripdem.data.datamodule import TrajectoryDataModule
from gripdem.data.dataset_io import read_dataset, read_meta, write_dataset
from gripdem.data.protocols import plan_windows
from gripdem.data.schema import DatasetError
from gripdem.data.windows import SplitError


@pytest.fixture
def nan_file(tmp_path, trajectories):
    path = write_dataset(tmp_path / "nan.h5", trajectories(n_sims=3, n_frames=60, n_particles=10))
    with h5py.File(path, "r+") as h5:
        h5["positions"][2, 50, 7, 0] = np.nan
    return path


def test_the_runner_path_finds_the_nan(nan_file):
    dm = TrajectoryDataModule(nan_file, split="10-5", history_len=5)
    with pytest.raises(DatasetError) as info:
        dm.setup("fit")
    assert str(info.value) == (
        f"{nan_file}: field 'positions': expected finite values, found NaN/Inf: nan at "
        "simulation 2, frame 50, particle 7, axis x"
    )


def test_a_changed_file_is_checked_again(tmp_path, trajectories):
    path = write_dataset(tmp_path / "d.h5", trajectories(n_sims=1, n_frames=20, n_particles=8))
    read_meta(path)
    read_meta(path)  # remembered: no second scan
    with h5py.File(path, "r+") as h5:
        h5["positions"][0, 3, 2, 1] = np.inf
    with pytest.raises(DatasetError, match="simulation 0, frame 3, particle 2, axis y"):
        read_meta(path)


def test_a_whole_missing_particle_says_counts_must_be_constant(tmp_path, trajectories):
    path = write_dataset(tmp_path / "d.h5", trajectories(n_sims=1, n_frames=20, n_particles=8))
    with h5py.File(path, "r+") as h5:
        h5["positions"][0, 12, 5] = np.nan
    with pytest.raises(DatasetError, match="particle counts must be constant"):
        read_dataset(path)


@pytest.mark.parametrize(
    ("box", "radius", "message"),
    [
        (Box(32.0, 32.0, 32.0), 1.25e-6, "volume fraction of at least"),  # box in um, size in m
        (Box(8e-6, 8e-6, 2.4e-6), 1.25e-6, "below half the shortest box length"),
    ],
)
def test_implausible_units_are_refused(tmp_path, trajectories, box, radius, message):
    data = trajectories(n_sims=1, n_frames=10, n_particles=4, lees_edwards=False)
    data.positions = (data.positions / data.box.lengths) * box.lengths
    data.boundary, data.radius = Boundary(box), radius
    with pytest.raises(DatasetError, match=message):
        write_dataset(tmp_path / "d.h5", data)


def test_a_declared_size_the_file_does_not_hold_is_refused_before_reading(tmp_path, trajectories):
    path = write_dataset(tmp_path / "d.h5", trajectories(n_sims=1, n_frames=10, n_particles=4))
    with h5py.File(path, "r+") as h5:
        del h5["positions"]
        h5.create_dataset("positions", shape=(1, 10**9, 4, 3), dtype="f8", chunks=(1, 1, 4, 3))
    with pytest.raises(DatasetError, match=r"field 'positions': declares shape \(1, 1000000000"):
        read_meta(path)


def test_a_split_longer_than_the_data_is_refused_even_with_a_short_history():
    with pytest.raises(SplitError, match=r"split 300-10 needs 311 frames.*has 201"):
        plan_windows(3, 201, "300-10", "sims", history_len=10)
    assert plan_windows(3, 201, "190-10", "sims", history_len=10).split.name == "190-10"
