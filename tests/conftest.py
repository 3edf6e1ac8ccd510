"""Shared fixtures: the cached tiny datasets of the built-in DEM generator.

``tiny_pbc_path`` / ``tiny_lebc_path`` are generated once per test session (a few seconds
each) through :func:`gripdem.data.cache.ensure_scene_dataset` into a session temporary
directory, from the same configs as ``python -m gripdem.simulate scene=... preset=tiny``.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from gripdem.data.cache import ensure_scene_dataset

CONF_DIR = Path(__file__).resolve().parents[1] / "conf"

# One intra-op thread: the tests' tensors are small, and on a loaded 2-core machine torch's
# OpenMP threads spin against each other (measured here: a tiny training step 100x slower).
torch.set_num_threads(1)


def compose_simulate(overrides: list[str]) -> DictConfig:
    """The config ``python -m gripdem.simulate <overrides>`` would run with."""
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return compose(config_name="simulate", overrides=overrides)


@pytest.fixture
def compose_simulate_config():
    """``compose_simulate_config(overrides) -> DictConfig`` of ``gripdem.simulate``."""
    return compose_simulate


@pytest.fixture(scope="session")
def gripdem_data_root(tmp_path_factory) -> Path:
    """Session cache directory for generated datasets."""
    return tmp_path_factory.mktemp("gripdem-data")


def _tiny_dataset(scene: str, root: Path) -> Path:
    cfg = compose_simulate([f"scene={scene}", "preset=tiny"])
    return ensure_scene_dataset(
        cfg.scene, cfg.preset, sims=cfg.sims, seed=cfg.seed, root=root, progress=False
    )


@pytest.fixture(scope="session")
def tiny_pbc_path(gripdem_data_root) -> Path:
    """Tiny periodic dataset (3 simulations x 61 frames x 400 particles), validated."""
    return _tiny_dataset("pbc", gripdem_data_root)


@pytest.fixture(scope="session")
def tiny_lebc_path(gripdem_data_root) -> Path:
    """Tiny Lees-Edwards dataset (3 simulations x 61 frames x 400 particles), validated."""
    return _tiny_dataset("lebc", gripdem_data_root)
