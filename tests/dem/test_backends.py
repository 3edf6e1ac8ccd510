"""The numba and torch kernels implement one force law: same forces, torques, spring
history and trajectories on the same dense sheared configuration, every term switched on."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gripdem.dem import forces_numba, forces_torch
from gripdem.dem.engine import Simulation
from gripdem.dem.packing import random_packing
from gripdem.dem.scenes import initial_velocities

D = 2.5e-6


def _sheared(make_config, scene: str):
    cfg = make_config(scene, particles=200, lubrication_viscosity=1e-3)
    pos = random_packing(200, cfg.box, D, np.random.default_rng(5))
    sim = Simulation(cfg, pos, initial_velocities(cfg, pos))
    sim.run(2000)
    return cfg, sim


@pytest.mark.parametrize("scene", ["lebc", "pbc"])
def test_same_forces_on_the_same_configuration(make_config, scene):
    cfg, sim = _sheared(make_config, scene)
    b = sim._backend
    p = sim.pairs
    delta = p.delta + sim.boundary.image_velocity * (sim.step - p.step) * sim.dt
    assert (np.linalg.norm(b.hist, axis=1) > 0).sum() > 50  # many loaded tangential springs
    hist_numba = b.hist.copy()
    force, torque = np.zeros_like(b.pos), np.zeros_like(b.pos)
    ov_n = forces_numba.compute_forces(
        b.pos,
        b.vel,
        b.omega,
        sim.radius,
        sim.mass,
        p.i,
        p.j,
        p.shift,
        hist_numba,
        sim.law,
        delta,
        sim.dt,
        force,
        torque,
    )
    t = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
    f_t, tq_t, h_t, ov_t = forces_torch.compute_forces(
        t(b.pos),
        t(b.vel),
        t(b.omega),
        t(sim.radius),
        t(sim.mass),
        torch.as_tensor(p.i),
        torch.as_tensor(p.j),
        t(p.shift),
        t(b.hist),
        sim.law,
        delta,
        sim.dt,
    )
    # the kernels may round a centre distance differently (sqrt of a sum vs torch's norm):
    # one ulp of the distance is one ulp of the overlap, i.e. k_n * ulp(d) of contact force
    ulp = 64 * np.spacing(D)
    np.testing.assert_allclose(f_t.numpy(), force, rtol=1e-12, atol=cfg.scene.stiffness * ulp)
    np.testing.assert_allclose(tq_t.numpy(), torque, rtol=1e-12, atol=cfg.scene.stiffness * ulp * D)
    np.testing.assert_allclose(h_t.numpy(), hist_numba, rtol=1e-12, atol=ulp)
    assert float(ov_t) == pytest.approx(ov_n, rel=1e-9)
    # Newton's third law: the pair forces sum to zero (drag and body force need not)
    none = np.zeros(0, dtype=np.int64)
    single, single_t = np.zeros_like(force), np.zeros_like(force)
    forces_numba.compute_forces(
        b.pos,
        b.vel,
        b.omega,
        sim.radius,
        sim.mass,
        none,
        none,
        np.zeros((0, 3), np.int64),
        np.zeros((0, 3)),
        sim.law,
        delta,
        sim.dt,
        single,
        single_t,
    )
    pair_part = force - single
    assert np.abs(pair_part.sum(0)).max() < 1e-9 * np.abs(pair_part).sum(0).max()


def test_same_trajectory_for_a_few_hundred_steps(make_config):
    cfg = make_config("lebc", particles=200, lubrication_viscosity=1e-3)
    pos = random_packing(200, cfg.box, D, np.random.default_rng(6))
    vel = initial_velocities(cfg, pos)
    runs = []
    for backend in ("numba", "torch"):
        sim = Simulation(cfg, pos, vel, backend=backend)
        sim.run(300)
        runs.append(sim.snapshot())
    for a, b in zip(*runs, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * np.abs(a).max())
