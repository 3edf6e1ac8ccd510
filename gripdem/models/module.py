"""One LightningModule for GRIP++, PCT and VCT; the decoder mode comes from config.

Training minimises the mode's loss (see :mod:`gripdem.models.decoder_modes`); validation and
test roll the model out over the horizon, decode to wrapped Cartesian positions and score them
with the LE-aware RMSE of :mod:`gripdem.metrics`, beside the baselines on the same windows.
The best checkpoint is chosen on ``val/rmse`` (the rollout), not on the training loss.
"""

from __future__ import annotations

import math
from typing import Any

import lightning as L
import numpy as np
import torch

from gripdem.boundary import Boundary, Box, LeesEdwards
from gripdem.data.features import Normalizer, make_encoding
from gripdem.metrics import position_residuals, rmse_per_step, rmse_split
from gripdem.models import decoder_modes as modes
from gripdem.models.baselines import BASELINES, predict_baseline
from gripdem.nn.graph_conv import EdgeGraph, GraphConvEncoder
from gripdem.nn.seq2seq import TrajectoryDecoder


def boundary_from_hparams(scene: dict[str, Any]) -> Boundary:
    box = Box.from_lengths(scene["box"])
    if scene["boundary"] == "lees_edwards":
        le = LeesEdwards(scene["shear_rate"], int(scene["le_sign"]), scene["le_time_origin"])
        return Boundary(box, le)
    return Boundary(box)


class TrajectoryModule(L.LightningModule):
    """GRIP++ / PCT / VCT on a sparse graph-conv encoder.

    Args:
        scene: ``box``, ``boundary``, ``shear_rate``, ``le_sign``, ``le_time_origin``,
            ``diameter`` of the data (plain values, saved with the model).
        normalizer: :meth:`Normalizer.to_dict` of the training split's statistics.
        encoding: ``sincos`` | ``vct`` | ``unwrapped``.
        horizon: predicted frames f.
        decoder_mode: ``grip`` | ``pct`` | ``vct``; vct_shift: ``learned`` | ``exact``;
        residual_base: ``constant_velocity`` | ``stay`` (start of pct/vct, see decoder_modes).
        encoder: kwargs of :class:`GraphConvEncoder` (channels, n_blocks, trainable_graph, ...).
        hidden, layers, n_heads, decoder_dropout: the seq2seq GRU networks.
        lr, weight_decay: Adam.
        n_particles: needed only by ``trainable_graph=dense``.
        graph_cutoff: the graph's cut-off in diameters (scales the learned edge features).
        profile: mean-flow baseline profile (``cosine`` | ``linear``; default by boundary).
    """

    def __init__(
        self,
        scene: dict[str, Any],
        normalizer: dict[str, Any],
        encoding: str,
        horizon: int,
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
        n_particles: int | None = None,
        graph_cutoff: float = 3.0,
        profile: str | None = None,
    ):
        super().__init__()
        self.save_hyperparameters(logger=False)
        modes.check_mode(decoder_mode, encoding, vct_shift, residual_base)
        self.boundary = boundary_from_hparams(scene)
        self.diameter = float(scene["diameter"])
        self.encoding = make_encoding(encoding, self.boundary)
        self.normalizer = Normalizer.from_dict(normalizer)
        if self.normalizer.n_channels != self.encoding.n_channels:
            raise ValueError(
                f"normaliser has {self.normalizer.n_channels} channels, encoding {encoding!r} "
                f"has {self.encoding.n_channels}"
            )
        self.profile = profile or ("linear" if self.boundary.is_lees_edwards else "cosine")
        encoder_kwargs = dict(encoder or {})
        self.encoder = GraphConvEncoder(
            self.encoding.n_channels, n_particles=n_particles, **encoder_kwargs
        )
        channels = self.encoder.lift.out_features
        lay = modes.layout(decoder_mode, self.encoding, self.normalizer)
        self.decoder = TrajectoryDecoder(
            channels,
            lay.state_channels,
            lay.out_channels,
            hidden=hidden,
            layers=layers,
            n_heads=n_heads,
            dropout=decoder_dropout,
            fold=lay.fold,
            shift=lay.shift,
        )
        self._eval_store: dict[str, list] = {}

    # ----------------------------------------------------------------------------------------
    # forward
    # ----------------------------------------------------------------------------------------
    def forward(
        self, inputs: torch.Tensor, last_positions: torch.Tensor, graph: EdgeGraph
    ) -> torch.Tensor:
        """inputs ``(batch, particles, K, C)`` normalised deltas, last_positions
        ``(batch, particles, 3)`` wrapped -> normalised predicted deltas
        ``(batch, particles, horizon, C)``."""
        mode = self.hparams.decoder_mode
        features = self.encoder(inputs, graph)
        state = modes.initial_state(mode, self.encoding, last_positions, inputs)
        base = modes.residual_base(mode, self.hparams.residual_base, inputs, self.normalizer)
        outputs = self.decoder(features, state, base, self.hparams.horizon)
        return modes.outputs_to_deltas(mode, outputs, inputs, self.normalizer)

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

    def decode(self, pred_norm: torch.Tensor, batch) -> torch.Tensor:
        """Normalised deltas -> wrapped positions ``(batch, horizon, particles, 3)`` float64."""
        deltas = self.normalizer.denormalize(pred_norm.double())
        last = batch.last_positions.double()
        offsets = batch.target_offsets.double() if self.boundary.is_lees_edwards else None
        if self.hparams.decoder_mode == "vct":
            exact = self.hparams.vct_shift == "exact"
            positions = self.encoding.decode(last, deltas, offsets, exact_shift=exact)
        else:
            positions = self.encoding.decode(last, deltas, offsets)
        return positions.transpose(1, 2)

    def _loss(self, pred_norm: torch.Tensor, batch) -> torch.Tensor:
        pred, true = modes.loss_terms(
            self.hparams.decoder_mode, self.hparams.vct_shift, pred_norm, batch.target_deltas
        )
        return torch.mean((pred - true) ** 2)

    # ----------------------------------------------------------------------------------------
    # steps
    # ----------------------------------------------------------------------------------------
    def training_step(self, batch, batch_idx: int) -> torch.Tensor:
        pred = self(batch.inputs, batch.last_positions, self.graph(batch))
        loss = self._loss(pred, batch)
        if not torch.isfinite(loss):
            raise FloatingPointError(
                f"non-finite training loss ({loss.item()}) at global step {self.global_step} "
                f"(epoch {self.current_epoch}, batch {batch_idx}); the last good checkpoint is "
                "kept in the run's checkpoints/ folder; lower model.lr or enable gradient "
                "clipping (trainer.gradient_clip_val)"
            )
        self.log("train/loss", loss, prog_bar=True, batch_size=batch.inputs.shape[0])
        return loss

    def _evaluate(self, batch, stage: str) -> None:
        pred_norm = self(batch.inputs, batch.last_positions, self.graph(batch))
        loss = self._loss(pred_norm, batch)
        positions = self.decode(pred_norm, batch)
        if not torch.isfinite(positions).all():
            raise FloatingPointError(
                f"non-finite predicted positions in {stage} at global step {self.global_step}"
            )
        store = self._eval_store.setdefault(stage, [])
        target = batch.target_positions.double().transpose(1, 2)
        offsets = batch.target_offsets.double() if self.boundary.is_lees_edwards else None
        record = {
            "loss": float(loss),
            "n": batch.inputs.shape[0],
            "pred": positions.detach().cpu(),
            "true": target.cpu(),
            "last": batch.last_positions.double().cpu(),
            "offsets": None if offsets is None else offsets.cpu(),
            "times": batch.target_times.double().cpu(),
            "mask": batch.crossing_mask.cpu().numpy(),
            "sim_index": batch.sim_index.cpu(),
            "window_start": batch.window_start.cpu(),
        }
        observed = batch.input_positions.double().transpose(1, 2)
        in_off = batch.input_offsets.double()
        for name in BASELINES:
            record[name] = predict_baseline(
                name,
                observed,
                in_off,
                batch.target_offsets.double(),
                self.boundary.box,
                self.profile,
            ).cpu()
        store.append(record)

    def validation_step(self, batch, batch_idx: int) -> None:
        self._evaluate(batch, "val")

    def test_step(self, batch, batch_idx: int) -> None:
        self._evaluate(batch, "test")

    def _collected(self, stage: str) -> dict[str, Any]:
        records = self._eval_store.pop(stage, [])
        if not records:
            return {}
        out: dict[str, Any] = {}
        for key in ("pred", "true", "last", "times", "sim_index", "window_start", *BASELINES):
            out[key] = torch.cat([r[key] for r in records])
        out["offsets"] = (
            None if records[0]["offsets"] is None else torch.cat([r["offsets"] for r in records])
        )
        out["mask"] = np.concatenate([r["mask"] for r in records])
        total = sum(r["n"] for r in records)
        out["loss"] = sum(r["loss"] * r["n"] for r in records) / total
        return out

    def stage_metrics(self, stage: str, data: dict[str, Any]) -> dict[str, float]:
        """All scalar metrics of a stage from the collected rollouts."""
        box = self.boundary.box
        metrics = {f"{stage}/loss": data["loss"]}

        def score(pred, prefix: str) -> np.ndarray:
            res = position_residuals(pred, data["true"], box, data["offsets"])
            per_step = rmse_per_step(res)
            total = float(np.sqrt(np.mean(per_step**2)))
            metrics[f"{stage}/{prefix}"] = total
            metrics[f"{stage}/{prefix}_over_d"] = total / self.diameter
            if self.boundary.is_lees_edwards:
                crossers, others, count = rmse_split(res, data["mask"])
                metrics[f"{stage}/{prefix}_crossers"] = crossers
                metrics[f"{stage}/{prefix}_others"] = others
                metrics[f"{stage}/n_crossers"] = float(count)
            return per_step

        per_step = score(data["pred"], "rmse")
        for step, value in enumerate(per_step, start=1):
            metrics[f"{stage}/rmse_step/{step:03d}"] = float(value)
        for name in BASELINES:
            score(data[name], f"rmse_{name}")
        return metrics

    def _end_of_eval(self, stage: str) -> dict[str, Any]:
        data = self._collected(stage)
        if not data:
            return {}
        metrics = self.stage_metrics(stage, data)
        for key, value in metrics.items():
            if not math.isnan(value):
                self.log(key, value, prog_bar=key == f"{stage}/rmse", sync_dist=True)
        data["metrics"] = metrics
        return data

    def on_validation_epoch_end(self) -> None:
        self._end_of_eval("val")

    def on_test_epoch_end(self) -> None:
        self.test_results = self._end_of_eval("test")

    def configure_optimizers(self):
        return torch.optim.Adam(
            self.parameters(), lr=self.hparams.lr, weight_decay=self.hparams.weight_decay
        )
