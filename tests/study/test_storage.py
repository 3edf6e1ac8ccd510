"""Where a study lives: opening storages, the study's definition kept, heartbeats and re-queues,
counting without double counts (real journal files and SQLite databases)."""

import threading
import time

import optuna
import pytest

from gripdem.study.space import parse_space, space_record
from gripdem.study.storage import (
    HEARTBEAT_ATTR,
    RETRY_OF_ATTR,
    StudyDefinition,
    beat,
    count_trials,
    fail_and_requeue,
    open_storage,
    open_study,
    pruner_from_record,
    pruner_record,
    requeue_stale,
    storage_url,
)

optuna.logging.set_verbosity(optuna.logging.WARNING)
SPACE = parse_space(
    {"model.lr": "tag(log, interval(1e-4, 1e-2))", "model.hidden": "choice(32, 64)"}
)
PRUNER = {"_target_": "optuna.pruners.SuccessiveHalvingPruner", "min_resource": 2}


def definition(**changes) -> StudyDefinition:
    fields = {
        "space": space_record(*SPACE),
        "metric": "val/rmse_best",
        "direction": "minimize",
        "pruner": pruner_record(PRUNER),
    }
    return StudyDefinition(**{**fields, **changes})


def test_the_default_storage_is_a_journal_file_in_the_study_folder(tmp_path):
    url = storage_url(None, tmp_path)
    assert url == str(tmp_path.resolve() / "study.journal")
    assert storage_url("sqlite:///x.db", tmp_path) == "sqlite:///x.db"
    study, resumed = open_study(open_storage(url), "s", definition())
    assert not resumed and (tmp_path / "study.journal").exists()
    assert isinstance(
        pruner_from_record(study.user_attrs["gripdem:pruner"]),
        optuna.pruners.SuccessiveHalvingPruner,
    )


@pytest.mark.parametrize(
    ("storage", "message"),
    [
        ("{tmp}/missing/study.journal", "its folder .* does not exist"),
        ("{tmp}", "it is a folder"),
        ("{tmp}/db.sqlite", "it is an SQLite file: give sqlite:///"),
        ("nosuchdriver://host/db", "cannot be opened"),
    ],
)
def test_a_storage_that_cannot_be_opened_is_one_line_naming_the_option(tmp_path, storage, message):
    optuna.create_study(storage=f"sqlite:///{tmp_path / 'db.sqlite'}", study_name="x")
    url = storage_url(storage.format(tmp=tmp_path), tmp_path)
    with pytest.raises(ValueError, match=message) as info:
        open_storage(url)
    assert str(info.value).startswith("hydra.sweeper.storage=") and "\n" not in str(info.value)


@pytest.mark.parametrize("url", ["journal", "sqlite"])
def test_a_study_resumes_with_its_definition_and_refuses_another(tmp_path, url):
    url = str(tmp_path / "s.journal") if url == "journal" else f"sqlite:///{tmp_path / 's.db'}"
    study, _ = open_study(open_storage(url), "s", definition())
    trial = study.ask(SPACE[0])
    study.tell(trial, 1.0)
    again, resumed = open_study(open_storage(url), "s", definition())
    assert resumed and len(again.trials) == 1 and again.trials[0].value == 1.0
    other_space = space_record(
        *parse_space({"model.lr": "interval(1e-4, 1e-1)", "model.hidden": "choice(32, 64)"})
    )
    cases = {
        "hydra.sweeper.params: study 's' was made with another search space (model.lr": {
            "space": other_space
        },
        "hydra.sweeper.direction=maximize": {"direction": "maximize"},
        "optimized_metric=test/rmse": {"metric": "test/rmse"},
        "hydra.sweeper.pruner": {"pruner": "null"},
    }
    for start, change in cases.items():
        with pytest.raises(ValueError) as info:
            open_study(open_storage(url), "s", definition(**change))
        assert str(info.value).startswith(start) and "another hydra.sweeper.study_name" in str(
            info.value
        )
    kept = optuna.load_study(study_name="s", storage=open_storage(url))
    assert len(kept.trials) == 1 and kept.user_attrs["gripdem:space"] == space_record(*SPACE)


def test_a_study_not_made_by_gripdem_is_not_taken_over(tmp_path):
    url = str(tmp_path / "s.journal")
    optuna.create_study(storage=open_storage(url), study_name="theirs")
    with pytest.raises(ValueError, match="not made by gripdem"):
        open_study(open_storage(url), "theirs", definition())


def test_a_silent_trial_is_failed_and_requeued_once_and_counted_once(tmp_path):
    url = str(tmp_path / "s.journal")
    study, _ = open_study(open_storage(url), "s", definition())
    done = study.ask(SPACE[0])
    study.tell(done, 0.5)
    alive, silent = study.ask(SPACE[0]), study.ask(SPACE[0])
    beat(study._storage, alive._trial_id)
    study._storage.set_trial_system_attr(silent._trial_id, HEARTBEAT_ATTR, time.time() - 100)
    # two processes look at once: only one re-queues
    other, _ = open_study(open_storage(url), "s", definition())
    results = []
    threads = [
        threading.Thread(target=lambda s=s: results.append(requeue_stale(s, 30)))
        for s in (study, other)
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(map(len, results)) == [0, 1] and [silent.number] in results
    counts = count_trials(study)
    assert (counts.complete, counts.failed, counts.retried, counts.running, counts.waiting) == (
        1,
        1,
        1,
        1,
        1,
    )
    assert counts.counted == 1  # the failed one is run again: not counted
    rerun = study.ask(SPACE[0])  # the queued parameters come first
    assert rerun.params == silent.params
    assert study._storage.get_trial(rerun._trial_id).user_attrs[RETRY_OF_ATTR] == silent.number
    study.tell(rerun, 0.7)
    assert count_trials(study).counted == 2
    assert fail_and_requeue(study, study._storage.get_trial(silent._trial_id), "again") is False


def test_only_optunas_pruners_are_stored(tmp_path):
    with pytest.raises(ValueError, match="give one of Optuna's pruners"):
        pruner_record({"_target_": "os.system", "command": "echo"})
    with pytest.raises(ValueError, match="is not Optuna's"):
        pruner_from_record('{"name": "system", "kwargs": {}}')
    assert isinstance(pruner_from_record("null"), optuna.pruners.NopPruner)
