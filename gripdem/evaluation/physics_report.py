"""The physics report of a run's test windows: the truth, the model and every baseline side by
side (docs/spec/evaluation.md#physics), from a :class:`~gripdem.evaluation.predictions.Predictions`
alone.

Per-particle RMSE does not say whether a predicted flow is physical. For each trajectory set
(``truth``, ``model``, each baseline) over the horizon this computes

- the z-velocity profile against x (binned), and its RMS difference to the truth's;
- the LE-aware radial distribution function g(r) at the last predicted step, and its distance
  to the truth's: ``∫|g - g_truth| dr / ∫ g_truth dr`` over ``[0, 2.97 d)`` (0 = identical
  structure, 1 = nothing in common);
- the mean coordination at contact (neighbours closer than ``CONTACT_FACTOR`` d) at the last
  predicted step: the soft-contact truth keeps its contacts at overlaps of ~1e-5 d, a prediction
  that blurs the structure loses them;
- the mean-squared displacement over the horizon (lattice-continuous);
- the non-affine displacement: the lattice-continuous displacement minus the mean flow
  ``u_z(x)`` (the imposed shape, cosine or linear, fitted to the truth's steps), its mean square
  at every horizon step (the MSD without the flow, which otherwise dominates) and at the last
  step its RMS and distribution (histogram of the z component);
- the overlap fraction at the last predicted step;

and, in a Lees-Edwards box, the RMSE of the particles that cross an x face in the horizon with a
bootstrap confidence interval over those particle-windows (they are few: the interval says how
far the crosser numbers can be trusted).

Scalar keys (``metrics``): ``<set>/<name>`` with ``<set>`` in ``truth``, ``model`` and the
baselines; lengths in diameters (``_over_d``, ``_over_d2``), ``crossers/<set>/rmse_over_d``,
``.../ci_low_over_d``, ``.../ci_high_over_d`` and ``crossers/n``. Curves (``curves``), for the
figure: ``profile_x``, ``gr_r``, ``non_affine_edges`` and per set ``profile``, ``gr``, ``msd``,
``non_affine_msd``, ``non_affine_hist``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gripdem.boundary import lattice_continuous_steps
from gripdem.evaluation.metrics import crossing_mask, position_residuals
from gripdem.evaluation.physics import (
    OVERLAP_TOLERANCE,
    coordination_number,
    fit_profile,
    mean_squared_displacement,
    overlap_fraction,
    profile_basis,
    radial_distribution,
    velocity_profile,
    velocity_profile_error,
)
from gripdem.evaluation.predictions import Predictions

#: contacts: centre distance below CONTACT_FACTOR diameters (the truth's overlaps are ~1e-5 d)
CONTACT_FACTOR = 1.01
#: g(r) range and bins, in diameters: bins of 0.03 d with edges at 0.99 and 1.02 d, so the
#: truth's contact peak (overlaps ~1e-5 d) lies inside one bin instead of on an edge, where
#: sub-bin jitter of a prediction would move it between two bins
GR_MAX_D = 2.97
GR_BINS = 99
#: z-velocity profile bins along x
PROFILE_BINS = 16
#: non-affine displacement histogram: bins over +-NON_AFFINE_RANGE_D diameters
NON_AFFINE_BINS = 60
NON_AFFINE_RANGE_D = 0.15
#: bootstrap resamples of the crossers' RMSE, and the interval
BOOTSTRAP_SAMPLES = 2000
CONFIDENCE = 0.95


@dataclass
class PhysicsReport:
    """Scalars (``metrics``) and curves (``curves``) of every trajectory set; see module doc."""

    sets: list[str]
    metrics: dict[str, float] = field(default_factory=dict)
    curves: dict[str, Any] = field(default_factory=dict)
    profile_kind: str = "linear"


def _trajectory_sets(p: Predictions) -> dict[str, np.ndarray]:
    sets = {"truth": p.true_positions, "model": p.pred_positions}
    sets.update({name: p.baselines[name] for name in sorted(p.baselines)})
    return {k: np.asarray(v, dtype=np.float64) for k, v in sets.items()}


def _continuous_steps(p: Predictions, positions: np.ndarray) -> np.ndarray:
    """Lattice-continuous steps over the horizon ``(windows, particles, f, 3)``, anchored at
    the last observed frame (the first step from it)."""
    frames = np.concatenate([p.last_positions[:, None], positions], axis=1)  # (W, f+1, N, 3)
    frames = frames.transpose(0, 2, 1, 3)
    if not p.boundary.is_lees_edwards:
        return lattice_continuous_steps(frames, p.box)
    offsets = np.concatenate([np.zeros((p.n_windows, 1)), p.offsets()], axis=1)[:, None, :]
    increments = np.full(p.horizon, p.offset_increment)  # the anchor's offset is not used
    return lattice_continuous_steps(frames, p.box, offsets, anchor=0, increments=increments)


def mean_flow_fit(p: Predictions, kind: str) -> tuple[float, float]:
    """The imposed profile ``u_z(x)`` per frame (``kind`` cosine or linear) fitted to the
    truth's lattice-continuous steps at their mid-point x: the reference of the non-affine
    displacements."""
    steps = _continuous_steps(p, p.true_positions)
    x_mid = p.last_positions[..., 0][..., None] + np.cumsum(steps[..., 0], -1) - 0.5 * steps[..., 0]
    return fit_profile(x_mid.reshape(-1), steps[..., 2].reshape(-1), p.box, kind)


def non_affine_displacements(
    p: Predictions, positions: np.ndarray, kind: str, coeffs: tuple[float, float]
) -> np.ndarray:
    """``(windows, particles, f, 3)`` displacement from the last observed frame to each
    predicted frame, minus the mean flow ``u_z(x_mid)`` of every step on the way (metres)."""
    steps = _continuous_steps(p, positions)
    x_mid = p.last_positions[..., 0][..., None] + np.cumsum(steps[..., 0], -1) - 0.5 * steps[..., 0]
    flow = profile_basis(x_mid.reshape(-1), p.box, kind) @ np.asarray(coeffs)
    steps[..., 2] -= flow.reshape(x_mid.shape)
    return np.cumsum(steps, axis=-2)


def bootstrap_rmse(
    squared: np.ndarray, samples: int = BOOTSTRAP_SAMPLES, seed: int = 0
) -> tuple[float, float, float]:
    """RMSE of units whose mean squared error is ``squared (units,)`` and the
    ``CONFIDENCE`` percentile interval of its bootstrap over units (NaN when empty)."""
    if squared.size == 0:
        return math.nan, math.nan, math.nan
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, squared.size, size=(samples, squared.size))
    boot = np.sqrt(squared[draws].mean(axis=1))
    tail = 50.0 * (1.0 - CONFIDENCE)
    low, high = np.percentile(boot, [tail, 100.0 - tail])
    return float(np.sqrt(squared.mean())), float(low), float(high)


def physics_report(p: Predictions, profile_kind: str | None = None) -> PhysicsReport:
    """Everything in the module docstring for ``p`` (out of sample or not: ``p.in_sample``)."""
    le = p.boundary.is_lees_edwards
    kind = profile_kind or ("linear" if le else "cosine")
    d, box, off = p.diameter, p.box, p.offsets()
    sets = _trajectory_sets(p)
    report = PhysicsReport(list(sets), profile_kind=kind)
    m, c = report.metrics, report.curves
    coeffs = mean_flow_fit(p, kind)
    edges = np.linspace(-NON_AFFINE_RANGE_D, NON_AFFINE_RANGE_D, NON_AFFINE_BINS + 1)
    c["non_affine_edges"] = edges
    for name, pos in sets.items():
        x, profile, _ = velocity_profile(pos, p.last_positions, box, off, bins=PROFILE_BINS)
        c["profile_x"] = x / d
        c[f"{name}/profile"] = profile / d
        r, gr = radial_distribution(pos[:, -1], box, GR_MAX_D * d, GR_BINS, off[:, -1])
        c["gr_r"] = r / d
        c[f"{name}/gr"] = gr
        msd = mean_squared_displacement(pos, p.last_positions, box, off, p.offset_increment)
        c[f"{name}/msd"] = msd / d**2
        na = non_affine_displacements(p, pos, kind, coeffs) / d  # (W, N, f, 3)
        c[f"{name}/non_affine_msd"] = (na**2).sum(-1).mean(axis=(0, 1))
        na = na[..., -1, :]
        c[f"{name}/non_affine_hist"] = np.histogram(na[..., 2], bins=edges)[0]
        m[f"{name}/overlap_fraction"] = overlap_fraction(
            pos[:, -1], box, d, off[:, -1], OVERLAP_TOLERANCE
        )
        m[f"{name}/coordination_contact"] = coordination_number(
            pos[:, -1], box, CONTACT_FACTOR * d, off[:, -1]
        )
        m[f"{name}/msd_last_over_d2"] = float(msd[-1]) / d**2
        m[f"{name}/non_affine_rms_over_d"] = float(np.sqrt((na**2).sum(-1).mean()))
    dr = c["gr_r"][1] - c["gr_r"][0]
    truth_mass = float(c["truth/gr"].sum() * dr)
    for name in sets:
        if name == "truth":
            continue
        m[f"{name}/profile_error_over_d"] = velocity_profile_error(
            c[f"{name}/profile"], c["truth/profile"]
        )
        m[f"{name}/gr_distance"] = float(
            np.abs(c[f"{name}/gr"] - c["truth/gr"]).sum() * dr / truth_mass
        )
    if le:
        mask = crossing_mask(p.last_positions, p.true_positions, box, off)
        m["crossers/n"] = float(mask.sum())
        for name, pos in sets.items():
            if name == "truth":
                continue
            res = position_residuals(pos, p.true_positions, box, off)
            squared = (res**2).sum(-1).mean(1)[mask]  # (crosser particle-windows,)
            value, low, high = bootstrap_rmse(squared)
            m[f"crossers/{name}/rmse_over_d"] = value / d
            m[f"crossers/{name}/ci_low_over_d"] = low / d
            m[f"crossers/{name}/ci_high_over_d"] = high / d
    return report


# --------------------------------------------------------------------------------------------
# command line: the report of any predictions.h5 (a run's, or gripdem.predict's)
# --------------------------------------------------------------------------------------------
#: the table's columns: metric key suffix, heading
TABLE_COLUMNS = (
    ("profile_error_over_d", "profile RMS diff / d"),
    ("gr_distance", "g(r) distance"),
    ("coordination_contact", "contacts Z"),
    ("msd_last_over_d2", "MSD / d²"),
    ("non_affine_rms_over_d", "non-affine RMS / d"),
    ("overlap_fraction", "overlap"),
)


def report_table(report: PhysicsReport) -> str:
    """Markdown table: one row per trajectory set (truth first), the scalars against the truth,
    and for LE data the crossers' RMSE with its bootstrap interval."""
    m = report.metrics
    head = "| set | " + " | ".join(h for _, h in TABLE_COLUMNS) + " |"
    lines = [head, "|" + "---|" * (len(TABLE_COLUMNS) + 1)]
    for name in report.sets:
        cells = []
        for key, _ in TABLE_COLUMNS:
            value = m.get(f"{name}/{key}")
            cells.append("–" if value is None else f"{value:.4g}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    if "crossers/n" in m:
        n = m["crossers/n"]
        lines += ["", f"LE crossers (n = {n:.0f} particle-windows): RMSE / d [95 % CI]"]
        for name in report.sets[1:]:
            lines.append(
                f"- {name}: {m[f'crossers/{name}/rmse_over_d']:.4g} "
                f"[{m[f'crossers/{name}/ci_low_over_d']:.4g}, "
                f"{m[f'crossers/{name}/ci_high_over_d']:.4g}]"
            )
    return "\n".join(lines)
