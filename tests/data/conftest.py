"""Small real trajectories for the data-pipeline tests (built with the ``trajectories``
fixture of ``tests/conftest.py``: random walks with many face crossings)."""

from __future__ import annotations

import pytest

from gripdem.data.dataset_io import write_dataset
from gripdem.data.schema import TrajectoryData


@pytest.fixture(scope="session")
def le_data(trajectories) -> TrajectoryData:
    return trajectories(n_sims=1, n_frames=60, n_particles=32, lees_edwards=True)


@pytest.fixture(scope="session")
def le_path(tmp_path_factory, le_data):
    return write_dataset(tmp_path_factory.mktemp("le") / "le.h5", le_data)


@pytest.fixture(scope="session")
def le_sims_path(tmp_path_factory, trajectories):
    data = trajectories(n_sims=5, n_frames=30, n_particles=20, lees_edwards=True, seed=3)
    return write_dataset(tmp_path_factory.mktemp("le_sims") / "le_sims.h5", data)


@pytest.fixture(scope="session")
def pbc_path(tmp_path_factory, trajectories):
    data = trajectories(n_sims=3, n_frames=30, n_particles=20, lees_edwards=False, seed=5)
    return write_dataset(tmp_path_factory.mktemp("pbc") / "pbc.h5", data)
