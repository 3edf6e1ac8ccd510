"""One experiment: resolve the data, train, test out of sample beside the baselines, report.

:func:`run_experiment` does the work of ``python -m gripdem.run`` for one composed config and
one output directory. Everything it writes goes under that directory (Hydra does not change
the working directory):

    events.out.tfevents.*  TensorBoard: scalars, HParams (hp/ metrics), figures as images; the
                        folder is the run (gripdem.runner.tensorboard_log), hparams.yaml beside
    checkpoints/        best.ckpt (lowest val/rmse), last.ckpt, best.safetensors (shareable)
    predictions.h5      test windows: prediction, truth, baselines (gripdem.evaluation.predictions)
    figures/*.png       the paper's figures (gripdem.plots.run)
    trajectories/*.xyz  predicted and true trajectories for OVITO / ParaView
    metrics.json        final metrics, baselines, timings, data summary
"""

from __future__ import annotations

import json
import logging
import math
import time
from pathlib import Path
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import EarlyStopping, ModelCheckpoint
from omegaconf import DictConfig

from gripdem.data.datamodule import TrajectoryDataModule
from gripdem.data.h5io import atomic_write_text
from gripdem.dem.output import ensure_scene_dataset
from gripdem.inference.checkpoint import (
    FINETUNE_BEYOND,
    check_compatible,
    data_scene,
    export_run_model,
    load_checkpoint_model,
    load_model,
)
from gripdem.inference.rollout_training import attach
from gripdem.models.autoregressive import LinearAR, fit_on_training_frames
from gripdem.models.module import TrajectoryModule
from gripdem.runner.atomic_files import AtomicCheckpointIO
from gripdem.runner.chained_evaluation import evaluate_chained
from gripdem.runner.config_schema import check_combination, given_data_path, plain
from gripdem.runner.console import lightning_info_muted, quiet_console
from gripdem.runner.finetune import (
    apply_finetune_defaults,
    initialise,
    keep_start_unless_beaten,
    load_source,
    validate_start,
)
from gripdem.runner.outputs import (
    physics_metrics,
    result_table,
    to_predictions,
    trial_report,
    write_outputs,
)
from gripdem.runner.progress import StepBudgetBar
from gripdem.runner.resume import ResumeCheckpoint, resumed_seconds
from gripdem.runner.tensorboard_log import (
    RunLogger,
    horizon_curves,
    hp_metrics,
    run_hparams,
    test_scalars,
    trial_name,
)

log = logging.getLogger(__name__)


def resolve_data_path(cfg: DictConfig) -> Path:
    """``data.path`` if given, else the built-in scene dataset (generated once, cached)."""
    path = given_data_path(cfg)
    if path is not None:
        return path
    backend = cfg.get("generator_backend", "numba")
    return ensure_scene_dataset(
        plain(cfg.scene), plain(cfg.preset), seed=cfg.data_seed, backend=backend
    )


def build_datamodule(cfg: DictConfig, path: Path) -> TrajectoryDataModule:
    dm = TrajectoryDataModule.from_config(
        plain(cfg.data), plain(cfg.split), path=str(path), seed=int(cfg.seed)
    )
    dm.setup("fit")
    return dm


def fit_linear_ar(cfg: DictConfig, dm: TrajectoryDataModule) -> LinearAR:
    """The linear AR baseline on the training windows (lags: ``baselines.ar_lags`` or
    ``min(history_len, 10)``)."""
    lags = cfg.baselines.ar_lags  # checked against the history by check_combination
    lags = min(int(dm.plan.history_len), 10) if lags is None else int(lags)
    return fit_on_training_frames(dm, lags, float(cfg.baselines.ar_ridge))


def accelerator(cfg: DictConfig) -> str:
    """The accelerator of one-process evaluation (validation of a start, the test)."""
    return cfg.trainer.accelerator if cfg.trainer.get("strategy") is None else "cpu"


def build_model(cfg: DictConfig, dm: TrajectoryDataModule) -> TrajectoryModule:
    """The configured model for ``dm``'s data, with the link chain of rollout training
    (:mod:`gripdem.inference.rollout_training`)."""
    meta = dm.meta
    model_cfg = plain(cfg.model)
    model = TrajectoryModule(
        scene=data_scene(meta),
        normalizer=dm.normalizer.to_dict(),
        encoding=model_cfg["encoding"],
        horizon=dm.model_horizon,
        history_len=int(dm.plan.history_len),
        decoder_mode=model_cfg["decoder_mode"],
        vct_shift=model_cfg["vct_shift"],
        residual_base=model_cfg["residual_base"],
        encoder=model_cfg["encoder"],
        hidden=model_cfg["hidden"],
        layers=model_cfg["layers"],
        n_heads=model_cfg["n_heads"],
        decoder_dropout=model_cfg["decoder_dropout"],
        lr=model_cfg["lr"],
        weight_decay=model_cfg["weight_decay"],
        lr_schedule=model_cfg["lr_schedule"],
        warmup_fraction=model_cfg["warmup_fraction"],
        input_noise=model_cfg["input_noise"],
        ar_prior=model_cfg["ar_prior"],
        decoder=model_cfg["decoder"],
        zero_mean=model_cfg["zero_mean"],
        history_noise=model_cfg["history_noise"],
        loss=model_cfg["loss"],
        members=model_cfg["members"],
        eval_members=model_cfg["eval_members"],
        loss_weighting=model_cfg["loss_weighting"],
        pair_crps=model_cfg["pair_crps"],
        contact_capture=model_cfg["contact_capture"],
        noise_scale=model_cfg["noise_scale"],
        rollout_links=dm.rollout_links,
        rollout_loss=model_cfg["rollout"]["loss"],
        rollout_target=model_cfg["rollout"]["target"],
        rollout_start=model_cfg["rollout"]["start"],
        contact_loss=model_cfg["contact_loss"],
        n_particles=meta.n_particles,
        graph_cutoff=float(cfg.data.graph_cutoff),
        linear_ar=fit_linear_ar(cfg, dm).to_dict(),
    )
    return attach(model)


def hparams(cfg: DictConfig, dm: TrajectoryDataModule) -> dict[str, Any]:
    """The run's settings as its model card and predictions file record them (TensorBoard's
    HParams: :func:`gripdem.runner.tensorboard_log.run_hparams`)."""
    summary = dm.summary()
    model = plain(cfg.model)
    return {
        "scene": cfg.scene.name,
        "boundary": summary["boundary"],
        "split": cfg.split.name,
        "model": model["name"],
        "decoder_mode": model["decoder_mode"],
        "vct_shift": model["vct_shift"],
        "encoding": summary["encoding"],
        "frame": "exact" if summary["encoding"] == "unwrapped" else "paper",
        "encoder": model["encoder"]["name"],
        "protocol": summary.get("protocol", cfg.data.protocol.value),
        "in_sample": bool(dm.in_sample),
        "history_len": int(dm.plan.history_len),
        "horizon": int(dm.split.horizon),
        "n_particles": int(summary["n_particles"]),
        "channels": int(model["encoder"]["channels"]),
        "trainable_graph": model["encoder"]["trainable_graph"],
        "hidden": int(model["hidden"]),
        "n_heads": int(model["n_heads"]),
        "lr": float(model["lr"]),
        "lr_schedule": model["lr_schedule"],
        "input_noise": float(model["input_noise"]),
        "history_noise": float(model["history_noise"]),
        "rollout_links": int(dm.rollout_links),
        "rollout_loss": model["rollout"]["loss"],
        "rollout_target": model["rollout"]["target"],
        "rollout_start": float(model["rollout"]["start"]),
        "contact_loss": float(model["contact_loss"]),
        "ar_prior": bool(model["ar_prior"]),
        "graph_cutoff_d": float(cfg.data.graph_cutoff),
        "seed": int(cfg.seed),
    }


def build_trainer(
    cfg: DictConfig, out_dir: Path, logger: RunLogger, extra: list | None = None
) -> L.Trainer:
    """The fit's Trainer: checkpoints, resume, early stopping and the progress bar as the
    config says, then ``extra`` callbacks (a study trial's reporter)."""
    callbacks_cfg = plain(cfg.callbacks) or {}
    ckpt = callbacks_cfg.get("checkpoint", {})
    callbacks = [
        ModelCheckpoint(
            dirpath=out_dir / "checkpoints",
            filename="best",
            monitor=ckpt.get("monitor", "val/rmse"),
            mode=ckpt.get("mode", "min"),
            save_last=False,  # last.ckpt: ResumeCheckpoint (after this one: it holds the best)
            save_top_k=ckpt.get("save_top_k", 1),
            save_on_train_epoch_end=False,  # at validations: before ResumeCheckpoint's save
            enable_version_counter=ckpt.get("save_top_k", 1) != 1,  # one best.ckpt, resumed too
        )
    ]
    if ckpt.get("save_last", True):
        every = ckpt.get("every_n_train_steps", 100)
        callbacks.append(ResumeCheckpoint(out_dir / "checkpoints", every))
    early = callbacks_cfg.get("early_stopping", {})
    if early.get("enabled", False):
        callbacks.append(
            EarlyStopping(
                monitor=early["monitor"],
                mode=early["mode"],
                patience=early["patience"],
                check_on_train_epoch_end=False,  # at validations, as the checkpoints
            )
        )
    if cfg.trainer.get("enable_progress_bar", True):  # steps of the budget, RMSE in d and / CV
        callbacks.append(StepBudgetBar())
    callbacks += list(extra or [])
    return L.Trainer(
        **plain(cfg.trainer),
        logger=logger,
        callbacks=callbacks,
        default_root_dir=str(out_dir),
        plugins=[AtomicCheckpointIO()],  # checkpoints renamed into place when complete
    )


def test_model(model, dm: TrajectoryDataModule, test_trainer) -> dict:
    """The test windows: chained with the stepper when the model's horizon is shorter than the
    split's (the surrogate path), else Lightning's test step; what ``model.test_results`` holds
    (nothing logged: the runner logs the test at the last optimiser step)."""
    if dm.model_horizon < dm.split.horizon:
        return evaluate_chained(model, dm)
    test_trainer.test(model, dm, verbose=False)
    return model.test_results


def run_experiment(cfg: DictConfig, out_dir: Path, trial=None) -> dict[str, Any]:
    """Train and test one configuration; returns the metrics written to ``metrics.json``.
    ``trial``: the study trial this run is (:class:`gripdem.study.trial.TrialLink`): its
    validations are reported to the study, and a pruned trial, or any trial when
    ``study_trial.test`` is false, ends after training with its validation record."""
    out_dir = Path(out_dir)
    run_started = time.perf_counter()
    quiet_console()
    if cfg.torch_threads:
        torch.set_num_threads(int(cfg.torch_threads))
    check_combination(cfg)
    L.seed_everything(int(cfg.seed), workers=True)
    data_path = resolve_data_path(cfg)
    data_seconds = time.perf_counter() - run_started  # the built-in DEM, when not cached
    dm = build_datamodule(cfg, data_path)
    source = load_source(cfg)  # fine-tuning: start from a trained model (model.init_from)
    outside = False  # the source's training scene is beyond the tolerance of this data's
    if source is not None:
        # the rule for a model on other data, as predict and the API apply it
        notes = check_compatible(cfg.model.init_from, dm.meta, purpose="finetune")[1]
        for note in notes:
            log.info("model.init_from=%s on %s: %s", cfg.model.init_from, dm.meta.path, note)
        outside = any(FINETUNE_BEYOND in note for note in notes)
        dm.load_state_dict(
            {"normalizer": source.normalizer.to_dict(), "encoding": dm.encoding_name}
        )
    apply_finetune_defaults(cfg)  # fine-tuning: its own learning rate and warm-up
    model = build_model(cfg, dm)
    if source is not None:
        initialise(model, source, str(cfg.model.init_from))
        checkpoint_cfg = (plain(cfg.callbacks) or {}).get("checkpoint", {})
        monitor = checkpoint_cfg.get("monitor", "val/rmse")  # the score training must beat
        start = validate_start(model, dm, accelerator(cfg), monitor)
    logger = RunLogger(**plain(cfg.logger))
    hp = hparams(cfg, dm)
    logger.log_run_hparams(run_hparams(cfg, dm.in_sample), trial_name(out_dir))
    reporter = [trial.reporter()] if trial is not None else []  # validations to the study
    trainer = build_trainer(cfg, out_dir, logger, reporter)
    resume = out_dir / "checkpoints" / "last.ckpt"
    ckpt_path = str(resume) if cfg.resume and resume.exists() else None
    if cfg.resume and ckpt_path is None:
        log.warning("resume=true but %s does not exist: starting from scratch", resume)
    started = time.perf_counter()
    trainer.fit(model, dm, ckpt_path=ckpt_path, weights_only=True)  # never unpickle code
    train_seconds = time.perf_counter() - started + resumed_seconds(trainer)
    if not trainer.is_global_zero:
        return {}
    if trial is not None and (trial.pruned or not cfg.study_trial.test):
        return trial_report(out_dir, trainer, logger, trial, train_seconds, run_started)
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        torch.distributed.destroy_process_group()  # test on one process, all windows at once
    best = trainer.checkpoint_callback.best_model_path or None
    with lightning_info_muted():  # the fit's Trainer has said which devices there are
        test_trainer = L.Trainer(
            accelerator=accelerator(cfg),
            devices=1,
            logger=False,  # the test is logged below, at the fit's last step
            enable_progress_bar=False,
            enable_checkpointing=False,
        )
    if best:  # the best validation rollout, not the last epoch
        model = load_checkpoint_model(best)
    best_score = trainer.checkpoint_callback.best_model_score
    trained_metrics = None
    if source is not None:  # fine-tuning never returns a model worse than its start
        kept = keep_start_unless_beaten(model, start, best_score)
        if kept[1]:  # what training reached, for the record, before the start replaces it
            trained_metrics = test_model(model, dm, test_trainer)["metrics"]
            best, best_score = f"{cfg.model.init_from} (the starting model)", start.val_rmse
        model, kept_start = kept
    results = test_model(model, dm, test_trainer)
    metrics = dict(results["metrics"])
    if trained_metrics is not None:
        metrics["finetune/trained_test_rmse"] = trained_metrics["test/rmse"]
    if source is not None:  # the source model as it was, on the same test windows
        as_is = load_model(cfg.model.init_from, dm.meta)  # its own AR prior, the data's scene
        before = test_model(as_is, dm, test_trainer)
        metrics.update({f"before/{k}": v for k, v in before["metrics"].items()})
        metrics[f"finetune/start_{start.monitor.replace('/', '_')}"] = start.val_rmse
        metrics["finetune/kept_start"] = float(kept_start)
        metrics["finetune/start_outside_scene"] = float(outside)
    metrics["val/rmse_best"] = float(best_score) if best_score is not None else math.nan
    metrics["train_seconds"] = train_seconds
    trained = trainer.lightning_module
    metrics["epochs"] = trainer.current_epoch
    metrics["steps"] = trainer.global_step
    model_file = out_dir / "checkpoints" / "best.safetensors"  # its card: data and split plan
    export_run_model(model, model_file, hp, metrics, dm.meta, dm.summary())
    predictions = to_predictions(results, dm, hp)
    physics, physics_report = physics_metrics(predictions)
    metrics.update(physics)
    # TensorBoard: the test and the hp/ metrics at the fit's last step (the axis of the
    # validation curves), the error per horizon step as one curve per forecaster
    diameter = dm.meta.diameter
    parameters = sum(p.numel() for p in model.parameters() if p.requires_grad)
    metrics.update(hp_metrics(metrics, diameter, parameters, trainer.global_step))
    hp_values = {k: v for k, v in metrics.items() if k.startswith("hp/")}
    logger.log_metrics({**test_scalars(metrics, diameter), **hp_values}, trainer.global_step)
    logger.log_curves(horizon_curves(results.get("scores")))
    report = {
        **metrics,
        # time to accuracy: (training seconds, optimiser step, validation RMSE / CV's) at each
        # validation of the fit
        "accuracy_curve": [list(point) for point in trained.accuracy_curve],
        "in_sample": bool(dm.in_sample),
        # the test windows' horizon was chained with the stepper (model.horizon < split's)
        "test_chained": results.get("chained"),
        "best_checkpoint": best,
        "hparams": hp,
        "data": dm.summary(),
    }
    report["scores"] = results.get("scores")  # CRPS, spread/skill, rank histogram curves
    write_outputs(
        cfg, out_dir, predictions, logger, trainer.global_step, physics_report, report["scores"]
    )
    # the job's wall time: the dataset (generated or found), then everything else
    report["data_seconds"] = data_seconds
    report["run_seconds"] = time.perf_counter() - run_started
    atomic_write_text(out_dir / "metrics.json", json.dumps(report, indent=2, default=str), True)
    logger.finish()
    title = f"{cfg.scene.name} / {cfg.split.name} / {cfg.model.name} (seed {cfg.seed})"
    print(f"\n== gripdem result: {title} ==")
    print(result_table(metrics, dm.meta.diameter, dm.in_sample))
    print(f"outputs: {out_dir}\n")
    return report
