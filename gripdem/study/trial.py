"""A study's trial, seen from its run: the heartbeat, the validation reports and the pruner's
verdict, and the trial's end told to the study.

The study sweeper (:mod:`gripdem.study.sweeper`) starts each trial as a run with
``study_trial.storage``, ``study_trial.study`` and ``study_trial.number`` on its command line;
:func:`open_trial` reads them. While the run lives, a thread records its heartbeat every
``study_trial.heartbeat_seconds``; :class:`TrialReporter` reports the validation rollout RMSE
(``val/rmse``) at every validation and stops training when the study's pruner says so. The
run tells the study its end itself (complete with ``optimized_metric``, pruned, or failed
with its error line), so a trial's result survives its controlling process (a cluster's jobs
go on when the login node's process is gone).
"""

from __future__ import annotations

import math
import threading
from typing import Any

import optuna
from lightning.pytorch.callbacks import Callback
from optuna.exceptions import UpdateFinishedTrialError
from optuna.trial import TrialState

from gripdem.study.storage import (
    ERROR_ATTR,
    PRUNED_AT_ATTR,
    PRUNER_ATTR,
    beat,
    open_storage,
    pruner_from_record,
)

#: the validation metric reported to the pruner (the rollout RMSE of the validation windows)
REPORTED_METRIC = "val/rmse"


class TrialLink:
    """The run's handle on its trial: report, prune, tell (one per run)."""

    def __init__(self, storage: str, study: str, number: int, heartbeat_seconds: float):
        backend = open_storage(storage)
        attrs = backend.get_study_user_attrs(backend.get_study_id_from_name(study))
        pruner = pruner_from_record(attrs.get(PRUNER_ATTR))  # the study's own, as stored
        self.study = optuna.load_study(study_name=study, storage=backend, pruner=pruner)
        self.number = int(number)
        trial_id = backend.get_trial_id_from_study_id_trial_number(self.study._study_id, number)
        self.trial = optuna.trial.Trial(self.study, trial_id)
        self.pruned_at: int | None = None
        self._stop = threading.Event()
        self._beats = threading.Thread(
            target=self._beat, args=(float(heartbeat_seconds),), daemon=True, name="heartbeat"
        )
        self._beats.start()

    def _beat(self, seconds: float) -> None:
        while not self._stop.is_set():
            try:
                if not beat(self.study._storage, self.trial._trial_id):
                    return  # finished (told by this run, or failed by another process)
            except Exception:  # noqa: BLE001 - a storage hiccup: the next beat tries again
                pass
            self._stop.wait(seconds)

    def report(self, value: float, step: int) -> bool:
        """Report the validation value at optimiser step ``step``; True when the study's
        pruner stops this trial."""
        self.trial.report(float(value), int(step))
        if self.trial.should_prune():
            self.pruned_at = int(step)
            return True
        return False

    def reporter(self) -> TrialReporter:
        """The Lightning callback that reports this trial's validations."""
        return TrialReporter(self)

    @property
    def pruned(self) -> bool:
        return self.pruned_at is not None

    def _tell(self, state: TrialState, value: float | None = None) -> None:
        self._stop.set()
        try:
            if state == TrialState.PRUNED:
                self.study._storage.set_trial_user_attr(
                    self.trial._trial_id, PRUNED_AT_ATTR, self.pruned_at
                )
            self.study.tell(self.number, value, state=state)
        except UpdateFinishedTrialError:
            pass  # failed meanwhile by another process (no heartbeat): its re-run goes on

    def complete(self, value: float) -> None:
        if math.isnan(value) or math.isinf(value):
            self.fail(
                f"optimized_metric is {value} (a validation never ran? trainer.val_check_interval"
                " must be within the steps the trial trains)"
            )
        else:
            self._tell(TrialState.COMPLETE, float(value))

    def prune(self) -> None:
        self._tell(TrialState.PRUNED)

    def fail(self, reason: str) -> None:
        try:
            self.study._storage.set_trial_user_attr(self.trial._trial_id, ERROR_ATTR, reason)
        except UpdateFinishedTrialError:
            pass
        self._tell(TrialState.FAIL)

    def close(self) -> None:
        """Stop the heartbeat (an interrupted run: the trial stays running until its silence
        makes a study process re-queue it)."""
        self._stop.set()


def open_trial(cfg: Any) -> TrialLink | None:
    """The trial this run is (``study_trial.*`` set by the study sweeper), else None."""
    node = cfg.get("study_trial")
    if node is None or node.get("number") is None:
        return None
    missing = [key for key in ("storage", "study") if not node.get(key)]
    if missing:
        raise ValueError(
            f"study_trial.number={node.number} needs study_trial.{missing[0]} (the study "
            "sweeper sets all three)"
        )
    return TrialLink(str(node.storage), str(node.study), int(node.number), node.heartbeat_seconds)


class TrialReporter(Callback):
    """Reports ``val/rmse`` at every validation to the trial; stops training when pruned."""

    def __init__(self, link: TrialLink):
        self.link = link

    def on_validation_end(self, trainer, pl_module) -> None:
        if trainer.sanity_checking:
            return
        value = trainer.callback_metrics.get(REPORTED_METRIC)
        if value is None:
            raise ValueError(
                f"hydra.sweeper.pruner: the run logged no {REPORTED_METRIC} at validation"
            )
        if self.link.report(float(value), trainer.global_step):
            trainer.should_stop = True
