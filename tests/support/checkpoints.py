"""Real Lightning checkpoints of untrained models, as ``gripdem.run`` builds them (the model of
the smoke preset on a given dataset, written by a Lightning ``Trainer`` after a zero-step fit):
for tests outside tests/inference (whose conftest has the same as fixtures)."""

from __future__ import annotations

from pathlib import Path

import lightning as L
from hydra import compose, initialize_config_dir

from gripdem.run import CONFIG_DIR
from gripdem.runner.experiment import build_datamodule, build_model


def quiet_trainer(**options) -> L.Trainer:
    """A Lightning ``Trainer`` for tests: no logger, checkpoints, progress bar, model summary or
    sanity validation; ``options`` (budget, callbacks, clipping, ...) on top."""
    return L.Trainer(
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        num_sanity_val_steps=0,
        **options,
    )


def untrained_checkpoint(data_path: Path, path: Path, overrides: list[str]) -> Path:
    """``path``: the untrained smoke model on ``data_path`` as a Lightning checkpoint."""
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose(
            "config", overrides=["experiment=smoke", f"data.path={data_path}", *overrides]
        )
    datamodule = build_datamodule(cfg, Path(data_path))
    trainer = quiet_trainer(max_steps=0)
    trainer.fit(build_model(cfg, datamodule), datamodule)
    path.parent.mkdir(parents=True, exist_ok=True)
    trainer.save_checkpoint(path)
    return path
