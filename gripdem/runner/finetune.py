"""Fine-tuning: a run that starts from a trained model (``model.init_from``) instead of zeros.

``model.init_from`` is a checkpoint, a model file or ``pretrained:NAME``. The source model is read
safely (:func:`gripdem.inference.checkpoint.load_checkpoint_model`); its architecture must be the
one the config builds (encoder, decoder, widths, history, horizon: every option that shapes a
weight), or the run stops naming the option that differs. The run then keeps the source's
normalisation (its weights expect inputs in those units; the data's own statistics are not
refitted) and starts from its weights; the linear AR baseline (and with it the AR prior's
forecast) is fitted on the new data as in any run. Before training, the source model as it is is
tested on the same test windows, so the result table shows the model before and after
fine-tuning beside the baselines.

A deterministic source may start an ensemble run (``model=ensemble``,
docs/spec/long-rollouts.md#ensembles): the run's encoder adds the latent-noise path (its embeddings
start at their initialisation, every other weight is the source's), so the members start around the
source's mean forecast and training on the fair CRPS learns their spread (:func:`initialise`).

Fine-tuning never loses what it started from: the source model, as initialised, is validated
before the first step (:func:`validate_start`), and after training it stays the run's model
unless training beat it on the validation windows (:func:`keep_start_unless_beaten`). Fine-tuning
has its own optimiser defaults (``finetune.lr``, ``finetune.warmup_fraction`` in
``conf/config.yaml``: a lower learning rate and a longer warm-up than training from scratch;
:func:`apply_finetune_defaults`), chosen from the comparison in
``experiments/results/fine_tuning/finetune_defaults.md``.
"""

from __future__ import annotations

import copy
import logging
import math
from typing import Any

import lightning as L
from omegaconf import DictConfig, open_dict

from gripdem.inference.checkpoint import load_checkpoint_model
from gripdem.models.encoder_options import encoder_options

#: encoder options of the latent-noise path (an ensemble may start from a model without it)
NOISE_OPTIONS = ("noise_channels", "noise_into", "noise_neighbours")

log = logging.getLogger(__name__)

#: hyperparameters that shape the weights: they must agree between the source and the run
ARCHITECTURE = (
    "encoding",
    "decoder_mode",
    "decoder",
    "encoder",
    "hidden",
    "layers",
    "n_heads",
    "history_len",
    "horizon",
    "ar_prior",
    "graph_cutoff",
)


def load_source(cfg: DictConfig):
    """The model ``model.init_from`` names (None when the run starts from scratch)."""
    spec = cfg.model.get("init_from")
    return None if spec in (None, "") else load_checkpoint_model(spec)


def check_architecture(source_hp: dict[str, Any], run_hp: dict[str, Any], spec: str) -> None:
    """Refuse a source whose weights cannot be the run's, naming the first option that differs."""
    for key in ARCHITECTURE:
        a, b = source_hp.get(key), run_hp.get(key)
        if key == "encoder":  # the options that shape weights, defaults filled in
            skip = {"position_features"}
            if adds_noise(source_hp, run_hp):  # an ensemble from a deterministic model
                skip |= set(NOISE_OPTIONS)
            a = {k: v for k, v in encoder_options(a).items() if k not in skip}
            b = {k: v for k, v in encoder_options(b).items() if k not in skip}
        if a != b:
            raise ValueError(
                f"model.init_from={spec}: the source model has {key}={a!r}, this run builds "
                f"{key}={b!r}; fine-tuning needs the same architecture (set the run's options to "
                "the source's)"
            )


def adds_noise(source_hp: dict[str, Any], run_hp: dict[str, Any]) -> bool:
    """Whether the run is an ensemble started from a deterministic source."""
    noise = [
        int(encoder_options(hp.get("encoder")).get("noise_channels") or 0)
        for hp in (source_hp, run_hp)
    ]
    return noise[0] == 0 and noise[1] > 0


def initialise(model, source, spec: str) -> None:
    """Copy the source's weights into the run's freshly built model: every weight (strict),
    but for an ensemble started from a deterministic source, whose noise embeddings keep their
    initialisation."""
    check_architecture(dict(source.hparams), dict(model.hparams), spec)
    if not adds_noise(dict(source.hparams), dict(model.hparams)):
        model.load_state_dict(source.state_dict(), strict=True)
        return
    missing, unexpected = model.load_state_dict(source.state_dict(), strict=False)
    if unexpected or any(not k.startswith("encoder.noise_embedding.") for k in missing):
        raise ValueError(
            f"model.init_from={spec}: the source's weights do not fit this ensemble beyond its "
            f"noise path (missing {missing}, unexpected {unexpected})"
        )


def apply_finetune_defaults(cfg: DictConfig) -> None:
    """A run with ``model.init_from`` trains with ``finetune.lr``, ``finetune.warmup_fraction``
    and ``finetune.max_steps`` (each unless null) in place of the model's own ``lr`` and
    ``warmup_fraction`` and the trainer's ``max_steps``: weights that
    already fit a scene are nudged, not retrained (measured: the from-scratch learning rate made
    the shipped model worse on scenes unlike its own,
    experiments/results/fine_tuning/finetune_defaults.md)."""
    if cfg.model.get("init_from") in (None, "") or cfg.get("finetune") is None:
        return
    with open_dict(cfg):
        for key in ("lr", "warmup_fraction"):
            value = cfg.finetune.get(key)
            if value is not None:
                cfg.model[key] = float(value)
        if cfg.finetune.get("max_steps") is not None:
            cfg.trainer.max_steps = int(cfg.finetune.max_steps)


class StartingPoint:
    """The source model as the run initialised it: its weights and its validation score
    (``monitor``: the metric the run's best checkpoint is chosen on, ``val/rmse`` by default)."""

    def __init__(self, model, val_rmse: float, monitor: str = "val/rmse"):
        self.model = model
        self.val_rmse = val_rmse  # the score on `monitor` (named for the default)
        self.monitor = monitor


def validate_start(model, dm, accelerator: str = "cpu", monitor: str = "val/rmse") -> StartingPoint:
    """Validate the initialised model on the run's validation windows before the first step
    (``monitor``: the metric the best checkpoint is chosen on) and keep a copy of it."""
    trainer = L.Trainer(
        accelerator=accelerator,
        devices=1,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
    )
    trainer.validate(model, dm, verbose=False)
    # every metric reaches the callbacks; the returned results hold only the logged ones
    value = trainer.callback_metrics.get(monitor)
    score = float(value) if value is not None else math.nan
    log.info("fine-tuning starts from %s %.6g (the model as it is)", monitor, score)
    return StartingPoint(copy.deepcopy(model), score, monitor)


def keep_start_unless_beaten(trained, start: StartingPoint, best_score: float | None):
    """``(model, kept_start)``: the trained model if its best validation score (the start's
    ``monitor``) is below the starting model's, else the starting model (a tie keeps the start:
    nothing was gained)."""
    best = math.nan if best_score is None else float(best_score)
    if math.isnan(start.val_rmse) or (not math.isnan(best) and best < start.val_rmse):
        return trained, False
    log.warning(
        "fine-tuning did not beat the starting model on validation (best %s %.6g, "
        "start %.6g): the run keeps the starting model",
        start.monitor,
        best,
        start.val_rmse,
    )
    return start.model, True
