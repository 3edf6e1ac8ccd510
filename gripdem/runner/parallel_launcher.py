"""Jobs of a multirun side by side, each in its own process with its own threads.

The default launcher of ``python -m gripdem.run -m ...`` (``hydra/launcher=parallel``; the
Hydra plugin class is ``hydra_plugins.gripdem_launcher.ParallelLauncher``, which calls
:func:`launch_jobs`). Measured on a 2-core AMD EPYC machine with the split sweep
``python -m gripdem.run -m split=190-10,100-100 model=vct``
(``experiments/results/split_sweep/split_sweep.md``): two jobs with one torch thread each finish
sooner than the same jobs one after another with two threads, because a small model at batch
size one keeps a second thread mostly idle.

Each job is ``python -m gripdem.run <its overrides> hydra.run.dir=<sweep>/<its name>
hydra.mode=RUN hydra.job.num=<n>`` (its name: ``hydra.sweep.subdir``, what differs,
:mod:`gripdem.runner.run_names`) with ``OMP_NUM_THREADS=<threads>``: a single run in a fresh
process, so its log, TensorBoard run, checkpoints and errors stay its own. What it prints goes
to ``<job folder>/console.log``; the sweep's console gets one line when a job starts and one
when it ends (its time and error line), and, between them, the job's data generation or its
wait for another job's (:mod:`gripdem.runner.job_relay`). At most ``n_jobs`` run at once, and
``n_jobs x threads`` never exceeds the CPUs given to this process (no oversubscription). A job
that fails writes ``error.txt`` (the one error line), returns NaN to the sweeper, and leaves the
other jobs running; the sweep's summary names it.

Stopping: Ctrl-C reaches every job (one process group) and each answers with its one
``interrupted:`` line in its console.log (a job still running 5 s later gets SIGTERM); SIGTERM
to the sweep is forwarded to every job;
if the sweep process is killed outright, the kernel sends each job SIGTERM
(``PR_SET_PDEATHSIG``), so no job outlives it. Every file a job writes is written atomically.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra.core.utils import JobReturn, JobStatus, filter_overrides
from omegaconf import DictConfig, open_dict

from gripdem.evaluation.sweep_summary import ERROR_FILE
from gripdem.provenance import available_cpus
from gripdem.runner.console import SWEEP_JOB_ENV, Terminated
from gripdem.runner.job_relay import ConsoleRelay

#: seconds between checks of the running jobs
POLL_SECONDS = 0.2
#: seconds a job gets to stop after SIGTERM before SIGKILL
STOP_SECONDS = 20.0
#: seconds the jobs get to answer a terminal's Ctrl-C themselves before they are sent SIGTERM
CTRL_C_SECONDS = 5.0
#: the jobs running now, over every call of :func:`launch_jobs` (a study launches its trials
#: one per call, from several threads: :func:`stop_running_jobs` stops them all)
_RUNNING: set[_Job] = set()
_RUNNING_LOCK = threading.Lock()


def plan_parallel(n_jobs: int | None, threads: int | None, uses_gpu: bool) -> tuple[int, int]:
    """``(jobs at once, torch threads per job)``. ``n_jobs=None``: as many one-thread jobs as
    CPUs (one at a time on a GPU: jobs would share it); ``threads=None``: the CPUs shared
    out. Refuses a pair that would oversubscribe the CPUs."""
    cpus = available_cpus()
    if n_jobs is None:
        n_jobs = 1 if uses_gpu else max(1, cpus // (threads or 1))
    if n_jobs < 1:
        raise ValueError(f"hydra.launcher.n_jobs must be >= 1 or null (auto), got {n_jobs}")
    if threads is None:
        threads = max(1, cpus // n_jobs)
    if n_jobs * threads > cpus and n_jobs > 1:
        raise ValueError(
            f"hydra.launcher.n_jobs={n_jobs} jobs x torch_threads={threads} exceeds the "
            f"{cpus} CPUs of this process: lower one of them (threads of several jobs "
            "spinning on too few cores are many times slower)"
        )
    return n_jobs, threads


def _set_parent_death_signal() -> None:  # pragma: no cover - runs in the child before exec
    from gripdem.dem.workers import _parent_death_signal

    _parent_death_signal(signal.SIGTERM)


def quoted(value: str) -> str:
    """A string as one value of Hydra's override grammar (quoted: ``=`` and ``,`` kept)."""
    # Hydra's rule: backslashes before a quote (the closing one too) are doubled
    escaped = re.sub(r"(\\*)'", lambda m: m.group(1) * 2 + "\\'", value)
    escaped = re.sub(r"(\\+)$", lambda m: m.group(1) * 2, escaped)
    return f"'{escaped}'"


def _job_dir(config: DictConfig) -> Path:
    return Path(str(config.hydra.sweep.dir)) / str(config.hydra.sweep.subdir)


def _return_value(job_dir: Path, metric: str) -> tuple[Any, str | None]:
    """The job's ``metric`` from its metrics.json and its error line (error.txt), if any."""
    error_file = job_dir / ERROR_FILE
    if error_file.exists():
        return math.nan, error_file.read_text().strip()
    metrics_file = job_dir / "metrics.json"
    if not metrics_file.exists():
        return math.nan, "no metrics.json (see console.log)"
    metrics = json.loads(metrics_file.read_text())
    value = metrics.get(metric)
    if not isinstance(value, (int, float)):
        return math.nan, f"optimized_metric={metric!r} is not in metrics.json"
    return float(value), None


class _Job:
    def __init__(self, number: int, overrides: Sequence[str], config: DictConfig):
        self.number, self.overrides, self.config = number, list(overrides), config
        self.dir = _job_dir(config)
        self.process: subprocess.Popen | None = None
        self.started = 0.0
        self.relay = ConsoleRelay(self.dir / "console.log")

    @property
    def label(self) -> str:
        # a study trial's link to its study (study_trial.*) is the same for every trial
        shown = [o for o in filter_overrides(self.overrides) if not o.startswith("study_trial.")]
        return f"#{self.number} : {' '.join(shown)}"

    def start(self, threads: int) -> None:
        self.dir.mkdir(parents=True, exist_ok=True)
        command = [
            *(sys.executable, "-m", "gripdem.run"),
            *self.overrides,
            f"hydra.run.dir={quoted(str(self.dir))}",  # a job's name holds = and ,
            # a single run, whatever the overrides select (hparams_search=optuna sets
            # hydra.mode=MULTIRUN: without this each trial would start a study of its own)
            "hydra.mode=RUN",
            f"hydra.job.num={self.number}",  # the sweep's order (the summary's rows)
        ]
        # torch's default thread count follows OMP_NUM_THREADS (torch_threads=N, when given
        # among the job's overrides, sets it again); the job's overrides stay as the user's
        threads_env = {name: str(threads) for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS")}
        env = {**os.environ, **threads_env, SWEEP_JOB_ENV: "1"}
        console = open(self.dir / "console.log", "w")  # noqa: SIM115 - closed by the child
        with console:
            self.process = subprocess.Popen(
                command,
                stdin=subprocess.DEVNULL,
                stdout=console,
                stderr=subprocess.STDOUT,
                env=env,
                preexec_fn=_set_parent_death_signal if sys.platform.startswith("linux") else None,
            )
        self.started = time.perf_counter()
        with _RUNNING_LOCK:
            _RUNNING.add(self)
        print(f"job {self.label} started (log: {self.dir / 'console.log'})", flush=True)

    def show_progress(self) -> None:
        """The job's long work (its data generation, or its wait for another's) as it goes."""
        for line in self.relay.poll(time.monotonic()):
            print(f"job #{self.number}: {line}", flush=True)

    def result(self, metric: str) -> JobReturn:
        with _RUNNING_LOCK:
            _RUNNING.discard(self)
        value, error = _return_value(self.dir, metric)
        minutes = (time.perf_counter() - self.started) / 60
        if error is None and self.process is not None and self.process.returncode != 0:
            error = f"exited with status {self.process.returncode} (see console.log)"
        end = f"failed: {error}" if error else "done"
        print(f"job {self.label} {end} ({minutes:.1f} min)", flush=True)
        ret = JobReturn(
            overrides=self.overrides,
            cfg=self.config,
            hydra_cfg=None,
            working_dir=str(self.dir),
            task_name=str(self.config.hydra.job.name),
            status=JobStatus.COMPLETED,
        )
        ret.return_value = value
        return ret


def _wait(jobs: list[_Job], seconds: float) -> None:
    """Give running jobs ``seconds`` to end on their own."""
    deadline = time.monotonic() + seconds
    for job in jobs:
        if job.process is not None:
            try:
                job.process.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                return


def _stop(jobs: list[_Job]) -> None:
    """SIGTERM to every running job (each answers like Ctrl-C), SIGKILL after a grace."""
    running = [j.process for j in jobs if j.process is not None and j.process.poll() is None]
    for process in running:
        process.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + STOP_SECONDS
    for process in running:
        try:
            process.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def stop_running_jobs() -> None:
    """SIGTERM to every job running now (SIGKILL after a grace), whichever call started it."""
    with _RUNNING_LOCK:
        jobs = list(_RUNNING)
    _stop(jobs)


def launch_jobs(
    hydra_context: Any,
    config: DictConfig,
    job_overrides: Sequence[Sequence[str]],
    initial_job_idx: int,
    n_jobs: int | None,
    announce: bool = True,
) -> list[JobReturn]:
    """Run the jobs, at most ``n_jobs`` at once; returns their results in job order
    (``announce``: say how many and how, first)."""
    trainer = config.get("trainer", {})
    uses_gpu = str(trainer.get("accelerator", "cpu")) not in ("cpu", "auto") or bool(
        trainer.get("strategy")
    )
    at_once, threads = plan_parallel(n_jobs, config.get("torch_threads"), uses_gpu)
    Path(str(config.hydra.sweep.dir)).mkdir(parents=True, exist_ok=True)
    jobs = []
    for offset, overrides in enumerate(job_overrides):
        number = initial_job_idx + offset
        job_config = hydra_context.config_loader.load_sweep_config(config, list(overrides))
        with open_dict(job_config):
            job_config.hydra.job.id = number
            job_config.hydra.job.num = number
        jobs.append(_Job(number, overrides, job_config))
    at_once = min(at_once, len(jobs))
    if announce:  # a study launches its trials one at a time: its own lines say more
        print(
            f"launching {len(jobs)} job(s), {at_once} at a time with {threads} torch thread(s) "
            "each (hydra.launcher.n_jobs, torch_threads)",
            flush=True,
        )
    metric = str(config.get("optimized_metric", "val/rmse_best"))
    pending, running, results = list(jobs), [], {}
    try:
        while pending or running:
            while pending and len(running) < at_once:
                job = pending.pop(0)
                job.start(threads)
                running.append(job)
            time.sleep(POLL_SECONDS)
            for job in running:
                job.show_progress()
            for job in [j for j in running if j.process.poll() is not None]:
                running.remove(job)
                results[job.number] = job.result(metric)
    except BaseException as exc:  # Ctrl-C, SIGTERM (a KeyboardInterrupt here), a bug
        if isinstance(exc, KeyboardInterrupt) and not isinstance(exc, Terminated):
            _wait(running, CTRL_C_SECONDS)  # a terminal's Ctrl-C reached every job too
        _stop(running)
        raise
    return [results[job.number] for job in jobs]
