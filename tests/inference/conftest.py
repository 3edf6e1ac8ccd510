"""Fixtures for the DEM-engine workflow (predict, rollout, hand-back): small real datasets and
real Lightning checkpoints of untrained models.

An untrained model is exactly the constant-velocity (CV) predictor (every learned output starts
at zero, SPEC §11), which makes rollouts checkable to round-off: a chained rollout of it must
equal the one-shot CV rollout. The checkpoints are written by a Lightning ``Trainer`` after a
zero-step ``fit`` of the model :mod:`gripdem.runner.experiment` builds from the smoke preset.
"""

from __future__ import annotations

from pathlib import Path

import lightning as L
import pytest
from hydra import compose, initialize_config_dir

from gripdem.run import CONFIG_DIR
from gripdem.runner.experiment import build_datamodule, build_model


def make_checkpoint(data_path: Path, out: Path, overrides: list[str]) -> Path:
    """``out/checkpoints/best.ckpt`` of the untrained smoke model on ``data_path``."""
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose(
            "config",
            overrides=["experiment=smoke", f"data.path={data_path}", *overrides],
        )
    dm = build_datamodule(cfg, Path(data_path))
    model = build_model(cfg, dm)
    trainer = L.Trainer(
        max_steps=0,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        num_sanity_val_steps=0,
    )
    trainer.fit(model, dm)
    path = out / "checkpoints" / "best.ckpt"
    path.parent.mkdir(parents=True, exist_ok=True)
    trainer.save_checkpoint(path)
    return path


@pytest.fixture(scope="session", name="make_checkpoint")
def make_checkpoint_fixture():
    """``make_checkpoint(data_path, out_dir, overrides) -> checkpoint path``."""
    return make_checkpoint


@pytest.fixture(scope="session")
def le_checkpoint(tmp_path_factory, le_file):
    """Untrained default model (interaction encoder, exact frame) on ``le_file``."""
    return make_checkpoint(le_file, tmp_path_factory.mktemp("le_run"), ["scene=lebc"])


@pytest.fixture(scope="session")
def pbc_checkpoint(tmp_path_factory, pbc_file):
    return make_checkpoint(pbc_file, tmp_path_factory.mktemp("pbc_run"), ["scene=pbc"])
