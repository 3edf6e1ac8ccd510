"""Where a study lives, how it is opened and resumed, and how the trials of dead processes are
found and run again.

Storage (``hydra.sweeper.storage``):

- ``null``: the journal file ``study.journal`` in the study's folder (``hparams_search=optuna``
  puts the folder at ``multirun/studies/<study_name>``, so the same command finds it again);
- a path: an Optuna journal file there (on a cluster, a path on a shared file system);
- a URL (``sqlite:///study.db``, ``postgresql://user@host/db``): Optuna's RDB storage;
  ``redis://host:port``: Optuna's journal on Redis.

The journal file was chosen over SQLite by measurement: SIGKILLed mid-write, neither lost a
finished trial, and only the journal is safe on a network file system
(``experiments/results/studies/storage_kill.md``).

A study records what defines it when it is created (user attributes ``gripdem:space``,
``gripdem:direction``, ``gripdem:metric``, ``gripdem:pruner``); opening it again with another
definition is refused, naming the option and what differs, so a study is never mixed with
another space.

Heartbeat: every running trial carries the wall-clock time of its last beat (system attribute
``gripdem:heartbeat``), written by the process that launched it and by the trial's own run. A
trial whose beat is older than the grace period is marked failed and queued again with the same
parameters (the new trial's user attribute ``gripdem:retry_of`` names the old one). Counting
the study's trials (:func:`count_trials`) leaves out a failed trial that was queued again, so no
trial is counted twice.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import optuna
from optuna.exceptions import UpdateFinishedTrialError
from optuna.storages import BaseStorage
from optuna.trial import FrozenTrial, TrialState

#: the default storage's file name, in the study's folder
DEFAULT_FILE = "study.journal"
#: seconds a process waits for the journal's lock before it takes it over: a lock is held for
#: milliseconds, and one left by a killed process would otherwise stall the study for Optuna's
#: default 30 s (experiments/results/studies/storage_kill.md)
JOURNAL_LOCK_GRACE_SECONDS = 5
#: what defines a study, stored when it is created (user attributes)
SPACE_ATTR = "gripdem:space"
METRIC_ATTR = "gripdem:metric"
PRUNER_ATTR = "gripdem:pruner"
DIRECTION_ATTR = "gripdem:direction"
#: a running trial's last beat (seconds since the epoch; system attribute)
HEARTBEAT_ATTR = "gripdem:heartbeat"
#: a re-queued trial: the number of the trial it runs again (user attribute)
RETRY_OF_ATTR = "gripdem:retry_of"
#: why a trial failed, in one line (user attribute)
ERROR_ATTR = "gripdem:error"
#: the step at which a pruned trial stopped (user attribute)
PRUNED_AT_ATTR = "gripdem:pruned_at_step"


def storage_url(storage: str | None, study_dir: Path) -> str:
    """The storage a study uses: ``storage`` as given (a URL, or a path made absolute), or the
    default journal file in ``study_dir``."""
    if storage is None or str(storage) == "":
        return str(Path(study_dir).resolve() / DEFAULT_FILE)
    storage = str(storage)
    if "://" in storage:
        return storage
    return str(Path(storage).expanduser().resolve())


def open_storage(url: str) -> BaseStorage:
    """An Optuna storage for :func:`storage_url`'s answer; a storage that cannot be opened is
    one ``ValueError`` naming ``hydra.sweeper.storage`` and why."""
    try:
        if url.startswith("redis://") or url.startswith("rediss://"):
            from optuna.storages.journal import JournalRedisBackend

            return optuna.storages.JournalStorage(JournalRedisBackend(url))
        if "://" in url:
            return optuna.storages.RDBStorage(url)
        path = Path(url)
        if path.is_dir():
            raise ValueError("it is a folder: give a file (a journal) or a URL")
        if not path.parent.is_dir():
            raise ValueError(f"its folder {path.parent} does not exist")
        if path.exists() and path.read_bytes()[:16] == b"SQLite format 3\x00":
            raise ValueError(f"it is an SQLite file: give sqlite:///{path}")
        from optuna.storages.journal import JournalFileBackend, JournalFileSymlinkLock

        lock = JournalFileSymlinkLock(str(path), grace_period=JOURNAL_LOCK_GRACE_SECONDS)
        return optuna.storages.JournalStorage(JournalFileBackend(str(path), lock_obj=lock))
    except ValueError as exc:
        raise ValueError(f"hydra.sweeper.storage={url!r} cannot be opened: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - a driver's or a file's error: one line of ours
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ValueError(f"hydra.sweeper.storage={url!r} cannot be opened: {first}") from None


@dataclass(frozen=True)
class StudyDefinition:
    """What a study is: its search space (:func:`gripdem.study.space.space_record`), the metric
    and its direction, and the pruner (a JSON record or ``"null"``)."""

    space: str
    metric: str
    direction: str
    pruner: str

    def attrs(self) -> dict[str, str]:
        return {
            SPACE_ATTR: self.space,
            METRIC_ATTR: self.metric,
            DIRECTION_ATTR: self.direction,
            PRUNER_ATTR: self.pruner,
        }


def _mismatch(name: str, stored: dict[str, Any], given: StudyDefinition) -> str | None:
    from gripdem.study.space import describe_difference

    if stored.get(SPACE_ATTR) != given.space:
        diff = describe_difference(stored[SPACE_ATTR], given.space)
        return f"hydra.sweeper.params: study {name!r} was made with another search space ({diff})"
    if stored.get(DIRECTION_ATTR) != given.direction:
        return (
            f"hydra.sweeper.direction={given.direction}: study {name!r} was made to "
            f"{stored.get(DIRECTION_ATTR)} its metric"
        )
    if stored.get(METRIC_ATTR) != given.metric:
        return (
            f"optimized_metric={given.metric}: study {name!r} was made for "
            f"{stored.get(METRIC_ATTR)}"
        )
    if stored.get(PRUNER_ATTR) != given.pruner:
        return (
            f"hydra.sweeper.pruner: study {name!r} was made with pruner "
            f"{stored.get(PRUNER_ATTR)}, given {given.pruner}"
        )
    return None


def open_study(
    storage: BaseStorage, name: str, definition: StudyDefinition, sampler=None, pruner=None
) -> tuple[optuna.Study, bool]:
    """``(study, resumed)``: the study ``name`` in ``storage``, created with ``definition``, or
    the existing one when its definition is the same. Another definition is one
    ``ValueError`` saying what differs (the stored study untouched: pick another
    ``hydra.sweeper.study_name`` for another space)."""
    existing = {s.study_name for s in optuna.study.get_all_study_summaries(storage)}
    resumed = name in existing
    if resumed:
        study = optuna.load_study(study_name=name, storage=storage, sampler=sampler, pruner=pruner)
        stored = study.user_attrs
        if SPACE_ATTR not in stored:
            raise ValueError(
                f"hydra.sweeper.study_name={name}: a study of that name exists in the storage "
                "but was not made by gripdem (no stored search space): choose another name"
            )
        problem = _mismatch(name, stored, definition)
        if problem:
            raise ValueError(f"{problem}; choose another hydra.sweeper.study_name")
        return study, True
    study = optuna.create_study(
        storage=storage,
        study_name=name,
        direction=definition.direction,
        sampler=sampler,
        pruner=pruner,
        load_if_exists=True,  # another worker may create it between the check and here
    )
    stored = study.user_attrs
    if SPACE_ATTR in stored:  # that other worker was first: its definition must be ours
        problem = _mismatch(name, stored, definition)
        if problem:
            raise ValueError(f"{problem}; choose another hydra.sweeper.study_name")
        return study, True
    for key, value in definition.attrs().items():
        study.set_user_attr(key, value)
    return study, False


def beat(storage: BaseStorage, trial_id: int) -> bool:
    """Record that the trial's process is alive now; False once the trial has finished."""
    try:
        storage.set_trial_system_attr(trial_id, HEARTBEAT_ATTR, time.time())
    except UpdateFinishedTrialError:
        return False
    return True


def last_beat(trial: FrozenTrial) -> float:
    """Seconds since the epoch of the trial's last beat (its start when it never beat)."""
    value = trial.system_attrs.get(HEARTBEAT_ATTR)
    if isinstance(value, (int, float)):
        return float(value)
    start = trial.datetime_start
    return start.timestamp() if start is not None else time.time()


def fail_and_requeue(study: optuna.Study, trial: FrozenTrial, reason: str) -> bool:
    """Mark a running trial failed (``reason`` recorded) and queue its parameters again; False
    when another process finished or failed it first (then nothing is queued here)."""
    storage = study._storage
    try:
        storage.set_trial_user_attr(trial._trial_id, ERROR_ATTR, reason)
        changed = storage.set_trial_state_values(trial._trial_id, TrialState.FAIL)
    except UpdateFinishedTrialError:
        return False
    if not changed:
        return False
    study.enqueue_trial(
        dict(trial.params), user_attrs={RETRY_OF_ATTR: trial.number}, skip_if_exists=False
    )
    return True


def requeue_stale(study: optuna.Study, grace_seconds: float) -> list[int]:
    """Fail and re-queue the running trials whose last beat is older than ``grace_seconds``
    (their process died: killed, or its machine lost); returns their numbers."""
    now = time.time()
    stale = []
    for trial in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        silent = now - last_beat(trial)
        if silent > grace_seconds:
            reason = f"no heartbeat for {silent:.0f} s (its process was killed or lost): re-queued"
            if fail_and_requeue(study, trial, reason):
                stale.append(trial.number)
    return stale


@dataclass(frozen=True)
class TrialCounts:
    """A study's trials by state. ``counted``: the trials that count toward ``n_trials``
    (complete, pruned, and failed ones not queued again)."""

    complete: int
    pruned: int
    failed: int
    retried: int
    running: int
    waiting: int

    @property
    def counted(self) -> int:
        return self.complete + self.pruned + self.failed - self.retried


def count_trials(study: optuna.Study) -> TrialCounts:
    trials = study.get_trials(deepcopy=False)
    by_state: dict[TrialState, int] = {}
    for trial in trials:
        by_state[trial.state] = by_state.get(trial.state, 0) + 1
    failed_numbers = {t.number for t in trials if t.state == TrialState.FAIL}
    retried = {t.user_attrs.get(RETRY_OF_ATTR) for t in trials} & failed_numbers
    return TrialCounts(
        complete=by_state.get(TrialState.COMPLETE, 0),
        pruned=by_state.get(TrialState.PRUNED, 0),
        failed=by_state.get(TrialState.FAIL, 0),
        retried=len(retried),
        running=by_state.get(TrialState.RUNNING, 0),
        waiting=by_state.get(TrialState.WAITING, 0),
    )


def pruner_record(spec: Any) -> str:
    """A pruner's config (``{_target_: optuna.pruners.X, ...}`` or null) as the JSON record a
    study stores; only Optuna's own pruners (a shared storage is data, never code to run)."""
    if spec is None:
        return "null"
    spec = dict(spec)
    target = str(spec.pop("_target_", ""))
    name = target.rsplit(".", 1)[-1]
    if not target.startswith("optuna.pruners.") or not _is_pruner(name):
        raise ValueError(
            f"hydra.sweeper.pruner._target_={target!r}: give one of Optuna's pruners "
            "(optuna.pruners.MedianPruner, optuna.pruners.SuccessiveHalvingPruner, ...) or "
            "hydra.sweeper.pruner=null"
        )
    return json.dumps({"name": name, "kwargs": spec}, sort_keys=True)


def _is_pruner(name: str) -> bool:
    cls = getattr(optuna.pruners, name, None)
    return isinstance(cls, type) and issubclass(cls, optuna.pruners.BasePruner)


def pruner_from_record(record: str | None) -> optuna.pruners.BasePruner:
    """The pruner a study stored (:func:`pruner_record`); Optuna's ``NopPruner`` for none."""
    if record in (None, "null"):
        return optuna.pruners.NopPruner()
    data = json.loads(record)
    if not _is_pruner(str(data.get("name"))):
        raise ValueError(f"the study's stored pruner {data.get('name')!r} is not Optuna's")
    return getattr(optuna.pruners, data["name"])(**data.get("kwargs", {}))
