"""Validation and test of a trajectory model: roll out over the horizon, decode to wrapped
Cartesian positions, score with the LE-aware RMSE (:mod:`gripdem.evaluation.metrics`) beside
every baseline on the same windows, and log the stage's metrics. The best checkpoint is chosen on
``val/rmse`` (the rollout), not on the training loss.

:class:`RolloutEvaluation` is a mixin of :class:`gripdem.models.module.TrajectoryModule`: it reads
the module's ``boundary``, ``diameter``, ``profile``, ``linear_ar``, ``baselines`` and its
``forward`` / ``decode`` / ``_loss``.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import torch

from gripdem.evaluation.ensemble_scores import (
    crps_per_step,
    rank_flatness,
    rank_histogram,
    spread_skill_per_step,
)
from gripdem.evaluation.metrics import (
    position_residuals,
    rmse_per_step,
    rmse_split,
    shown_in_tensorboard,
)
from gripdem.models.baselines import predict_baseline

#: the stage's scores on the progress bar (``prog_bar``; gripdem.runner.progress shows them as
#: RMSE in diameters and over constant velocity's); validation's metrics in diameters and
#: ratios go to the logger (gripdem.evaluation.metrics.shown_in_tensorboard), the test's are
#: logged by the runner at the last optimiser step
PROGRESS_BAR = ("rmse_over_d", "rmse_ratio_constant_velocity")


class RolloutEvaluation:
    """Validation/test steps and epoch ends of the trajectory module (see the module doc)."""

    def predict_baselines(self, batch) -> dict[str, torch.Tensor]:
        """Every baseline's wrapped positions ``(B, f, N, 3)`` on the batch's windows."""
        observed = batch.input_positions.double().transpose(1, 2)
        in_off = batch.input_offsets.double()
        out_off = batch.target_offsets.double()
        box = self.boundary.box
        return {
            name: predict_baseline(
                name, observed, in_off, out_off, box, self.profile, self.linear_ar, self.boundary
            )
            for name in self.baselines
        }

    def _evaluate(self, batch, stage: str) -> None:
        members = None
        if batch.horizon > self.hparams.horizon:  # windows of several links: chained
            loss, positions = self.chain(batch).evaluate(self, batch)
            self.record(batch, positions.to(batch.times.device), loss, stage)
            return
        if self.is_ensemble:
            outputs = self.forward_members(batch, self.hparams.eval_members)
            pred = outputs.mean(dim=0)  # decode is affine: the mean of the members' positions
            members = torch.stack([self.decode(p, batch) for p in outputs])
            loss = self._loss(outputs, batch)
        else:
            pred = self(batch)
            loss = self._loss(pred, batch)
        positions = self.decode(pred, batch)
        if not torch.isfinite(positions).all() or (
            members is not None and not torch.isfinite(members).all()
        ):
            raise FloatingPointError(
                f"non-finite predicted positions in {stage} at global step {self.global_step}"
            )
        self.record(batch, positions, float(loss), stage, members)

    def record(
        self,
        batch,
        positions: torch.Tensor,
        loss: float,
        stage: str,
        members: torch.Tensor | None = None,
    ) -> None:
        """Keep one batch's predicted wrapped positions ``(B, f, N, 3)`` (an ensemble's mean,
        with its ``members`` ``(M, B, f, N, 3)``) beside its truth and every baseline, for the
        stage's metrics (also fed by chained rollouts)."""
        store = self._eval_store.setdefault(stage, [])
        target = batch.target_positions.double().transpose(1, 2)
        offsets = batch.target_offsets.double() if self.boundary.is_lees_edwards else None
        record = {
            "loss": loss,
            "n": batch.inputs.shape[0],
            "pred": positions.detach().cpu(),
            "true": target.cpu(),
            "last": batch.last_positions.double().cpu(),
            "offsets": None if offsets is None else offsets.cpu(),
            "times": batch.target_times.double().cpu(),
            "mask": batch.crossing_mask.cpu().numpy(),
            "sim_index": batch.sim_index.cpu(),
            "window_start": batch.window_start.cpu(),
            "members": None if members is None else members.detach().cpu(),
        }
        record.update({k: v.cpu() for k, v in self.predict_baselines(batch).items()})
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
        keys = ("pred", "true", "last", "times", "sim_index", "window_start", *self.baselines)
        for key in keys:
            out[key] = torch.cat([r[key] for r in records])
        out["offsets"] = (
            None if records[0]["offsets"] is None else torch.cat([r["offsets"] for r in records])
        )
        out["mask"] = np.concatenate([r["mask"] for r in records])
        with_members = [r["members"] for r in records if r["members"] is not None]
        out["members"] = (
            torch.cat(with_members, dim=1) if len(with_members) == len(records) else None
        )
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
        rmse_curves = {"model": (per_step / self.diameter).tolist()}
        for name in self.baselines:
            rmse_curves[name] = (score(data[name], f"rmse_{name}") / self.diameter).tolist()
            metrics[f"{stage}/rmse_ratio_{name}"] = (
                metrics[f"{stage}/rmse"] / metrics[f"{stage}/rmse_{name}"]
            )
        metrics.update(self.ensemble_metrics(stage, data))
        data["scores"]["rmse_over_d"] = rmse_curves  # per step of the horizon, each forecaster
        return metrics

    def ensemble_metrics(self, stage: str, data: dict[str, Any]) -> dict[str, float]:
        """CRPS (m; per step in diameters) for the model (its members' fair CRPS; a point forecast's
        is its mean absolute error) and every baseline; for an ensemble also the spread/skill
        ratio per step, a member's RMSE and the rank histogram's extreme bins over uniform. The
        curves behind them go into ``data["scores"]`` (the run's scores figure)."""
        box, d = self.boundary.box, self.diameter
        metrics: dict[str, float] = {}
        curves: dict[str, Any] = {"crps_over_d": {}}
        data["scores"] = curves
        members = data.get("members")
        forecasts = {"crps": data["pred"] if members is None else members}
        forecasts.update({f"crps_{name}": data[name] for name in self.baselines})
        residuals = {}
        for key, forecast in forecasts.items():
            res = residuals[key] = position_residuals(forecast, data["true"], box, data["offsets"])
            per_step = crps_per_step(res)
            metrics[f"{stage}/{key}"] = float(per_step.mean())
            curves["crps_over_d"][key.removeprefix("crps_") if key != "crps" else "model"] = (
                per_step / d
            ).tolist()
            if key == "crps":
                metrics[f"{stage}/crps_over_d"] = float(per_step.mean()) / d
                for step, value in enumerate(per_step / d, start=1):
                    metrics[f"{stage}/crps_step/{step:03d}"] = float(value)
        if members is None:
            return metrics
        res = residuals["crps"]  # the members' (M, W, f, N, 3)
        metrics[f"{stage}/members"] = float(members.shape[0])
        ratio = spread_skill_per_step(res)
        metrics[f"{stage}/spread_skill"] = float(ratio.mean())
        for step, value in enumerate(ratio, start=1):
            metrics[f"{stage}/spread_skill_step/{step:03d}"] = float(value)
        metrics[f"{stage}/rmse_member"] = float(np.sqrt(np.mean(rmse_per_step(res[0]) ** 2)))
        deviation = res - res.mean(dim=0)  # a member's distance from the ensemble mean
        spread = deviation.pow(2).sum(-1).mean(dim=(0, 1, 3)).sqrt() / d  # (f,)
        metrics[f"{stage}/spread_over_d"] = float(spread.mean())
        metrics[f"{stage}/spread_last_step_over_d"] = float(spread[-1])
        histogram = rank_histogram(res)
        curves.update(spread_skill=ratio.tolist(), rank_histogram=histogram.tolist())
        top, bottom = rank_flatness(histogram)
        metrics[f"{stage}/rank_max_over_uniform"] = top
        metrics[f"{stage}/rank_min_over_uniform"] = bottom
        return metrics

    def results(self, stage: str) -> dict[str, Any]:
        """The recorded batches of a stage, collected, with their metrics under ``metrics``."""
        data = self._collected(stage)
        if data:
            data["metrics"] = self.stage_metrics(stage, data)
        return data

    def _end_of_eval(self, stage: str) -> dict[str, Any]:
        data = self.results(stage)
        if not data:
            return {}
        metrics = data["metrics"]
        on_bar = {f"{stage}/{name}" for name in PROGRESS_BAR}
        for key, value in metrics.items():
            # every metric reaches the callbacks (checkpoint, early stopping, the bar); the
            # logger gets those in diameters and ratios, never one per horizon step
            if "_step/" in key or math.isnan(value):
                continue
            logged = shown_in_tensorboard(key) and stage != "test"  # the test: at the last step
            self.log(key, value, prog_bar=key in on_bar, logger=logged, sync_dist=True)
        return data

    def on_validation_epoch_end(self) -> None:
        data = self._end_of_eval("val")
        if data and self._fit_started is not None and not self.trainer.sanity_checking:
            seconds = time.perf_counter() - self._fit_started
            ratio = data["metrics"]["val/rmse_ratio_constant_velocity"]
            self.accuracy_curve.append((seconds, int(self.global_step), float(ratio)))

    def on_test_epoch_end(self) -> None:
        self.test_results = self._end_of_eval("test")
