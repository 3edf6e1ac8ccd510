"""The test step of a model whose horizon is shorter than the split's: chained, as a surrogate.

A model that predicts ``f_model`` frames per forward pass (``model.horizon``, 10 for the default)
is tested on the split's windows of ``f > f_model`` frames (150-50, 100-100) the way a user runs
it beyond its horizon: :class:`gripdem.inference.stepper.Stepper` from each window's observed
frames, in the stable setting (links of the model's horizon, contact correction after every
frame), for the window's ``f`` frames. The predictions are recorded and scored exactly as the
Lightning test step's (:meth:`gripdem.models.evaluation.RolloutEvaluation.record`), beside every
baseline on the same windows (the runner logs them).
"""

from __future__ import annotations

import math
from typing import Any

import torch

from gripdem.inference.rollout_training import chained_positions
from gripdem.inference.stepper import StepperSettings


@torch.no_grad()
def evaluate_chained(model, dm, settings=None) -> dict[str, Any]:
    """Test ``model`` on ``dm``'s test windows through the stepper; returns what the Lightning
    test step leaves in ``model.test_results`` (collected arrays and ``metrics``)."""
    model = model.eval()
    settings = settings or StepperSettings()
    for batch in dm.test_dataloader():
        model.record(batch, chained_positions(model, batch, settings), math.nan, "test")
    results = model.results("test")
    results["chained"] = {"model_horizon": int(model.hparams.horizon), **settings.to_dict()}
    return results
