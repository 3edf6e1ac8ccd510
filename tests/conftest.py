"""Shared fixtures: the cached tiny datasets of the built-in DEM generator, and synthetic
trajectories with many face crossings.

``tiny_pbc_path`` / ``tiny_lebc_path`` are generated once per test session (a few seconds
each) through :func:`gripdem.dem.output.ensure_scene_dataset` into a session temporary
directory, from the same configs as ``python -m gripdem.simulate scene=... preset=tiny``
(tests/support/tiny_scenes.py; a whole-suite run under pytest-xdist makes them while its
workers start).

``trajectories(...)`` makes small real trajectories: particles move in lattice-continuous
coordinates (affine shear u_z = k*x in the LE scene, a cosine profile in the periodic one, plus
a random walk large enough to cross every face often) and each frame is wrapped with
:func:`gripdem.boundary.wrap_positions` at that frame's LE offset. Frame times do not start at
0, so the offset of frame 0 is not 0.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from tiny_scenes import compose_simulate, tiny_dataset

from gripdem.boundary import Boundary, Box, LeesEdwards, wrap_positions
from gripdem.data.dataset_io import write_dataset
from gripdem.data.schema import TrajectoryData


def pytest_sessionstart(session):
    """Byte-compile gripdem and the experiment scripts' modules once, in the controlling
    process: the suite starts some 40 Python processes (scripts, sweeps and their jobs, the
    CLIs), and where ``PYTHONDONTWRITEBYTECODE`` is set (this machine sets it) none of them
    writes a ``.pyc``, so each would compile every gripdem module it imports from source again
    (0.3-0.5 s a process, measured); the variable stops writing, not reading. (The test
    modules are left out: pytest rewrites and caches them its own way.)"""
    if getattr(session.config, "workerinput", None) is not None:  # an xdist worker
        return
    import compileall

    root = Path(__file__).resolve().parents[1]
    for folder in ("gripdem", "experiments"):
        compileall.compile_dir(root / folder, quiet=2, workers=1)
    _start_making_the_tiny_scenes(session.config)


#: the process making the tiny scenes ahead of the workers (tests/support/tiny_scenes.py)
_SCENE_MAKER: list[subprocess.Popen] = []


def _start_making_the_tiny_scenes(config) -> None:
    """A whole-suite run under pytest-xdist (no test paths given) makes the tiny scenes in a
    process of its own while the workers start: in the folder that the workers'
    ``gripdem_data_root`` names, through the dataset cache, whose lock makes a worker that
    needs a scene before it is ready wait for it. Measured on 2 cores: without it, one worker
    made the periodic scene (and, in a fresh clone, compiled the DEM's kernels) while the
    other waited for it, idle. A run of some tests, or without workers, makes what it needs
    when it needs it."""
    if os.environ.get("GRIPDEM_TEST_DATA") or not config.pluginmanager.hasplugin("dsession"):
        return
    if config.args_source != pytest.Config.ArgsSource.TESTPATHS:
        return
    shared = config._tmp_path_factory.getbasetemp() / "gripdem-data"  # the workers' parent
    shared.mkdir(exist_ok=True)
    script = Path(__file__).resolve().parent / "support" / "tiny_scenes.py"
    with open(shared / "tiny_scenes.log", "w") as log:
        _SCENE_MAKER.append(
            subprocess.Popen(
                [sys.executable, str(script), str(shared)],
                stdout=log,
                stderr=subprocess.STDOUT,
                env={**os.environ, "OMP_NUM_THREADS": "1"},
            )
        )


def pytest_sessionfinish(session):
    """The scene maker ends with the run (an early stop: ``-x``, Ctrl-C); the dataset cache
    writes atomically, so a stopped generation leaves nothing that a later run would read."""
    for maker in _SCENE_MAKER:
        if maker.poll() is None:
            maker.terminate()
        maker.wait()


# One intra-op thread by default: the tests' tensors are small, and on a loaded 2-core machine
# torch's OpenMP threads spin against each other (measured here: a tiny training step 100x
# slower). GRIPDEM_TEST_THREADS sets another count: experiments/analyses/threshold_spread.py runs
# the suite with 1 and 2 threads to check that no threshold depends on it.
torch.set_num_threads(int(os.environ.get("GRIPDEM_TEST_THREADS", "1")))

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


@pytest.fixture
def compose_simulate_config():
    """``compose_simulate_config(overrides) -> DictConfig`` of ``gripdem.simulate``."""
    return compose_simulate


@pytest.fixture(scope="session")
def gripdem_data_root(tmp_path_factory, worker_id) -> Path:
    """Session cache directory for generated datasets. Under pytest-xdist every worker uses
    the same one (in the parent of the workers' temporary folders): the dataset cache's file
    lock lets the first worker generate the tiny scenes while the others wait, so they are
    generated once per test run, not once per worker. ``GRIPDEM_TEST_DATA`` names another
    test run's folder to share (tests/test_portable_numerics.py hands its own to the run it
    starts)."""
    if os.environ.get("GRIPDEM_TEST_DATA"):
        return Path(os.environ["GRIPDEM_TEST_DATA"])
    if worker_id == "master":
        return tmp_path_factory.mktemp("gripdem-data")
    shared = tmp_path_factory.getbasetemp().parent / "gripdem-data"
    shared.mkdir(exist_ok=True)
    return shared


@pytest.fixture(scope="session")
def worker_id(request) -> str:
    """pytest-xdist's worker name ("gw0", ...), or "master" without xdist."""
    workerinput = getattr(request.config, "workerinput", None)
    return workerinput["workerid"] if workerinput else "master"


def pytest_collection_modifyitems(config, items) -> None:
    """Tests marked ``first`` (the longest, each a minute or so) start before the others, so
    that under pytest-xdist they do not form the tail of the run on one worker."""
    items.sort(key=lambda item: item.get_closest_marker("first") is None)  # stable


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_auto_num_workers(config) -> int:
    """``-n auto``: one worker per available core, at most 4 (each worker holds its own torch,
    numba and datasets: about 1 GB), and no more than the tests need."""
    available = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(4, available or 1))


#: Test modules whose tests share one costly module fixture (a sweep, a wheel, a trained
#: model): under pytest-xdist each is sent whole to one worker, which makes the fixture once
#: (sent test by test, two workers made it twice: 27 s of the suite for the TensorBoard sweep).
ONE_WORKER_MODULES = (
    "tests/runner/test_tensorboard.py",
    "tests/runner/test_finetune.py",
    "tests/test_wheel.py",
)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """``-n``'s default distribution (``load``: test by test to whichever worker is free), but
    the tests of each of ONE_WORKER_MODULES as one unit. This is what ``--dist loadgroup`` with
    an ``xdist_group`` mark does, but pytest 9.2 drops the mark's node-id suffix that loadgroup
    reads (pytest-xdist issue 1386), so the controller groups by path itself. Another ``--dist``
    given on the command line is left to xdist."""
    if config.getvalue("dist") != "load":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class OneWorkerModules(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            path = nodeid.split("::", 1)[0]
            return path if path in ONE_WORKER_MODULES else nodeid

    return OneWorkerModules(config, log)


@pytest.fixture(scope="session")
def run_experiment_quick(gripdem_data_root):
    """``run_experiment_quick(name, *args)``: ``python experiments/<name>.py --quick ARGS`` from
    the repository root with the session's dataset cache, output captured (the callers assert
    on it)."""
    root = Path(__file__).resolve().parents[1]

    def run(name: str, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, str(root / "experiments" / f"{name}.py"), "--quick", *args],
            capture_output=True,
            text=True,
            cwd=root,
            timeout=900,
            env={**os.environ, "GRIPDEM_DATA": str(gripdem_data_root)},
        )

    return run


@pytest.fixture(scope="session")
def tiny_pbc_path(gripdem_data_root) -> Path:
    """Tiny periodic dataset (3 simulations x 61 frames x 400 particles), validated."""
    return tiny_dataset("pbc", gripdem_data_root)


@pytest.fixture(scope="session")
def tiny_lebc_path(gripdem_data_root) -> Path:
    """Tiny Lees-Edwards dataset (3 simulations x 61 frames x 400 particles), validated."""
    return tiny_dataset("lebc", gripdem_data_root)


@pytest.fixture(scope="session")
def le_file(tmp_path_factory):
    """3 sheared simulations x 40 frames x 24 particles, crossing the LE faces often."""
    data = make_trajectories(n_sims=3, n_frames=40, n_particles=24, lees_edwards=True, seed=11)
    return write_dataset(tmp_path_factory.mktemp("files") / "le.h5", data)


@pytest.fixture(scope="session")
def pbc_file(tmp_path_factory):
    data = make_trajectories(n_sims=3, n_frames=40, n_particles=24, lees_edwards=False, seed=12)
    return write_dataset(tmp_path_factory.mktemp("files") / "pbc.h5", data)
