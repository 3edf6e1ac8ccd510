"""Every metric of a run recomputed from its ``predictions.h5`` alone, independently of the
training code: the model's and each baseline's RMSE (LE crossers apart) and the physics report."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from gripdem.evaluation import metrics
from gripdem.evaluation.physics_report import physics_report
from gripdem.evaluation.predictions import Predictions, read_predictions


def _summary(p: Predictions, pred: np.ndarray, offsets: np.ndarray) -> dict[str, float]:
    return metrics.summarize(
        pred,
        p.true_positions,
        p.last_positions,
        p.box,
        p.diameter,
        offsets,
        le=p.boundary.is_lees_edwards,
    )


def evaluate_predictions(
    source: str | os.PathLike | Predictions, physics: bool = True
) -> dict[str, Any]:
    """Every metric of a run from its predictions, computed independently of the training code.

    Keys: the model's :func:`gripdem.evaluation.metrics.summarize` keys (``rmse``, ``rmse_over_d``,
    ``rmse_step/001`` ..., and for LE data ``rmse_crossers``, ``rmse_others``, ``n_crossers``);
    the same under ``baseline/<name>/`` for each stored baseline; with ``physics=True`` the
    physics report (:func:`gripdem.evaluation.physics_report.physics_report`:
    ``physics/<set>/<name>`` for the truth, the model and each baseline, and for LE data
    ``crossers/...`` with bootstrap intervals); and ``n_windows``, ``n_particles``, ``horizon``,
    ``in_sample``.
    """
    p = source if isinstance(source, Predictions) else read_predictions(source)
    offsets = p.offsets()
    out: dict[str, Any] = dict(_summary(p, p.pred_positions, offsets))
    for name, arr in sorted(p.baselines.items()):
        for key, value in _summary(p, arr, offsets).items():
            out[f"baseline/{name}/{key}"] = value
    if physics:
        for key, value in physics_report(p).metrics.items():
            out[key if key.startswith("crossers/") else f"physics/{key}"] = value
    out.update(
        n_windows=p.n_windows,
        n_particles=p.n_particles,
        horizon=p.horizon,
        in_sample=bool(p.in_sample),
    )
    return out
