"""What a run writes to TensorBoard, chosen for comparing runs.

- **Run name**: the run's folder (TensorBoard names a run by its path below ``--logdir``): a
  single run's ``<scene>/<split>/<model>/<time>``, a sweep job's ``<sweep>/<swept values>``
  (:mod:`gripdem.runner.run_names`).
- **HParams** (:func:`run_hparams`): the keys given on the command line (so a sweep's keys are
  always there), then the settings that define a run (:data:`RUN_SETTINGS`), named as they are
  written on the command line, each with its type: booleans as booleans, numbers as numbers.
  No experiment summary is written: TensorBoard then builds the columns from every run in the
  log folder, marks the keys whose values differ and shows them first, so several sweeps in one
  folder share one table.
- **hp/ metrics** (:func:`hp_metrics`): the test in diameters and ratios, the overlap at the last
  predicted frame, the training time, steps per second and parameter count, logged once at the
  last optimiser step; their names sort so that TensorBoard's first five columns are the error,
  the two ratios, the overlap and the training seconds (the scatter view: error against time).
- **Scalars**: per validation the loss, RMSE / d, the ratios to every baseline and CRPS / d; at
  the last optimiser step the test's (:func:`test_scalars`); the error per step of the horizon
  as one curve per forecaster (``test_per_horizon_step/...``, x = the step of the horizon).
  No tag per horizon step, no ``epoch`` (the budget is in steps), nothing in metres.
- **Custom scalars**: one layout grouping loss, validation RMSE / d and the ratios, and the
  error per horizon step beside the baselines (:data:`LAYOUT`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from lightning.fabric.utilities.logger import _convert_params
from lightning.pytorch.utilities import rank_zero_only
from omegaconf import DictConfig, OmegaConf

from gripdem.evaluation.metrics import shown_in_tensorboard
from gripdem.runner.atomic_files import AtomicTensorBoardLogger
from gripdem.runner.run_names import hydra_choices, override_keys

#: settings that define a run, as command-line keys (a group's key holds its choice)
RUN_SETTINGS = (
    "scene",
    "split",
    "model",
    "model.decoder_mode",
    "model/encoder",
    "model.decoder",
    "model.encoder.channels",
    "model.hidden",
    "model.lr",
    "model.ar_prior",
    "data.batch_size",
    "data.history_len",
    "data.train_stride",
    "data.protocol",
    "trainer.max_steps",
    "seed",
    "data_seed",
    "preset",
    "experiment",
)
#: config groups: their HParams value is the chosen file's name
GROUPS = ("scene", "split", "model", "model/encoder", "preset", "experiment", "data", "trainer")

#: hp/ metrics: the HParams columns (TensorBoard shows the first five by name)
HP_METRICS = (
    "hp/overlap_last_frame",
    "hp/ratio_ar",
    "hp/ratio_cv",
    "hp/rmse_over_d",
    "hp/seconds_training",
    "hp/steps_per_second",
    "hp/test_crps_over_d",
    "hp/trainable_parameters",
    "hp/val_rmse_over_d_best",
)


def _task_keys() -> list[str]:
    """The keys of the job's command-line overrides (none outside Hydra; deletions left out)."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return []
    return override_keys(list(HydraConfig.get().overrides.task))


def _typed(value: Any) -> bool | float | str | None:
    """An HParams value of TensorBoard's three kinds (None: not recorded)."""
    value = getattr(value, "value", value)  # schema enums
    if value is None:
        return None
    if isinstance(value, bool):
        return value
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, (DictConfig, Mapping)):
        return None
    return str(value)


def run_hparams(cfg: DictConfig, in_sample: bool) -> dict[str, bool | float | str]:
    """``{command-line key: typed value}``: the job's own override keys first (a sweep's keys
    among them), then :data:`RUN_SETTINGS`, then ``in_sample``. Scene, split, model, encoder
    and preset are recorded by the name of what ran, other groups by the chosen file."""
    choices = hydra_choices(cfg)
    named = {  # what ran, by its own name (split.horizon=20 on split=10-5 runs 10-20)
        "scene": cfg.scene.get("name"),
        "split": cfg.split.get("name"),
        "model": cfg.model.get("name"),
        "model/encoder": cfg.model.encoder.get("name"),
        "preset": cfg.preset.get("name"),
    }
    out: dict[str, bool | float | str] = {}
    for key in [*_task_keys(), *RUN_SETTINGS]:
        if key in out:
            continue
        if key in named:
            value = named[key]
        elif key in choices or key in GROUPS:
            value = choices.get(key)
        else:
            value = OmegaConf.select(cfg, key.replace("/", "."), default=None)
        typed = _typed(value)
        if typed is not None:
            out[key] = typed
    out["in_sample"] = bool(in_sample)
    return out


def hp_metrics(
    metrics: Mapping[str, Any], diameter: float, parameters: int, steps: int
) -> dict[str, float]:
    """The hp/ metrics of a finished run (NaN where a run has no such value)."""
    seconds = float(metrics.get("train_seconds", math.nan))
    out = {
        "hp/rmse_over_d": metrics["test/rmse"] / diameter,
        "hp/ratio_cv": metrics.get("test/rmse_ratio_constant_velocity", math.nan),
        "hp/ratio_ar": metrics.get("test/rmse_ratio_linear_ar", math.nan),
        "hp/overlap_last_frame": metrics.get("test/physics/model/overlap_fraction", math.nan),
        "hp/seconds_training": seconds,
        "hp/steps_per_second": steps / seconds if seconds > 0 else math.nan,
        "hp/trainable_parameters": float(parameters),
        "hp/val_rmse_over_d_best": metrics.get("val/rmse_best", math.nan) / diameter,
    }
    if "test/spread_skill" in metrics:  # a probabilistic model: its members' CRPS
        out["hp/test_crps_over_d"] = metrics["test/crps_over_d"]
    return out


#: physics of the test rollouts, as the model's value or its ratio to the truth's
PHYSICS_VALUES = ("gr_distance", "profile_error_over_d")
PHYSICS_RATIOS = ("coordination_contact", "msd_last_over_d2", "non_affine_rms_over_d")


def test_scalars(metrics: Mapping[str, Any], diameter: float) -> dict[str, float]:
    """The test's scalars for TensorBoard (one point each, at the last optimiser step)."""
    out = {
        k: float(v) for k, v in metrics.items() if k.startswith("test/") and shown_in_tensorboard(k)
    }
    for part in ("crossers", "others"):  # Lees-Edwards: particles that crossed the x faces
        if f"test/rmse_{part}" in metrics:
            out[f"test/rmse_{part}_over_d"] = metrics[f"test/rmse_{part}"] / diameter
    for name in PHYSICS_VALUES:
        key = f"test/physics/model/{name}"
        if key in metrics:
            out[f"test/physics/{name}"] = float(metrics[key])
    for name in PHYSICS_RATIOS:
        model = metrics.get(f"test/physics/model/{name}")
        truth = metrics.get(f"test/physics/truth/{name}")
        if model is not None and truth:
            out[f"test/physics/{name}_over_truth"] = float(model) / float(truth)
    return {k: v for k, v in out.items() if math.isfinite(v)}


#: the tag group of the curves per horizon step (its name sorts after ``hp/``: TensorBoard's
#: HParams tab shows the first five metric tags by name, and those are the hp/ ones)
HORIZON_GROUP = "test_per_horizon_step"


def horizon_curves(scores: Mapping[str, Any] | None) -> dict[str, list[float]]:
    """``{tag: values per horizon step}`` from the test's score curves: RMSE / d and CRPS / d
    of the model and every baseline, the ensemble's spread/skill."""
    curves: dict[str, list[float]] = {}
    for kind in ("rmse_over_d", "crps_over_d"):
        for forecaster, values in (scores or {}).get(kind, {}).items():
            curves[f"{HORIZON_GROUP}/{kind}/{forecaster}"] = list(values)
    if scores and scores.get("spread_skill"):
        curves[f"{HORIZON_GROUP}/spread_skill/model"] = list(scores["spread_skill"])
    return curves


#: TensorBoard's Custom Scalars tab: one chart per question, every run on it
LAYOUT = {
    "training": {
        "loss (train and validation)": ["Multiline", [r"^train/loss$", r"^val/loss$"]],
        "validation RMSE / d and CRPS / d": [
            "Multiline",
            [r"^val/rmse_over_d$", r"^val/crps_over_d$"],
        ],
        "validation RMSE / baseline's": ["Multiline", [r"^val/rmse_ratio_"]],
    },
    "test": {
        "test RMSE / baseline's": ["Multiline", [r"^test/rmse_ratio_", r"^hp/ratio_"]],
        "RMSE / d per step of the horizon": ["Multiline", [r"^test_per_horizon_step/rmse_"]],
        "CRPS / d per step of the horizon": ["Multiline", [r"^test_per_horizon_step/crps_"]],
    },
}


def trial_name(out_dir: Path) -> str:
    """The HParams row's name (its *Trial ID*) of a sweep's job: what differs first, then the
    sweep (``split=190-10 @ 07-29-23``), so that TensorBoard's narrow column shows the part
    that tells rows apart. Empty for a single run: the row is then named by the run."""
    from gripdem.runner.console import in_sweep_job

    return f"{out_dir.name} @ {out_dir.parent.name}" if in_sweep_job() else ""


def session_start(hparams: Mapping[str, bool | float | str], trial: str = ""):
    """TensorBoard's HParams session record (``_hparams_/session_start_info``) as a Summary,
    each value of its own type (torch's writer turns booleans into numbers). ``trial`` names
    its row (:func:`trial_name`; one run per name: distinct runs never share a row)."""
    from tensorboard.compat.proto.summary_pb2 import Summary
    from tensorboard.plugins.hparams import metadata, plugin_data_pb2

    info = plugin_data_pb2.SessionStartInfo(start_time_secs=time.time(), group_name=trial)
    for key, value in hparams.items():
        if isinstance(value, bool):
            info.hparams[key].bool_value = value
        elif isinstance(value, float):
            info.hparams[key].number_value = value
        else:
            info.hparams[key].string_value = str(value)
    content = plugin_data_pb2.HParamsPluginData(session_start_info=info, version=0)
    summary_metadata = metadata.create_summary_metadata(content)
    return Summary(
        value=[Summary.Value(tag=metadata.SESSION_START_INFO_TAG, metadata=summary_metadata)]
    )


def session_end(status_ok: bool = True):
    """``_hparams_/session_end_info``: the run finished (or failed)."""
    from tensorboard.compat.proto.summary_pb2 import Summary
    from tensorboard.plugins.hparams import api_pb2, metadata, plugin_data_pb2

    status = api_pb2.STATUS_SUCCESS if status_ok else api_pb2.STATUS_FAILURE
    info = plugin_data_pb2.SessionEndInfo(status=status, end_time_secs=time.time())
    content = plugin_data_pb2.HParamsPluginData(session_end_info=info, version=0)
    return Summary(
        value=[
            Summary.Value(
                tag=metadata.SESSION_END_INFO_TAG,
                metadata=metadata.create_summary_metadata(content),
            )
        ]
    )


class RunLogger(AtomicTensorBoardLogger):
    """The run's TensorBoard logger: Lightning's, with ``hparams.yaml`` written atomically,
    the HParams session typed (:meth:`log_run_hparams`), no ``epoch`` scalar (training has a
    step budget: the epoch is a number nobody compares) and the custom-scalars layout."""

    @rank_zero_only
    def log_run_hparams(self, hparams: Mapping[str, bool | float | str], trial: str = "") -> None:
        """Record the run's settings (HParams session and ``hparams.yaml``) and the layout."""
        self.hparams.update(dict(hparams))
        writer = self.experiment
        writer.file_writer.add_summary(session_start(hparams, trial))
        writer.add_custom_scalars(LAYOUT)

    @rank_zero_only
    def log_hyperparams(self, params: Any, metrics: Any = None, step: Any = None) -> None:
        """Lightning's own call keeps only ``hparams.yaml``: the HParams session is the run's
        settings, written once by :meth:`log_run_hparams`."""
        self.hparams.update(_convert_params(params))

    @rank_zero_only
    def log_metrics(self, metrics: Mapping[str, float], step: int | None = None) -> None:
        super().log_metrics({k: v for k, v in metrics.items() if k != "epoch"}, step)

    @rank_zero_only
    def log_curves(self, curves: Mapping[str, list[float]]) -> None:
        """Each curve as one tag, x = the step of the horizon (1 ... f)."""
        writer = self.experiment
        for tag, values in curves.items():
            for step, value in enumerate(values, start=1):
                if math.isfinite(value):
                    writer.add_scalar(tag, value, step)

    @rank_zero_only
    def finish(self, ok: bool = True) -> None:
        """The HParams session's end (status) and the files flushed."""
        self.experiment.file_writer.add_summary(session_end(ok))
        self.finalize("success" if ok else "failed")
