"""The training progress bar of ``python -m gripdem.run``: the optimiser steps of the budget and
the validation score in units a reader can judge at a glance.

Lightning's own bar counts the batches of each epoch under ``Epoch 4/-2`` (a step budget,
``trainer.max_steps``, has no epoch count) and shows ``val/rmse: 0.000`` (metres, ~1e-8).
:class:`StepBudgetBar` is one bar over the whole budget::

    step 800/2400  33%|███▎   | [00:40<01:20, 20.0step/s, train/loss=0.512, val rmse=0.00481 d,
    ÷CV=0.637]

- ``step n/total``: optimiser steps done (``trainer.global_step``: a resumed run starts where
  it stopped) of the budget (``trainer.estimated_stepping_batches``: ``max_steps``, or the
  epochs' steps); a budget in wall time only (``max_time``) shows ``step n``;
- ``val rmse``: the last validation rollout's RMSE in particle diameters
  (``val/rmse_over_d``);
- ``÷CV``: that RMSE over the constant-velocity baseline's on the same windows
  (``val/rmse_ratio_constant_velocity``; below 1 beats it).

The module puts those two on the bar (``self.log(..., prog_bar=True)``); their names in
TensorBoard are unchanged. Validation's own bar is Lightning's.
"""

from __future__ import annotations

import math
import sys
from typing import Any

from lightning.pytorch.callbacks import TQDMProgressBar
from lightning.pytorch.callbacks.progress.tqdm_progress import Tqdm

#: logged validation metric -> (label on the bar, format of its value)
SHOWN = {
    "val/rmse_over_d": ("val rmse", "{:.3g} d"),
    "val/rmse_ratio_constant_velocity": ("÷CV", "{:.3f}"),
}
#: the training bar: the description carries ``step n/total`` (tqdm's own count is dropped)
BUDGET_FORMAT = (
    "{desc} {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}, {rate_noinv_fmt}{postfix}]"
)
#: without a step budget (wall time only): no percentage, no bar
OPEN_FORMAT = "{desc} [{elapsed}, {rate_noinv_fmt}{postfix}]"


def step_budget(trainer) -> int | None:
    """The optimiser steps the fit may take, or None when only wall time bounds it."""
    total = trainer.estimated_stepping_batches
    return int(total) if total is not None and math.isfinite(total) and total > 0 else None


class StepBudgetBar(TQDMProgressBar):
    """One training bar over the optimiser-step budget, with the validation RMSE in particle
    diameters and over constant velocity's (see the module doc)."""

    def __init__(self, refresh_rate: int = 1, process_position: int = 0):
        super().__init__(refresh_rate=refresh_rate, process_position=process_position, leave=False)
        self.budget: int | None = None

    def description(self, trainer) -> str:
        step = int(trainer.global_step)
        return f"step {step}" if self.budget is None else f"step {step}/{self.budget}"

    def get_metrics(self, trainer, pl_module) -> dict[str, Any]:
        """Lightning's bar metrics without the logger's version number, the validation scores
        as :data:`SHOWN` labels and formats them."""
        items = super().get_metrics(trainer, pl_module)
        items.pop("v_num", None)
        for key, (label, form) in SHOWN.items():
            if key in items:
                items[label] = form.format(float(items.pop(key)))
        return items

    def init_train_tqdm(self) -> Tqdm:
        """The training bar, counting optimiser steps from where the fit starts (a resumed
        fit: its rate counts this session's steps only)."""
        self.budget = step_budget(self.trainer)
        return Tqdm(
            desc=self.description(self.trainer),
            total=self.budget,
            initial=int(self.trainer.global_step),
            unit="step",
            position=2 * self.process_position,
            disable=self.is_disabled,
            leave=True,
            dynamic_ncols=True,
            file=sys.stdout,
            smoothing=0,
            bar_format=OPEN_FORMAT if self.budget is None else BUDGET_FORMAT,
        )

    def on_train_epoch_start(self, trainer, *_: Any) -> None:
        """Nothing: the bar spans the budget, not an epoch."""

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx: int) -> None:
        bar, step = self.train_progress_bar, int(trainer.global_step)
        if bar.disable or (step % self.refresh_rate and step != bar.total):
            return
        bar.set_description_str(self.description(trainer), refresh=False)
        bar.set_postfix(self.get_metrics(trainer, pl_module), refresh=False)
        bar.n = step
        bar.refresh()

    def on_train_epoch_end(self, trainer, pl_module) -> None:
        if not self.train_progress_bar.disable:
            self.train_progress_bar.set_postfix(self.get_metrics(trainer, pl_module))
