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
from gripdem.runner.finetune import check_architecture


def run(tmp_path, name, overrides):
    out = tmp_path / name
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose(
            "config", overrides=["experiment=smoke", f"logger.save_dir={out}", *overrides]
        )
    return out, run_experiment(cfg, out)


def test_fine_tune_from_a_model_file(
    tmp_path, monkeypatch, gripdem_data_root, tiny_pbc_path, capsys
):
    monkeypatch.setenv("GRIPDEM_DATA", str(gripdem_data_root))
    source_dir, _ = run(tmp_path, "source", ["trainer.max_epochs=1"])
    source = source_dir / "checkpoints" / "best.safetensors"
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


def test_fine_tune_refuses_another_architecture(
    tmp_path, monkeypatch, gripdem_data_root, tiny_pbc_path
):
    monkeypatch.setenv("GRIPDEM_DATA", str(gripdem_data_root))
    source_dir, _ = run(tmp_path, "source", ["trainer.max_epochs=1"])
    source = source_dir / "checkpoints" / "best.safetensors"
    with pytest.raises(ValueError, match="model.init_from=.*encoder"):
        run(tmp_path, "other", [f"model.init_from={source}", "model.encoder.channels=16"])


def test_a_source_saved_before_an_option_existed_compares_with_its_default():
    """The shipped models predate ``edge_updates``: their encoder lacks the key, which means the
    encoder's default (True); a run with the default accepts them, one without refuses."""
    encoder = {"name": "interaction", "channels": 64, "rounds": 4, "edge_history": 3}
    source = {"encoder": dict(encoder), "horizon": 10}
    check_architecture(source, {"encoder": {**encoder, "edge_updates": True}, "horizon": 10}, "s")
    with pytest.raises(ValueError, match="encoder=.*edge_updates.: True"):
        check_architecture(
            source, {"encoder": {**encoder, "edge_updates": False}, "horizon": 10}, "s"
        )
