"""Configs and hand-placed particle pairs for the DEM tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from gripdem.dem import forces_numba, forces_torch
from gripdem.dem.config import GeneratorConfig

CONF = Path(__file__).resolve().parents[2] / "conf"


def load_yaml(group: str, name: str) -> dict:
    return yaml.safe_load((CONF / group / f"{name}.yaml").read_text())


def config(scene: str = "pbc", preset: str = "tiny", sims: int = 1, **overrides) -> GeneratorConfig:
    """A generator config from the repo's YAML files with keys overridden (scene or preset)."""
    s, p = load_yaml("scene", scene), load_yaml("preset", preset)
    for key, value in overrides.items():
        (p if key in p else s)[key] = value
    return GeneratorConfig.from_mappings(s, p, sims=sims)


def two_particle_config(scene: str = "pbc", **overrides) -> GeneratorConfig:
    """Two particles in a dilute box (~10 d wide): only the terms switched on act."""
    base = dict(particles=2, volume_fraction=0.001)
    if scene == "pbc":
        base["body_force_amplitude"] = 0.0
    base.update(overrides)
    return config(scene, **base)


def pair_forces(
    cfg: GeneratorConfig,
    pos,
    vel,
    omega=None,
    shift=(0, 0, 0),
    history=None,
    delta=0.0,
    hist_dt=0.0,
    backend="numba",
):
    """Force, torque (both (2, 3)), new history (3,) and max overlap for the pair (0, 1)."""
    pos = np.asarray(pos, dtype=np.float64)
    vel = np.asarray(vel, dtype=np.float64)
    omega = np.zeros((2, 3)) if omega is None else np.asarray(omega, dtype=np.float64)
    radius = np.full(2, cfg.radius)
    mass = np.full(2, cfg.mass)
    pi, pj = np.array([0]), np.array([1])
    sh = np.asarray([shift], dtype=np.int64)
    hist = np.zeros((1, 3)) if history is None else np.asarray([history], dtype=np.float64)
    law = cfg.force_law()
    if backend == "numba":
        force, torque = np.zeros((2, 3)), np.zeros((2, 3))
        ov = forces_numba.compute_forces(
            pos, vel, omega, radius, mass, pi, pj, sh, hist, law, delta, hist_dt, force, torque
        )
        return force, torque, hist[0], ov
    import torch

    t = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
    f, tq, h, ov = forces_torch.compute_forces(
        t(pos),
        t(vel),
        t(omega),
        t(radius),
        t(mass),
        torch.as_tensor(pi),
        torch.as_tensor(pj),
        t(sh),
        t(hist),
        law,
        delta,
        hist_dt,
    )
    return f.numpy(), tq.numpy(), h.numpy()[0], float(ov)


@pytest.fixture(params=["numba", "torch"])
def backend(request) -> str:
    return request.param


@pytest.fixture
def make_config():
    """``make_config(scene, preset, sims, **overrides) -> GeneratorConfig``."""
    return config


@pytest.fixture
def two_particles():
    """``two_particles(scene, **overrides) -> GeneratorConfig`` for a dilute two-particle box."""
    return two_particle_config


@pytest.fixture
def pair_kernel():
    """``pair_kernel(cfg, pos, vel, ..., backend) -> (force, torque, history, overlap)``."""
    return pair_forces
