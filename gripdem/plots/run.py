"""The paper's figures for one run (docs/spec/evaluation.md#run-figures), drawn from its computed
:class:`~gripdem.evaluation.figure_data.RunFigureData`. Lengths in particle diameters d,
velocities in d per frame interval. :func:`make_run_figures` draws them all, writes
``<name>.png`` atomically and, given a TensorBoard ``SummaryWriter``, logs each as an image.

Figures (names as returned by :func:`make_run_figures`):

- ``rmse_per_step``: RMSE/d at each horizon step, model vs stored baselines;
- ``crossers``: x and z over the horizon of sample particles that cross the x and the z faces
  (chosen from the truth), true vs predicted, box faces dotted;
- ``velocity_profile``: z velocity against x averaged over the horizon, true vs predicted vs
  the imposed profile;
- ``parity_z``: predicted vs true z, particles crossing an x face in the horizon (the LE
  crossers) vs the rest;
- ``pair_distances``: histogram of minimum-image pair distances at the last predicted step,
  model and truth, with d and the overlap tolerance marked and both overlap fractions printed;
- ``physics`` (given a physics report, :mod:`gripdem.plots.physics`): velocity profile, g(r),
  non-affine MSD and displacement distribution of the truth, the model and every baseline.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from gripdem.evaluation.figure_data import (
    CrosserTracks,
    PairHistogram,
    ParityPoints,
    ProfileCurves,
    RmseCurves,
    RunFigureData,
)
from gripdem.plots.common import new_figure, save_figure
from gripdem.plots.physics import plot_physics
from gripdem.plots.scores import plot_scores

FIGURES = ("rmse_per_step", "crossers", "velocity_profile", "parity_z", "pair_distances")


def plot_rmse_per_step(data: RmseCurves, title: str, horizon: int) -> Figure:
    """RMSE / d at each horizon step for the model (first set) and every stored baseline."""
    fig = new_figure()
    ax = fig.add_subplot()
    steps = np.arange(1, horizon + 1)
    for i, (label, (per_step, total)) in enumerate(data.curves.items()):
        style = {"lw": 2.4, "color": "k"} if i == 0 else {"lw": 1.4, "ls": "--"}
        ax.plot(
            steps,
            per_step,
            marker="o" if horizon <= 20 else None,
            ms=3,
            label=f"{label} (RMSE {total:.3g} d)",
            **style,
        )
    positive = np.concatenate([c[0] for c in data.curves.values()])
    positive = positive[positive > 0]
    if positive.size and positive.max() / positive.min() > 30:
        ax.set_yscale("log")
    ax.set_xlabel("horizon step (frames after the last observed frame)")
    ax.set_ylabel("RMSE / d (particle diameters)")
    ax.set_title(f"RMSE per horizon step\n{title}", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def plot_crossers(data: CrosserTracks, title: str, model_name: str) -> Figure:
    """x and z against horizon step of the sample crossers (one row each), truth solid and
    prediction dashed, each panel zoomed on its particle; dotted lines are the box faces +-l/2.
    A prediction that misses the LE remap shows as a jump of delta in z."""
    rows = data.rows
    fig = new_figure(9.0, 1.0 + 2.1 * max(len(rows), 1))
    if not rows:
        ax = fig.add_subplot()
        ax.text(
            0.5,
            0.5,
            "no particle crosses a face in the horizon",
            ha="center",
            va="center",
            transform=ax.transAxes,
        )
        ax.set_axis_off()
    axes = fig.subplots(len(rows), 2, sharex=True, squeeze=False) if rows else []
    for r, (face, w, n, true_c, pred_c) in enumerate(rows):
        steps = np.arange(true_c.shape[0])
        marker = "." if len(steps) <= 31 else None
        for col, (coord, c) in enumerate((("x", 0), ("z", 2))):
            ax = axes[r, col]
            ax.plot(steps, true_c[:, c], color="k", marker=marker, label="true")
            ax.plot(steps, pred_c[:, c], color="C3", ls="--", marker=marker, label=model_name)
            values = np.concatenate([true_c[:, c], pred_c[:, c]])
            pad = max(0.25, 0.15 * float(np.ptp(values)))
            lo, hi = float(values.min()) - pad, float(values.max()) + pad
            for edge in (-0.5, 0.5):
                face_at = edge * data.box[c]
                if lo <= face_at <= hi:
                    ax.axhline(face_at, color="0.4", ls=":", lw=1.2)
            ax.set_ylim(lo, hi)
            ax.set_ylabel(f"{coord} / d")
            ax.set_title(f"{face}-face crosser (window {w}, particle {n}): {coord}", fontsize=8)
            ax.grid(alpha=0.3)
        if r == 0:
            axes[0, 0].legend(fontsize=7)
    for col in range(2 if rows else 0):
        axes[-1, col].set_xlabel("horizon step (0 = last observed frame)")
    fig.suptitle(
        f"Particles crossing the x and z faces, unwrapped; dotted: box faces\n{title}",
        fontsize=10,
    )
    return fig


def plot_velocity_profile(data: ProfileCurves, title: str, horizon: int) -> Figure:
    """Mean z velocity against x over the horizon: truth, model (and baselines), imposed."""
    fig = new_figure()
    ax = fig.add_subplot()
    ax.plot(data.imposed_x, data.imposed_vz, color="0.5", lw=3, alpha=0.6, label=data.imposed_label)
    styles = [
        {"color": "k", "lw": 2, "marker": "o"},
        {"color": "C3", "lw": 1.8, "marker": "s", "ls": "--"},
        {"color": "C2", "lw": 1, "ls": ":"},
    ]
    for (label, (centres, vz)), style in zip(data.curves.items(), styles, strict=False):
        ax.plot(centres, vz, ms=4, label=label, **style)
    ax.set_xlabel("x / d (gradient direction)")
    ax.set_ylabel("mean $v_z$ (d per frame interval)")
    ax.set_title(
        f"z-velocity profile, averaged over the horizon ({horizon} steps; "
        f"frame interval {data.frame_interval:.3g} s)\n{title}",
        fontsize=9,
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def plot_parity_z(data: ParityPoints, title: str) -> Figure:
    """Predicted vs true z over all windows and steps: crossers against the rest; the distance
    from the diagonal is the z part of the RMSE residual."""
    fig = new_figure(5.6, 5.4)
    ax = fig.add_subplot()
    for (label, (t, q, rmse_z)), (colour, alpha) in zip(
        data.groups.items(), (("C0", 0.25), ("C3", 0.8)), strict=True
    ):
        ax.scatter(
            t, q, s=4, color=colour, alpha=alpha, lw=0, label=f"{label}, z RMSE {rmse_z:.3g} d"
        )
    ax.plot([-data.half, data.half], [-data.half, data.half], color="k", lw=0.8)
    ax.set_xlabel("true z / d (wrapped)")
    ax.set_ylabel("predicted z / d (image nearest the truth)")
    ax.set_aspect("equal")
    ax.set_title(f"Parity of z, all windows and horizon steps\n{title}", fontsize=9)
    ax.legend(fontsize=7, loc="upper left", markerscale=3)
    return fig


def plot_pair_distances(data: PairHistogram, title: str, horizon: int) -> Figure:
    """Histogram of minimum-image pair distances at the last predicted step, truth and model,
    d and the overlap tolerance marked, both overlap fractions printed."""
    fig = new_figure()
    ax = fig.add_subplot()
    text = []
    for (label, counts), style in zip(
        data.counts.items(), ({"color": "k", "lw": 1.8}, {"color": "C3", "lw": 1.4}), strict=True
    ):
        ax.stairs(counts, data.edges, label=label, **style)
        text.append(
            f"{label}: {100 * data.overlap[label]:.2f}% of particles overlap "
            f"(< {data.tolerance:g} d)"
        )
    ax.axvline(1.0, color="C1", lw=1.5, label="d (contact)")
    ax.axvline(
        data.tolerance, color="C1", lw=1, ls="--", label=f"{data.tolerance:g} d (overlap tolerance)"
    )
    ax.text(
        0.02,
        0.97,
        "\n".join(text),
        transform=ax.transAxes,
        va="top",
        fontsize=8,
        bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "0.7"},
    )
    ax.set_xlabel("minimum-image pair distance / d")
    ax.set_ylabel(f"pairs per bin ({data.n_windows} windows)")
    ax.set_title(f"Pair distances at the last predicted step (step {horizon})\n{title}", fontsize=9)
    ax.legend(fontsize=7, loc="center left")
    return fig


def run_figures(data: RunFigureData, physics: Any = None, scores=None) -> dict[str, Figure]:
    """All figures of :data:`FIGURES` for one run, by name, ``physics`` (truth, model and
    baselines side by side) when a :class:`~gripdem.evaluation.physics_report.PhysicsReport`
    is given, and ``scores`` (CRPS, spread/skill, rank histogram: :mod:`gripdem.plots.scores`)
    when the test's score curves are."""
    figures = {
        "rmse_per_step": plot_rmse_per_step(data.rmse, data.title, data.horizon),
        "crossers": plot_crossers(data.crossers, data.title, data.model_name),
        "velocity_profile": plot_velocity_profile(data.profile, data.title, data.horizon),
        "parity_z": plot_parity_z(data.parity, data.title),
        "pair_distances": plot_pair_distances(data.pairs, data.title, data.horizon),
    }
    if physics is not None:
        figures["physics"] = plot_physics(physics, data.title, data.model_name)
    if scores:
        figures["scores"] = plot_scores(scores, data.title, data.model_name)
    return figures


def make_run_figures(
    data: RunFigureData,
    out_dir: str | os.PathLike,
    writer: Any = None,
    step: int = 0,
    tag_prefix: str = "figures/",
    physics: Any = None,
    scores: dict | None = None,
) -> dict[str, Path]:
    """Draw every figure of a run, write ``out_dir/<name>.png`` and return ``{name: path}``.

    writer: a TensorBoard ``SummaryWriter`` (e.g. Lightning's ``TensorBoardLogger.experiment``);
    each figure is then also logged as image ``<tag_prefix><name>`` at ``step``."""
    out_dir = Path(out_dir)
    paths: dict[str, Path] = {}
    for name, fig in run_figures(data, physics, scores).items():
        path = out_dir / f"{name}.png"
        image = save_figure(fig, path)
        if writer is not None:
            writer.add_image(f"{tag_prefix}{name}", image, step, dataformats="HWC")
        paths[name] = path
    return paths
