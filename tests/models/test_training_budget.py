"""The training budget in optimiser steps or in wall time: training stops when it runs out and
the cosine learning rate reaches zero with it, whichever budget is used."""

from __future__ import annotations

import time

import lightning as L
import pytest
from checkpoints import quiet_trainer
from stress_models import smoke_model


def trainer(**budget) -> L.Trainer:
    return quiet_trainer(limit_val_batches=0, **budget)


def test_step_budget_ends_the_schedule(tiny_pbc_path):
    model, dm = smoke_model(tiny_pbc_path, "model.lr_schedule=cosine")
    model.train()
    t = trainer(max_steps=12, max_epochs=None)
    t.fit(model, dm)
    assert t.global_step == 12
    lr = t.optimizers[0].param_groups[0]["lr"]
    assert lr < 0.01 * model.hparams.lr


@pytest.mark.parametrize("seconds", [3])
def test_time_budget_stops_training_and_decays_the_learning_rate(tiny_pbc_path, seconds):
    model, dm = smoke_model(tiny_pbc_path, "model.lr_schedule=cosine")
    model.train()
    t = trainer(max_time={"seconds": seconds}, max_epochs=-1)
    start = time.perf_counter()
    t.fit(model, dm)
    assert time.perf_counter() - start < seconds + 10
    assert t.global_step >= 2
    lr = t.optimizers[0].param_groups[0]["lr"]
    assert lr < 0.1 * model.hparams.lr
