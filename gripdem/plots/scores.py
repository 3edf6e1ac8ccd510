"""The scores figure of a run: the CRPS per predicted step of the model and every baseline (a
point forecast's CRPS is its mean absolute error, so every run has one), and for an ensemble the
spread/skill ratio per step (docs/spec/long-rollouts.md#spread-skill) and the rank histogram of the
truth among the members (docs/spec/long-rollouts.md#rank-histogram).

Input: the ``scores`` curves of :meth:`gripdem.models.evaluation.RolloutEvaluation.
ensemble_metrics`: ``crps_over_d`` (set -> per step), and for an ensemble ``spread_skill`` (per
step) and ``rank_histogram`` (``M + 1`` frequencies).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure

from gripdem.evaluation.figure_data import BASELINE_LABELS
from gripdem.plots.common import new_figure


def plot_scores(scores: dict[str, Any], title: str, model_name: str = "model") -> Figure:
    ensemble = "spread_skill" in scores
    fig = new_figure(13.0 if ensemble else 6.4, 4.2)
    axes = fig.subplots(1, 3 if ensemble else 1)
    axes = np.atleast_1d(axes)
    ax = axes[0]
    colours = iter(["C0", "C1", "C2", "C4", "C5", "C6"])  # C3: the model
    for name, values in scores["crps_over_d"].items():
        steps = np.arange(1, len(values) + 1)
        if name == "model":
            label = f"{model_name} (members' fair CRPS)" if ensemble else model_name
            ax.plot(steps, values, color="C3", lw=2, label=label)
        else:
            label = BASELINE_LABELS.get(name, name)
            ax.plot(steps, values, ls="--", lw=1, color=next(colours), label=label)
    ax.set(xlabel="predicted step", ylabel="CRPS / d (point forecasts: MAE)", yscale="log")
    ax.set_title("CRPS per predicted step", fontsize=9)
    ax.legend(fontsize=7)
    if ensemble:
        ratio = scores["spread_skill"]
        ax = axes[1]
        ax.plot(np.arange(1, len(ratio) + 1), ratio, marker="o", ms=3, color="C3")
        ax.axhline(1.0, color="0.3", ls=":", label="calibrated")
        ax.axhspan(0.8, 1.2, color="C2", alpha=0.12, label="target 0.8-1.2")
        ax.set(xlabel="predicted step", ylabel="spread / skill", ylim=(0, max(1.5, max(ratio))))
        ax.set_title("spread/skill (M+1)/M-corrected", fontsize=9)
        ax.legend(fontsize=7)
        hist = np.asarray(scores["rank_histogram"]) * len(scores["rank_histogram"])
        ax = axes[2]
        ax.bar(np.arange(len(hist)), hist, color="C3", alpha=0.7)
        ax.axhline(1.0, color="0.3", ls=":", label="flat")
        ax.axhspan(0.5, 1.5, color="C2", alpha=0.12, label="target 0.5-1.5")
        ax.set(xlabel="rank of the truth among the members", ylabel="frequency / uniform")
        ax.set_title(f"rank histogram ({len(hist) - 1} members)", fontsize=9)
        ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    return fig
