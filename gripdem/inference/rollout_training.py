"""Rollout training: a model that learns on its own chained, corrected rollouts.

A model whose link (``model.horizon`` = ``f`` frames per forward pass) is shorter than the
split's horizon is used by chaining links (:class:`~gripdem.inference.stepper.Stepper`): every
link after the first reads the frames that the previous links predicted, after the contact
correction. Trained on windows of the truth only, the model never sees such states: its errors
compound, its raw frames overlap, and the correction has to repair them.

With ``model.rollout.links = L > 1`` a training window spans ``K + 1 + L f`` frames and is
unrolled as the test unrolls it, through the same stepper: link 1 reads the true history; each
later link reads the stepper's state (the model's own frames, corrected without gradient, as at
test: the correction is not differentiable). Every link is scored against the true frames of its
span. ``model.rollout.target`` says what a later link is asked to reach:

- ``steps`` (as learned simulators train on noisy histories, Sanchez-Gonzalez et al. 2020): the
  true motion continued from where the rollout stands, the true frames shifted by the rollout's
  offset from the truth at the link's start. The model learns to move its own states as the
  DEM moves true ones; the offset it has accumulated is not asked back.
- ``truth``: the true frames themselves. The first step must then also undo the offset the
  earlier links accumulated, which the model cannot see: measured, that unpredictable part
  drowns the signal (docs/explanation/models.md#rollout-training).

The loss is the plain training loss of a batch whose history is the rollout's and whose targets
are these (:meth:`~gripdem.models.training.TrainingSteps.true_deviation`).

``model.rollout.loss`` says which links' losses count:

- ``last``: the pushforward trick (Brandstetter et al., ICLR 2022): links 1..L-1 run without
  gradient, the loss is the last link's. One backward pass per window.
- ``all``: the mean of every link's loss, each link's gradient through its own forward pass (its
  inputs are the detached rollout). L backward passes per window.

Validation windows span the same ``L`` links and are chained the same way, without gradient
(:func:`chained_positions`), so the best checkpoint is the best at what training trains for.

The models layer cannot import the stepper: :func:`attach` gives a
:class:`~gripdem.models.module.TrajectoryModule` its :class:`LinkChain` (the runner does it for
every model it trains).

Shapes: a :class:`~gripdem.data.batch.WindowBatch` of ``B`` windows, ``N`` particles, ``K``
observed steps and ``L f`` target frames; positions ``(B, L f, N, 3)``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from gripdem.boundary import minimum_image, wrap_positions
from gripdem.inference.stepper import Stepper, StepperSettings


class LinkChain:
    """Chains a model's links over a window's frames with the stepper (the contact correction
    between frames, as at test); ``settings``: the stepper's (default: the stable setting,
    float32, as :func:`gripdem.runner.chained_evaluation.evaluate_chained` tests)."""

    def __init__(self, settings: StepperSettings | None = None):
        self.settings = settings or StepperSettings()

    def stepper(self, model, batch) -> Stepper:
        """A stepper at ``batch``'s observed frames; the model keeps its training mode."""
        observed = batch.input_positions.detach().transpose(1, 2).cpu().numpy()
        times = batch.input_times.detach().cpu().numpy()
        training = model.training
        stepper = Stepper(model, observed, times, self.settings)
        model.train(training)
        return stepper

    def loss(self, model, batch) -> torch.Tensor:
        """The rollout loss of one training batch (see the module doc): a scalar with gradient
        through the links that count."""
        return self._unroll(model, batch, keep=False)[0]

    @torch.no_grad()
    def evaluate(self, model, batch) -> tuple[float, torch.Tensor]:
        """Validation of a window of the links trained: its rollout loss (as training scores
        it) and its predicted frames ``(B, L f, N, 3)`` float64 wrapped, from one rollout."""
        loss, frames = self._unroll(model, batch, keep=True)
        return float(loss), torch.from_numpy(np.concatenate(frames, axis=1))

    def _unroll(self, model, batch, keep: bool) -> tuple[torch.Tensor, list[np.ndarray]]:
        """The links of ``batch``'s windows chained: the loss of those that count and, with
        ``keep``, every link's kept frames ``(B, f, N, 3)`` (else only the frames the next
        link reads)."""
        f = int(model.hparams.horizon)
        links = batch.horizon // f
        if links * f != batch.horizon:
            raise ValueError(
                f"a rollout-training window of {batch.horizon} target frames is not a whole "
                f"number of links of model.horizon={f}"
            )
        every = model.hparams.get("rollout_loss", "all") == "all"
        shift = model.boundary if model.hparams.get("rollout_target", "steps") == "steps" else None
        stepper = self.stepper(model, batch)
        losses, frames = [], []
        for link in range(links):
            scored = every or link == links - 1
            inputs = stepper.link_batch()
            with torch.set_grad_enabled(scored and torch.is_grad_enabled()):
                outputs = model(inputs)
            if scored:
                targets = with_targets(inputs, batch, link * f, f, shift)
                losses.append(model._loss(outputs, targets))
            if link < links - 1 or keep:
                stepper.take_link(inputs, outputs)
                frames.append(stepper.advance(f))
                if stepper.stopped is not None:
                    raise FloatingPointError(
                        f"rollout training: link {link + 1} of {links}: {stepper.stopped} (lower "
                        "model.lr, or train with model.rollout.links=1 first)"
                    )
        return torch.stack(losses).mean(), frames

    @torch.no_grad()
    def positions(self, model, batch) -> torch.Tensor:
        """The window's predicted frames, chained over its horizon ``(B, f_window, N, 3)``
        float64 wrapped (the test of a chained model: any horizon, not only whole links)."""
        stepper = self.stepper(model, batch)
        predicted = stepper.advance(batch.horizon)
        if stepper.stopped is not None:
            raise FloatingPointError(f"chained rollout: {stepper.stopped}")
        return torch.from_numpy(predicted)


def with_targets(inputs, batch, first: int, count: int, boundary=None):
    """The link batch ``inputs`` (the rollout's history) with ``batch``'s true frames
    ``first .. first + count - 1`` of its horizon as targets ``(B, N, count, 3)``. With the
    scene's ``boundary``: each particle's true frames moved by the rollout's offset from the
    truth at the link's start (the true steps continued from the rollout's last frame), wrapped
    with each frame's LE offset. The quantities derived from the history, computed for the
    forward pass, are shared."""
    targets = batch.target_positions[:, :, first : first + count].double()
    if boundary is not None and first > 0:
        box = boundary.box
        offsets = batch.target_offsets.double()  # (B, horizon)
        start = batch.target_positions[:, :, first - 1].double()  # the truth at the link's start
        drift = minimum_image(
            inputs.last_positions.double() - start, box, offsets[:, first - 1, None]
        )  # (B, N, 3)
        targets = wrap_positions(
            targets + drift[:, :, None], box, offsets[:, None, first : first + count]
        )
    out = replace(
        inputs,
        target_positions=targets,
        target_deltas=None,
        crossing_mask=None,
        sim_index=batch.sim_index,
        window_start=batch.window_start,
    )
    out.__dict__["_derived"] = inputs.__dict__.get("_derived", {})
    return out


def attach(model, settings: StepperSettings | None = None):
    """Give ``model`` the link chain that its rollout training and chained validation use;
    returns the model."""
    model.link_chain = LinkChain(settings)
    return model


def chained_positions(model, batch, settings: StepperSettings | None = None) -> torch.Tensor:
    """``batch``'s windows predicted by chaining ``model`` over their horizon ``(B, f, N, 3)``
    with the stepper's ``settings`` (the chained test)."""
    return LinkChain(settings).positions(model, batch)
