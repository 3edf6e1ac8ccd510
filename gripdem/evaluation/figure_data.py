"""What the run figures show, computed from a :class:`Predictions`
(docs/spec/evaluation.md#run-figures): the curves, samples and counts that :mod:`gripdem.plots.run`
draws without computing anything itself.

Lengths are in particle diameters d, velocities in d per frame interval. One dataclass per
figure; :func:`run_figure_data` computes all of them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from gripdem.boundary import lattice_shift, unwrap_trajectory
from gripdem.evaluation import metrics
from gripdem.evaluation.physics import (
    OVERLAP_TOLERANCE,
    fit_profile,
    overlap_fraction,
    pair_distances,
    profile_basis,
    velocity_profile,
)
from gripdem.evaluation.predictions import Predictions

#: at most this many points per group in the parity plot (a random subset beyond)
PARITY_MAX_POINTS = 20000
BASELINE_LABELS = {
    "stay": "stay",
    "constant_velocity": "constant velocity",
    "linear_ar": "linear AR",
    "mean_flow": "mean-flow profile",
    "member_0": "one ensemble member",
}


@dataclass
class RmseCurves:
    """Per horizon step RMSE / d ``(f,)`` and the total RMSE / d of each labelled set, model
    first."""

    curves: dict[str, tuple[np.ndarray, float]]


@dataclass
class CrosserTracks:
    """Rows of ``(face, window, particle, truth (f+1, 3), prediction (f+1, 3))``,
    lattice-continuous from the last observed frame, in d; ``box`` lengths in d."""

    rows: list[tuple[str, int, int, np.ndarray, np.ndarray]]
    box: np.ndarray


@dataclass
class ProfileCurves:
    """The imposed profile on a fine grid and the binned mean z velocity of each set."""

    imposed_x: np.ndarray
    imposed_vz: np.ndarray
    imposed_label: str
    curves: dict[str, tuple[np.ndarray, np.ndarray]]
    frame_interval: float


@dataclass
class ParityPoints:
    """Per group: true z, predicted z (image nearest the truth), z RMSE, in d; ``half`` lz/2."""

    groups: dict[str, tuple[np.ndarray, np.ndarray, float]]
    half: float


@dataclass
class PairHistogram:
    """Pair-distance histograms at the last predicted step and each set's overlap fraction."""

    edges: np.ndarray
    counts: dict[str, np.ndarray]
    overlap: dict[str, float]
    tolerance: float
    n_windows: int


@dataclass
class RunFigureData:
    """Everything the run figures draw (see the module doc)."""

    title: str
    model_name: str
    horizon: int
    rmse: RmseCurves
    crossers: CrosserTracks
    profile: ProfileCurves
    parity: ParityPoints
    pairs: PairHistogram
    extra: dict = field(default_factory=dict)


def model_name(p: Predictions) -> str:
    return str(p.info.get("model", "model"))


def rmse_curves(p: Predictions) -> RmseCurves:
    offsets = p.offsets()
    sets = {model_name(p): p.pred_positions}
    sets.update({BASELINE_LABELS.get(k, k): v for k, v in sorted(p.baselines.items())})
    curves = {}
    for label, pred in sets.items():
        res = metrics.position_residuals(pred, p.true_positions, p.box, offsets)
        curves[label] = (
            metrics.rmse_per_step(res) / p.diameter,
            metrics.rmse(res) / p.diameter,
        )
    return RmseCurves(curves)


def _with_last(p: Predictions, positions: np.ndarray) -> np.ndarray:
    """``(windows, horizon + 1, particles, 3)``: the last observed frame in front."""
    return np.concatenate([p.last_positions[:, None], positions], axis=1)


def pick_crossers(shifts: np.ndarray, axis: int, count: int) -> list[tuple[int, int]]:
    """Up to ``count`` (window, particle) whose truth crosses the face of ``axis`` (0: x, 2: z
    not through an x crossing), the crossing nearest the middle of the horizon first.
    ``shifts``: lattice counts of each true step ``(windows, horizon, particles, 3)``."""
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


def crosser_tracks(p: Predictions, per_face: int = 2) -> CrosserTracks:
    """Sample particles whose truth crosses the x and the z faces (up to ``per_face`` each),
    unwrapped from the last observed frame (:func:`gripdem.boundary.unwrap_trajectory`, image
    cells moving with the LE offset), so a face crossing is a curve passing a face line."""
    frames = _with_last(p, p.true_positions)
    pred = _with_last(p, p.pred_positions)
    shifts = lattice_shift(frames[:, 1:] - frames[:, :-1], p.box, p.offsets()[..., None])
    increments = np.full(p.horizon, p.offset_increment)
    rows = []
    for face, axis in (("x", 0), ("z", 2)):
        for w, n in pick_crossers(shifts, axis, per_face):
            offsets = np.concatenate([[0.0], p.offsets()[w]])  # the anchor's is not used
            true_c = unwrap_trajectory(frames[w, :, n], p.box, offsets, increments)
            pred_c = unwrap_trajectory(pred[w, :, n], p.box, offsets, increments)
            rows.append((face, w, n, true_c / p.diameter, pred_c / p.diameter))
    return CrosserTracks(rows, p.box.lengths / p.diameter)


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


def profile_curves(
    p: Predictions,
    imposed: Callable[[np.ndarray], np.ndarray] | None = None,
    imposed_label: str = "imposed",
    bins: int = 16,
) -> ProfileCurves:
    """Mean z velocity against x over the horizon: truth, model, the mean-flow baseline, and
    the imposed profile (``None``: :func:`default_imposed`)."""
    if imposed is None:
        imposed, imposed_label = default_imposed(p)
    d, dt, offsets = p.diameter, p.frame_interval, p.offsets()
    x_fine = np.linspace(-0.5 * p.box.lx, 0.5 * p.box.lx, 200)
    sets = {"truth": p.true_positions, model_name(p): p.pred_positions}
    if "mean_flow" in p.baselines:
        sets["mean-flow baseline"] = p.baselines["mean_flow"]
    curves = {}
    for label, pos in sets.items():
        centres, vz, _ = velocity_profile(pos, p.last_positions, p.box, offsets, dt, bins)
        curves[label] = (centres / d, vz * dt / d)
    return ProfileCurves(
        x_fine / d, np.asarray(imposed(x_fine)) * dt / d, imposed_label, curves, dt
    )


def parity_points(p: Predictions, seed: int = 0) -> ParityPoints:
    """Predicted vs true z over all windows and steps. The prediction is taken at the image
    nearest the truth (true z minus the minimum-image residual), so a prediction just across a
    z face sits next to the diagonal; LE (or periodic x) crossers apart from the rest."""
    offsets = p.offsets()
    res = metrics.position_residuals(p.pred_positions, p.true_positions, p.box, offsets)
    true_z = p.true_positions[..., 2] / p.diameter
    pred_z = (p.true_positions[..., 2] - res[..., 2]) / p.diameter
    crossers = metrics.crossing_mask(p.last_positions, p.true_positions, p.box, offsets)
    mask = np.broadcast_to(crossers[:, None, :], true_z.shape)
    rng = np.random.default_rng(seed)
    kind = "LE" if p.boundary.is_lees_edwards else "periodic x"
    groups = {}
    for label, sel in (
        (f"others ({int((~crossers).sum())} particle-windows)", ~mask),
        (f"{kind}-face crossers ({int(crossers.sum())})", mask),
    ):
        t, q = true_z[sel], pred_z[sel]
        rmse_z = float(np.sqrt(np.mean((t - q) ** 2))) if t.size else float("nan")
        if t.size > PARITY_MAX_POINTS:
            keep = rng.choice(t.size, PARITY_MAX_POINTS, replace=False)
            t, q = t[keep], q[keep]
        groups[label] = (t, q, rmse_z)
    return ParityPoints(groups, 0.5 * p.box.lz / p.diameter)


def pair_histogram(
    p: Predictions, r_max_over_d: float = 2.0, bins: int = 80, tol: float = OVERLAP_TOLERANCE
) -> PairHistogram:
    """LE-aware minimum-image pair distances below ``r_max_over_d`` d at the last predicted
    step (all windows), truth and model, and their overlap fractions (below ``tol`` d)."""
    d, off = p.diameter, p.offsets()[:, -1]
    r_max = min(r_max_over_d * d, 0.499 * float(p.box.lengths.min()))
    edges = np.linspace(0.0, r_max / d, bins + 1)
    counts, overlap = {}, {}
    for label, pos in (("truth", p.true_positions), (model_name(p), p.pred_positions)):
        dist = pair_distances(pos[:, -1], p.box, r_max, off) / d
        counts[label] = np.histogram(dist, bins=edges)[0]
        overlap[label] = overlap_fraction(pos[:, -1], p.box, d, off, tol)
    return PairHistogram(edges, counts, overlap, tol, p.n_windows)


def run_figure_data(
    p: Predictions,
    imposed: Callable[[np.ndarray], np.ndarray] | None = None,
    imposed_label: str = "imposed",
) -> RunFigureData:
    """Everything :func:`gripdem.plots.run.run_figures` draws."""
    return RunFigureData(
        title=p.title(),
        model_name=model_name(p),
        horizon=p.horizon,
        rmse=rmse_curves(p),
        crossers=crosser_tracks(p),
        profile=profile_curves(p, imposed, imposed_label),
        parity=parity_points(p),
        pairs=pair_histogram(p),
    )
