"""The in-sample check of ``python -m gripdem.predict`` away from a run's folder: shipped models
(``pretrained:NAME``, from any working folder) and a run's model file copied elsewhere find
their training data by the model file's card (its provenance, sizes and split plan)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from gripdem.data.dataset_io import write_dataset
from gripdem.evaluation.predictions import read_predictions
from gripdem.inference.checkpoint import export_run_model, load_checkpoint_model
from gripdem.inference.in_sample import training_overlap
from gripdem.inference.model_file import read_model_file
from gripdem.predict import main
from gripdem.run import CONFIG_DIR
from gripdem.runner.experiment import build_datamodule

SHIPPED_LEBC = "out of sample: the model's card names its training data (lebc-default-"


def test_a_shipped_model_run_from_another_folder_reads_its_card(
    tmp_path, monkeypatch, capsys, tiny_lebc_path
):
    """``pretrained:lebc`` is the shipped file wherever predict runs: no ``metrics.json`` is
    looked for beside the working folder; its card names other data than the tiny scene's."""
    folder = tmp_path / "a" / "b"
    folder.mkdir(parents=True)
    monkeypatch.chdir(folder)
    args = ["pretrained:lebc", str(tiny_lebc_path), "--out", "p.h5", "--sims", "0"]
    assert main([*args, "--frames", "10", "--no-overlap"]) == 0
    printed = capsys.readouterr().out
    assert "metrics.json" not in printed
    note = next(line for line in printed.splitlines() if SHIPPED_LEBC in line)
    assert note.endswith(".h5, gripdem.dem seed 0); this file is another dataset")
    assert read_predictions(folder / "p.h5").in_sample is False


@pytest.fixture(scope="module")
def run_model_file(tmp_path_factory, le_file, le_checkpoint) -> Path:
    """The run's ``best.safetensors`` as the runner exports it (card: the training data and
    the split plan), copied out of its run folder."""
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose(
            "config", overrides=["experiment=smoke", "scene=lebc", f"data.path={le_file}"]
        )
    dm = build_datamodule(cfg, Path(le_file))
    run = tmp_path_factory.mktemp("run")
    exported = export_run_model(
        load_checkpoint_model(le_checkpoint),
        run / "checkpoints" / "best.safetensors",
        {"scene": "lebc", "split": "10-5"},
        {},
        dm.meta,
        dm.summary(),
    )
    away = tmp_path_factory.mktemp("elsewhere") / "model.safetensors"
    shutil.copy(exported, away)
    return away


def test_a_run_model_file_away_from_its_run_flags_its_training_simulations(
    tmp_path, capsys, le_file, run_model_file
):
    split = read_model_file(run_model_file, tensors=False)[2]["training_data"]["split"]
    assert split == {
        "split": "10-5",
        "protocol": "sims",
        "sims_train": [0],
        "sims_val": [1],
        "sims_test": [2],
    }
    in_sample, protocol, note = training_overlap(run_model_file, le_file, [0, 2], 11)
    assert (in_sample, protocol) == (True, "in_sample")
    assert (
        note == "IN SAMPLE: simulations [0] were training simulations of this model (per its card)"
    )
    assert "validation" in training_overlap(run_model_file, le_file, [1], 11)[2]
    assert training_overlap(run_model_file, le_file, [2], 11) == (
        False,
        "sims",
        "out of sample: simulations [2] were not trained on (per its card)",
    )
    copy = shutil.copy(le_file, tmp_path / "renamed.h5")  # the same data under another name
    assert training_overlap(run_model_file, copy, [0], 11)[0] is True
    out = tmp_path / "p.h5"
    args = [str(run_model_file), str(le_file), "--out", str(out), "--sims", "0", "--no-overlap"]
    assert main(args) == 0
    assert "(per its card)" in capsys.readouterr().out
    assert read_predictions(out).in_sample and read_predictions(out).protocol == "in_sample"


def test_other_data_and_cards_without_training_data(
    tmp_path, le_file, run_model_file, trajectories, le_checkpoint
):
    # the fixture's generator with another seed, the same sizes: another dataset
    other = write_dataset(tmp_path / "other.h5", trajectories(3, 40, 24, True, seed=13))
    in_sample, _, note = training_overlap(run_model_file, other, [0], 11)
    assert not in_sample
    assert note == (
        "out of sample: the model's card names its training data (le.h5, "
        "tests/data/conftest.py seed 11); this file is another dataset"
    )
    # the same generator and seed, fewer simulations: another dataset too
    fewer = write_dataset(tmp_path / "fewer.h5", trajectories(2, 40, 24, True, seed=11))
    assert "another dataset" in training_overlap(run_model_file, fewer, [0], 11)[2]
    bare = export_run_model(
        load_checkpoint_model(le_checkpoint), tmp_path / "bare.safetensors", {}, {}
    )
    assert training_overlap(bare, le_file, [0], 11) == (
        False,
        "sims",
        "in-sample check: the model file's card names no training data; the predictions are "
        "labelled out of sample",
    )
