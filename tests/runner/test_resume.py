"""A killed training resumed with ``resume=true`` ends where the uninterrupted run ends, bit for
bit: the same weights and optimiser state, the same best checkpoint, the same test RMSE and the
same validation curve. The kills fall mid-epoch (so the loader's position and the random state
matter: the runs draw history and input noise), twice in a row, under a step budget and under an
epoch budget (where Lightning builds the loader before restoring its state)."""

from __future__ import annotations

import random

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from lightning.pytorch.callbacks import Callback

import gripdem.runner.experiment as experiment
from gripdem.data.resumable import ResumableLoader
from gripdem.run import CONFIG_DIR
from gripdem.runner.resume import get_rng_state, set_rng_state

# the tiny scene's smoke windows: 7 batches an epoch, a validation after each epoch
BUDGETS = {
    "steps": ["trainer.max_epochs=-1", "trainer.max_steps=14"],
    "epochs": ["trainer.max_epochs=2", "trainer.max_steps=-1"],
}


class Killed(RuntimeError):
    pass


class KillAt(Callback):
    """Dies after the optimiser step ``step``, before anything saves it (runs before the
    checkpoint callbacks): last.ckpt is the one of the cadence before."""

    def __init__(self, step: int):
        self.step = step

    def on_train_batch_end(self, trainer, *args) -> None:
        if trainer.global_step == self.step:
            raise Killed(f"killed after step {self.step}")


def run(out, budget, resume=False, kill_at=None, monkeypatch=None):
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose(
            "config",
            overrides=[
                "experiment=smoke",
                f"logger.save_dir={out}",
                *BUDGETS[budget],
                "model.lr_schedule=cosine",
                "model.history_noise=0.1",  # random draws in every training step
                "model.input_noise=0.1",
                "callbacks.checkpoint.every_n_train_steps=5",
                f"resume={resume}",
                "outputs.figures=false",
                "outputs.export_xyz=false",
                "outputs.predictions=false",
            ],
        )
    if kill_at is None:
        return experiment.run_experiment(cfg, out)
    build = experiment.build_trainer

    def build_and_arm(*args):
        trainer = build(*args)
        trainer.callbacks.insert(0, KillAt(kill_at))
        return trainer

    monkeypatch.setattr(experiment, "build_trainer", build_and_arm)
    with pytest.raises(Killed):
        experiment.run_experiment(cfg, out)
    monkeypatch.setattr(experiment, "build_trainer", build)


def load(path):
    return torch.load(path, weights_only=True)  # what resume=true reads: nothing unpickled


def assert_same_tensors(a, b):
    flat_a, flat_b = _flat(a), _flat(b)
    assert flat_a.keys() == flat_b.keys()
    for key, value in flat_a.items():
        assert torch.equal(value, flat_b[key]), key


def _flat(tree, prefix=""):
    if isinstance(tree, torch.Tensor):
        return {prefix: tree}
    items = tree.items() if isinstance(tree, dict) else enumerate(tree)
    out = {}
    for key, value in items:
        if isinstance(value, (dict, list, tuple, torch.Tensor)):
            out.update(_flat(value, f"{prefix}/{key}"))
    return out


@pytest.mark.parametrize("budget", sorted(BUDGETS))
def test_a_killed_run_resumes_to_the_uninterrupted_result(
    tmp_path, monkeypatch, gripdem_data_root, tiny_pbc_path, budget
):
    monkeypatch.setenv("GRIPDEM_DATA", str(gripdem_data_root))
    whole = run(tmp_path / "whole", budget)
    out = tmp_path / "killed"
    run(out, budget, kill_at=7, monkeypatch=monkeypatch)  # last.ckpt: step 5, batch 5 of 7
    assert load(out / "checkpoints" / "last.ckpt")["global_step"] == 5
    run(out, budget, resume=True, kill_at=13, monkeypatch=monkeypatch)  # again: step 10
    cut = load(out / "checkpoints" / "last.ckpt")
    assert (
        cut["global_step"] == 10
        and cut["loops"]["fit_loop"]["epoch_progress"]["current"]["completed"] == 1
    )  # mid-epoch: batch 3 of the second epoch
    resumed = run(out, budget, resume=True)

    a = load(tmp_path / "whole" / "checkpoints" / "last.ckpt")
    b = load(out / "checkpoints" / "last.ckpt")
    assert_same_tensors(a["state_dict"], b["state_dict"])
    assert_same_tensors(a["optimizer_states"], b["optimizer_states"])
    assert a["lr_schedulers"] == b["lr_schedulers"]
    best_a, best_b = whole["best_checkpoint"], resumed["best_checkpoint"]
    assert best_b.endswith("best.ckpt") and best_a.endswith("best.ckpt")
    assert_same_tensors(load(best_a)["state_dict"], load(best_b)["state_dict"])
    for key in ("test/rmse", "val/rmse_best", "steps", "epochs"):
        assert resumed[key] == whole[key], key
    assert [p[1:] for p in resumed["accuracy_curve"]] == [p[1:] for p in whole["accuracy_curve"]]
    # the training seconds carry the killed runs' time on
    seconds = [p[0] for p in resumed["accuracy_curve"]]
    assert seconds == sorted(seconds)
    assert resumed["train_seconds"] > cut["callbacks"]["ResumeCheckpoint"]["train_seconds"] > 0


def windows(loader):
    return [batch.tolist() for batch in loader]


def test_the_loader_resumes_mid_epoch_and_leaves_the_global_random_state_alone():
    data = torch.arange(10)
    first = ResumableLoader(data, batch_size=3, seed=7)
    before = torch.get_rng_state()
    epoch0 = windows(first)
    first.sampler.set_epoch(1)
    epoch1 = windows(first)
    assert torch.equal(torch.get_rng_state(), before)
    assert sorted(sum(epoch0, [])) == list(range(10)) and epoch0 != epoch1
    again = ResumableLoader(data, batch_size=3, seed=7)
    assert windows(again) == epoch0  # the order is (seed, epoch)'s, nothing else's

    it = iter(first)  # epoch 1 again: two batches, then a "kill"
    taken = [next(it).tolist(), next(it).tolist()]
    state = first.state_dict()
    assert state == {"epoch": 1, "batches": 2} and taken == epoch1[:2]
    restored = ResumableLoader(data, batch_size=3, seed=7)
    restored.load_state_dict(state)
    restored.sampler.set_epoch(1)  # what Lightning does before the epoch's first batch
    assert windows(restored) == epoch1[2:]
    assert restored.state_dict() == {"epoch": 1, "batches": 4}
    assert len(restored) == 4  # an epoch's length stays whole (Lightning counts from it)

    done = ResumableLoader(data, batch_size=3, seed=7)
    done.load_state_dict({"epoch": 0, "batches": 4})  # a finished epoch: the next from its start
    assert windows(done) == epoch1


def test_the_random_state_goes_through_a_weights_only_checkpoint(tmp_path):
    """The global generators (numpy's legacy one included: it is what a library would draw
    from) come back from a file that ``torch.load(weights_only=True)`` reads."""
    torch.manual_seed(1)
    np.random.seed(2)  # noqa: NPY002
    random.seed(3)
    torch.save({"rng": get_rng_state()}, tmp_path / "rng.ckpt")
    draws = (torch.rand(3), np.random.rand(3), random.random())  # noqa: NPY002
    torch.manual_seed(9)
    np.random.seed(9)  # noqa: NPY002
    random.seed(9)
    set_rng_state(load(tmp_path / "rng.ckpt")["rng"])
    assert torch.equal(torch.rand(3), draws[0])
    assert np.array_equal(np.random.rand(3), draws[1])  # noqa: NPY002
    assert random.random() == draws[2]
