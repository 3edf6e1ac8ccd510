"""The study sweeper (``hydra/sweeper=study``; ``hparams_search=optuna`` selects it): an
Optuna study that is stored, resumed, pruned, and runs its trials without batches.

``python -m gripdem.run hparams_search=optuna`` opens (or creates) the study
``hydra.sweeper.study_name`` in ``hydra.sweeper.storage`` (:mod:`gripdem.study.storage`), then
keeps ``hydra.sweeper.n_jobs`` trials running until the study holds ``n_trials`` counted
trials: as soon as one ends, the next is asked from the sampler and launched, with no batch
barrier. Each trial is one job of the configured Hydra launcher: gripdem's parallel launcher
(one process per trial, the CPUs shared out, one thread each on 2 cores) or submitit (a SLURM
job per trial; several such sweeps, on any machines, can share one storage). Each trial runs
with ``study_trial.*`` on its command line and reports to the study itself
(:mod:`gripdem.study.trial`).

Running the same command again resumes the study: finished trials are kept, and the trials
that were running when it was stopped are re-queued with their parameters: at once when it was
interrupted (Ctrl-C, SIGTERM), after ``hydra.sweeper.grace_seconds`` without a heartbeat when
its process was killed outright. The sweep folder gets ``study.md`` and ``study.csv``: every
trial ranked (:mod:`gripdem.study.report`).
"""

from __future__ import annotations

import math
import threading
import time
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import optuna
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.types import HydraContext
from omegaconf import DictConfig, OmegaConf

from gripdem.provenance import available_cpus
from gripdem.runner.parallel_launcher import quoted
from gripdem.study.space import parse_space, space_record, trial_overrides
from gripdem.study.storage import (
    ERROR_ATTR,
    PRUNED_AT_ATTR,
    StudyDefinition,
    beat,
    count_trials,
    fail_and_requeue,
    open_storage,
    open_study,
    pruner_record,
    requeue_stale,
    storage_url,
)

#: seconds between looks at the running trials and the study
POLL_SECONDS = 0.5
#: the validation metrics a pruner can follow (reported at every validation)
VALIDATION_METRICS = ("val/rmse_best",)


@dataclass(frozen=True)
class StudyOptions:
    """``hydra.sweeper``'s options (``hydra_plugins.gripdem_launcher.study_sweeper``)."""

    study_name: str
    storage: str | None
    direction: str
    n_trials: int
    n_jobs: int | None
    sampler: Any
    pruner: Any
    params: dict[str, str] | None
    heartbeat_seconds: float
    grace_seconds: float
    test_trials: bool
    timeout_minutes: float | None = None


class _SerialLoader:
    """A Hydra config loader whose ``load_sweep_config`` runs one call at a time: trials are
    launched from several threads, and Hydra's composition is not thread-safe."""

    def __init__(self, loader: Any):
        self._loader, self._lock = loader, threading.Lock()

    def load_sweep_config(self, *args: Any, **kwargs: Any) -> Any:
        with self._lock:
            return self._loader.load_sweep_config(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):  # not set yet (unpickling): no recursion through _loader
            raise AttributeError(name)
        return getattr(self._loader, name)

    # a cluster launcher (submitit) pickles itself, its context included, into each job
    def __getstate__(self) -> dict:
        return {"loader": self._loader}

    def __setstate__(self, state: dict) -> None:
        self._loader, self._lock = state["loader"], threading.Lock()


def serial_context(context: HydraContext) -> HydraContext:
    return HydraContext(
        config_loader=_SerialLoader(context.config_loader), callbacks=context.callbacks
    )


def _is_parallel_launcher(launcher: Any) -> bool:
    return type(launcher).__name__ == "ParallelLauncher"


def trials_at_once(options: StudyOptions, launcher: Any) -> int:
    """``n_jobs`` checked: at most the CPUs on gripdem's parallel launcher (trials on this
    machine); any number on a cluster's launcher. null: one per CPU locally, else 1."""
    n_jobs = options.n_jobs
    local = _is_parallel_launcher(launcher)
    if n_jobs is None:
        return available_cpus() if local else 1
    if n_jobs < 1:
        raise ValueError(f"hydra.sweeper.n_jobs must be >= 1 or null, got {n_jobs}")
    if local and n_jobs > available_cpus():
        raise ValueError(
            f"hydra.sweeper.n_jobs={n_jobs} exceeds the {available_cpus()} CPUs of this "
            f"process: at most {available_cpus()} trials at once on this machine (one thread "
            "each), or a cluster launcher (hydra/launcher=slurm)"
        )
    return n_jobs


def check_pruning(options: StudyOptions, config: DictConfig) -> None:
    """A pruner needs the validation metric it follows: refused before any trial starts."""
    if options.pruner is None:
        return
    metric = str(config.get("optimized_metric"))
    if metric not in VALIDATION_METRICS:
        raise ValueError(
            f"hydra.sweeper.pruner needs a validation metric: optimized_metric={metric} is "
            f"not reported at validations (allowed: {', '.join(VALIDATION_METRICS)}), or set "
            "hydra.sweeper.pruner=null"
        )
    limit = config.trainer.get("limit_val_batches")
    if limit is not None and float(limit) == 0:
        raise ValueError(
            "hydra.sweeper.pruner needs validations: trainer.limit_val_batches=0 runs none "
            "(or set hydra.sweeper.pruner=null)"
        )


def split_arguments(arguments: list[str]) -> tuple[dict[str, str], list[str]]:
    """The command line's sweep overrides (searched, like ``hydra.sweeper.params``) and its
    plain overrides (fixed in every trial)."""
    searched, fixed = {}, []
    for override in OverridesParser.create().parse_overrides(list(arguments)):
        key = override.get_key_element()
        if override.is_sweep_override():
            searched[key] = override.input_line.split("=", 1)[1]
        else:
            fixed.append(override.input_line)
    return searched, fixed


class StudyRun:
    """One sweeper process's part of a study (see the module doc)."""

    def __init__(
        self,
        options: StudyOptions,
        config: DictConfig,
        launcher: Any,
        arguments: list[str],
    ):
        self.options, self.config, self.launcher = options, config, launcher
        searched, self.fixed_arguments = split_arguments(arguments)
        self.space, fixed = parse_space({**(options.params or {}), **searched})
        self.fixed = fixed
        self.at_once = trials_at_once(options, launcher)
        check_pruning(options, config)
        self.sweep_dir = Path(str(config.hydra.sweep.dir))
        self.sweep_dir.mkdir(parents=True, exist_ok=True)
        self.url = storage_url(options.storage, self.sweep_dir)
        if options.direction not in ("minimize", "maximize"):
            raise ValueError(
                f"hydra.sweeper.direction={options.direction}: give minimize or maximize"
            )
        self.definition = StudyDefinition(
            space=space_record(self.space, fixed),
            metric=str(config.optimized_metric),
            direction=options.direction,
            pruner=pruner_record(options.pruner),
        )
        if _is_parallel_launcher(launcher):  # threads per trial: the CPUs shared out
            launcher.n_jobs = self.at_once
            launcher.announce = False  # one trial per launch: the study's lines say more

    def _sampler(self, trials_so_far: int):
        """The configured sampler; its seed moved on by the trials the study holds, so that
        a resumed study does not draw its first trials' values again."""
        from hydra.utils import instantiate

        if not self.options.sampler:
            return None
        spec = dict(self.options.sampler)
        if spec.get("seed") is not None:
            spec["seed"] = int(spec["seed"]) + trials_so_far
        return instantiate(OmegaConf.create(spec))

    def _overrides(self, trial: optuna.Trial) -> list[str]:
        return [
            *self.fixed_arguments,
            *trial_overrides(trial.params, self.fixed),
            f"study_trial.storage={quoted(self.url)}",
            f"study_trial.study={quoted(self.options.study_name)}",
            f"study_trial.number={trial.number}",
            f"study_trial.heartbeat_seconds={self.options.heartbeat_seconds}",
            f"study_trial.test={str(self.options.test_trials).lower()}",
        ]

    def _launch(self, overrides: list[str], number: int) -> Any:
        return self.launcher.launch([overrides], initial_job_idx=number)[0]

    def run(self) -> optuna.Study:
        storage = open_storage(self.url)
        study, resumed = open_study(storage, self.options.study_name, self.definition)
        study.sampler = self._sampler(len(study.get_trials(deepcopy=False))) or study.sampler
        counts = count_trials(study)
        verb = "resumed" if resumed else "created"
        print(
            f"study {self.options.study_name!r} {verb} in {self.url}: {counts.counted} of "
            f"{self.options.n_trials} trials counted ({counts.complete} complete, "
            f"{counts.pruned} pruned, {counts.failed - counts.retried} failed), "
            f"{counts.running} running, {counts.waiting} queued; {self.at_once} at a time "
            f"(look at it: optuna-dashboard {self.url})",
            flush=True,
        )
        mine: dict[Future, optuna.Trial] = {}
        with ThreadPoolExecutor(self.at_once, thread_name_prefix="trial") as pool:
            try:
                self._loop(study, pool, mine)
            except BaseException:
                self._interrupted(study, mine)
                raise
        return study

    def _loop(self, study: optuna.Study, pool, mine: dict[Future, optuna.Trial]) -> None:
        last_beat = 0.0
        minutes = self.options.timeout_minutes
        deadline = math.inf if minutes is None else time.monotonic() + 60 * float(minutes)
        while True:
            for number in requeue_stale(study, self.options.grace_seconds):
                print(f"trial {number}: no heartbeat (killed?): failed and queued again")
            counts = count_trials(study)
            others = counts.running - len(mine)
            budget = self.options.n_trials - counts.counted - counts.running - counts.waiting
            queued = counts.waiting
            if time.monotonic() > deadline:  # no new trial; the running ones finish
                budget = queued = others = 0
            while len(mine) < self.at_once and (queued > 0 or budget > 0):
                trial = study.ask(self.space)  # a re-queued trial first
                beat(study._storage, trial._trial_id)
                if queued > 0:
                    queued -= 1
                else:
                    budget -= 1
                future = pool.submit(self._launch, self._overrides(trial), trial.number)
                mine[future] = trial
            if not mine:
                if others <= 0:
                    return  # the study holds n_trials counted trials
                time.sleep(POLL_SECONDS)  # another worker's trials: wait for their end
                continue
            done, _ = wait(list(mine), timeout=POLL_SECONDS, return_when=FIRST_COMPLETED)
            for future in done:
                self._settle(study, mine.pop(future), future)
            if time.monotonic() - last_beat > self.options.heartbeat_seconds:
                for trial in mine.values():  # alive from here until its run beats itself
                    beat(study._storage, trial._trial_id)
                last_beat = time.monotonic()

    def _settle(self, study: optuna.Study, trial: optuna.Trial, future: Future) -> None:
        """A trial's job ended: its run told the study how (complete, pruned, failed);
        a job that ended without telling (a crash) fails the trial here."""
        error = None
        try:
            result = future.result()
            value = result.return_value
        except Exception as exc:  # noqa: BLE001 - a launcher's or a job's failure
            value, error = math.nan, str(exc).strip().splitlines()[0] if str(exc) else repr(exc)
        frozen = study._storage.get_trial(trial._trial_id)
        if frozen.state == optuna.trial.TrialState.RUNNING:
            reason = frozen.user_attrs.get(ERROR_ATTR) or error or "its job ended without a result"
            if isinstance(value, float) and math.isfinite(value) and error is None:
                study.tell(trial.number, value)
            else:
                study._storage.set_trial_user_attr(trial._trial_id, ERROR_ATTR, reason)
                study.tell(trial.number, state=optuna.trial.TrialState.FAIL)
            frozen = study._storage.get_trial(trial._trial_id)
        print(f"trial {trial.number}: {describe(frozen)}", flush=True)

    def _interrupted(self, study: optuna.Study, mine: dict[Future, optuna.Trial]) -> None:
        """Stopped (Ctrl-C, SIGTERM): the running trials' jobs are stopped and the trials
        re-queued at once, so that running the command again starts with them."""
        if _is_parallel_launcher(self.launcher):
            from gripdem.runner.parallel_launcher import stop_running_jobs

            stop_running_jobs()
        wait(list(mine), timeout=60)
        for trial in mine.values():
            frozen = study._storage.get_trial(trial._trial_id)
            if frozen.state == optuna.trial.TrialState.RUNNING:
                fail_and_requeue(study, frozen, "interrupted: re-queued")
        print(
            f"study {self.options.study_name!r} stopped: {len(mine)} running trial(s) queued "
            "again; run the same command to resume it",
            flush=True,
        )


def describe(trial: optuna.trial.FrozenTrial) -> str:
    """One trial's end in a few words."""
    state = trial.state
    if state == optuna.trial.TrialState.COMPLETE:
        return f"complete, value {trial.value:.4g}"
    if state == optuna.trial.TrialState.PRUNED:
        return f"pruned at step {trial.user_attrs.get(PRUNED_AT_ATTR, trial.last_step)}"
    if state == optuna.trial.TrialState.FAIL:
        return f"failed: {trial.user_attrs.get(ERROR_ATTR, 'no reason recorded')}"
    return state.name.lower()
