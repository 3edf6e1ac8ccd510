"""The paper's figures for one run (SPEC §6), drawn from its predictions.

Every function takes a :class:`gripdem.evaluation.predictions.Predictions` and returns a matplotlib
``Figure`` on its own Agg canvas: no pyplot, no global backend switch, no open windows, safe in
sweep workers. Lengths are shown in
particle diameters d, velocities in d per frame interval. :func:`make_run_figures` draws them
all, writes ``<name>.png`` atomically and, given a TensorBoard ``SummaryWriter``, logs each as
an image.

Figures (names as returned by :func:`make_run_figures`):

- ``rmse_per_step``: RMSE/d at each horizon step, model vs stored baselines;
- ``crossers``: x and z over the horizon of sample particles that cross the x and the z faces
  (chosen from the truth), true vs predicted, box faces dashed;
- ``velocity_profile``: z velocity against x averaged over the horizon, true vs predicted vs
  the imposed profile;
- ``parity_z``: predicted vs true z, particles crossing an x face in the horizon (the LE
  crossers) vs the rest;
- ``pair_distances``: histogram of minimum-image pair distances at the last predicted step,
  model and truth, with d and the overlap tolerance marked and both overlap fractions printed;
- ``physics`` (given a physics report, :mod:`gripdem.plots_physics`): velocity profile, g(r),
  non-affine MSD and displacement distribution of the truth, the model and every baseline.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from gripdem.boundary import lattice_shift, unwrap_trajectory
from gripdem.data.h5io import atomic_path
from gripdem.evaluation import metrics
from gripdem.evaluation.physics import (
    OVERLAP_TOLERANCE,
    fit_profile,
    overlap_fraction,
    pair_distances,
    profile_basis,
    velocity_profile,
)
from gripdem.evaluation.predictions import Predictions, read_predictions

FIGURES = ("rmse_per_step", "crossers", "velocity_profile", "parity_z", "pair_distances")
#: at most this many points per group in the parity plot (a random subset beyond)
PARITY_MAX_POINTS = 20000
BASELINE_LABELS = {
    "stay": "stay",
    "constant_velocity": "constant velocity",
    "linear_ar": "linear AR",
    "mean_flow": "mean-flow profile",
}


def _figure(width: float = 6.4, height: float = 4.4) -> Figure:
    fig = Figure(figsize=(width, height), dpi=110, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _model_name(p: Predictions) -> str:
    return str(p.info.get("model", "model"))


def _frames(p: Predictions) -> np.ndarray:
    """Truth with the last observed frame in front: ``(windows, horizon + 1, particles, 3)``."""
    return np.concatenate([p.last_positions[:, None], p.true_positions], axis=1)


def _step_shifts(p: Predictions) -> np.ndarray:
    """Lattice counts of each true step ``(windows, horizon, particles, 3)``: a non-zero x count
    is an x-face crossing (with the LE remap), a non-zero z count with zero x count a z one."""
    frames = _frames(p)
    return lattice_shift(frames[:, 1:] - frames[:, :-1], p.box, p.offsets()[..., None])


# --------------------------------------------------------------------------------------------
# the figures
# --------------------------------------------------------------------------------------------
def plot_rmse_per_step(p: Predictions) -> Figure:
    """RMSE / d at each horizon step for the model and every stored baseline."""
    fig = _figure()
    ax = fig.add_subplot()
    offsets = p.offsets()
    steps = np.arange(1, p.horizon + 1)
    curves = {_model_name(p): p.pred_positions}
    curves.update({BASELINE_LABELS.get(k, k): v for k, v in sorted(p.baselines.items())})
    values = []
    for i, (label, pred) in enumerate(curves.items()):
        res = metrics.position_residuals(pred, p.true_positions, p.box, offsets)
        per_step = metrics.rmse_per_step(res) / p.diameter
        total = metrics.rmse(res) / p.diameter
        values.append(per_step)
        style = {"lw": 2.4, "color": "k"} if i == 0 else {"lw": 1.4, "ls": "--"}
        ax.plot(
            steps,
            per_step,
            marker="o" if p.horizon <= 20 else None,
            ms=3,
            label=f"{label} (RMSE {total:.3g} d)",
            **style,
        )
    positive = np.concatenate(values)
    positive = positive[positive > 0]
    if positive.size and positive.max() / positive.min() > 30:
        ax.set_yscale("log")
    ax.set_xlabel("horizon step (frames after the last observed frame)")
    ax.set_ylabel("RMSE / d (particle diameters)")
    ax.set_title(f"RMSE per horizon step\n{p.title()}", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def _pick_crossers(shifts: np.ndarray, axis: int, count: int) -> list[tuple[int, int]]:
    """Up to ``count`` (window, particle) whose truth crosses the face of ``axis`` (0: x, 2: z
    not through an x crossing), the crossing nearest the middle of the horizon first."""
    if axis == 0:
        crossing = shifts[..., 0] != 0
    else:
        crossing = (shifts[..., 2] != 0) & (shifts[..., 0] == 0)
    w_idx, n_idx = np.nonzero(crossing.any(axis=1))
    if w_idx.size == 0:
        return []
    first = crossing[w_idx, :, n_idx].argmax(axis=1)
    order = np.argsort(np.abs(first - 0.5 * (shifts.shape[1] - 1)), kind="stable")
    return [(int(w_idx[k]), int(n_idx[k])) for k in order[:count]]


def _continuous(p: Predictions, series: np.ndarray, w: int, n: int) -> np.ndarray:
    """Lattice-continuous trajectory ``(horizon + 1, 3)`` of particle n of window w from the
    last observed frame on (:func:`gripdem.boundary.unwrap_trajectory`, image cells moving with
    the LE offset), so a face crossing is a curve passing a face line, not a jump."""
    offsets = np.concatenate([[0.0], p.offsets()[w]])  # the anchor's offset is not used
    increments = np.full(p.horizon, p.offset_increment)
    return unwrap_trajectory(series[w, :, n], p.box, offsets, increments)


def plot_crossers(p: Predictions, per_face: int = 2) -> Figure:
    """x and z against horizon step of sample particles whose truth crosses the x faces and
    the z faces (one row each, up to ``per_face`` per face), truth solid and prediction dashed,
    both unwrapped from the last observed frame (lattice-continuous), each panel zoomed on its
    particle; dotted lines are the box faces +-l/2. A prediction that misses the LE remap shows
    as a jump of delta in z."""
    shifts = _step_shifts(p)
    frames = _frames(p)
    pred = np.concatenate([p.last_positions[:, None], p.pred_positions], axis=1)
    steps = np.arange(p.horizon + 1)
    d = p.diameter
    rows = [
        (face, pick)
        for face, axis in (("x", 0), ("z", 2))
        for pick in _pick_crossers(shifts, axis, per_face)
    ]
    fig = _figure(9.0, 1.0 + 2.1 * max(len(rows), 1))
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
    marker = "." if p.horizon <= 30 else None
    for r, (face, (w, n)) in enumerate(rows):
        true_c = _continuous(p, frames, w, n) / d
        pred_c = _continuous(p, pred, w, n) / d
        for col, (coord, c) in enumerate((("x", 0), ("z", 2))):
            ax = axes[r, col]
            ax.plot(steps, true_c[:, c], color="k", marker=marker, label="true")
            ax.plot(steps, pred_c[:, c], color="C3", ls="--", marker=marker, label=_model_name(p))
            values = np.concatenate([true_c[:, c], pred_c[:, c]])
            pad = max(0.25, 0.15 * float(np.ptp(values)))
            lo, hi = float(values.min()) - pad, float(values.max()) + pad
            for edge in (-0.5, 0.5):
                face_at = edge * p.box.lengths[c] / d
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
        f"Particles crossing the x and z faces, unwrapped; dotted: box faces\n{p.title()}",
        fontsize=10,
    )
    return fig


def default_imposed(p: Predictions) -> tuple[Callable[[np.ndarray], np.ndarray], str]:
    """The imposed profile u_z(x) in data units (length/time) and its legend label: for LE data
    the known ``sign * shear_rate * x``; for periodic data the cosine shape fitted to the true
    profile (its amplitude depends on the drag, which the predictions do not record)."""
    le = p.boundary.lees_edwards
    if le is not None:
        rate = le.sign * le.shear_rate
        return (lambda x: rate * np.asarray(x)), f"imposed: u_z = {rate:g} 1/s · x"
    centres, vz, _ = velocity_profile(
        p.true_positions, p.last_positions, p.box, p.offsets(), p.frame_interval, bins=32
    )
    a, b = fit_profile(centres, vz, p.box, "cosine")
    box = p.box
    return (lambda x: profile_basis(x, box, "cosine") @ np.array([a, b])), (
        f"imposed shape: cosine fit to truth (A = {a:.3g} m/s)"
    )


def plot_velocity_profile(
    p: Predictions,
    imposed: Callable[[np.ndarray], np.ndarray] | None = None,
    imposed_label: str = "imposed",
    bins: int = 16,
) -> Figure:
    """Mean z velocity against x over the horizon: truth, model (and baselines), imposed.

    ``imposed``: u_z(x) in data units (x in length, result in length/time); ``None`` uses
    :func:`default_imposed`."""
    if imposed is None:
        imposed, imposed_label = default_imposed(p)
    d, dt, offsets = p.diameter, p.frame_interval, p.offsets()
    fig = _figure()
    ax = fig.add_subplot()
    x_fine = np.linspace(-0.5 * p.box.lx, 0.5 * p.box.lx, 200)
    ax.plot(
        x_fine / d,
        np.asarray(imposed(x_fine)) * dt / d,
        color="0.5",
        lw=3,
        alpha=0.6,
        label=imposed_label,
    )
    curves = [
        ("truth", p.true_positions, {"color": "k", "lw": 2, "marker": "o"}),
        (_model_name(p), p.pred_positions, {"color": "C3", "lw": 1.8, "marker": "s", "ls": "--"}),
    ]
    if "mean_flow" in p.baselines:
        curves.append(
            ("mean-flow baseline", p.baselines["mean_flow"], {"color": "C2", "lw": 1, "ls": ":"})
        )
    for label, pos, style in curves:
        centres, vz, _ = velocity_profile(pos, p.last_positions, p.box, offsets, dt, bins)
        ax.plot(centres / d, vz * dt / d, ms=4, label=label, **style)
    ax.set_xlabel("x / d (gradient direction)")
    ax.set_ylabel("mean $v_z$ (d per frame interval)")
    ax.set_title(
        f"z-velocity profile, averaged over the horizon ({p.horizon} steps; "
        f"frame interval {dt:.3g} s)\n{p.title()}",
        fontsize=9,
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def plot_parity_z(p: Predictions, seed: int = 0) -> Figure:
    """Predicted vs true z over all windows and steps. The prediction is shown at the image
    nearest the truth (true z minus the minimum-image residual), so a prediction just across a
    z face sits next to the diagonal, not in the opposite corner; its distance from the
    diagonal is the z part of the RMSE residual."""
    offsets = p.offsets()
    res = metrics.position_residuals(p.pred_positions, p.true_positions, p.box, offsets)
    true_z = p.true_positions[..., 2] / p.diameter
    pred_z = (p.true_positions[..., 2] - res[..., 2]) / p.diameter
    crossers = metrics.crossing_mask(p.last_positions, p.true_positions, p.box, offsets)
    mask = np.broadcast_to(crossers[:, None, :], true_z.shape)
    rng = np.random.default_rng(seed)
    fig = _figure(5.6, 5.4)
    ax = fig.add_subplot()
    kind = "LE" if p.boundary.is_lees_edwards else "periodic x"
    groups = (
        (f"others ({int((~crossers).sum())} particle-windows)", ~mask, "C0", 0.25),
        (f"{kind}-face crossers ({int(crossers.sum())})", mask, "C3", 0.8),
    )
    for label, sel, colour, alpha in groups:
        t, q = true_z[sel], pred_z[sel]
        rmse_z = float(np.sqrt(np.mean((t - q) ** 2))) if t.size else float("nan")
        if t.size > PARITY_MAX_POINTS:
            keep = rng.choice(t.size, PARITY_MAX_POINTS, replace=False)
            t, q = t[keep], q[keep]
        ax.scatter(
            t, q, s=4, color=colour, alpha=alpha, lw=0, label=f"{label}, z RMSE {rmse_z:.3g} d"
        )
    half = 0.5 * p.box.lz / p.diameter
    ax.plot([-half, half], [-half, half], color="k", lw=0.8)
    ax.set_xlabel("true z / d (wrapped)")
    ax.set_ylabel("predicted z / d (image nearest the truth)")
    ax.set_aspect("equal")
    ax.set_title(f"Parity of z, all windows and horizon steps\n{p.title()}", fontsize=9)
    ax.legend(fontsize=7, loc="upper left", markerscale=3)
    return fig


def plot_pair_distances(
    p: Predictions, r_max_over_d: float = 2.0, bins: int = 80, tol: float = OVERLAP_TOLERANCE
) -> Figure:
    """Histogram of LE-aware minimum-image pair distances below ``r_max_over_d`` d at the last
    predicted step (all windows), model and truth, d and ``tol * d`` marked."""
    d, off = p.diameter, p.offsets()[:, -1]
    r_max = min(r_max_over_d * d, 0.499 * float(p.box.lengths.min()))
    edges = np.linspace(0.0, r_max / d, bins + 1)
    fig = _figure()
    ax = fig.add_subplot()
    text = []
    for label, pos, style in (
        ("truth", p.true_positions, {"color": "k", "lw": 1.8}),
        (_model_name(p), p.pred_positions, {"color": "C3", "lw": 1.4}),
    ):
        dist = pair_distances(pos[:, -1], p.box, r_max, off) / d
        ax.hist(dist, bins=edges, histtype="step", label=label, **style)
        frac = overlap_fraction(pos[:, -1], p.box, d, off, tol)
        text.append(f"{label}: {100 * frac:.2f}% of particles overlap (< {tol:g} d)")
    ax.axvline(1.0, color="C1", lw=1.5, label="d (contact)")
    ax.axvline(tol, color="C1", lw=1, ls="--", label=f"{tol:g} d (overlap tolerance)")
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
    ax.set_ylabel(f"pairs per bin ({p.n_windows} windows)")
    ax.set_title(
        f"Pair distances at the last predicted step (step {p.horizon})\n{p.title()}", fontsize=9
    )
    ax.legend(fontsize=8, loc="center left")
    return fig


# --------------------------------------------------------------------------------------------
# saving and logging
# --------------------------------------------------------------------------------------------
def figure_to_array(fig: Figure) -> np.ndarray:
    """RGB image ``(height, width, 3)`` uint8 of a figure, for
    ``SummaryWriter.add_image(tag, image, step, dataformats="HWC")``."""
    canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def save_figure(fig: Figure, path: str | os.PathLike, overwrite: bool = True) -> np.ndarray:
    """Write ``fig`` as PNG atomically and return its RGB array (see :func:`figure_to_array`)."""
    image = figure_to_array(fig)
    with atomic_path(path, overwrite) as tmp:
        fig.savefig(tmp, format="png")
    return image


def run_figures(
    p: Predictions,
    imposed: Callable[[np.ndarray], np.ndarray] | None = None,
    imposed_label: str = "imposed",
    physics: Any = None,
) -> dict[str, Figure]:
    """All figures of :data:`FIGURES` for one run, by name, and ``physics`` (truth, model and
    baselines side by side) when a :class:`~gripdem.evaluation.physics_report.PhysicsReport` is
    given."""
    figures = {
        "rmse_per_step": plot_rmse_per_step(p),
        "crossers": plot_crossers(p),
        "velocity_profile": plot_velocity_profile(p, imposed, imposed_label),
        "parity_z": plot_parity_z(p),
        "pair_distances": plot_pair_distances(p),
    }
    if physics is not None:
        from gripdem.plots_physics import plot_physics

        figures["physics"] = plot_physics(physics, p.title(), _model_name(p))
    return figures


def make_run_figures(
    source: str | os.PathLike | Predictions,
    out_dir: str | os.PathLike,
    imposed: Callable[[np.ndarray], np.ndarray] | None = None,
    imposed_label: str = "imposed",
    writer: Any = None,
    step: int = 0,
    tag_prefix: str = "figures/",
    physics: Any = None,
) -> dict[str, Path]:
    """Draw every figure of a run, write ``out_dir/<name>.png`` and return ``{name: path}``.

    source: a ``predictions.h5`` path or a :class:`Predictions` built from arrays. writer: a
    TensorBoard ``SummaryWriter`` (e.g. Lightning's ``TensorBoardLogger.experiment``); each
    figure is then also logged as image ``<tag_prefix><name>`` at ``step``.
    """
    p = source if isinstance(source, Predictions) else read_predictions(source)
    out_dir = Path(out_dir)
    paths: dict[str, Path] = {}
    for name, fig in run_figures(p, imposed, imposed_label, physics).items():
        path = out_dir / f"{name}.png"
        image = save_figure(fig, path)
        if writer is not None:
            writer.add_image(f"{tag_prefix}{name}", image, step, dataformats="HWC")
        paths[name] = path
    return paths
