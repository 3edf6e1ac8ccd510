"""Structured schema of the runner's config: the nodes that must be right.

Registered in Hydra's ConfigStore as ``config_schema`` and listed first in
``conf/config.yaml``'s defaults, so that Hydra validates every group option and every
command-line override while composing: an unknown key, a wrong type (``split.horizon=ten``)
or a value outside a fixed set (``model.decoder_mode=gripp``) fails before anything runs,
with a message naming the key and what was expected. Scene physics and preset sizes are
checked by :class:`gripdem.dem.config.GeneratorConfig`; trainer arguments by Lightning.
Option names removed in gripdem 0.2.0 (``model.fast_steps``, ``data.protocol=paper``, ...) are
refused by name before Hydra composes (:mod:`gripdem.runner.renamed_options`).

Scene x model specifics live in :func:`check_combination` (the one place for them).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, DictConfig, OmegaConf

from gripdem.runner.config_checks import check_rollout_training, check_split_fits_the_preset

log = logging.getLogger(__name__)


class DecoderMode(Enum):
    grip = "grip"
    pct = "pct"
    vct = "vct"


class VctShift(Enum):
    learned = "learned"
    exact = "exact"


class ResidualBase(Enum):
    constant_velocity = "constant_velocity"
    stay = "stay"


class TrainableGraph(Enum):
    edge = "edge"
    dense = "dense"
    none = "none"


class EncoderName(Enum):
    graph_conv = "graph_conv"
    contact = "contact"


class PositionFeatures(Enum):
    auto = "auto"
    true = "true"
    false = "false"


class DecoderKind(Enum):
    direct = "direct"
    gru = "gru"


class LrSchedule(Enum):
    constant = "constant"
    cosine = "cosine"


class RolloutLoss(Enum):
    last = "last"
    all = "all"


class RolloutTarget(Enum):
    steps = "steps"
    truth = "truth"


class EncodingName(Enum):
    sincos = "sincos"
    vct = "vct"
    unwrapped = "unwrapped"


class Protocol(Enum):
    sims = "sims"
    time = "time"
    in_sample = "in_sample"
    auto = "auto"


@dataclass
class SplitSchema:
    history: int = MISSING
    horizon: int = MISSING
    name: str = MISSING


@dataclass
class EncoderSchema:
    """The options of both encoders (each reads its own, see gripdem.models.module)."""

    name: EncoderName = EncoderName.graph_conv
    cutoff: float = 3.0
    channels: int = 64
    # graph_conv
    n_blocks: int = 3
    temporal_kernel: int = 3
    dropout: float = 0.0
    trainable_graph: TrainableGraph = TrainableGraph.edge
    edge_feature_dim: int = 4
    dense_init: str = "zeros"
    # contact
    rounds: int = 3
    edge_history: int = 3
    edge_updates: bool = True
    position_features: PositionFeatures = PositionFeatures.auto
    noise_channels: int = 0
    noise_into: str = "rounds"
    noise_neighbours: bool = False
    pair_channels: Optional[int] = None


@dataclass
class RolloutSchema:
    """Rollout training (gripdem.inference.rollout_training): links chained per training window
    (``auto`` or a whole number, gripdem.data.windows.resolve_rollout_links), which links'
    losses count and what a later link is asked to reach."""

    links: Any = 1
    loss: RolloutLoss = RolloutLoss.all
    target: RolloutTarget = RolloutTarget.steps
    start: float = 0.5


@dataclass
class ModelSchema:
    encoder: EncoderSchema = field(default_factory=EncoderSchema)
    name: str = MISSING
    decoder_mode: DecoderMode = DecoderMode.grip
    encoding: EncodingName = EncodingName.unwrapped
    vct_shift: VctShift = VctShift.learned
    residual_base: ResidualBase = ResidualBase.constant_velocity
    hidden: int = 350
    layers: int = 2
    n_heads: int = 2
    decoder_dropout: float = 0.0
    train_steps: int = 1820
    lr: float = 1e-4
    weight_decay: float = 0.0
    lr_schedule: LrSchedule = LrSchedule.constant
    warmup_fraction: float = 0.05
    input_noise: float = 0.0
    ar_prior: bool = False
    horizon: Optional[int] = None
    init_from: Optional[str] = None
    decoder: DecoderKind = DecoderKind.gru
    zero_mean: bool = False
    history_noise: float = 0.0
    loss: str = "mse"
    members: int = 2
    eval_members: int = 8
    loss_weighting: str = "horizon"
    pair_crps: float = 0.0
    contact_capture: float = 0.0
    noise_scale: float = 1.0
    rollout: RolloutSchema = field(default_factory=RolloutSchema)
    contact_loss: float = 0.0
    monitor: str = "val/rmse"


@dataclass
class BaselinesSchema:
    # lags of the linear autoregressive baseline (null: min(history_len, 10))
    ar_lags: Optional[int] = None
    # relative ridge penalty of its least-squares fit
    ar_ridge: float = 1e-6


@dataclass
class DataSchema:
    path: Optional[str] = None
    expect_boundary: Optional[str] = None
    protocol: Protocol = Protocol.auto
    fractions: dict[str, float] = field(default_factory=dict)
    sims: dict[str, Optional[list[int]]] = field(default_factory=dict)
    simulations: Optional[list[int]] = None
    in_sample_windows: int = 1
    history_len: Optional[int] = None
    train_stride: int = 1
    eval_stride: Optional[int] = None
    encoding: EncodingName = EncodingName.unwrapped
    normalise: bool = True
    graph_cutoff: float = 3.0
    graph_alpha: float = 0.001
    graph_cache_mb: float = 256.0
    memory_mb: float = 2048.0
    model_horizon: Optional[int] = None
    rollout_links: Any = 1
    batch_size: int = 1
    num_workers: int = 0
    pin_memory: bool = False


@dataclass
class FinetuneSchema:
    # optimiser settings of a run with model.init_from (null: the model's own)
    lr: Optional[float] = None
    warmup_fraction: Optional[float] = None
    max_steps: Optional[int] = None


@dataclass
class OutputsSchema:
    predictions: bool = True
    figures: bool = True
    export_xyz: bool = True
    export_windows: Optional[int] = 1


@dataclass
class LoggerSchema:
    """TensorBoard logger (conf/logger/tensorboard.yaml): event files in ``save_dir`` (the
    run's folder, so that TensorBoard names the run by it)."""

    save_dir: str = MISSING
    name: str = ""
    version: str = ""
    flush_secs: int = 10


@dataclass
class StudyTrialSchema:
    """Set by the study sweeper (``hparams_search=optuna``, :mod:`gripdem.study`) on each
    trial's command line: the run is trial ``number`` of ``study`` in ``storage``; null
    outside a study."""

    storage: Optional[str] = None
    study: Optional[str] = None
    number: Optional[int] = None
    heartbeat_seconds: float = 10.0
    # test the trial's model (and write its predictions and figures): false in a study, which
    # ranks on validation; retrain the best setting and test it
    test: bool = False


@dataclass
class ConfigSchema:
    scene: Any = MISSING
    preset: Any = MISSING
    split: SplitSchema = field(default_factory=SplitSchema)
    data: DataSchema = field(default_factory=DataSchema)
    model: ModelSchema = field(default_factory=ModelSchema)
    baselines: BaselinesSchema = field(default_factory=BaselinesSchema)
    trainer: dict[str, Any] = field(default_factory=dict)
    logger: LoggerSchema = field(default_factory=LoggerSchema)
    callbacks: Any = None
    seed: int = 0
    torch_threads: Optional[int] = None
    data_seed: int = 0
    resume: bool = False
    finetune: FinetuneSchema = field(default_factory=FinetuneSchema)
    optimized_metric: str = "val/rmse_best"
    outputs: OutputsSchema = field(default_factory=OutputsSchema)
    study_trial: StudyTrialSchema = field(default_factory=StudyTrialSchema)


def register() -> None:
    """Make ``config_schema`` known to Hydra and the sweep's job-name resolver to OmegaConf
    (idempotent)."""
    from gripdem.runner.run_names import register_resolver

    ConfigStore.instance().store(name="config_schema", node=ConfigSchema)
    register_resolver()


def plain(node: Any) -> Any:
    """A config node as plain Python values (enums as their names)."""
    if isinstance(node, DictConfig):
        return OmegaConf.to_container(node, resolve=True, enum_to_str=True)
    return node


def given_data_path(cfg: DictConfig) -> Path | None:
    """``data.path`` as a path, refused naming the option when no such file exists; None for
    the built-in scene. Light (no torch): ``python -m gripdem.run`` checks it before importing
    Lightning, so a wrong path fails in a second, not after the seconds of that import."""
    if cfg.data.path is None:
        return None
    path = Path(cfg.data.path).expanduser()
    if not path.exists():
        raise FileNotFoundError(f"data.path={cfg.data.path}: no such file")
    return path


def check_combination(cfg: DictConfig, notes: bool = True) -> None:
    """Scene x model x data specifics, in one place. Raises on what cannot work, logs what
    works but is probably not meant (``notes=False``: checks only; the runner checks every
    job before it starts and again, with the notes, inside the job)."""
    if not notes:
        previous = log.disabled
        log.disabled = True
        try:
            check_combination(cfg)
        finally:
            log.disabled = previous
        return
    mode = str(cfg.model.decoder_mode.value)
    boundary = cfg.scene.get("boundary")
    if cfg.data.encoding != cfg.model.encoding:
        raise ValueError(
            f"data.encoding={cfg.data.encoding.value} differs from model.encoding="
            f"{cfg.model.encoding.value}; leave data.encoding to follow the model"
        )
    exact = cfg.model.encoding == EncodingName.unwrapped
    if mode == "vct" and boundary == "periodic" and not exact:
        log.warning(
            "model=vct_paper on a periodic scene: the LE shift channels are identically zero; "
            "vct reduces to pct with a different loss"
        )
    if cfg.model.decoder == DecoderKind.direct and not exact:
        raise ValueError(
            "model.decoder=direct reads the exact frame: it needs model.encoding=unwrapped, got "
            f"{cfg.model.encoding.value}; the paper's wrapped-space modes take model.decoder=gru "
            "(allowed: model.decoder=direct|gru with unwrapped, gru with sincos or vct)"
        )
    if cfg.model.vct_shift == VctShift.exact and mode != "vct":
        raise ValueError("model.vct_shift=exact is only read by model.decoder_mode=vct")
    if cfg.model.encoder.name == EncoderName.contact and not exact:
        raise ValueError(
            "model.encoder.name=contact needs the exact frame: model.encoding=unwrapped, "
            f"got {cfg.model.encoding.value}"
        )
    for option, on in (
        ("ar_prior=true", cfg.model.ar_prior),
        ("zero_mean=true", cfg.model.zero_mean),
        ("history_noise>0", cfg.model.history_noise > 0),
    ):
        if on and not exact:
            raise ValueError(
                f"model.{option} works in the exact frame: it needs model.encoding=unwrapped, "
                f"got {cfg.model.encoding.value} (the paper's models: leave it at its default)"
            )
    if not exact:
        log.info(
            "model.encoding=%s: the paper's wrapped-space decoding (for reproduction; not exact "
            "for LE crossers)",
            cfg.model.encoding.value,
        )
    if cfg.data.protocol == Protocol.in_sample:
        log.warning(
            "data.protocol=in_sample tests on the training windows (train = test): report it "
            "as in-sample"
        )
    check_split_fits_the_preset(cfg)
    check_rollout_training(cfg, exact)
    _check_logger_options(cfg.get("logger") or {})
    history = cfg.data.history_len if cfg.data.history_len is not None else cfg.split.history
    if cfg.model.encoder.n_blocks > 0 and history < 1:
        raise ValueError(f"data.history_len must be >= 1, got {history}")
    lags = cfg.baselines.ar_lags
    if lags is not None and not 1 <= lags <= history:
        raise ValueError(
            f"baselines.ar_lags={lags} must lie in 1..{history}, the history the windows hold "
            f"(data.history_len {history}; null: min(history_len, 10))"
        )


def _check_logger_options(options) -> None:
    """Refuse a logger option that neither Lightning's TensorBoardLogger nor TensorBoard's
    SummaryWriter takes (``+logger.max_queue=20`` is one; a typo is not), in one line. The
    schema's own keys need no look-up (and no import of Lightning before a sweep starts)."""
    extra = set(options) - set(LoggerSchema.__dataclass_fields__)
    if not extra:
        return
    import inspect

    from lightning.pytorch.loggers import TensorBoardLogger
    from torch.utils.tensorboard import SummaryWriter

    allowed = set(LoggerSchema.__dataclass_fields__)
    for function in (TensorBoardLogger.__init__, SummaryWriter.__init__):
        allowed |= set(inspect.signature(function).parameters) - {"self", "kwargs", "args"}
    unknown = sorted(extra - allowed)
    if unknown:
        raise ValueError(
            f"logger.{unknown[0]}: not an option of the TensorBoard logger; allowed: "
            f"{', '.join(sorted(allowed))}"
        )
