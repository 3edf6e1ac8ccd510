"""Fixtures of the Python API's tests: a real Lightning checkpoint of an untrained model."""

from __future__ import annotations

import pytest
from checkpoints import untrained_checkpoint


@pytest.fixture(scope="session")
def pbc_checkpoint(tmp_path_factory, pbc_file):
    """The untrained smoke model of ``pbc_file`` (a run's ``checkpoints/best.ckpt``)."""
    out = tmp_path_factory.mktemp("api_pbc_run") / "checkpoints" / "best.ckpt"
    return untrained_checkpoint(pbc_file, out, ["scene=pbc"])


@pytest.fixture(scope="session")
def le_ensemble_checkpoint(tmp_path_factory, le_file):
    """The untrained ensemble model (``model=ensemble``) of ``le_file``."""
    out = tmp_path_factory.mktemp("api_le_ensemble_run") / "checkpoints" / "best.ckpt"
    return untrained_checkpoint(le_file, out, ["scene=lebc", "model=ensemble"])
