"""One LightningModule for GRIP++, PCT and VCT; the decoder mode and the encoder come from config.

Training minimises the mode's loss (see :mod:`gripdem.models.decoder_modes`); validation and
test roll the model out over the horizon, decode to wrapped Cartesian positions and score them
with the LE-aware RMSE of :mod:`gripdem.evaluation.metrics`, beside the baselines on the same
windows. The best checkpoint is chosen on ``val/rmse`` (the rollout), not on the training loss.

Encoders (``encoder["name"]``): ``graph_conv`` (the paper's graph convolution on the fixed
graph, :mod:`gripdem.nn.graph_conv`) and ``contact`` (learned pair messages from relative
geometry and motion, :mod:`gripdem.nn.contact`; needs the exact frame).
"""

from __future__ import annotations

import math
from typing import Any

import lightning as L
import torch

from gripdem.boundary import (
    Boundary,
    Box,
    LeesEdwards,
    affine_flow_strain,
)
from gripdem.data.encodings import make_encoding
from gripdem.data.normalizer import Normalizer
from gripdem.models import decoder_modes as modes
from gripdem.models.autoregressive import LinearAR
from gripdem.models.baselines import BASELINES
from gripdem.models.encoder_options import (
    ENCODER_OPTIONS,
    ENCODERS,
    current_encoder_name,
    uses_position_features,
)
from gripdem.models.ensemble import EnsembleMembers, check_rollout_options
from gripdem.models.evaluation import RolloutEvaluation
from gripdem.models.training import TrainingSteps, check_rollout_training
from gripdem.nn.contact import ContactEncoder, ContactGraph
from gripdem.nn.direct import DirectDecoder
from gripdem.nn.graph_conv import EdgeGraph, GraphConvEncoder
from gripdem.nn.seq2seq import TrajectoryDecoder

LR_SCHEDULES = ("constant", "cosine")
DECODERS = ("gru", "direct")


def boundary_from_hparams(scene: dict[str, Any]) -> Boundary:
    box = Box.from_lengths(scene["box"])
    if scene["boundary"] == "lees_edwards":
        le = LeesEdwards(scene["shear_rate"], int(scene["le_sign"]), scene["le_time_origin"])
        return Boundary(box, le)
    return Boundary(box)


class TrajectoryModule(TrainingSteps, RolloutEvaluation, EnsembleMembers, L.LightningModule):
    """GRIP++ / PCT / VCT on a graph encoder and the seq2seq GRU block.

    Args:
        scene: ``box``, ``boundary``, ``shear_rate``, ``le_sign``, ``le_time_origin``,
            ``diameter`` and ``frame_interval`` of the data (plain values, saved with the model).
        normalizer: :meth:`Normalizer.to_dict` of the training split's statistics.
        encoding: ``unwrapped`` (exact frame, default) | ``sincos`` | ``vct`` (the paper's).
        horizon: predicted frames f. history_len: observed steps K the model reads.
        decoder_mode: ``grip`` | ``pct`` | ``vct``; vct_shift: ``learned`` | ``exact`` (paper
            frame only); residual_base: ``constant_velocity`` | ``stay`` (paper pct/vct only).
        encoder: ``name`` (``graph_conv`` | ``contact``) and that encoder's options.
        hidden, layers, n_heads, decoder_dropout: the seq2seq GRU networks.
        lr, weight_decay: Adam (AdamW when weight_decay > 0); lr_schedule: ``constant`` |
            ``cosine`` (linear warm-up over ``warmup_fraction`` of the steps, then cosine to 0).
        input_noise: training-time Gaussian noise on the encoder's input steps, in units of
            the per-step velocity change (0: off).
        ar_prior: exact frame: add the linear AR forecast's deviation from CV to the output
            through a learned gate ``(horizon, 3)`` that starts at zero (needs ``linear_ar``).
        decoder: ``gru`` (the seq2seq GRU block) | ``direct`` (every horizon step at once from
            each particle's context vector, :mod:`gripdem.nn.direct`; the exact frame, any mode:
            the graph-conv encoder's context is its last time step).
        zero_mean: exact frame: remove the mean over particles of the deviation from CV at every
            step (the truth's mean displacement equals CV's: pair forces cancel and the drag's
            mean flow has a fixed average, docs/spec/long-rollouts.md#net-drift), so a rollout
            cannot drift as a whole.
        history_noise: exact frame: random-walk noise on the observed frames during training,
            final std in diameters (:mod:`gripdem.models.history_noise`; 0: off).
        contact_loss: exact frame: weight of the predicted frames' neighbour-pair overlaps in
            the loss (:mod:`gripdem.models.contact_loss`; 0: off).
        n_particles: needed only by ``trainable_graph=dense``.
        graph_cutoff: the graph's cut-off in diameters (scales the edge features).
        profile: mean-flow baseline profile (``cosine`` | ``linear``; default by boundary).
        linear_ar: :meth:`LinearAR.to_dict` of the fitted AR baseline (None: not reported).
        loss: ``mse`` (the conditional mean) | ``crps`` (the fair CRPS of ``members``
            members per window: an ensemble learns the spread too; :mod:`gripdem.models.ensemble`).
        members, eval_members: ensemble members per window in training and in validation/test
            (``encoder.noise_channels > 0``: one forward pass draws one member).
        loss_weighting, pair_crps: how the CRPS weighs the horizon steps and the neighbour
            pairs' relative motion (:func:`gripdem.models.decoder_modes.exact_crps_loss`).
        contact_capture, noise_scale: rollouts only: pairs closer than this gap (contact
            distances) are pulled into contact (0: off; :mod:`gripdem.inference.contacts`); the
            members' latent noise is scaled by this (inflation; 1: as trained).
        rollout_links, rollout_loss, rollout_target: rollout training
            (:mod:`gripdem.inference.rollout_training`): the links chained per training window
            (the DataModule's windows span them; 1: one link from the true history), which
            links' losses count (``last`` | ``all``), what a later link is asked to reach
            (``steps``: the true motion from where the rollout stands | ``truth``) and the
            fraction of the budget trained on each window's first link before the links are
            chained (``rollout_start``).
            Windows longer than one link are trained and validated through the link chain that
            :func:`gripdem.inference.rollout_training.attach` gives the model.
    """

    def __init__(
        self,
        scene: dict[str, Any],
        normalizer: dict[str, Any],
        encoding: str,
        horizon: int,
        history_len: int | None = None,
        decoder_mode: str = "grip",
        vct_shift: str = "learned",
        residual_base: str = "constant_velocity",
        encoder: dict[str, Any] | None = None,
        hidden: int = 350,
        layers: int = 2,
        n_heads: int = 2,
        decoder_dropout: float = 0.0,
        lr: float = 1e-4,
        weight_decay: float = 0.0,
        lr_schedule: str = "constant",
        warmup_fraction: float = 0.05,
        input_noise: float = 0.0,
        ar_prior: bool = False,
        decoder: str = "gru",
        zero_mean: bool = False,
        history_noise: float = 0.0,
        n_particles: int | None = None,
        graph_cutoff: float = 3.0,
        profile: str | None = None,
        linear_ar: dict[str, Any] | None = None,
        loss: str = "mse",
        members: int = 2,
        eval_members: int = 8,
        loss_weighting: str = "horizon",
        pair_crps: float = 0.0,
        contact_capture: float = 0.0,
        noise_scale: float = 1.0,
        rollout_links: int = 1,
        rollout_loss: str = "all",
        rollout_target: str = "steps",
        rollout_start: float = 0.0,
        contact_loss: float = 0.0,
    ):
        super().__init__()
        self.save_hyperparameters(logger=False)
        modes.check_mode(decoder_mode, encoding, vct_shift, residual_base)
        if lr_schedule not in LR_SCHEDULES:
            raise ValueError(
                f"model.lr_schedule must be one of {LR_SCHEDULES}, got {lr_schedule!r}"
            )
        check_rollout_options(contact_capture, noise_scale)
        self.boundary = boundary_from_hparams(scene)
        self.diameter = float(scene["diameter"])
        self.strain = affine_flow_strain(self.boundary, float(scene.get("frame_interval", 0.0)))
        self.encoding = make_encoding(encoding, self.boundary)
        self.exact = modes.is_exact(encoding)
        self.normalizer = Normalizer.from_dict(normalizer)
        if self.normalizer.n_channels != self.encoding.n_channels:
            raise ValueError(
                f"normaliser has {self.normalizer.n_channels} channels, encoding {encoding!r} "
                f"has {self.encoding.n_channels}"
            )
        if self.exact and not self.normalizer.change_std:
            raise ValueError("the exact frame needs the normaliser's change statistics")
        self.profile = profile or ("linear" if self.boundary.is_lees_edwards else "cosine")
        self.linear_ar = None if linear_ar is None else LinearAR.from_dict(linear_ar)
        self.baselines = tuple(b for b in BASELINES if b != "linear_ar" or self.linear_ar)
        self.ar_gate = None  # starts at zero (untrained: CV), one per horizon step and axis
        if ar_prior:
            if not self.exact or self.linear_ar is None:
                raise ValueError(
                    "model.ar_prior=true needs the exact frame (model.encoding=unwrapped) and the "
                    "fitted linear AR baseline"
                )
            self.ar_gate = torch.nn.Parameter(torch.zeros(horizon, 3))
        self.position_features = False  # x-position node features (contact encoder)
        self.encoder_name, self.encoder = self._build_encoder(dict(encoder or {}), n_particles)
        lay = modes.layout(decoder_mode, self.encoding, self.normalizer)
        self.decoder = self._build_decoder(decoder, lay, hidden, layers, n_heads, decoder_dropout)
        self.register_buffer(
            "change_std", torch.tensor(self.normalizer.change_std or (1.0,), dtype=torch.float64)
        )
        if history_noise and not self.exact:
            raise ValueError(
                "model.history_noise > 0 needs the exact frame (model.encoding=unwrapped)"
            )
        if contact_loss < 0 or (contact_loss > 0 and (not self.exact or loss != "mse")):
            raise ValueError(
                "model.contact_loss is a weight >= 0 of the predicted frames' pair overlaps in "
                f"the exact frame's MSE loss (model.encoding=unwrapped, model.loss=mse), got "
                f"{contact_loss} with model.loss={loss}, encoding {encoding!r}"
            )
        if zero_mean and not self.exact:
            raise ValueError(
                "model.zero_mean=true needs the exact frame (model.encoding=unwrapped)"
            )
        self._check_ensemble(loss, members, eval_members, loss_weighting)
        check_rollout_training(
            rollout_links, rollout_loss, rollout_target, rollout_start, loss, self.exact
        )
        #: set by gripdem.inference.rollout_training.attach (windows of several links)
        self.link_chain = None
        self._eval_store: dict[str, list] = {}
        self.accuracy_curve: list[tuple[float, int, float]] = []
        self._fit_started: float | None = None

    def _build_decoder(self, kind, lay, hidden, layers, n_heads, dropout):
        if kind not in DECODERS:
            raise ValueError(f"model.decoder must be one of {DECODERS}, got {kind!r}")
        if kind == "direct":
            if not self.exact:
                raise ValueError(
                    "model.decoder=direct needs the exact frame (model.encoding=unwrapped), got "
                    f"{self.encoding.name!r}; the paper's wrapped-space modes take "
                    "model.decoder=gru"
                )
            return DirectDecoder(
                self.encoder.out_channels,
                modes.DIRECT_STATE_CHANNELS[self.hparams.decoder_mode],
                lay.out_channels,
                int(self.hparams.horizon),
                hidden,
            )
        return TrajectoryDecoder(
            self.encoder.out_channels,
            lay.state_channels,
            lay.out_channels,
            hidden=hidden,
            layers=layers,
            n_heads=n_heads,
            dropout=dropout,
            fold=lay.fold,
            shift=lay.shift,
            context=self.encoder.context,
        )

    def _build_encoder(self, cfg: dict[str, Any], n_particles: int | None):
        """The encoder named ``cfg["name"]`` with its own options (the shared config schema
        holds the options of both; each reads its own)."""
        name = current_encoder_name(cfg.get("name", "graph_conv"))
        if name not in ENCODERS:
            raise ValueError(f"model.encoder.name must be one of {ENCODERS}, got {name!r}")
        options = {k: v for k, v in cfg.items() if k in ENCODER_OPTIONS[name]}
        if name == "graph_conv":
            return name, GraphConvEncoder(
                self.encoding.n_channels, n_particles=n_particles, **options
            )
        if not self.exact:
            raise ValueError(
                "model.encoder.name=contact reads Cartesian steps: it needs the exact frame "
                f"(model.encoding=unwrapped), got {self.encoding.name!r}"
            )
        if self.hparams.history_len is None:
            raise ValueError("the contact encoder needs history_len")
        self.position_features = uses_position_features(
            options.pop("position_features", "auto"), self.boundary
        )
        static = 2 if self.position_features else 0
        return name, ContactEncoder(int(self.hparams.history_len), static, **options)

    # ----------------------------------------------------------------------------------------
    # forward
    # ----------------------------------------------------------------------------------------
    @property
    def velocity_unit(self) -> float:
        """Spread of the steps across the flow (x and y: no mean flow in either scene), in
        metres per frame: the unit of the contact encoder's inputs."""
        std = self.normalizer.std
        return math.sqrt(0.5 * (std[0] ** 2 + std[1] ** 2))

    def _contact_inputs(self, batch) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Flow-relative steps ``(B, N, K, 3)`` in velocity units and, where the drive depends
        on x, ``sin``/``cos`` of x at the last observed frame ``(B, N, 2)``."""
        relative = modes.flow_relative_history(batch, self.boundary, self.strain)
        relative = (relative / self.velocity_unit).float()
        if self.training and self.hparams.input_noise > 0:
            scale = self.hparams.input_noise * float(self.change_std.mean()) / self.velocity_unit
            relative = relative + scale * torch.randn_like(relative)
        static = None
        if self.position_features:
            theta = 2 * math.pi * batch.last_positions[..., 0] / self.boundary.box.lx
            static = torch.stack([torch.sin(theta), torch.cos(theta)], -1).float()
        return relative, static

    def _encode(self, batch, noise: torch.Tensor | None = None) -> torch.Tensor:
        """Per-particle features ``(B, N, T, C)`` of the seq2seq block (ensembles draw noise)."""
        if self.encoder_name == "contact":
            history, static = self._contact_inputs(batch)
            if noise is None and self.is_ensemble:
                noise = self.sample_noise(history.shape[0], history.shape[1])
            return self.encoder(history, static, self.contact_graph(batch), noise)
        inputs = batch.inputs
        if self.training and self.hparams.input_noise > 0:
            inputs = inputs + self.hparams.input_noise * torch.randn_like(inputs)
        return self.encoder(inputs, self.graph(batch))

    def forward(self, batch, noise: torch.Tensor | None = None) -> torch.Tensor:
        """A :class:`~gripdem.data.batch.WindowBatch` -> ``(B, N, horizon, C)``: normalised
        per-step deltas (paper frame) or the per-step deviation from constant velocity in units
        of the velocity change (exact frame, ``C = 3``). An ensemble model draws one member:
        its latent noise ``(B, N, noise_channels)`` is ``noise`` or, when None, drawn from
        :attr:`noise_generator` (zeros give the noise-free network)."""
        mode = self.hparams.decoder_mode
        features = self._encode(batch, noise)
        if self.hparams.decoder == "direct":
            state = modes.direct_state(mode, self.boundary.box, batch.last_positions, batch.inputs)
            outputs = self.decoder(features, state)
        else:
            state = modes.initial_state(mode, self.encoding, batch.last_positions, batch.inputs)
            base = modes.residual_base(
                mode, self.hparams.residual_base, self.encoding, batch.inputs, self.normalizer
            )
            drift = None
            if self.exact and mode != "grip":
                drift = modes.state_drift(
                    mode, self.encoding, modes.last_step(batch, self.boundary)
                )
            outputs = self.decoder(features, state, base, self.hparams.horizon, drift)
        deviation = modes.outputs_to_deltas(mode, self.exact, outputs, batch.inputs)
        if self.ar_gate is not None:
            deviation = deviation + self.ar_gate * self.ar_deviation(batch)
        if self.hparams.zero_mean:
            deviation = deviation - deviation.mean(dim=1, keepdim=True)
        return deviation

    def ar_deviation(self, batch) -> torch.Tensor:
        """The linear AR forecast's per-step deviation from CV in units of the velocity change
        ``(B, N, f, 3)`` float32 (computed in float64; the exact frame's prior)."""
        same = self.linear_ar.strain == self.strain
        steps = self.linear_ar.rollout_steps(
            batch.input_positions.double().transpose(1, 2),
            batch.input_offsets.double(),
            self.hparams.horizon,
            self.boundary,
            modes.flow_relative_history(batch, self.boundary, self.strain) if same else None,
        )
        v0 = modes.last_step(batch, self.boundary)[:, :, None]
        return ((steps - v0) / self.change_std).float()

    def graph(self, batch) -> EdgeGraph:
        """The batch's fixed graph with edge features ``(E, 4)``: minimum-image vector and
        distance, in units of the cut-off (so within [-1, 1])."""
        features = torch.cat([batch.edge_vector, batch.edge_distance[:, None]], dim=1)
        return EdgeGraph(
            batch.edge_index,
            batch.edge_weight,
            features / self.hparams.graph_cutoff,
            batch.inputs.shape[0] * batch.inputs.shape[1],
        )

    def contact_graph(self, batch) -> ContactGraph:
        """The batch's neighbour pairs without the self pairs (contact encoder)."""
        keep = batch.edge_index[0] != batch.edge_index[1]
        return ContactGraph(
            batch.edge_index[:, keep],
            batch.edge_vector[keep],
            batch.edge_gap[keep],
            float(self.hparams.graph_cutoff),
            batch.inputs.shape[0] * batch.inputs.shape[1],
        )

    def decode(self, pred: torch.Tensor, batch) -> torch.Tensor:
        """Model output -> wrapped positions ``(batch, horizon, particles, 3)`` float64."""
        last = batch.last_positions.double()
        offsets = batch.target_offsets.double() if self.boundary.is_lees_edwards else None
        if self.exact:
            v0 = modes.last_step(batch, self.boundary)[:, :, None]
            steps = v0 + pred.double() * self.change_std
            return self.encoding.decode(last, steps, offsets).transpose(1, 2)
        deltas = self.normalizer.denormalize(pred.double())
        if self.hparams.decoder_mode == "vct":
            exact = self.hparams.vct_shift == "exact"
            positions = self.encoding.decode(last, deltas, offsets, exact_shift=exact)
        else:
            positions = self.encoding.decode(last, deltas, offsets)
        return positions.transpose(1, 2)
