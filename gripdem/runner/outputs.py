"""What a run writes after its test: the predictions file, the physics report's metrics,
figures (PNG and TensorBoard images) and XYZ trajectories, and the result table it prints."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from gripdem.data.datamodule import TrajectoryDataModule
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
