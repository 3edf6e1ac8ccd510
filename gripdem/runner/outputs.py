"""What a run writes after its test: the predictions file, the physics report's metrics,
figures (PNG and TensorBoard images) and XYZ trajectories, and the result table it prints; a
study trial's validation record when it ends without a test (:func:`trial_report`)."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

from gripdem.data.datamodule import TrajectoryDataModule
from gripdem.data.h5io import atomic_write_text
from gripdem.evaluation.predictions import Predictions, write_predictions
from gripdem.models.baselines import BASELINES
from gripdem.runner.config_schema import plain

#: the comparison set that holds an ensemble's first member
ENSEMBLE_MEMBER = "member_0"


def to_predictions(results: dict[str, Any], dm: TrajectoryDataModule, info: dict) -> Predictions:
    """The test results as a predictions file's content. An ensemble's ``pred`` is its mean;
    its first member rides beside the baselines as the set ``member_0`` (a sample: what moves
    like the DEM's particles), so the physics report and the figures show both."""
    meta = dm.meta
    sets = {name: results[name].numpy() for name in BASELINES}
    if results.get("members") is not None:
        sets[ENSEMBLE_MEMBER] = results["members"][0].numpy()
    return Predictions(
        pred_positions=results["pred"].numpy(),
        true_positions=results["true"].numpy(),
        last_positions=results["last"].numpy(),
        times=results["times"].numpy(),
        boundary=meta.boundary,
        radius=meta.radius,
        frame_interval=meta.frame_interval,
        in_sample=bool(dm.in_sample),
        protocol=str(dm.plan.protocol),
        sim_index=results["sim_index"].numpy(),
        window_start=results["window_start"].numpy(),
        baselines=sets,
        body_force_amplitude=meta.body_force_amplitude,
        info=info,
    )


def physics_metrics(predictions: Predictions) -> tuple[dict[str, float], Any]:
    """The physics report of the test windows (truth, model and every baseline side by side,
    :mod:`gripdem.evaluation.physics_report`) as ``test/physics/<set>/<name>`` and, in an LE box,
    ``test/crossers/...`` (RMSE of the crossers with a bootstrap interval); and the report."""
    from gripdem.evaluation.physics_report import physics_report

    report = physics_report(predictions)
    out = {}
    for key, value in report.metrics.items():
        prefix = "test/" if key.startswith("crossers/") else "test/physics/"
        out[prefix + key] = float(value)
    return out, report


def write_outputs(
    cfg,
    out_dir: Path,
    predictions: Predictions,
    logger,
    step: int,
    physics_report=None,
    scores: dict | None = None,
) -> None:
    """predictions.h5, figures (PNG + TensorBoard images; the physics figure from the report,
    the scores figure from the test's score curves) and XYZ trajectories."""
    outputs = plain(cfg.outputs)
    if outputs["predictions"]:
        write_predictions(out_dir / "predictions.h5", predictions, overwrite=True)
    if outputs["figures"]:
        from gripdem.evaluation.figure_data import run_figure_data
        from gripdem.plots.run import make_run_figures

        make_run_figures(
            run_figure_data(predictions),
            out_dir / "figures",
            writer=logger.experiment,
            step=step,
            physics=physics_report,
            scores=scores,
        )
    if outputs["export_xyz"]:
        from gripdem.formats.export import export_extxyz

        count = outputs["export_windows"]
        n = predictions.n_windows if count is None else min(count, predictions.n_windows)
        windows = list(range(n))
        export_extxyz(predictions, out_dir / "trajectories", windows=windows, overwrite=True)


def result_table(metrics: dict[str, float], diameter: float, in_sample: bool) -> str:
    """Model vs baselines on the test windows, as a Markdown table: RMSE, and the CRPS (a
    point forecast's is its mean absolute error; an ensemble's, its members' fair CRPS, with
    its mean's RMSE, a member's and the spread/skill ratio below)."""
    label = "test (IN-SAMPLE: trained on these windows)" if in_sample else "test (out of sample)"
    rows = [
        f"| {label} | RMSE (m) | RMSE / d | model / this | CRPS / d |",
        "|---|---|---|---|---|",
    ]
    model = metrics.get("test/rmse", math.nan)
    names = [("model", "test/rmse", "test/crps")]
    if "test/spread_skill" in metrics:
        names = [("model (ensemble mean; CRPS of the members)", "test/rmse", "test/crps")]
    if "before/test/rmse" in metrics:  # fine-tuned: the source model as it was, same windows
        tuned = "model (fine-tuned)"
        if metrics.get("finetune/kept_start"):
            tuned = "model (the start: training did not beat it on validation)"
        before = "before fine-tuning"
        if metrics.get("finetune/start_outside_scene"):
            before += " (outside its training scene)"
        names = [
            (tuned, "test/rmse", "test/crps"),
            (before, "before/test/rmse", "before/test/crps"),
        ]
    names += [(b, f"test/rmse_{b}", f"test/crps_{b}") for b in BASELINES]
    for name, key, crps in names:
        value = metrics.get(key, math.nan)
        score = metrics.get(crps, math.nan) / diameter
        rows.append(
            f"| {name} | {value:.4g} | {value / diameter:.4g} | {model / value:.3f} | {score:.4g} |"
        )
    if "test/spread_skill" in metrics:
        member = metrics.get("test/rmse_member", math.nan)
        rows.append(
            f"\nensemble of {metrics.get('test/members', math.nan):.0f} members: one member's "
            f"RMSE / d {member / diameter:.4g}, spread/skill {metrics['test/spread_skill']:.3f} "
            "(1: calibrated), rank histogram's bins "
            f"{metrics['test/rank_min_over_uniform']:.2f}-{metrics['test/rank_max_over_uniform']:.2f}"
            " of uniform"
        )
    return "\n".join(rows)


def trial_report(
    out_dir: Path, trainer, logger, trial, seconds: float, started: float
) -> dict[str, Any]:
    """A study trial's end without the test (:mod:`gripdem.study.trial`): its validation
    record in ``metrics.json`` (``study/state`` complete or pruned, the step it stopped at) and
    in TensorBoard (``study/pruned``: 1 at the step a pruned trial stopped, else 0)."""
    trained = trainer.lightning_module
    best_score = trainer.checkpoint_callback.best_model_score
    ratios = [ratio for _, _, ratio in trained.accuracy_curve]
    metrics = {
        "val/rmse_best": float(best_score) if best_score is not None else math.nan,
        # the validation windows are fixed, so the lowest ratio is the best RMSE's
        "val/rmse_ratio_constant_velocity_best": min(ratios) if ratios else math.nan,
        "train_seconds": seconds,
        "epochs": trainer.current_epoch,
        "steps": trainer.global_step,
        "study/number": trial.number,
        "study/state": "pruned" if trial.pruned else "complete",
        "study/pruned_at_step": trial.pruned_at,
    }
    logger.log_metrics({"study/pruned": float(trial.pruned)}, trainer.global_step)
    report = {
        **metrics,
        "accuracy_curve": [list(point) for point in trained.accuracy_curve],
        "best_checkpoint": trainer.checkpoint_callback.best_model_path or None,
        "run_seconds": time.perf_counter() - started,
    }
    atomic_write_text(out_dir / "metrics.json", json.dumps(report, indent=2, default=str), True)
    logger.finish()
    state = f"pruned at step {trial.pruned_at}" if trial.pruned else "complete"
    print(
        f"\n== gripdem study trial {trial.number}: {state}, val/rmse_best "
        f"{metrics['val/rmse_best']:.4g} m ({metrics['val/rmse_ratio_constant_velocity_best']:.3f}"
        f" of CV) ==\noutputs: {out_dir}\n"
    )
    return report
