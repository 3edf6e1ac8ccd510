"""Fixtures for the DEM-engine workflow (predict, rollout, hand-back): small real datasets and
real Lightning checkpoints of untrained models.

An untrained model is exactly the constant-velocity (CV) predictor (every learned output starts
at zero, docs/spec/model.md#exact-frame), which makes rollouts checkable to round-off: a chained
rollout of it must equal the one-shot CV rollout. The checkpoints are written by a Lightning
``Trainer`` after a zero-step ``fit`` of the model :mod:`gripdem.runner.experiment` builds from the
smoke preset.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from checkpoints import untrained_checkpoint


def make_checkpoint(data_path: Path, out: Path, overrides: list[str]) -> Path:
    """``out/checkpoints/best.ckpt`` of the untrained smoke model on ``data_path``."""
    return untrained_checkpoint(data_path, out / "checkpoints" / "best.ckpt", overrides)


@pytest.fixture(scope="session", name="make_checkpoint")
def make_checkpoint_fixture():
    """``make_checkpoint(data_path, out_dir, overrides) -> checkpoint path``."""
    return make_checkpoint


@pytest.fixture(scope="session")
def le_checkpoint(tmp_path_factory, le_file):
    """Untrained default model (contact encoder, exact frame) on ``le_file``."""
    return make_checkpoint(le_file, tmp_path_factory.mktemp("le_run"), ["scene=lebc"])


@pytest.fixture(scope="session")
def pbc_checkpoint(tmp_path_factory, pbc_file):
    return make_checkpoint(pbc_file, tmp_path_factory.mktemp("pbc_run"), ["scene=pbc"])
