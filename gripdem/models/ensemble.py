"""Ensemble members of a trajectory model: a model whose encoder draws per-particle latent noise
(``model.encoder.noise_channels > 0``, :mod:`gripdem.nn.contact`) is an *ensemble* model;
every forward pass is one member, a sample of the next frames. Trained on the fair CRPS over
``model.members`` members per window (``model.loss=crps``,
:func:`gripdem.models.decoder_modes.exact_crps_loss`), scored in validation and test on
``model.eval_members`` members (:mod:`gripdem.evaluation.ensemble_scores`).

:class:`EnsembleMembers` is a mixin of :class:`gripdem.models.module.TrajectoryModule`: it reads
the module's ``encoder``, ``exact``, ``change_std`` and its ``forward``.
"""

from __future__ import annotations

import torch

LOSSES = ("mse", "crps")
#: the largest ``contact_capture`` (contact distances): the built-in scenes' cohesion reach
MAX_CONTACT_CAPTURE = 0.1
LOSS_WEIGHTINGS = ("horizon", "step")


def check_contact_capture(value: float, name: str) -> float:
    """A ``contact_capture`` gap (contact distances: a pair of a predicted frame closer than it
    is pulled into contact, :mod:`gripdem.inference.contacts`), checked: [0,
    ``MAX_CONTACT_CAPTURE``], 0 is off."""
    if not 0.0 <= float(value) <= MAX_CONTACT_CAPTURE:
        raise ValueError(
            f"{name} is a gap in contact distances in [0, {MAX_CONTACT_CAPTURE:g}] (0: off), "
            f"got {value}"
        )
    return float(value)


def check_rollout_options(contact_capture: float, noise_scale: float) -> None:
    """The model's rollout-only hyperparameters: ``model.contact_capture`` and
    ``model.noise_scale`` (a positive finite factor on the members' latent noise)."""
    check_contact_capture(contact_capture, "model.contact_capture")
    if not 0.0 < float(noise_scale) < float("inf"):
        raise ValueError(
            f"model.noise_scale scales the members' latent noise: a positive number, got "
            f"{noise_scale}"
        )


class EnsembleMembers:
    """Noise draws and members of an ensemble model (see the module doc)."""

    #: the source of the members' noise (None: torch's global generator); set by the rollout
    #: from its seed
    noise_generator: torch.Generator | None = None

    def _check_ensemble(self, loss: str, members: int, eval_members: int, weighting: str) -> None:
        if loss not in LOSSES:
            raise ValueError(f"model.loss must be one of {LOSSES}, got {loss!r}")
        if weighting not in LOSS_WEIGHTINGS:
            raise ValueError(
                f"model.loss_weighting must be one of {LOSS_WEIGHTINGS}, got {weighting!r}"
            )
        if weighting == "step" and loss != "crps":
            raise ValueError("model.loss_weighting=step weighs the CRPS: it needs model.loss=crps")
        if loss == "crps" and not self.exact:
            raise ValueError("model.loss=crps needs the exact frame (model.encoding=unwrapped)")
        if int(members) < 1 or int(eval_members) < 1:
            raise ValueError(
                f"model.members and model.eval_members must be >= 1, got {members} and "
                f"{eval_members}"
            )
        if self.is_ensemble and loss == "crps" and int(members) < 2:
            raise ValueError(
                "model.loss=crps trains an ensemble on at least 2 members per window (the fair "
                f"CRPS's spread term needs a pair), got model.members={members}"
            )

    @property
    def is_ensemble(self) -> bool:
        """Whether a forward pass draws latent noise (one ensemble member per pass)."""
        return int(getattr(self.encoder, "noise_channels", 0)) > 0

    def sample_noise(self, batch_size: int, particles: int) -> torch.Tensor:
        """Standard normal latent noise ``(batch, particles, noise_channels)`` from
        :attr:`noise_generator`; outside training scaled by ``hparams.noise_scale`` (inflation of
        an under-dispersed ensemble, chosen on validation data)."""
        gen = self.noise_generator
        device = gen.device if gen is not None else self.change_std.device
        shape = (batch_size, particles, self.encoder.noise_channels)
        noise = torch.randn(shape, generator=gen, device=device).to(self.change_std.device)
        scale = 1.0 if self.training else float(self.hparams.get("noise_scale", 1.0))
        return noise if scale == 1.0 else scale * noise

    def forward_members(self, batch, members: int) -> torch.Tensor:
        """``members`` forward passes with independent noise: ``(M, B, N, horizon, C)`` (a
        deterministic model gives one)."""
        m = int(members) if self.is_ensemble else 1
        return torch.stack([self(batch) for _ in range(m)])
