"""Fine-tuning from a trained model: the run starts from its weights and normalisation, reports
the model before and after beside the baselines, and refuses a source of another architecture."""

from __future__ import annotations

import json
import math

import pytest
import torch
from hydra import compose, initialize_config_dir

from gripdem.inference.checkpoint import load_checkpoint_model
from gripdem.run import CONFIG_DIR
from gripdem.runner.experiment import run_experiment
from gripdem.runner.finetune import (
    StartingPoint,
    apply_finetune_defaults,
    check_architecture,
    keep_start_unless_beaten,
)


def run(tmp_path, name, overrides):
    out = tmp_path / name
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose(
            "config",
            overrides=[
                "experiment=smoke",
                f"logger.save_dir={out}",
                "outputs.figures=false",  # not read here (about half of a smoke run's time)
                *overrides,
            ],
        )
    return out, run_experiment(cfg, out)


@pytest.fixture(scope="module")
def source(tmp_path_factory, gripdem_data_root, tiny_pbc_path):
    """A source model file: one epoch of the smoke run (trained once for this module)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("GRIPDEM_DATA", str(gripdem_data_root))
        out, _ = run(tmp_path_factory.mktemp("finetune"), "source", ["trainer.max_epochs=1"])
    return out / "checkpoints" / "best.safetensors"


def test_fine_tune_from_a_model_file(tmp_path, monkeypatch, gripdem_data_root, source, capsys):
    monkeypatch.setenv("GRIPDEM_DATA", str(gripdem_data_root))
    capsys.readouterr()
    out, report = run(tmp_path, "tuned", [f"model.init_from={source}", "data_seed=0"])
    printed = capsys.readouterr().out
    assert "| model (fine-tuned) |" in printed and "| before fine-tuning |" in printed
    metrics = json.loads((out / "metrics.json").read_text())
    assert math.isfinite(metrics["before/test/rmse"]) and math.isfinite(metrics["test/rmse"])
    tuned = load_checkpoint_model(out / "checkpoints" / "best.safetensors")
    original = load_checkpoint_model(source)
    assert tuned.normalizer == original.normalizer  # the source's units are kept
    changed = [
        not torch.equal(a, b)
        for a, b in zip(tuned.state_dict().values(), original.state_dict().values(), strict=True)
    ]
    assert any(changed)  # and it trained from there


def test_an_ensemble_starts_from_a_deterministic_model(
    tmp_path, monkeypatch, gripdem_data_root, source
):
    """model=ensemble from a deterministic source: every weight but the noise path is the
    source's, the run is scored and kept on the validation CRPS."""
    monkeypatch.setenv("GRIPDEM_DATA", str(gripdem_data_root))
    out, report = run(tmp_path, "ens", ["model=ensemble", f"model.init_from={source}"])
    assert math.isfinite(report["finetune/start_val_crps"]) and "test/spread_skill" in report
    original = load_checkpoint_model(source).state_dict()
    model = load_checkpoint_model(out / "checkpoints" / "best.safetensors")
    assert model.is_ensemble
    state = model.state_dict()
    assert {k for k in state if k not in original} == {
        k for k in state if k.startswith("encoder.noise_embedding.")
    }


def test_fine_tune_refuses_another_architecture(tmp_path, monkeypatch, gripdem_data_root, source):
    monkeypatch.setenv("GRIPDEM_DATA", str(gripdem_data_root))
    with pytest.raises(ValueError, match="model.init_from=.*encoder"):
        run(tmp_path, "other", [f"model.init_from={source}", "model.encoder.channels=16"])


def test_a_source_saved_before_an_option_existed_compares_with_its_default():
    """The shipped models predate ``edge_updates``: their encoder lacks the key, which means the
    encoder's default (True); a run with the default accepts them, one without refuses."""
    encoder = {"name": "contact", "channels": 64, "rounds": 4, "edge_history": 3}
    source = {"encoder": dict(encoder), "horizon": 10}
    check_architecture(source, {"encoder": {**encoder, "edge_updates": True}, "horizon": 10}, "s")
    with pytest.raises(ValueError, match="encoder=.*edge_updates.: True"):
        check_architecture(
            source, {"encoder": {**encoder, "edge_updates": False}, "horizon": 10}, "s"
        )


def test_fine_tuning_that_cannot_beat_the_start_returns_the_start(
    tmp_path, monkeypatch, gripdem_data_root, source, capsys
):
    """A learning rate of 0 cannot improve on the starting model: the run validates the start
    before its first step, keeps it, says so, and its model file holds the source's weights."""
    monkeypatch.setenv("GRIPDEM_DATA", str(gripdem_data_root))
    capsys.readouterr()
    out, report = run(tmp_path, "frozen", [f"model.init_from={source}", "finetune.lr=0"])
    assert report["finetune/kept_start"] == 1.0
    assert report["val/rmse_best"] == report["finetune/start_val_rmse"]
    assert "the start: training did not beat it on validation" in capsys.readouterr().out
    kept = load_checkpoint_model(out / "checkpoints" / "best.safetensors")
    original = load_checkpoint_model(source)
    for (name, a), b in zip(kept.state_dict().items(), original.state_dict().values(), strict=True):
        assert torch.equal(a, b), name


def test_the_start_is_kept_unless_training_beats_it_on_validation():
    start = StartingPoint(model="start", val_rmse=2.0)
    assert keep_start_unless_beaten("trained", start, 1.9) == ("trained", False)
    assert keep_start_unless_beaten("trained", start, 2.0) == ("start", True)  # a tie gains nothing
    assert keep_start_unless_beaten("trained", start, 2.1) == ("start", True)
    assert keep_start_unless_beaten("trained", start, None) == ("start", True)  # never validated
    unvalidated = StartingPoint(model="start", val_rmse=math.nan)
    assert keep_start_unless_beaten("trained", unvalidated, 2.1) == ("trained", False)


def test_fine_tuning_uses_its_own_optimiser_defaults():
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose("config", overrides=["model.init_from=pretrained:pbc"])
        scratch = compose("config")
    apply_finetune_defaults(cfg)
    apply_finetune_defaults(scratch)
    assert cfg.model.lr == cfg.finetune.lr < scratch.model.lr
    assert cfg.model.warmup_fraction == cfg.finetune.warmup_fraction
    assert scratch.model.lr == 4.0e-3  # a run from scratch keeps the preset's


def _variant(source_path, path, **changes):
    """A copy of a dataset with some fields changed (real HDF5, written atomically)."""
    from dataclasses import replace

    from gripdem.data.dataset_io import read_dataset, write_dataset

    return write_dataset(path, replace(read_dataset(source_path), **changes))


def test_one_rule_for_predict_the_api_and_fine_tuning(
    tmp_path, monkeypatch, gripdem_data_root, source, tiny_pbc_path, tiny_lebc_path, capsys
):
    """docs/reference/rules.md: the same cases through ``gripdem.predict``, the Python API and
    the runner's ``model.init_from``. Within 1 % of the training scene: applied with the same
    note everywhere. Beyond it (here the drive halved): refused as it is by predict and the API
    naming the field, accepted for fine-tuning with that note and the as-it-is row labelled.
    Another boundary kind: refused by all three, before any training."""
    import gripdem
    from gripdem.boundary import Boundary, Box
    from gripdem.data.dataset_io import read_dataset, read_meta
    from gripdem.inference.checkpoint import FINETUNE_BEYOND, IncompatibleError, check_compatible
    from gripdem.predict import main as predict

    monkeypatch.setenv("GRIPDEM_DATA", str(gripdem_data_root))
    data = read_dataset(tiny_pbc_path)
    model = gripdem.load_model(source)
    k1 = model.history_len + 1

    def api(path):
        trajectory = gripdem.read_trajectory(path)
        return model.rollout(
            trajectory.positions[0, :k1],
            trajectory.times[0, :k1],
            frames=1,
            scene=trajectory.scene,
        )

    def cli(path, name):
        out = tmp_path / f"{name}_pred.h5"
        return predict([str(source), str(path), "--frames", "1", "--out", str(out)])

    # within the tolerance: the same note from all three
    close = _variant(
        tiny_pbc_path,
        tmp_path / "close.h5",
        boundary=Boundary(Box(*(1.004 * data.box.lengths)), None),
        positions=data.positions * 1.004,
    )
    applied = check_compatible(source, read_meta(close))[1]
    assert len(applied) == 1 and applied[0].startswith("box: ") and "within the 1 %" in applied[0]
    assert check_compatible(source, read_meta(close), purpose="finetune")[1] == applied
    assert api(close).notes == applied
    capsys.readouterr()
    assert cli(close, "close") == 0 and f"note: {applied[0]}" in capsys.readouterr().out

    # beyond it: refused as it is, naming the field; fine-tuned with a note
    halved = _variant(
        tiny_pbc_path, tmp_path / "halved.h5", body_force_amplitude=0.5 * data.body_force_amplitude
    )
    with pytest.raises(IncompatibleError, match="field 'body_force_amplitude'.*beyond the 1 %"):
        api(halved)
    assert cli(halved, "halved") == 1
    assert "field 'body_force_amplitude'" in capsys.readouterr().err
    notes = check_compatible(source, read_meta(halved), purpose="finetune")[1]
    assert len(notes) == 1 and notes[0].endswith(FINETUNE_BEYOND)
    out, report = run(
        tmp_path, "halved_run", [f"model.init_from={source}", f"data.path={halved}", "data_seed=0"]
    )
    assert report["finetune/start_outside_scene"] == 1.0
    assert "| before fine-tuning (outside its training scene) |" in capsys.readouterr().out

    # another boundary kind: refused by all three
    with pytest.raises(IncompatibleError, match="field 'boundary'"):
        api(tiny_lebc_path)
    assert cli(tiny_lebc_path, "lebc") == 1 and "field 'boundary'" in capsys.readouterr().err
    with pytest.raises(IncompatibleError, match="field 'boundary'"):
        run(
            tmp_path,
            "lebc_run",
            [f"model.init_from={source}", f"data.path={tiny_lebc_path}", "scene=lebc"],
        )
    assert not (tmp_path / "lebc_run" / "checkpoints").exists()
