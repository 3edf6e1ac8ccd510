"""Lightning's files of a run are written atomically (issue 24): a checkpoint save that dies
half-way leaves the previous checkpoint and no temporary file; hparams.yaml likewise."""

from __future__ import annotations

import pytest
import torch
import yaml

from gripdem.runner.atomic_files import AtomicCheckpointIO, AtomicTensorBoardLogger


def test_checkpoint_is_replaced_only_when_complete(tmp_path, monkeypatch):
    io = AtomicCheckpointIO()
    path = tmp_path / "checkpoints" / "last.ckpt"
    io.save_checkpoint({"step": torch.tensor(1)}, path)
    assert torch.load(path, weights_only=True)["step"] == 1

    def torn(obj, target, *args, **kwargs):
        with open(target, "wb") as handle:
            handle.write(b"PK\x03\x04 half a zip")
        raise KeyboardInterrupt  # a Ctrl-C or SIGTERM in the middle of the write

    monkeypatch.setattr(torch, "save", torn)
    with pytest.raises(KeyboardInterrupt):
        io.save_checkpoint({"step": torch.tensor(2)}, path)
    monkeypatch.undo()
    assert torch.load(path, weights_only=True)["step"] == 1
    assert [p.name for p in path.parent.iterdir()] == ["last.ckpt"]
    killed = path.with_name(".last.ckpt.tmp-99999-0badf00d")  # what a SIGKILL leaves
    killed.write_bytes(b"PK\x03\x04 half")
    io.save_checkpoint({"step": torch.tensor(3)}, path)
    assert [p.name for p in path.parent.iterdir()] == ["last.ckpt"]


def test_hparams_yaml_is_written_once_and_whole(tmp_path):
    logger = AtomicTensorBoardLogger(save_dir=str(tmp_path), name="tensorboard", version="")
    logger.log_hyperparams({"scene": "pbc", "hidden": 16})
    logger.save()
    hparams = tmp_path / "tensorboard" / "hparams.yaml"
    assert yaml.safe_load(hparams.read_text()) == {"scene": "pbc", "hidden": 16}
    assert sorted(p.name for p in hparams.parent.iterdir() if p.name.startswith(".")) == []
    logger.finalize("success")
