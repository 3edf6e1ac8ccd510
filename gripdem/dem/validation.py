"""Validation report of a trajectory dataset: is it physically plausible and worth learning?

Computed from the written frames alone (any gripdem dataset, not only generated ones):

- no NaN/Inf;
- largest overlap over all frames (LE-aware minimum-image pair distances), < 2% of d;
- time-averaged z velocity binned by x (frame-to-frame displacements over the frame interval,
  LE-aware with the later frame's offset) fitted by the imposed shape: ``A cos(2 pi x / lx) + c``
  (periodic) or ``s x + c`` (LE, slope s close to the shear rate), R^2 > 0.95;
- LE crossings of the x faces per frame (present in an LE scene);
- non-affine displacement (displacement minus the fitted mean flow): mean and RMS per frame
  and RMS over 10 frames, as fractions of d (must be measurable).

:func:`write_report` stores the numbers as JSON and the velocity profile as a PNG.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from gripdem.boundary import displacement
from gripdem.data.h5io import atomic_path, atomic_write_text
from gripdem.data.schema import TrajectoryData
from gripdem.dem.neighbours import build_pairs

MAX_OVERLAP = 0.02  # fraction of the diameter
MIN_R2 = 0.95
MAX_SLOPE_ERROR = 0.1  # LE: |fitted slope / shear rate - 1|
MIN_NONAFFINE_10 = 0.005  # RMS non-affine displacement over 10 frames, fraction of d (~10x the
# largest overlap: motion relative to the mean flow that a model can see)
WINDOW = 10


def max_frame_overlap(data: TrajectoryData) -> float:
    """Largest ``1 - r_ij / d`` over all pairs and frames (0 when nothing overlaps)."""
    d = data.diameter
    offsets = data.offsets()
    worst = 0.0
    for s in range(data.n_sims):
        for f in range(data.n_frames):
            pos = data.positions[s, f]
            pairs = build_pairs(pos, data.box, float(offsets[s, f]), d)
            if len(pairs):
                r = displacement(pos[pairs.i], pos[pairs.j], data.box, float(offsets[s, f]))
                worst = max(worst, 1.0 - float(np.sqrt((r * r).sum(-1)).min()) / d)
    return worst


def _fit(x: np.ndarray, y: np.ndarray, basis: np.ndarray) -> tuple[np.ndarray, float]:
    """Least squares ``y ~ basis @ coef``; returns ``(coef, R^2)``."""
    coef, *_ = np.linalg.lstsq(basis, y, rcond=None)
    resid = y - basis @ coef
    total = ((y - y.mean()) ** 2).sum()
    return coef, float(1.0 - (resid**2).sum() / total) if total > 0 else 0.0


def _profile_basis(x: np.ndarray, data: TrajectoryData) -> np.ndarray:
    if data.boundary.is_lees_edwards:
        return np.stack([x, np.ones_like(x)], -1)
    return np.stack([np.cos(2.0 * np.pi * x / data.box.lx), np.ones_like(x)], -1)


def velocity_profile(data: TrajectoryData, n_bins: int | None = None) -> dict[str, Any]:
    """Binned time-averaged v_z(x) and its fit by the imposed shape."""
    box, dt = data.box, data.frame_interval
    offsets = data.offsets()[:, 1:, None]
    disp = displacement(data.positions[:, 1:], data.positions[:, :-1], box, offsets)
    x = data.positions[:, :-1, :, 0]
    vz = disp[..., 2] / dt
    n_bins = n_bins or max(6, int(round(box.lx / data.diameter)))
    edges = np.linspace(-0.5 * box.lx, 0.5 * box.lx, n_bins + 1)
    centres = 0.5 * (edges[1:] + edges[:-1])
    which = np.clip(np.digitize(x, edges) - 1, 0, n_bins - 1)
    counts = np.bincount(which.ravel(), minlength=n_bins)
    mean = np.bincount(which.ravel(), vz.ravel(), minlength=n_bins) / np.maximum(counts, 1)
    # spread of the per-frame bin means (what one frame of data shows)
    per_frame = np.zeros((vz.shape[0] * vz.shape[1], n_bins))
    flat_which = which.reshape(-1, which.shape[-1])
    flat_vz = vz.reshape(-1, vz.shape[-1])
    for k in range(per_frame.shape[0]):
        c = np.bincount(flat_which[k], minlength=n_bins)
        per_frame[k] = np.bincount(flat_which[k], flat_vz[k], minlength=n_bins) / np.maximum(c, 1)
    coef, r2 = _fit(centres, mean, _profile_basis(centres, data))
    out = {
        "bin_centres": centres.tolist(),
        "mean_vz": mean.tolist(),
        "std_vz_per_frame": per_frame.std(0).tolist(),
        "counts": counts.tolist(),
        "fit_r2": r2,
        "fit_coefficients": coef.tolist(),
    }
    if data.boundary.is_lees_edwards:
        rate = data.boundary.lees_edwards.shear_rate * data.boundary.lees_edwards.sign
        out.update(
            shape="linear", slope=float(coef[0]), slope_over_shear_rate=float(coef[0] / rate)
        )
    else:
        out.update(
            shape="cosine",
            amplitude=float(coef[0]),
            peak_shear_rate=float(abs(coef[0]) * 2.0 * np.pi / box.lx),
        )
    return out


def nonaffine_motion(data: TrajectoryData, profile: dict[str, Any]) -> dict[str, float]:
    """Displacements relative to the fitted mean flow, as fractions of d."""
    box, dt, d = data.box, data.frame_interval, data.diameter
    offsets = data.offsets()[:, 1:, None]
    disp = displacement(data.positions[:, 1:], data.positions[:, :-1], box, offsets)
    x = data.positions[:, :-1, :, 0]
    u = _profile_basis(x, data) @ np.asarray(profile["fit_coefficients"])
    nonaffine = disp.copy()
    nonaffine[..., 2] -= u * dt
    step = np.sqrt((nonaffine**2).sum(-1))
    out = {
        "nonaffine_mean_per_frame_d": float(step.mean() / d),
        "nonaffine_rms_per_frame_d": float(np.sqrt((step**2).mean()) / d),
        "displacement_rms_per_frame_d": float(np.sqrt((disp**2).sum(-1).mean()) / d),
        "window_frames": WINDOW,
    }
    if nonaffine.shape[1] >= WINDOW:
        cum = np.concatenate([np.zeros_like(nonaffine[:, :1]), np.cumsum(nonaffine, 1)], 1)
        window = cum[:, WINDOW:] - cum[:, :-WINDOW]
        cum_disp = np.concatenate([np.zeros_like(disp[:, :1]), np.cumsum(disp, 1)], 1)
        total = cum_disp[:, WINDOW:] - cum_disp[:, :-WINDOW]
        out["nonaffine_rms_window_d"] = float(np.sqrt((window**2).sum(-1).mean()) / d)
        out["nonaffine_rms_window_per_axis_d"] = (np.sqrt((window**2).mean((0, 1, 2))) / d).tolist()
        out["displacement_rms_window_d"] = float(np.sqrt((total**2).sum(-1).mean()) / d)
    else:
        out["nonaffine_rms_window_d"] = math.nan
    return out


def crossings(data: TrajectoryData) -> dict[str, float]:
    """Face crossings between consecutive frames (x faces = LE faces in an LE scene)."""
    jumps = np.abs(np.diff(data.positions, axis=1)) > 0.5 * data.box.lengths
    per_frame = jumps.sum(2)  # (sims, frames-1, 3)
    return {
        "x_crossings_per_frame": float(per_frame[..., 0].mean()),
        "z_crossings_per_frame": float(per_frame[..., 2].mean()),
        "x_crossings_total": int(per_frame[..., 0].sum()),
        "x_crossers_per_10_frames": float(
            per_frame[..., 0][:, : (per_frame.shape[1] // WINDOW) * WINDOW]
            .reshape(per_frame.shape[0], -1, WINDOW)
            .sum(-1)
            .mean()
        )
        if per_frame.shape[1] >= WINDOW
        else math.nan,
    }


def validate_trajectories(data: TrajectoryData, extra: dict[str, Any] | None = None) -> dict:
    """The report as a JSON-able dict, with ``checks`` (name -> passed) and ``passed``."""
    finite = bool(np.isfinite(data.positions).all() and np.isfinite(data.times).all())
    report: dict[str, Any] = {
        "boundary": data.boundary.kind,
        "sims": data.n_sims,
        "frames": data.n_frames,
        "particles": data.n_particles,
        "diameter": data.diameter,
        "box": data.box.lengths.tolist(),
        "frame_interval": data.frame_interval,
        "first_frame_time": float(data.times[0, 0]),
        "finite": finite,
    }
    if not finite:
        report.update(checks={"finite": False}, passed=False)
        return report
    report["max_overlap_frames_d"] = max_frame_overlap(data)
    profile = velocity_profile(data)
    report["velocity_profile"] = profile
    report.update(nonaffine_motion(data, profile))
    report.update(crossings(data))
    checks = {
        "finite": finite,
        "max_overlap_below_2pct_d": report["max_overlap_frames_d"] < MAX_OVERLAP,
        "profile_fit_r2_above_0.95": profile["fit_r2"] > MIN_R2,
        "nonaffine_motion_measurable": bool(report["nonaffine_rms_window_d"] > MIN_NONAFFINE_10),
    }
    if data.boundary.is_lees_edwards:
        checks["le_slope_matches_shear_rate"] = (
            abs(profile["slope_over_shear_rate"] - 1.0) < MAX_SLOPE_ERROR
        )
        checks["le_crossings_present"] = report["x_crossings_total"] > 0
    report["checks"] = checks
    report["passed"] = all(checks.values())
    if extra:
        report.update(extra)
    return report


def plot_profile(report: dict[str, Any], path: Path, title: str = "") -> Path:
    """PNG of the binned time-averaged v_z(x) with its fit."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    prof = report["velocity_profile"]
    x = np.asarray(prof["bin_centres"])
    d = report["diameter"]
    lx = report["box"][0]
    fig, ax = plt.subplots(figsize=(5.5, 4.0), dpi=110)
    ax.errorbar(
        x / d,
        np.asarray(prof["mean_vz"]) * 1e3,
        yerr=np.asarray(prof["std_vz_per_frame"]) * 1e3,
        fmt="o",
        ms=4,
        capsize=2,
        label="DEM, binned (bars: spread of one frame)",
    )
    xf = np.linspace(-0.5 * lx, 0.5 * lx, 200)
    a, c = prof["fit_coefficients"]
    if prof["shape"] == "linear":
        yf = a * xf + c
        label = f"fit s·x + c, s/shear_rate = {prof['slope_over_shear_rate']:.3f}"
    else:
        yf = a * np.cos(2 * np.pi * xf / lx) + c
        label = f"fit A cos(2πx/lx) + c, peak rate {prof['peak_shear_rate']:.0f} 1/s"
    ax.plot(xf / d, yf * 1e3, "-", label=f"{label}\nR² = {prof['fit_r2']:.4f}")
    ax.set_xlabel("x / d")
    ax.set_ylabel("time-averaged $v_z$ (mm/s)")
    ax.set_title(
        title or f"{report['boundary']}: {report['sims']} sims x {report['frames']} frames"
    )
    ax.axhline(0.0, color="0.7", lw=0.8)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    try:
        with atomic_path(path, overwrite=True) as tmp:
            fig.savefig(tmp, format="png")
    finally:
        plt.close(fig)
    return path


def report_paths(dataset_path: str | os.PathLike) -> tuple[Path, Path]:
    """``(<stem>.validation.json, <stem>.profile.png)`` next to the dataset."""
    p = Path(dataset_path)
    return p.with_name(p.stem + ".validation.json"), p.with_name(p.stem + ".profile.png")


def write_report(
    report: dict[str, Any], dataset_path: str | os.PathLike, title: str = ""
) -> tuple[Path, Path]:
    """Write the JSON and PNG next to ``dataset_path`` (each atomically)."""
    json_path, png_path = report_paths(dataset_path)
    atomic_write_text(json_path, json.dumps(report, indent=2, default=float), overwrite=True)
    if report.get("finite"):
        plot_profile(report, png_path, title)
    return json_path, png_path
