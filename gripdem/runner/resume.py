"""Exact resumption of a killed training run: ``checkpoints/last.ckpt`` and what it holds.

:class:`ResumeCheckpoint` writes ``last.ckpt`` (through the Trainer's checkpoint IO, which the
runner makes atomic, :mod:`gripdem.runner.atomic_files`: a kill at any moment leaves the
previous complete file) every ``every_n_train_steps`` optimiser steps
(``callbacks.checkpoint.every_n_train_steps``), after every validation and at the end of
training; never on an exception (a state from the middle of a step would not resume exactly).
The best checkpoint stays the ``ModelCheckpoint``'s, chosen on ``val/rmse`` at validations only;
the runner has it save at the validation's end, and this callback comes after it there, so
``last.ckpt`` holds its updated state.

A run resumed from ``last.ckpt`` (``resume=true``) continues step for step as the uninterrupted
run would have (the same weights bit for bit on the same machine and thread count, the same
best checkpoint, the same test metrics), because the checkpoint holds, besides the weights,
optimiser, LR schedule and loop counters that Lightning saves:

- the position in the epoch: the training loader's state (:mod:`gripdem.data.resumable`: the
  epoch's order comes from ``(seed, epoch)``, the batches already trained on are skipped);
- the random generators (torch CPU and, when initialised, CUDA; numpy's and Python's global
  ones) at the save, given back just before the next training batch (dropout, input and
  history noise draw from them);
- the fit's bookkeeping: training seconds so far and the module's ``accuracy_curve``.

Where Lightning's own restart falls short, this module steps in: a step save that falls on a
batch after which a validation runs is made after that validation (a checkpoint between the
batch and its validation resumes past the validation: Lightning fast-forwards over it); no save
at the end of an epoch (resumed from there, Lightning sets the sampler's epoch one ahead); none
once a step budget is spent but the one at the end of training (resumed from before the loop's
end, Lightning never counts the last epoch); and the loader's state is given to it when an
epoch budget made Lightning build the loader before restoring the loop
(:func:`_load_loader_states`).

Everything is plain tensors, numbers, lists and dicts: ``torch.load(weights_only=True)`` reads it.
"""

from __future__ import annotations

import os
import random
import time
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import Checkpoint

__all__ = ["ResumeCheckpoint", "get_rng_state", "resumed_seconds", "set_rng_state"]


def get_rng_state() -> dict[str, Any]:
    """The global random generators' states as tensors and numbers (weights_only-safe)."""
    kind, keys, pos, has_gauss, cached = np.random.get_state()  # noqa: NPY002 (the global one)
    version, internal, gauss_next = random.getstate()
    state: dict[str, Any] = {
        "torch": torch.get_rng_state(),
        "numpy": {
            "kind": str(kind),
            "keys": torch.from_numpy(keys.astype(np.int64)),
            "pos": int(pos),
            "has_gauss": int(has_gauss),
            "cached_gaussian": float(cached),
        },
        "python": {
            "version": int(version),
            "internal": torch.tensor(internal, dtype=torch.int64),
            "gauss_next": gauss_next,
        },
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict[str, Any]) -> None:
    """Restore what :func:`get_rng_state` returned."""
    torch.set_rng_state(state["torch"])
    if "numpy" in state:
        n = state["numpy"]
        keys = n["keys"].numpy().astype(np.uint32)
        legacy = (n["kind"], keys, n["pos"], n["has_gauss"], n["cached_gaussian"])
        np.random.set_state(legacy)  # noqa: NPY002 (the global generator is what is restored)
    if "python" in state:
        p = state["python"]
        random.setstate((p["version"], tuple(int(v) for v in p["internal"]), p["gauss_next"]))
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def resumed_seconds(trainer: L.Trainer) -> float:
    """Training seconds of the runs before this one (0 for a fresh run): what the checkpoint
    it resumed from had recorded."""
    found = [c for c in trainer.callbacks if isinstance(c, ResumeCheckpoint)]
    return found[0].seconds_before if found else 0.0


def _last_step(trainer: L.Trainer) -> bool:
    """The step budget is spent: the save at the end of training follows (a checkpoint from
    before the loop's end would resume into a skipped loop that never counts its last epoch)."""
    return 0 <= trainer.max_steps <= trainer.global_step


def _load_loader_states(trainer: L.Trainer) -> None:
    """Give the training loader its saved position when Lightning has not: a budget in epochs
    makes ``configure_optimizers`` ask for ``estimated_stepping_batches``, which builds and
    iterates the loader before the checkpoint's loop state is restored, and Lightning then
    keeps that loader without its state (the epoch would restart at its first batch)."""
    loop = trainer.fit_loop
    states = getattr(loop, "_combined_loader_states_to_load", None)
    if not states or loop._combined_loader is None or not loop.restarting:
        return
    loop._load_combined_loader_states()
    iter(loop._data_fetcher)  # workers draw their first indices at iter(): draw them again


class ResumeCheckpoint(Checkpoint):
    """Writes ``<dirpath>/last.ckpt`` for an exact resume (see the module doc).
    ``every_n_train_steps`` <= 0 or None: after validations and at the end only."""

    FILENAME = "last.ckpt"

    def __init__(self, dirpath: str | os.PathLike, every_n_train_steps: int | None = 100):
        self.dirpath = Path(dirpath)
        self.every = int(every_n_train_steps or 0)
        self.seconds_before = 0.0  # training seconds recorded by the checkpoint resumed from
        self._started: float | None = None
        self._module: L.LightningModule | None = None
        self._restored: dict[str, Any] | None = None  # loaded, not yet given back
        self._deferred = False  # a step save moved to after the validation that follows

    @property
    def path(self) -> Path:
        return self.dirpath / self.FILENAME

    # ---- state ---------------------------------------------------------------------------
    def seconds(self) -> float:
        """Training seconds so far, the resumed-from runs' included."""
        now = 0.0 if self._started is None else time.perf_counter() - self._started
        return self.seconds_before + now

    def state_dict(self) -> dict[str, Any]:
        curve = getattr(self._module, "accuracy_curve", None) or []
        return {
            "rng": get_rng_state(),
            "train_seconds": float(self.seconds()),
            "accuracy_curve": [[float(s), int(step), float(r)] for s, step, r in curve],
        }

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self._restored = dict(state_dict)
        self.seconds_before = float(state_dict.get("train_seconds", 0.0))

    # ---- hooks ---------------------------------------------------------------------------
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        self._module = pl_module

    def on_fit_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self._restored is not None and hasattr(pl_module, "accuracy_curve"):
            curve = self._restored.get("accuracy_curve", [])
            pl_module.accuracy_curve = [(float(s), int(k), float(r)) for s, k, r in curve]

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._started = time.perf_counter()
        _load_loader_states(trainer)

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        self._give_back(pl_module)

    def _give_back(self, pl_module: L.LightningModule) -> None:
        """The restored random state (just before the first batch after the resume) and the
        clock of the module's accuracy curve."""
        if self._restored is None:
            return
        if "rng" in self._restored:
            set_rng_state(self._restored["rng"])
        if getattr(pl_module, "_fit_started", None) is not None:
            pl_module._fit_started -= self.seconds_before
        self._restored = None

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        due = self.every > 0 and trainer.global_step % self.every == 0
        if not (due or self._deferred) or _last_step(trainer):
            return
        loop = trainer.fit_loop
        if loop.epoch_loop._should_check_val_fx(loop._data_fetcher):
            self._deferred = True  # saved after the validation of this step
            return
        self._save(trainer)

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not (trainer.sanity_checking or _last_step(trainer)):
            self._save(trainer)

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._save(trainer)

    def _save(self, trainer: L.Trainer) -> None:
        self._deferred = False
        if trainer.state.fn != "fit" or trainer.sanity_checking or trainer.fast_dev_run:
            return
        # the full state (optimiser, loops, callbacks) for an exact resume; it holds tensors and
        # plain containers only, read back with weights_only=True. Saying so here also keeps
        # Lightning from logging "`weights_only` was not set" at every save.
        # The runner's CheckpointIO renames the file into place.
        trainer.save_checkpoint(self.path, weights_only=False)
