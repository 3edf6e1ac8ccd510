"""Small real trajectories for the data-pipeline tests.

Particles move in lattice-continuous coordinates (affine shear u_z = k*x in the LE scene, a
cosine profile in the periodic one, plus a random walk large enough to cross every face often)
and each frame is wrapped with :func:`gripdem.boundary.wrap_positions` at that frame's LE
offset. Frame times do not start at 0, so the offset of frame 0 is not 0.
"""

from __future__ import annotations

import numpy as np
import pytest

from gripdem.boundary import Boundary, Box, LeesEdwards, wrap_positions
from gripdem.data.schema import TrajectoryData, write_dataset

DIAMETER = 2.5e-6
BOX = Box(8 * DIAMETER, 7 * DIAMETER, 9 * DIAMETER)  # never cubic
DT = 5e-6
T0 = 1.1e-3  # absolute time of frame 0 (after a spin-up)
SHEAR_RATE = 1e4  # 0.4 d of LE offset per frame: offsets sweep the whole box in a test
STEP = 0.25 * DIAMETER  # random-walk step per frame and axis


def make_trajectories(
    n_sims: int = 1,
    n_frames: int = 40,
    n_particles: int = 24,
    lees_edwards: bool = True,
    seed: int = 0,
    box: Box = BOX,
) -> TrajectoryData:
    """Wrapped trajectories ``(sims, frames, particles, 3)`` with many face crossings."""
    rng = np.random.default_rng(seed)
    le = LeesEdwards(SHEAR_RATE, sign=1, time_origin=0.3e-3) if lees_edwards else None
    boundary = Boundary(box, le)
    times = T0 + DT * np.arange(n_frames)[None, :] + 7 * DT * np.arange(n_sims)[:, None]
    offsets = boundary.offset(times)
    cont = (rng.random((n_sims, n_particles, 3)) - 0.5) * box.lengths
    positions = np.empty((n_sims, n_frames, n_particles, 3))
    for t in range(n_frames):
        if t:
            flow = np.zeros_like(cont)
            if lees_edwards:
                flow[..., 2] = SHEAR_RATE * cont[..., 0] * DT
            else:
                flow[..., 2] = 0.3 * DIAMETER * np.cos(2 * np.pi * cont[..., 0] / box.lx)
            cont = cont + flow + rng.normal(0.0, STEP, cont.shape)
        positions[:, t] = wrap_positions(cont, box, offsets[:, t, None])
    return TrajectoryData(
        positions=positions,
        times=times,
        boundary=boundary,
        radius=DIAMETER / 2,
        provenance={"generator": "tests/data/conftest.py", "seed": seed},
    )


@pytest.fixture(scope="session")
def trajectories():
    """The generator :func:`make_trajectories` (tests import nothing from conftest)."""
    return make_trajectories


@pytest.fixture(scope="session")
def le_data() -> TrajectoryData:
    return make_trajectories(n_sims=1, n_frames=60, n_particles=32, lees_edwards=True)


@pytest.fixture(scope="session")
def le_path(tmp_path_factory, le_data):
    return write_dataset(tmp_path_factory.mktemp("le") / "le.h5", le_data)


@pytest.fixture(scope="session")
def le_sims_path(tmp_path_factory):
    data = make_trajectories(n_sims=5, n_frames=30, n_particles=20, lees_edwards=True, seed=3)
    return write_dataset(tmp_path_factory.mktemp("le_sims") / "le_sims.h5", data)


@pytest.fixture(scope="session")
def pbc_path(tmp_path_factory):
    data = make_trajectories(n_sims=3, n_frames=30, n_particles=20, lees_edwards=False, seed=5)
    return write_dataset(tmp_path_factory.mktemp("pbc") / "pbc.h5", data)
