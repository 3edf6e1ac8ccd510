"""A study's bad options are one line naming the option and what is allowed, before any trial
starts; a stored study is never overwritten or mixed with another definition (the real CLI)."""

import os
import subprocess
import sys
from pathlib import Path

import optuna
import pytest

from gripdem.provenance import available_cpus
from gripdem.study.storage import open_storage


def study(sweep: Path, *extra: str) -> subprocess.CompletedProcess:
    command = [
        sys.executable,
        "-m",
        "gripdem.run",
        "hparams_search=optuna",
        "experiment=smoke",
        f"hydra.sweep.dir={sweep}",
        *extra,
    ]
    return subprocess.run(command, capture_output=True, text=True, timeout=120, env=os.environ)


def error_line(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode == 1, proc.stdout[-2000:] + proc.stderr[-2000:]
    errors = [
        line for line in (proc.stdout + proc.stderr).splitlines() if line.startswith("error:")
    ]
    assert len(errors) == 1, proc.stdout + proc.stderr
    return errors[0]


@pytest.mark.parametrize(
    ("option", "expected"),
    [
        (f"hydra.sweeper.n_jobs={available_cpus() + 1}", "exceeds the"),
        ("optimized_metric=test/rmse", "hydra.sweeper.pruner needs a validation metric"),
        ("hydra.sweeper.storage=/nonexistent/folder/s.journal", "hydra.sweeper.storage="),
        ("hydra.sweeper.direction=upward", "give minimize or maximize"),
    ],
)
def test_a_bad_option_is_one_line_before_any_trial(tmp_path, option, expected):
    sweep = tmp_path / "study"
    line = error_line(study(sweep, option))
    assert expected in line and option.split("=")[0] in line
    assert not list(sweep.glob("trial=*"))  # no trial started


def test_a_stored_study_refuses_another_definition_and_stays_as_it_was(tmp_path):
    sweep = tmp_path / "study"
    created = study(sweep, "hydra.sweeper.n_trials=0")  # the study, with no trial yet
    assert created.returncode == 0, created.stdout + created.stderr
    journal = sweep / "study.journal"
    before = journal.read_bytes()
    for option, expected in [
        ("hydra.sweeper.direction=maximize", "was made to minimize its metric"),
        ("model.hidden=choice(16,32)", "was made with another search space (model.hidden"),
        ("hydra/sweeper/pruner=median", "was made with pruner"),
    ]:
        line = error_line(study(sweep, option))
        assert expected in line and "choose another hydra.sweeper.study_name" in line
    assert journal.read_bytes() == before  # nothing written to the stored study
    kept = optuna.load_study(study_name="gripdem", storage=open_storage(str(journal)))
    assert kept.direction == optuna.study.StudyDirection.MINIMIZE and not kept.trials
