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
"""

from __future__ import annotations

from typing import Any

from omegaconf import DictConfig

from gripdem.inference.checkpoint import load_checkpoint_model
from gripdem.models.module import encoder_options

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
            a = {k: v for k, v in encoder_options(a).items() if k != "position_features"}
            b = {k: v for k, v in encoder_options(b).items() if k != "position_features"}
        if a != b:
            raise ValueError(
                f"model.init_from={spec}: the source model has {key}={a!r}, this run builds "
                f"{key}={b!r}; fine-tuning needs the same architecture (set the run's options to "
                "the source's)"
            )


def initialise(model, source, spec: str) -> None:
    """Copy the source's weights into the run's freshly built model (strict)."""
    check_architecture(dict(source.hparams), dict(model.hparams), spec)
    model.load_state_dict(source.state_dict(), strict=True)
