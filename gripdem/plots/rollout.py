"""The surrogate figure of a long rollout, drawn from its computed report (the JSON of
``experiments/benchmarks/surrogate/surrogate_rollout.py``: per-frame RMSE of the model and the
baselines, per-frame overlap, per-block statistics from :mod:`gripdem.evaluation.rollout_stats`,
and the noise floor of two independent DEM simulations).

Six panels: RMSE / d over the first frames (model, constant velocity, linear AR); the overlap
fraction per frame (model, truth, the 1 % target); the g(r) L1 distance per block; the
mean-flow profile ratio per block; the non-affine MSD ratios at lags 10 and 100; the RMS step
ratio. Shaded bands are the targets; dotted lines the noise floor.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from gripdem.plots.common import new_figure

#: target bands of the surrogate issue (ratios to the truth)
TARGETS = {"profile": 0.03, "msd": 0.15, "rms_step": 0.10, "gr_l1": 0.02, "overlap": 0.01}
COLOURS = {"model": "C3", "truth": "k", "constant_velocity": "C1", "linear_ar": "C2"}


def _centres(blocks: list[dict]) -> np.ndarray:
    return np.array([0.5 * (b["frames"][0] + b["frames"][1]) for b in blocks])


def _ratio_panel(ax, x, blocks, keys, labels, band, floor_blocks, title):
    ax.axhspan(1 - band, 1 + band, color="0.85", label=f"target ±{band:.0%}")
    for key, label, marker in zip(keys, labels, "osd^", strict=False):
        ax.plot(x, [b[f"ratio/{key}"] for b in blocks], marker=marker, ms=3, label=label)
        if floor_blocks:
            floor = np.nanmax([abs(b[f"ratio/{key}"] - 1) for b in floor_blocks])
            ax.axhline(1 + floor, color="0.3", ls=":", lw=1)
            ax.axhline(1 - floor, color="0.3", ls=":", lw=1)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("predicted frame (block centre)")
    ax.set_ylabel("model / truth")
    ax.legend(fontsize=7)


def plot_surrogate(scene: dict, title: str) -> Figure:
    """The 2 x 3 panels of one scene's report (see the module doc)."""
    fig = new_figure(13.0, 7.6)
    axes = fig.subplots(2, 3).ravel()
    blocks, floor = scene["blocks"]["blocks"], scene.get("noise_floor", {}).get("blocks", [])
    x = _centres(blocks)
    ax = axes[0]
    for name, values in scene["rmse_over_d"].items():
        ax.plot(np.arange(1, len(values) + 1), values, color=COLOURS.get(name), label=name)
    ax.set(xlabel="predicted frame", ylabel="RMSE / d", yscale="log")
    ax.set_title("short term: RMSE against the truth", fontsize=9)
    ax.legend(fontsize=7)
    ax = axes[1]
    for name in ("model", "truth"):
        values = scene["blocks"]["overlap_per_frame"][name]
        ax.plot(
            np.arange(len(values)), np.asarray(values) * 100, color=COLOURS[name], lw=1, label=name
        )
    ax.axhline(100 * TARGETS["overlap"], color="C1", ls="--", label="target 1 %")
    ax.set(xlabel="predicted frame", ylabel="% particles with a neighbour < 0.98 d")
    corrected = scene.get("settings", {}).get("contact_correction", True)
    ax.set_title(
        "overlap" + (" (after the contact correction)" if corrected else " (no correction)"),
        fontsize=9,
    )
    ax.legend(fontsize=7)
    ax = axes[2]
    ax.plot(
        x,
        [b["gr_l1"] for b in blocks],
        marker="o",
        ms=3,
        color=COLOURS["model"],
        label="model vs truth",
    )
    if floor:
        ax.axhline(max(b["gr_l1"] for b in floor), color="0.3", ls=":", label="two DEM runs")
    ax.axhline(TARGETS["gr_l1"], color="C1", ls="--", label="target 0.02")
    ax.set(xlabel="predicted frame (block centre)", ylabel="g(r) L1 distance")
    ax.set_title("structure: pair-distance histogram 0-3 d", fontsize=9)
    ax.legend(fontsize=7)
    _ratio_panel(
        axes[3],
        x,
        blocks,
        ["profile"],
        ["amplitude / slope"],
        TARGETS["profile"],
        floor,
        "mean-flow profile",
    )
    _ratio_panel(
        axes[4],
        x,
        blocks,
        ["msd_10_over_d2", "msd_100_over_d2"],
        ["lag 10", "lag 100"],
        TARGETS["msd"],
        floor,
        "non-affine MSD",
    )
    _ratio_panel(
        axes[5],
        x,
        blocks,
        ["rms_step_over_d", "rms_non_affine_over_d"],
        ["RMS step", "RMS non-affine step"],
        TARGETS["rms_step"],
        floor,
        "per-frame step",
    )
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    return fig
