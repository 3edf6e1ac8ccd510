"""Training of a trajectory model: the loss of its decoder mode (relative to constant velocity's
in the exact frame), the training step with its non-finite checks, and the optimiser with its
learning-rate schedule. The cosine schedule follows the training budget, in optimiser steps
(``trainer.max_steps`` or epochs) or in wall time (``trainer.max_time``), whichever runs out
first, so a budget in minutes decays the learning rate to zero when the time is up.

:class:`TrainingSteps` is a mixin of :class:`gripdem.models.module.TrajectoryModule`: it reads
the module's ``boundary``, ``exact``, ``change_std`` and its ``forward``.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import torch
from lightning.pytorch.callbacks import Timer

from gripdem.models import decoder_modes as modes
from gripdem.models.contact_loss import contact_term
from gripdem.models.history_noise import noisy_history

#: ``model.rollout.loss`` (gripdem.inference.rollout_training): which links' losses count
ROLLOUT_LOSSES = ("last", "all")
#: ``model.rollout.target``: what a later link is asked to reach
ROLLOUT_TARGETS = ("steps", "truth")


def check_rollout_training(
    links: int, rollout_loss: str, rollout_target: str, start: float, loss: str, exact: bool
) -> None:
    """Refuse rollout-training options that cannot work, naming the option."""
    if not 0.0 <= float(start) < 1.0:
        raise ValueError(
            f"model.rollout.start is the fraction of the training budget trained on one link "
            f"before the links are chained, in [0, 1), got {start!r}"
        )
    if isinstance(links, bool) or not isinstance(links, int) or links < 1:
        raise ValueError(f"model.rollout.links must be a whole number >= 1, got {links!r}")
    if rollout_loss not in ROLLOUT_LOSSES:
        raise ValueError(
            f"model.rollout.loss must be one of {ROLLOUT_LOSSES}, got {rollout_loss!r}"
        )
    if rollout_target not in ROLLOUT_TARGETS:
        raise ValueError(
            f"model.rollout.target must be one of {ROLLOUT_TARGETS}, got {rollout_target!r}"
        )
    if links > 1 and (loss != "mse" or not exact):
        raise ValueError(
            f"model.rollout.links={links} trains point forecasts in the exact frame "
            f"(model.loss=mse, model.encoding=unwrapped), got model.loss={loss}"
            + ("" if exact else " in the paper's wrapped frame")
            + ": use model.rollout.links=1"
        )


def first_link(batch, link: int):
    """``batch`` cut to its first ``link`` target frames (windows of one link, as without
    rollout training)."""
    frames = batch.history_len + 1 + link
    return replace(
        batch,
        target_deltas=None if batch.target_deltas is None else batch.target_deltas[:, :, :link],
        target_positions=batch.target_positions[:, :, :link],
        times=batch.times[:, :frames],
        offsets=batch.offsets[:, :frames],
    )


class TrainingSteps:
    """Loss, training step, gradient checks and optimiser (see the module doc)."""

    def true_deviation(self, batch, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        """Exact frame: the true per-step deviation from CV in units of the velocity change
        ``(B, N, f, 3)`` (computed in float64, returned as ``dtype``)."""
        steps = modes.target_steps(batch, self.boundary)
        v0 = modes.last_step(batch, self.boundary)[:, :, None]
        return ((steps - v0) / self.change_std).to(dtype)

    def _loss(self, pred: torch.Tensor, batch) -> torch.Tensor:
        """The training loss of predictions ``(B, N, f, C)``, or, with ``model.loss=crps``, of
        ensemble members ``(M, B, N, f, C)``."""
        mode = self.hparams.decoder_mode
        if self.hparams.loss == "crps":
            members = pred if pred.ndim == 5 else pred[None]
            per_step = self.hparams.get("loss_weighting", "horizon") == "step"
            weight = float(self.hparams.get("pair_crps", 0.0))
            pairs = self.contact_graph(batch).edge_index if weight > 0 else None
            return modes.exact_crps_loss(
                mode, members, self.true_deviation(batch), per_step, pairs, weight
            )
        if pred.ndim == 5:  # an ensemble scored on squared error: its mean
            pred = pred.mean(dim=0)
        if self.exact:
            true = self.true_deviation(batch)
            loss = modes.exact_loss(mode, pred, true)
            weight = float(self.hparams.get("contact_loss", 0.0))
            if weight > 0:
                positions = self.decode(pred, batch)
                unit = self.change_std.mean()
                cv = modes.exact_cv_loss(mode, true)
                pairs, offsets = batch.edge_index, batch.target_offsets
                loss = loss + weight * contact_term(
                    positions, pairs, offsets, self.boundary, self.diameter, unit, cv
                )
            return loss
        pred, true = modes.loss_terms(mode, self.hparams.vct_shift, pred, batch.target_deltas)
        return torch.mean((pred - true) ** 2)

    # ----------------------------------------------------------------------------------------
    # steps
    # ----------------------------------------------------------------------------------------
    def on_train_start(self) -> None:
        self._fit_started = time.perf_counter()

    def chain(self, batch):
        """The link chain that rollout training and chained validation run ``batch``'s windows
        of several links through (:mod:`gripdem.inference.rollout_training`)."""
        if self.link_chain is None:
            raise RuntimeError(
                f"windows of {batch.horizon} frames are {batch.horizon // self.hparams.horizon} "
                f"links of model.horizon={self.hparams.horizon}: rollout training needs the link "
                "chain (gripdem.inference.rollout_training.attach(model); the runner attaches it)"
            )
        return self.link_chain

    def rollout_started(self) -> bool:
        """Whether the training budget has reached ``model.rollout.start`` (the fraction trained
        on the first link of each window only); True outside a trainer with a step budget."""
        start = float(self.hparams.get("rollout_start", 0.0))
        trainer = self._trainer
        if start <= 0 or trainer is None:
            return True
        total = trainer.estimated_stepping_batches
        if not math.isfinite(total) or total <= 0:
            return True
        return self.global_step >= start * total

    def training_step(self, batch, batch_idx: int) -> torch.Tensor:
        sigma = float(self.hparams.history_noise)
        if sigma > 0:
            batch = noisy_history(batch, sigma, self.diameter, self.boundary, self.normalizer)
        if batch.horizon > self.hparams.horizon and self.rollout_started():
            loss = self.chain(batch).loss(self, batch)  # rollout training: the links chained
        elif batch.horizon > self.hparams.horizon:  # before model.rollout.start: link 1 only
            first = first_link(batch, int(self.hparams.horizon))
            loss = self._loss(self(first), first)
        elif self.hparams.loss == "crps":
            loss = self._loss(self.forward_members(batch, self.hparams.members), batch)
        else:
            loss = self._loss(self(batch), batch)
        if not torch.isfinite(loss):
            raise FloatingPointError(
                f"non-finite training loss ({loss.item()}) at global step {self.global_step} "
                f"(epoch {self.current_epoch}, batch {batch_idx}); the last good checkpoint is "
                "kept in the run's checkpoints/ folder; lower model.lr or enable gradient "
                "clipping (trainer.gradient_clip_val)"
            )
        self.log("train/loss", loss, prog_bar=True, batch_size=batch.inputs.shape[0])
        return loss

    def on_before_optimizer_step(self, optimizer) -> None:
        """Stop at the step whose gradients are non-finite (an overflow with a finite loss),
        before the optimiser writes NaN into the weights: clipping cannot repair an infinite
        norm, and the loss would only turn NaN one step later."""
        grads = [(name, p.grad) for name, p in self.named_parameters() if p.grad is not None]
        if not grads or bool(torch.stack([torch.isfinite(g).all() for _, g in grads]).all()):
            return  # one host sync per step; the parameter is named only on failure
        for name, grad in grads:
            if not torch.isfinite(grad).all():
                raise FloatingPointError(
                    f"non-finite gradient of {name} at global step {self.global_step} (epoch "
                    f"{self.current_epoch}); the weights were not updated and the last good "
                    "checkpoint is kept in the run's checkpoints/ folder; lower model.lr or "
                    "check this batch's data"
                )

    def configure_optimizers(self):
        params = self.parameters()
        if self.hparams.weight_decay > 0:
            opt = torch.optim.AdamW(
                params, lr=self.hparams.lr, weight_decay=self.hparams.weight_decay
            )
        else:
            opt = torch.optim.Adam(params, lr=self.hparams.lr)
        if self.hparams.lr_schedule == "constant":
            return opt
        total = self.trainer.estimated_stepping_batches
        total = max(1, int(total)) if math.isfinite(total) else None
        timer = next((c for c in self.trainer.callbacks if isinstance(c, Timer)), None)
        warm = float(self.hparams.warmup_fraction)

        def progress(step: int) -> float:
            """Fraction of the budget used: optimiser steps or wall time (``trainer.max_time``),
            whichever runs out first."""
            done = 0.0 if total is None else (step + 1) / total
            if timer is not None:
                elapsed = timer.time_elapsed("train")
                budget = elapsed + (timer.time_remaining("train") or 0.0)
                done = max(done, elapsed / budget if budget > 0 else 1.0)
            return min(1.0, done)

        def factor(step: int) -> float:
            p = progress(step)
            if p < warm:
                return max(p / warm, 1e-3)
            return 0.5 * (1.0 + math.cos(math.pi * (p - warm) / max(1e-12, 1.0 - warm)))

        scheduler = torch.optim.lr_scheduler.LambdaLR(opt, factor)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}
