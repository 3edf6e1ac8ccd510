"""Rollout training (gripdem.inference.rollout_training) on the built-in DEM's tiny periodic
scene: the correction between links carries no gradient and leaves the centre of mass; only the
links that count are differentiated; a window of one link is scored exactly as the plain
training step scores it; an untrained model's rollout is constant velocity's and so is its loss;
the unrolled windows stay inside the training simulations; bad options are refused in one line
before anything runs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from checkpoints import quiet_trainer
from stress_models import perturb, smoke_model

from gripdem.boundary import minimum_image, wrap_positions
from gripdem.data.batch import collate_windows
from gripdem.data.datamodule import TrajectoryDataModule
from gripdem.data.windows import resolve_rollout_links
from gripdem.errors import SplitError
from gripdem.inference.rollout_training import LinkChain, with_targets
from gripdem.inference.stepper import StepperSettings
from gripdem.models.decoder_modes import last_step, target_steps
from gripdem.models.training import first_link

ROOT = Path(__file__).resolve().parents[2]
F = 5  # the smoke model's link (model.horizon) here
#: a split of four links of F, trained two links at a time
ROLLOUT = ("split=custom", "split.history=10", "split.horizon=20", f"model.horizon={F}")


def rollout_model(path, *overrides):
    model, dm = smoke_model(path, *ROLLOUT, "model.rollout.links=2", *overrides)
    return model, dm


def train_batch(dm, count=2):
    return collate_windows([dm.datasets["train"][i] for i in range(count)])


def test_the_split_shapes_the_training_windows(tiny_pbc_path):
    model, dm = rollout_model(tiny_pbc_path)
    assert dm.rollout_links == 2 and model.hparams.rollout_links == 2
    assert dm.datasets["train"][0]["target_positions"].shape[1] == 2 * F  # (N, 2 F, 3)
    assert dm.datasets["val"][0]["target_positions"].shape[1] == 2 * F
    assert dm.datasets["test"][0]["target_positions"].shape[1] == 20  # the split's, chained
    auto = smoke_model(tiny_pbc_path, *ROLLOUT, "model.rollout.links=auto")[1]
    assert auto.rollout_links == 2  # the smallest divisor >= 2 of the split's four links
    one = smoke_model(tiny_pbc_path, "split=custom", "split.history=10", "split.horizon=5")[1]
    assert one.rollout_links == 1  # a split of one link: windows of the truth, as before


def test_the_correction_between_links_carries_no_gradient_and_keeps_the_centre_of_mass(
    tiny_pbc_path,
):
    model, dm = rollout_model(tiny_pbc_path)
    perturb(model, scale=0.3).train()  # far enough off to overlap: the correction works
    batch = train_batch(dm)
    stepper = model.link_chain.stepper(model, batch)
    assert model.training  # the stepper leaves a model in training as it was
    inputs = stepper.link_batch()
    outputs = model(inputs)
    assert outputs.requires_grad
    raw = model.decode(outputs.detach(), inputs).numpy()  # (B, F, N, 3) before the correction
    stepper.take_link(inputs, outputs)
    kept = stepper.advance(F)
    assert sum(stepper.report.overlapping_before) > 0  # the correction moved particles
    moved = minimum_image(kept - raw, model.boundary.box)  # corrections, this link's frames
    assert np.abs(moved).max() > 1e-4 * model.diameter
    centre = np.abs(moved.sum(axis=2)).max()  # (B, F, 3) summed over the particles
    assert centre < 1e-9 * model.diameter
    following = stepper.link_batch()  # the next link reads the corrected state: no gradient
    for tensor in (following.inputs, following.input_positions, following.edge_vector):
        assert not tensor.requires_grad


def test_with_loss_last_only_the_last_link_is_differentiated(tiny_pbc_path):
    """Pushforward (model.rollout.loss=last): the rollout loss and its gradient are the last
    link's, that link reading the state the first link left (computed here step by step); the
    default (all) counts the first link's loss too."""
    model, dm = rollout_model(tiny_pbc_path, "model.rollout.loss=last")
    perturb(model).train()
    batch = train_batch(dm)
    loss = model.link_chain.loss(model, batch)
    loss.backward()
    grads = [p.grad.clone() for p in model.parameters()]
    model.zero_grad()
    stepper = model.link_chain.stepper(model, batch)
    first = stepper.link_batch()
    with torch.no_grad():
        stepper.take_link(first, model(first))
    stepper.advance(F)
    second = stepper.link_batch()
    expected = model._loss(model(second), with_targets(second, batch, F, F, model.boundary))
    expected.backward()
    assert float(loss.detach()) == pytest.approx(float(expected.detach()), rel=1e-6)
    for got, want in zip(grads, (p.grad for p in model.parameters()), strict=True):
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-9)
    every = smoke_model(tiny_pbc_path, *ROLLOUT, "model.rollout.links=2", "model.rollout.loss=all")
    every_model = perturb(every[0]).train()
    both = every_model.link_chain.loss(every_model, batch)
    assert float(both.detach()) != pytest.approx(
        float(loss.detach()), rel=1e-6
    )  # link 1's loss counts too


def test_a_window_of_one_link_is_scored_as_the_plain_training_step(tiny_pbc_path):
    model, dm = smoke_model(tiny_pbc_path, "split=custom", "split.history=10", "split.horizon=5")
    perturb(model).train()
    batch = train_batch(dm)
    assert batch.horizon == F
    plain = model._loss(model(batch), batch)
    chained = LinkChain().loss(model, batch)
    assert float(chained) == pytest.approx(float(plain), rel=1e-6)
    assert float(model.training_step(batch, 0)) == float(plain)  # the step: no chain at all


@pytest.mark.parametrize("scene", ["pbc", "lebc"])
def test_an_untrained_model_rolls_out_constant_velocity_and_scores_its_loss(request, scene):
    """Without the correction the chained rollout of an untrained model is CV's closed form
    (each frame wrapped with its own LE offset); its rollout loss is CV's (1: the exact-frame
    loss is relative to CV's error); its last link is scored, with target ``truth``, on CV's
    residual measured from CV's frame and, with target ``steps`` (the default), on the true
    steps' deviation from CV's step, across the sheared faces too."""
    model, dm = rollout_model(request.getfixturevalue(f"tiny_{scene}_path"), f"scene={scene}")
    model.train()
    train = dm.datasets["train"]
    crossing = [i for i in range(len(train)) if train[i]["crossing_mask"].any()]
    batch = collate_windows([train[i] for i in (crossing[:2] if scene == "lebc" else (0, 1))])
    chain = LinkChain(StepperSettings(contact_correction=False))
    box, boundary = model.boundary.box, model.boundary
    offsets = batch.target_offsets.numpy()[:, :, None]  # (B, 2 F, 1)
    last = batch.last_positions.numpy()  # (B, N, 3)
    v0 = last_step(batch, boundary).numpy()  # CV's step (lattice-continuous)
    continued = last[:, None] + np.arange(1, 2 * F + 1)[None, :, None, None] * v0[:, None]
    cv = wrap_positions(continued, box, offsets)  # (B, 2 F, N, 3)
    rollout = chain.positions(model, batch).numpy()
    np.testing.assert_allclose(
        minimum_image(rollout - cv, box, offsets), 0.0, atol=1e-12 * model.diameter
    )
    assert float(chain.loss(model, batch).detach()) == pytest.approx(1.0, abs=1e-6)
    stepper = chain.stepper(model, batch)
    stepper.advance(F)
    std = model.change_std.numpy()
    # target truth: from CV's frame F to the true frame F + 1, then the true steps
    second = with_targets(stepper.link_batch(), batch, F, F)
    truth = batch.target_positions.numpy().transpose(0, 2, 1, 3)  # (B, 2 F, N, 3)
    first = minimum_image(truth[:, F] - cv[:, F - 1], box, offsets[:, F])
    true_steps = target_steps(batch, boundary).numpy()  # (B, N, 2 F, 3)
    expected = np.concatenate([first[:, :, None], true_steps[:, :, F + 1 :]], axis=2)
    np.testing.assert_allclose(
        model.true_deviation(second, torch.float64).numpy(),
        (expected - v0[:, :, None]) / std,
        atol=1e-9,
    )
    # target steps: the true steps of frames F + 1 .. 2 F continued from CV's frame F
    shifted = with_targets(stepper.link_batch(), batch, F, F, boundary)
    np.testing.assert_allclose(
        model.true_deviation(shifted, torch.float64).numpy(),
        (true_steps[:, :, F:] - v0[:, :, None]) / std,
        atol=1e-9,
    )
    assert scene == "pbc" or batch.crossing_mask.numpy().any()  # LE: across the sheared faces


@pytest.mark.parametrize("protocol", ["sims", "time"])
def test_unrolled_windows_never_reach_past_the_training_frames(tiny_pbc_path, protocol):
    dm = TrajectoryDataModule(
        tiny_pbc_path,
        split="10-10",
        protocol=protocol,
        history_len=5,
        model_horizon=F,
        rollout_links=2,
        encoding="unwrapped",
        graph_cutoff=1.15,
    )
    dm.setup()
    frames = dm.meta.n_frames
    train = dm.plan.train
    assert len(train) > 0 and train.horizon == 2 * F
    assert all(w.stop <= frames for w in train)
    if protocol == "time":  # every training target before every validation target
        last_train = max(max(t) for t in train.target_frames().values())
        first_val = min(min(t) for t in dm.plan.val.target_frames().values())
        assert last_train < first_val
    else:
        assert not set(train.sims) & (set(dm.plan.val.sims) | set(dm.plan.test.sims))


def test_rollout_link_options_are_checked():
    assert resolve_rollout_links("auto", 10, 10) == 1
    assert resolve_rollout_links("auto", 100, 10) == 2
    assert resolve_rollout_links("auto", 50, 10) == 5
    assert resolve_rollout_links(5, 100, 10) == 5
    with pytest.raises(SplitError, match=r"model.rollout.links=2: the split's horizon \(10"):
        resolve_rollout_links(2, 10, 10)
    with pytest.raises(SplitError, match="model.rollout.links=3 does not divide.*1, 2, 5, 10"):
        resolve_rollout_links(3, 100, 10)
    with pytest.raises(SplitError, match="'auto' or a whole number"):
        resolve_rollout_links(0, 100, 10)


def test_run_refuses_rollout_options_in_one_line_before_anything_is_written(tmp_path):
    cases = (
        (["split=190-10", "model.rollout.links=2"], "model.rollout.links=2: the split's"),
        (["split=100-100", "model.rollout.links=3"], "model.rollout.links=3 does not divide"),
        (["split=100-100", "model=ensemble", "model.rollout.links=2"], "trains point forecasts"),
        (["split=100-100", "model.rollout.start=1.5"], "model.rollout.start is the fraction"),
    )
    for case, (options, expected) in enumerate(cases):
        out = tmp_path / f"run{case}"
        proc = subprocess.run(
            [sys.executable, "-m", "gripdem.run", *options, f"hydra.run.dir={out}"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 1, proc.stderr[-2000:]
        errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
        assert len(errors) == 1 and expected in errors[0], proc.stderr[-2000:]
        assert not out.exists()


class CountingChain(LinkChain):
    """The link chain, counting the training batches it unrolls."""

    calls = 0

    def loss(self, model, batch):
        self.calls += 1
        return super().loss(model, batch)


@pytest.mark.parametrize(("start", "chained"), [(0.0, 4), (0.5, 2), (0.9, 0)])
def test_the_links_are_chained_from_the_start_fraction_of_the_budget(tiny_pbc_path, start, chained):
    """model.rollout.start: the first steps train each window's first link only (exactly the
    one-link loss), then the links are chained; a real Trainer's step budget decides."""
    model, dm = rollout_model(tiny_pbc_path, f"model.rollout.start={start}")
    model.link_chain = chain = CountingChain()
    quiet_trainer(max_steps=4, limit_val_batches=0).fit(model, dm)
    assert chain.calls == chained
    batch = train_batch(dm)
    first = first_link(batch, F)
    assert first.horizon == F and first.target_positions.shape[2] == F
    torch.testing.assert_close(first.target_positions, batch.target_positions[:, :, :F])


def test_validation_scores_the_chained_window_as_training_and_the_test_do(tiny_pbc_path):
    """A validation window of the trained links: one rollout gives the training's rollout loss
    and the frames the chained test predicts."""
    model, dm = rollout_model(tiny_pbc_path)
    perturb(model).eval()
    batch = collate_windows([dm.datasets["val"][0]])
    loss, positions = model.link_chain.evaluate(model, batch)
    with torch.no_grad():
        assert loss == pytest.approx(float(model.link_chain.loss(model, batch)), rel=1e-6)
    torch.testing.assert_close(positions, model.link_chain.positions(model, batch))
    assert positions.shape == (1, 2 * F, dm.meta.n_particles, 3)
