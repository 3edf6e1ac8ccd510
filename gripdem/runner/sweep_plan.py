"""Hydra callback: check every job's configuration and say what a run or sweep will cost, before
anything runs or any folder is written.

- A single run: :func:`~gripdem.runner.config_schema.check_combination` on its config in
  ``on_run_start`` (Hydra creates the run folder after it), so an option that the model cannot
  take ends in one line and leaves no folder behind.
- A multirun with the basic sweeper: the sweep is expanded into its jobs as Hydra's
  ``BasicSweeper`` expands it, each job's config is composed and checked (the first bad job is
  named with its overrides), and one line gives the number of jobs and an estimate of their
  time from measured step rates (:data:`SECONDS_PER_STEP`), before the first job starts. Other
  sweepers (Optuna) choose their jobs as they go: only their trial count is printed.

The estimate is for a 2-core CPU like the AMD EPYC it was measured on: it scales the measured
seconds
per optimiser step of each encoder/decoder kind by particles and history length, and adds each
job's data, baseline and test time measured on the same machine
(``experiments/results/split_sweep/split_sweep.md``). A GPU or more cores run faster.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from hydra.core.global_hydra import GlobalHydra
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from gripdem.data.windows import resolve_rollout_links
from gripdem.provenance import available_cpus
from gripdem.runner.config_schema import check_combination
from gripdem.runner.console import report_error

log = logging.getLogger(__name__)

#: seconds per optimiser step at 2000 particles, history_len 10, batch size 1, 2 threads on the
#: reference 2-core machine (experiments/results/split_sweep/split_sweep.md): (encoder, decoder) ->
#: (base, per predicted frame of the model's horizon)
SECONDS_PER_STEP = {
    ("contact", "direct"): (0.046, 0.0),
    ("graph_conv", "direct"): (0.33, 0.0),
    ("contact", "gru"): (0.046, 0.0066),
    ("graph_conv", "gru"): (0.33, 0.0066),
}
#: rollout training (model.rollout.links = L): a chained training step (after
#: model.rollout.start of the budget) costs ``1 + c (L - 1)`` one-link steps, ``c`` by
#: model.rollout.loss (each further link: a forward pass, the contact correction
#: of its frames and, for ``all``, a backward pass; chained validation included), measured with
#: two one-thread jobs side by side (experiments/results/rollout_training/rollout_training.md)
ROLLOUT_LINK_COST = {"last": 0.65, "all": 1.1}
#: seconds per job besides training at 2000 particles: loading, the AR fit, validation, the
#: test and the outputs (per frame of the split's horizon: the chained test grows with it)
SECONDS_PER_JOB = (14.0, 0.02)
#: seconds of the built-in DEM per simulation of 2000 particles (the default preset, 2 cores)
DEM_SECONDS_PER_SIM = 30.0
#: wall time of two one-thread jobs side by side over one two-thread job's, on 2 cores
#: (experiments/results/split_sweep/split_sweep.md)
PARALLEL_SLOWDOWN = 1.3


def _value(option: Any) -> str:
    """A config option's value as a string (an enum of the schema or a plain string)."""
    return str(getattr(option, "value", option))


def job_seconds(cfg: DictConfig) -> float:
    """A rough estimate of one job's wall time on the 2-core machine it was measured on (see
    module doc)."""
    model = cfg.model
    kind = (_value(model.encoder.name), _value(model.decoder))
    if kind not in SECONDS_PER_STEP:
        raise ValueError(f"no measured step rate for encoder/decoder {kind}")
    base, per_frame = SECONDS_PER_STEP[kind]
    horizon = int(cfg.split.horizon)
    model_horizon = min(int(model.horizon or horizon), horizon)
    history = cfg.data.history_len or cfg.split.history
    scale = float(cfg.preset.get("particles", 2000)) / 2000.0
    per_step = (base + per_frame * model_horizon) * scale * max(1.0, history / 10.0)
    rollout = model.get("rollout") or {}
    links = resolve_rollout_links(rollout.get("links", 1), horizon, model_horizon)
    chained = 1.0 + ROLLOUT_LINK_COST[_value(rollout.get("loss", "last"))] * (links - 1)
    start = float(rollout.get("start", 0.0)) if links > 1 else 1.0  # one link until then
    per_step *= start + (1.0 - start) * chained
    steps = cfg.trainer.get("max_steps", -1)
    if steps is None or int(steps) < 0:  # an epoch budget: the preset's windows per epoch
        steps = 400 * int(cfg.trainer.get("max_epochs", 1) or 1)
    fixed, per_test_frame = SECONDS_PER_JOB
    return int(steps) * per_step + (fixed + per_test_frame * horizon) * scale


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:.0f} min" if seconds >= 600 else f"{seconds / 60:.1f} min"


def expand_jobs(config: DictConfig) -> list[list[str]] | None:
    """The override lists of a basic sweeper's jobs, in its order (None: another sweeper)."""
    target = str(config.hydra.sweeper.get("_target_", ""))
    if not target.endswith("BasicSweeper"):
        return None
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper

    params = config.hydra.sweeper.get("params") or {}
    arguments = [f"{k}={v}" for k, v in params.items()]
    arguments += list(OmegaConf.to_container(config.hydra.overrides.task, resolve=False))
    loader = GlobalHydra.instance().config_loader()
    overrides = OverridesParser.create(config_loader=loader).parse_overrides(arguments)
    return BasicSweeper.split_arguments(overrides, None)[0]


@contextmanager
def errors_end_the_command() -> Iterator[None]:
    """Hydra turns an exception raised in a callback into a warning and goes on; a user error
    found here must end the command before anything is written: its one line, status 1."""
    try:
        yield
    except ValueError as exc:
        report_error(exc)
        raise SystemExit(1) from None


class SweepPlan(Callback):
    """Checks and cost estimate before a run or a sweep starts (see the module doc)."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        with errors_end_the_command():
            check_combination(config, notes=False)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        with errors_end_the_command():
            self._plan(config)

    def _plan(self, config: DictConfig) -> None:
        jobs = expand_jobs(config)
        if jobs is None:  # Optuna: trials chosen as it goes, each like the base config
            check_combination(config, notes=False)
            trials = int(config.hydra.sweeper.get("n_trials") or 1)
            n_jobs = config.hydra.sweeper.get("n_jobs")
            study = str(config.hydra.sweeper.get("_target_")).endswith("StudySweeper")
            if n_jobs is None and study:
                n_jobs = available_cpus()  # the study sweeper: one trial per CPU
            at_once = _jobs_at_once(config, int(n_jobs or 1))
            wall = trials * job_seconds(config) / at_once
            wall *= PARALLEL_SLOWDOWN if at_once > 1 else 1.0
            pruned = study and config.hydra.sweeper.get("pruner") is not None
            print(
                f"sweep: {trials} trials chosen by the sweeper as it goes, {at_once} at a time, "
                f"{'at most ' if pruned else ''}about {_minutes(wall)} on a 2-core CPU like "
                "the one it was measured on (at the base config's size"
                f"{'; pruned trials end sooner' if pruned else ''})",
                flush=True,
            )
            return
        loader = GlobalHydra.instance().config_loader()
        total, longest, missing = 0.0, 0.0, {}
        for overrides in jobs:
            job = loader.load_sweep_config(config, list(overrides))
            try:
                check_combination(job, notes=False)
            except ValueError as exc:
                raise ValueError(f"job {' '.join(overrides) or '(no overrides)'}: {exc}") from exc
            seconds = job_seconds(job)
            total, longest = total + seconds, max(longest, seconds)
            if job.data.path is None:
                missing.update(_missing_dataset(job))
        n = len(jobs)
        at_once = _jobs_at_once(config, n)
        # side by side the sweep lasts at least as long as its longest job
        wall = max(total / at_once, longest) * (PARALLEL_SLOWDOWN if at_once > 1 else 1.0)
        how = "one after another" if at_once == 1 else f"{at_once} at a time"
        dem = ""
        if missing:
            minutes = _minutes(sum(missing.values()) / 2000.0 * DEM_SECONDS_PER_SIM)
            dem = f", plus about {minutes} to generate {len(missing)} dataset(s) first"
        print(
            f"sweep: {n} job{'s' if n != 1 else ''}, about {_minutes(wall)} ({how}) on a 2-core "
            f"CPU like the one it was measured on{dem}",
            flush=True,
        )


def _missing_dataset(job: DictConfig) -> dict[str, float]:
    """``{cache file: particles x simulations}`` of the job's built-in dataset when it is not
    in the cache yet (empty when it is)."""
    from gripdem.dem.config import GeneratorConfig
    from gripdem.dem.output import dataset_path
    from gripdem.runner.config_schema import plain

    config = GeneratorConfig.from_mappings(
        plain(job.scene),
        plain(job.preset),
        seed=int(job.data_seed),
        backend=job.get("generator_backend", "numba"),
    )
    path = dataset_path(config)
    if path.exists():
        return {}
    return {str(path): float(config.sims * config.preset.particles)}


def _jobs_at_once(config: DictConfig, n_jobs: int) -> int:
    """How many jobs the sweep's launcher runs at once (the parallel launcher's plan)."""
    launcher = config.hydra.launcher
    if not str(launcher.get("_target_", "")).endswith("ParallelLauncher"):
        return 1
    from gripdem.runner.parallel_launcher import plan_parallel

    trainer = config.get("trainer", {})
    uses_gpu = str(trainer.get("accelerator", "cpu")) not in ("cpu", "auto")
    try:
        at_once, _ = plan_parallel(launcher.get("n_jobs"), config.get("torch_threads"), uses_gpu)
    except ValueError:
        return 1  # the launcher itself refuses it, with its own message
    return max(1, min(at_once, n_jobs))
