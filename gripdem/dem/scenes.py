"""Scene drivers: pack, spin up (not written), record frames; S simulations -> one dataset.

Every simulation: random packing at the target volume fraction (own seed), velocities set
to the imposed mean flow (LE: u_z = shear_rate x; periodic: the drag-only steady profile
a tau_p cos(2 pi x / lx)), ``spinup_frames`` frame intervals of driven flow that are not
written, then ``frames`` frames. Frame times are absolute (time origin 0 at the start of
the spin-up, where the LE offset is 0), so the first written frame has t > 0 and delta != 0.
Everything stays in memory until the caller writes the dataset atomically.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from queue import Empty

import numpy as np
from tqdm.auto import tqdm

from gripdem._version import __version__
from gripdem.data.schema import TrajectoryData
from gripdem.dem.config import GeneratorConfig
from gripdem.dem.engine import Simulation
from gripdem.dem.packing import random_packing
from gripdem.dem.params import GENERATOR_NAME, GENERATOR_VERSION
from gripdem.dem.workers import die_with_parent
from gripdem.provenance import available_cpus

#: an overlap above this fraction of the diameter in any step means contacts pass through each
#: other: the step is too large for the stiffness (the refusal in GeneratorConfig covers equal
#: spheres; this catches the rest, e.g. smaller particles of a polydisperse state). The
#: validated data keeps overlaps below 2 % of d, the default scenes below 0.03 %.
DIVERGED_OVERLAP = 0.2


@dataclass
class SimulationResult:
    """Frames of one simulation: positions/velocities ``(frames, n, 3)``, times ``(frames,)``."""

    positions: np.ndarray
    velocities: np.ndarray
    times: np.ndarray
    max_overlap: float  # largest overlap / d over every DEM step (spin-up included)
    rebuilds: int
    wall_time: float  # seconds, packing included
    steps: int


def initial_velocities(config: GeneratorConfig, positions: np.ndarray) -> np.ndarray:
    """The imposed mean flow at ``positions`` ``(n, 3)``."""
    vel = np.zeros_like(positions)
    if config.scene.boundary == "lees_edwards":
        vel[:, 2] = config.scene.shear_rate * positions[:, 0]
    elif math.isfinite(config.relaxation_time):
        amplitude = config.body_force_amplitude * config.relaxation_time
        vel[:, 2] = amplitude * np.cos(2.0 * np.pi * positions[:, 0] / config.box.lx)
    return vel


def _check_contacts(sim: Simulation, where: str) -> None:
    """Raise when contacts have passed through each other (see :data:`DIVERGED_OVERLAP`)."""
    if sim.max_overlap > DIVERGED_OVERLAP:
        raise FloatingPointError(
            f"DEM diverged by {where} (t = {sim.time:.4g} s): an overlap of "
            f"{sim.max_overlap:.3g} d (limit {DIVERGED_OVERLAP:g} d) means contacts pass "
            f"through each other: the step dt = {sim.dt:.3g} s is too large for the contact "
            "stiffness; raise preset.steps_per_contact"
        )


def simulate_one(
    config: GeneratorConfig,
    rng: np.random.Generator,
    progress: tqdm | None = None,
    device: str = "cpu",
) -> SimulationResult:
    """Run one simulation of ``config`` (its frames, spin-up and particle count)."""
    start = time.perf_counter()
    p = config.preset
    pos = random_packing(
        p.particles, config.box, config.scene.diameter, rng, insert_fraction=p.pack_volume_fraction
    )
    sim = Simulation(config, pos, initial_velocities(config, pos), device=device)
    per_frame = config.steps_per_frame
    for k in range(config.spinup_frames):
        sim.run(per_frame)
        _check_contacts(sim, f"spin-up frame {k + 1} of {config.spinup_frames}")
        if progress is not None:
            progress.update(1)
    n = p.particles
    positions = np.empty((p.frames, n, 3))
    velocities = np.empty((p.frames, n, 3))
    times = np.empty(p.frames)
    for f in range(p.frames):
        if f:
            sim.run(per_frame)
        positions[f], velocities[f], _ = sim.snapshot()
        times[f] = sim.time
        if not np.isfinite(positions[f]).all():
            raise FloatingPointError(
                f"DEM state became non-finite at t = {sim.time:.4g} s (frame {f}); "
                "reduce dt (preset.steps_per_contact) or check the scene coefficients"
            )
        _check_contacts(sim, f"frame {f}")
        if progress is not None:
            progress.update(1)
    return SimulationResult(
        positions,
        velocities,
        times,
        sim.max_overlap,
        sim.rebuilds,
        time.perf_counter() - start,
        sim.step,
    )


#: the progress queue of this worker process (set by :func:`_init_worker`)
_PROGRESS = None


def _init_worker(parent_pid: int, queue) -> None:
    """First thing in each worker: die with the parent (:mod:`gripdem.dem.workers`), keep the
    progress queue."""
    global _PROGRESS
    die_with_parent(parent_pid)
    queue.cancel_join_thread()  # progress ticks unsent at exit may be dropped, never block it
    _PROGRESS = queue


def _worker(config: GeneratorConfig, seed: np.random.SeedSequence, device: str):
    """One simulation in a worker process; reports each frame through the progress queue."""

    class _Ticker:
        def update(self, k: int) -> None:
            _PROGRESS.put(k)

    return simulate_one(config, np.random.default_rng(seed), _Ticker(), device)


#: particle-steps per simulation below which one process is faster than spawning workers
PARALLEL_MIN_WORK = 5e7


def resolve_workers(config: GeneratorConfig, workers: int | None, device: str = "cpu") -> int:
    """Processes to use: one simulation per process, at most the CPUs available; 1 for a GPU
    run (one device) and, unless ``workers`` is given, for small jobs (a worker process
    costs about 2 s to start)."""
    if config.backend == "torch" and device != "cpu":
        return 1
    if multiprocessing.get_start_method(allow_none=True) not in (
        None,
        "fork",
        "spawn",
        "forkserver",
    ):
        # Inside a worker of another pool (e.g. Hydra's joblib launcher sets "loky"), spawned
        # children cannot start: simulate in this process.
        return 1
    if workers is None and config.preset.particles * config.total_steps < PARALLEL_MIN_WORK:
        return 1
    limit = available_cpus()
    return max(1, min(config.sims, limit if workers is None else int(workers)))


def generate(
    config: GeneratorConfig,
    progress: bool = True,
    workers: int | None = None,
    device: str = "cpu",
) -> tuple[TrajectoryData, list[SimulationResult]]:
    """All ``config.sims`` simulations (independent seeds from ``config.seed``) as one
    in-memory dataset, plus the per-simulation results (timings, in-run overlaps).

    Simulations run in ``workers`` processes (default: one per CPU, at most ``sims``); the
    result does not depend on ``workers``.
    """
    seeds = np.random.SeedSequence(config.seed).spawn(config.sims)
    per_sim = config.spinup_frames + config.preset.frames
    n_workers = resolve_workers(config, workers, device)
    label = f"{config.scene.name}/{config.preset.name}"
    with tqdm(
        total=per_sim * config.sims,
        desc=f"DEM {label}",
        unit="frame",
        disable=not progress,
        dynamic_ncols=True,
    ) as bar:
        bar.set_postfix_str(f"{config.sims} sims, {n_workers} process(es)")
        if n_workers == 1:
            results = [simulate_one(config, np.random.default_rng(s), bar, device) for s in seeds]
        else:
            results = _generate_parallel(config, seeds, n_workers, bar, device)
    data = TrajectoryData(
        positions=np.stack([r.positions for r in results]),
        times=np.stack([r.times for r in results]),
        boundary=config.boundary,
        radius=config.radius,
        body_force_amplitude=config.body_force_amplitude,
        velocities=np.stack([r.velocities for r in results]),
        provenance={
            "generator": GENERATOR_NAME,
            "version": GENERATOR_VERSION,
            "package_version": __version__,
            "parameters": config.to_dict(),
            "derived": config.describe(),
            "max_overlap_all_steps": [r.max_overlap for r in results],
            "wall_time_s": [r.wall_time for r in results],
        },
    )
    return data, results


def _generate_parallel(config, seeds, n_workers, bar, device) -> list[SimulationResult]:
    # spawn: a clean interpreter per worker (no forked torch/numba thread state). The workers
    # ignore Ctrl-C (started while it is ignored, they inherit that): this process alone
    # handles it (and SIGTERM) and stops them, so no worker prints a traceback of its own.
    # A SIGKILL leaves this process no say: the workers end themselves when it is gone
    # (gripdem.dem.workers), and progress comes through a plain queue (a Manager's server
    # process would outlive a killed parent).
    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    pool = ProcessPoolExecutor(
        n_workers, mp_context=ctx, initializer=_init_worker, initargs=(os.getpid(), queue)
    )
    try:
        with pool:
            with _children_ignore_sigint():
                futures = [pool.submit(_worker, config, s, device) for s in seeds]
            try:
                while not all(f.done() for f in futures):
                    _drain(queue, bar, timeout=0.5)
                results = [f.result() for f in futures]
                _drain(queue, bar, timeout=0.0)
                bar.update(max(0, bar.total - bar.n))  # ticks still on their way
                return results
            except BaseException:
                for f in futures:
                    f.cancel()
                _stop_workers(pool)
                raise
    finally:
        queue.close()
        queue.join_thread()


@contextmanager
def _children_ignore_sigint() -> Iterator[None]:
    """Processes started inside the block inherit an ignored SIGINT (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _stop_workers(pool: ProcessPoolExecutor) -> None:
    """Terminate the pool's worker processes (they ignore Ctrl-C and would run on)."""
    terminate = getattr(pool, "terminate_workers", None)  # Python >= 3.14
    if terminate is not None:
        terminate()
        return
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        if process.is_alive():
            process.terminate()


def _drain(queue, bar, timeout: float) -> None:
    try:
        bar.update(queue.get(timeout=timeout) if timeout else queue.get_nowait())
        while True:
            bar.update(queue.get_nowait())
    except Empty:
        pass
