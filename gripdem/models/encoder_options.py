"""Which encoder a model config names and the options each encoder reads (one place for the
encoder names, their renames and their option lists: the module, fine-tuning's compatibility
check and the release scripts read them here)."""

from __future__ import annotations

import inspect
from typing import Any

from gripdem.boundary import Boundary
from gripdem.nn.contact import ContactEncoder
from gripdem.nn.graph_conv import GraphConvEncoder

ENCODERS = ("graph_conv", "contact")
#: former encoder names (a model file written before the rename names its encoder so): old -> new
RENAMED_ENCODERS = {"interaction": "contact"}
#: the options each encoder reads from ``model.encoder`` (``name`` and ``cutoff`` are shared:
#: the cut-off is the data's graph cut-off, ``data.graph_cutoff`` follows it)
ENCODER_OPTIONS = {
    "graph_conv": (
        *("channels", "n_blocks", "temporal_kernel", "dropout", "trainable_graph"),
        *("edge_feature_dim", "dense_init"),
    ),
    "contact": (
        *("channels", "rounds", "edge_history", "edge_updates", "position_features"),
        *("noise_channels", "noise_into", "noise_neighbours", "pair_channels"),
    ),
}
POSITION_FEATURES = ("auto", "true", "false")


def encoder_options(cfg: dict[str, Any] | None) -> dict[str, Any]:
    """The options the named encoder reads, each missing one filled with the encoder's default
    (a model saved before an option existed compares equal to one built with its default)."""
    cfg = dict(cfg or {})
    name = current_encoder_name(cfg.get("name", "graph_conv"))
    if name not in ENCODER_OPTIONS:
        return cfg
    cls = GraphConvEncoder if name == "graph_conv" else ContactEncoder
    params = inspect.signature(cls.__init__).parameters
    out: dict[str, Any] = {"name": name}
    for key in ENCODER_OPTIONS[name]:
        default = params[key].default if key in params else None
        out[key] = cfg.get(key, None if default is inspect.Parameter.empty else default)
    return out


def current_encoder_name(name: Any) -> Any:
    """The encoder's name today: a model file keeps the name it was written with."""
    return RENAMED_ENCODERS.get(name, name) if isinstance(name, str) else name


def uses_position_features(setting: Any, boundary: Boundary) -> bool:
    """x-position features (contact encoder; ``auto``: periodic drive yes, sheared cell no)."""
    setting = str(setting).lower()
    if setting not in POSITION_FEATURES:
        raise ValueError(
            f"model.encoder.position_features must be one of {POSITION_FEATURES}, got {setting!r}"
        )
    return not boundary.is_lees_edwards if setting == "auto" else setting == "true"
