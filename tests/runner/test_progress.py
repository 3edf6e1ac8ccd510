"""The training progress bar: optimiser steps of the budget, the validation RMSE in particle
diameters and over constant velocity's (a real fit of the smoke model, its bar captured)."""

from __future__ import annotations

import re
from pathlib import Path

import lightning as L
from hydra import compose, initialize_config_dir

from gripdem.run import CONFIG_DIR
from gripdem.runner.experiment import build_datamodule, build_model, build_trainer
from gripdem.runner.progress import StepBudgetBar


def smoke_config(overrides: list[str]):
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        return compose("config", overrides=["experiment=smoke", *overrides])


def test_the_bar_counts_the_step_budget_and_shows_rmse_in_diameters_and_over_cv(
    tmp_path, capsys, le_file
):
    cfg = smoke_config([f"data.path={le_file}", "scene=lebc"])
    dm = build_datamodule(cfg, Path(le_file))
    batches = len(dm.train_dataloader())  # 4 of 2 windows: 2 epochs, a validation after each
    trainer = L.Trainer(
        max_steps=2 * batches,
        max_epochs=-1,
        logger=False,
        enable_checkpointing=False,
        enable_model_summary=False,
        num_sanity_val_steps=0,
        callbacks=[StepBudgetBar()],
    )
    trainer.fit(build_model(cfg, dm), dm)
    text = capsys.readouterr().out
    budget = 2 * batches
    assert f"step {budget}/{budget} 100%|" in text
    assert f"step 1/{budget}" in text and "Epoch" not in text
    rmse = re.findall(r"val rmse=([0-9.e+-]+) d, ÷CV=([0-9.]+)", text)
    assert rmse, text[-500:]
    over_d, ratio = map(float, rmse[-1])
    metrics = trainer.callback_metrics  # TensorBoard's names, unchanged
    assert over_d == float(f"{float(metrics['val/rmse_over_d']):.3g}")
    assert ratio == round(float(metrics["val/rmse_ratio_constant_velocity"]), 3)
    assert 0.5 < ratio < 2.0  # an untrained model is close to constant velocity
    assert {"val/rmse", "val/rmse_constant_velocity"} <= set(metrics)
    assert "val/rmse=" not in text and "v_num" not in text  # no metres, no version number


def test_the_run_uses_the_bar_when_the_trainer_shows_one(tmp_path):
    cfg = smoke_config(["trainer.enable_progress_bar=true", "trainer.max_steps=50"])
    trainer = build_trainer(cfg, tmp_path, logger=False)
    assert isinstance(trainer.progress_bar_callback, StepBudgetBar)
    quiet = build_trainer(smoke_config([]), tmp_path, logger=False)  # smoke: no bar
    assert quiet.progress_bar_callback is None
