"""Studies as users run them: ``python -m gripdem.run hparams_search=optuna``, killed and resumed,
pruned, shared by two workers, and on submitit's local executor standing in for SLURM (real
processes, real journal files, tiny real data)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import optuna
import pytest
from optuna.trial import TrialState

from gripdem.study.storage import HEARTBEAT_ATTR, RETRY_OF_ATTR, open_storage

optuna.logging.set_verbosity(optuna.logging.WARNING)

#: a pruner that stops every trial at its first validation (any RMSE is above 0)
ALWAYS = "_target_: optuna.pruners.ThresholdPruner\nupper: 0.0\n"


def study_command(sweep: Path, *extra: str, config_dir: Path | None = None) -> list[str]:
    flags = ["--config-dir", str(config_dir)] if config_dir else []
    return [
        sys.executable,
        "-m",
        "gripdem.run",
        *flags,
        "hparams_search=optuna",
        "experiment=smoke",
        f"hydra.sweep.dir={sweep}",
        "hydra.sweeper.heartbeat_seconds=1",
        "trainer.enable_progress_bar=false",
        *extra,
    ]


def run(command: list[str], data_root: Path, timeout: int = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "GRIPDEM_DATA": str(data_root)}
    proc = subprocess.run(command, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc


def load(sweep: Path) -> optuna.Study:
    return optuna.load_study(
        study_name="gripdem", storage=open_storage(str(sweep / "study.journal"))
    )


def always_pruner(tmp_path: Path) -> Path:
    folder = tmp_path / "conf" / "hydra" / "sweeper" / "pruner"
    folder.mkdir(parents=True)
    (folder / "always.yaml").write_text(ALWAYS)
    return tmp_path / "conf"


def test_a_killed_study_resumes_its_running_trials_once_and_pruned_trials_stop(
    tmp_path, gripdem_data_root, tiny_pbc_path
):
    sweep, conf = tmp_path / "study", always_pruner(tmp_path)
    short = ["trainer.max_steps=6", "trainer.val_check_interval=2", "hydra/sweeper/pruner=always"]
    # 1. one trial, pruned at its first validation: a finished trial
    run(
        study_command(sweep, "hydra.sweeper.n_trials=1", *short, config_dir=conf), gripdem_data_root
    )
    first = load(sweep).trials[0]
    assert first.state == TrialState.PRUNED and first.last_step == 2
    # 2. the study goes on with two long trials, and its controlling process is SIGKILLed
    long = [
        "trainer.max_steps=100000",
        "trainer.val_check_interval=50000",
        "hydra/sweeper/pruner=always",
    ]
    env = {**os.environ, "GRIPDEM_DATA": str(gripdem_data_root)}
    controller = subprocess.Popen(
        study_command(
            sweep, "hydra.sweeper.n_trials=4", "hydra.sweeper.n_jobs=2", *long, config_dir=conf
        ),
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 120
    while time.time() < deadline:  # both trials' runs beat (they are training)
        running = load(sweep).get_trials(states=(TrialState.RUNNING,))
        runs_beat = [
            t
            for t in running
            if (t.system_attrs.get(HEARTBEAT_ATTR) or 0) > t.datetime_start.timestamp() + 2
        ]
        if len(runs_beat) == 2:
            break
        time.sleep(0.5)
    else:
        controller.kill()
        pytest.fail("the study's two trials never started")
    controller.send_signal(signal.SIGKILL)
    controller.wait()
    killed = {t.number: t.params for t in load(sweep).get_trials(states=(TrialState.RUNNING,))}
    assert sorted(killed) == [1, 2]
    # 3. the same command resumes it: the silent trials failed and run again, none twice
    proc = run(
        study_command(
            sweep,
            "hydra.sweeper.n_trials=3",  # the kept trial and the two re-runs: no new one
            "hydra.sweeper.n_jobs=2",
            "hydra.sweeper.grace_seconds=3",
            *short,
            config_dir=conf,
        ),
        gripdem_data_root,
    )
    assert "resumed" in proc.stdout
    study = load(sweep)
    trials = {t.number: t for t in study.trials}
    assert (
        trials[0].state == TrialState.PRUNED
        and trials[0].intermediate_values == first.intermediate_values
    )
    assert {n: trials[n].state for n in killed} == {1: TrialState.FAIL, 2: TrialState.FAIL}
    retries = {
        t.user_attrs[RETRY_OF_ATTR]: t for t in study.trials if RETRY_OF_ATTR in t.user_attrs
    }
    assert sorted(retries) == [1, 2]
    assert all(retries[n].params == killed[n] for n in killed)
    assert len(study.trials) == 5  # 0 kept, 1 and 2 failed, their two re-runs (failed trials
    # that were queued again do not count toward n_trials)
    assert [t.state for t in study.trials if t.number not in killed] == [TrialState.PRUNED] * 3
    # a pruned trial stops training at once and says so in its folder and in TensorBoard
    for trial in study.trials:
        if trial.state != TrialState.PRUNED:
            continue
        folder = next(sweep.glob(f"trial={trial.number},*"))
        metrics = json.loads((folder / "metrics.json").read_text())
        assert metrics["study/state"] == "pruned" and metrics["steps"] == 2
        from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

        events = EventAccumulator(str(folder)).Reload()
        assert [s.value for s in events.Scalars("study/pruned")] == [1.0]
    ranked = (sweep / "study.md").read_text()
    assert (
        "3 pruned, 2 failed" not in ranked
        and "0 complete, 3 pruned, 0 failed (2 more re-queued" in ranked
    )


@pytest.mark.slow
def test_two_workers_on_one_journal_never_run_the_same_trial(
    tmp_path, gripdem_data_root, tiny_pbc_path
):
    sweep = tmp_path / "study"
    sweep.mkdir()
    journal = sweep / "shared.journal"
    env = {**os.environ, "GRIPDEM_DATA": str(gripdem_data_root)}
    workers = [
        subprocess.Popen(
            study_command(
                sweep,
                "hydra.sweeper.n_trials=6",
                "hydra.sweeper.n_jobs=1",
                f"hydra.sweeper.storage={journal}",
                "trainer.max_steps=6",
                "trainer.val_check_interval=2",
                "hydra.sweeper.pruner.min_resource=2",
            ),
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for _ in range(2)
    ]
    outputs = [w.communicate(timeout=600)[0] for w in workers]
    assert all(w.returncode == 0 for w in workers), outputs
    study = optuna.load_study(study_name="gripdem", storage=open_storage(str(journal)))
    assert len(study.trials) == 6 and all(t.state.is_finished() for t in study.trials)
    ran = [
        int(line.split()[1].rstrip(":"))
        for out in outputs
        for line in out.splitlines()
        if line.startswith("trial ") and ("complete" in line or "pruned" in line)
    ]
    assert sorted(ran) == list(range(6))  # each trial ran in one worker only
    assert all(any(f"trial {n}:" in out for n in range(6)) for out in outputs)  # both worked
    assert len(list(sweep.glob("trial=*/metrics.json"))) == 6


@pytest.mark.slow
def test_a_study_on_submitits_local_executor(tmp_path, gripdem_data_root, tiny_pbc_path):
    sweep = tmp_path / "study"
    run(
        study_command(
            sweep,
            "hydra/launcher=submitit_local",
            "hydra.sweeper.n_trials=3",
            "hydra.sweeper.n_jobs=2",
            "trainer.max_steps=6",
            "trainer.val_check_interval=2",
            "hydra.sweeper.pruner.min_resource=2",
        ),
        gripdem_data_root,
        timeout=600,
    )
    study = load(sweep)
    assert len(study.trials) == 3 and all(
        t.state in (TrialState.COMPLETE, TrialState.PRUNED) for t in study.trials
    )
    assert all(t.intermediate_values for t in study.trials)  # each job reported to the study
    assert len(list(sweep.glob("trial=*/metrics.json"))) == 3
    assert (sweep / ".submitit").is_dir()  # the jobs went through submitit


@pytest.mark.slow
def test_a_study_stopped_by_sigterm_queues_its_running_trials_again(
    tmp_path, gripdem_data_root, tiny_pbc_path
):
    sweep = tmp_path / "study"
    long = ["trainer.max_steps=100000", "trainer.val_check_interval=50000"]
    env = {**os.environ, "GRIPDEM_DATA": str(gripdem_data_root)}
    controller = subprocess.Popen(
        study_command(sweep, "hydra.sweeper.n_trials=4", "hydra.sweeper.n_jobs=2", *long),
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    deadline = time.time() + 120
    while time.time() < deadline:
        journal = sweep / "study.journal"
        if journal.exists() and len(load(sweep).get_trials(states=(TrialState.RUNNING,))) == 2:
            break
        time.sleep(0.5)
    time.sleep(5)  # the trials' runs are training
    controller.send_signal(signal.SIGTERM)
    output = controller.communicate(timeout=120)[0]
    assert controller.returncode != 0
    assert "2 running trial(s) queued again; run the same command to resume it" in output
    study = load(sweep)
    states = [t.state for t in study.trials]
    assert states == [TrialState.FAIL, TrialState.FAIL, TrialState.WAITING, TrialState.WAITING]
    queued = [t.system_attrs["fixed_params"] for t in study.trials[2:]]  # run when resumed
    assert queued == [t.params for t in study.trials[:2]]
