"""The physics of one trajectory on its own: structure, contacts, flow and motion.

Any trajectory ``(T, N, 3)`` of a scene (a DEM simulation, a rollout, data from another engine)
gets the quantities the rollout statistics compare (``gripdem.evaluation.rollout_stats``,
same definitions), for one set alone:

- ``g(r)``: the LE-aware radial distribution over ``[0, 3 d)`` in bins of ``0.03 d``, averaged
  over ``structure_frames`` frames spread evenly over the trajectory;
- ``coordination``: neighbours closer than 1.01 d per particle at those frames (the soft-contact
  DEM keeps its contacts at overlaps of ~1e-5 d);
- ``overlap_fraction``: particles with a neighbour closer than 0.98 d at those frames;
- the mean flow: the z-velocity profile against x (binned), and the least-squares imposed
  profile (periodic: ``A cos(2 pi x / lx) + drift``; Lees-Edwards: ``S x + drift``) of the
  per-frame steps;
- the motion: the mean-squared displacement against the lag of the lattice-continuous steps,
  with the flow (MSD) and with the fitted profile removed (non-affine MSD), and, from
  ``DIFFUSION_LAGS[1]`` frames on, the self-diffusion coefficient per axis.

Lengths in diameters, velocities in m/s, lags in frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gripdem.boundary import Boundary
from gripdem.evaluation.physics import (
    coordination_number,
    overlap_fraction,
    radial_distribution,
    velocity_profile,
)
from gripdem.evaluation.rollout_stats import (
    CONTACT_FACTOR,
    DIFFUSION_LAGS,
    diffusion_coefficients,
    fit_profile,
    frame_steps,
    lag_msd,
    profile_basis,
    profile_kind,
)

#: g(r) range and bin width, in diameters (bins with edges at 0.99 and 1.02 d, see
#: ``gripdem.evaluation.physics_report.GR_MAX_D``)
GR_MAX_D, GR_BIN_D = 2.97, 0.03
#: x bins of the velocity profile
PROFILE_BINS = 16


@dataclass
class TrajectoryPhysics:
    """The physics of one trajectory (see the module doc); arrays are numpy, lengths in d.

    ``gr_r_over_d``, ``gr``: ``(bins,)``; ``profile_x_over_d``, ``profile_vz``: ``(16,)``
    (m/s, NaN in an empty bin); ``profile``: ``(coefficient, drift)`` of the fitted imposed
    profile in m/s (``A`` of the cosine, or the slope ``S`` in 1/s for Lees-Edwards);
    ``lags``: ``(L,)`` frames with ``msd_over_d2`` and ``non_affine_msd_over_d2`` ``(L,)``;
    ``diffusion``: ``(3,)`` d² per frame interval, None for fewer than
    ``DIFFUSION_LAGS[1]`` frames.

    It is ``gripdem.PhysicsReport``, made by ``gripdem.physics``.

    Attributes:
        frames: frames of the trajectory.
        particles: particles per frame.
        profile_kind: ``"cosine"`` (periodic scene) or ``"linear"`` (Lees-Edwards).
        gr_r_over_d: ``(bins,)`` bin centres of g(r), in d.
        gr: ``(bins,)`` the radial distribution function.
        coordination: neighbours closer than 1.01 d per particle.
        overlap_fraction: particles with a neighbour closer than 0.98 d.
        profile_x_over_d: ``(16,)`` x bin centres of the velocity profile, in d.
        profile_vz: ``(16,)`` mean z velocity per bin, m/s (NaN in an empty bin).
        profile: ``(coefficient, drift)`` of the fitted imposed profile, m/s (the
            coefficient is the slope in 1/s for Lees-Edwards).
        lags: ``(L,)`` MSD lags, frames.
        msd_over_d2: ``(L,)`` mean-squared displacement, d².
        non_affine_msd_over_d2: ``(L,)`` the same with the fitted profile removed, d².
        diffusion: ``(3,)`` self-diffusion per axis, d² per frame interval, or None.
        notes: what could not be measured, and why.

    Examples:
        The report of a small sheared scene of the built-in DEM:

        >>> import gripdem
        >>> data = gripdem.generate("lebc", "tiny", sims=1, particles=300, frames=21)
        >>> report = gripdem.physics(data)
        >>> type(report) is gripdem.PhysicsReport
        True
        >>> report.gr.shape == report.gr_r_over_d.shape, report.profile_vz.shape
        (True, (16,))
        >>> bool((report.non_affine_msd_over_d2 < report.msd_over_d2).all())  # flow removed
        True
        >>> report.diffusion is None, report.notes[0]
        (True, 'self-diffusion needs 1000 frames (fit over lags (200, 1000)); this trajectory
        has 20')
    """

    frames: int
    particles: int
    profile_kind: str
    gr_r_over_d: np.ndarray
    gr: np.ndarray
    coordination: float
    overlap_fraction: float
    profile_x_over_d: np.ndarray
    profile_vz: np.ndarray
    profile: tuple[float, float]
    lags: np.ndarray
    msd_over_d2: np.ndarray
    non_affine_msd_over_d2: np.ndarray
    diffusion: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)

    def table(self) -> str:
        """The scalars as a Markdown table. Raises nothing of its own.

        Returns:
            the table, one row per quantity (``| quantity | value |``).

        Examples:
            ``data`` is the small sheared scene of the ``PhysicsReport`` example
            (``gripdem.generate("lebc", "tiny", sims=1, particles=300, frames=21)``):

            >>> table = gripdem.physics(data).table()
            >>> for line in table.splitlines()[:3]:
            ...     print(line)
            | quantity | value |
            |---|---|
            | frames x particles | 21 x 300 |
            >>> [line.split(" | ")[0].strip("| ") for line in table.splitlines()[3:7]]
            ['coordination (< 1.01 d)', 'overlap fraction (< 0.98 d)', 'g(r) peak (r / d)',
             'mean flow slope S (1/s)']
        """
        coefficient = "amplitude A (m/s)" if self.profile_kind == "cosine" else "slope S (1/s)"
        rows = [
            ("frames x particles", f"{self.frames} x {self.particles}"),
            ("coordination (< 1.01 d)", f"{self.coordination:.3f}"),
            ("overlap fraction (< 0.98 d)", f"{self.overlap_fraction:.4f}"),
            ("g(r) peak (r / d)", f"{self.gr.max():.2f} at {self.peak_over_d:.3f}"),
            (f"mean flow {coefficient}", f"{self.profile[0]:.4g}"),
            ("mean flow drift (m/s)", f"{self.profile[1]:.3g}"),
        ]
        for lag, total, na in zip(
            self.lags, self.msd_over_d2, self.non_affine_msd_over_d2, strict=True
        ):
            rows.append((f"MSD / non-affine MSD at lag {lag} (d²)", f"{total:.4g} / {na:.4g}"))
        if self.diffusion is not None:
            d = ", ".join(f"{v:.3g}" for v in self.diffusion)
            rows.append(("self-diffusion x, y, z (d² per frame)", d))
        return "\n".join(
            ["| quantity | value |", "|---|---|"] + [f"| {k} | {v} |" for k, v in rows]
        )

    @property
    def peak_over_d(self) -> float:
        """Where g(r) peaks, in diameters.

        Returns:
            the centre of g(r)'s highest bin, in d.

        Examples:
            ``data`` is the small sheared scene of the ``PhysicsReport`` example
            (``gripdem.generate("lebc", "tiny", sims=1, particles=300, frames=21)``): its
            particles touch, so g(r) peaks at one diameter:

            >>> round(gripdem.physics(data).peak_over_d, 1)
            1.0
        """
        return float(self.gr_r_over_d[int(np.argmax(self.gr))])


def default_lags(steps: int) -> list[int]:
    """1, 2, 5, 10, 20, 50, ... up to half the trajectory's steps (at least lag 1)."""
    lags, decade = [], 1
    while True:
        for factor in (1, 2, 5):
            lag = factor * decade
            if lag > max(1, steps // 2):
                return lags or [1]
            lags.append(lag)
        decade *= 10


def trajectory_physics(
    positions: np.ndarray,
    times: np.ndarray,
    boundary: Boundary,
    diameter: float,
    lags: list[int] | None = None,
    structure_frames: int = 10,
) -> TrajectoryPhysics:
    """The physics of ``positions`` ``(T, N, 3)`` (wrapped) at ``times`` ``(T,)`` in the cell
    ``boundary`` for particles of ``diameter`` (see the module doc). ``lags``: of the MSD, in
    frames (default ``default_lags``); ``structure_frames``: frames, spread evenly, over
    which g(r), coordination and overlaps are averaged."""
    positions = np.asarray(positions, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[-1] != 3 or len(positions) < 2:
        raise ValueError(f"positions must be (frames >= 2, particles, 3), got {positions.shape}")
    if times.shape != positions.shape[:1]:
        raise ValueError(f"times must be ({len(positions)},), got {times.shape}")
    if not (np.isfinite(positions).all() and np.isfinite(times).all()):
        raise ValueError("positions and times must be finite (NaN or Inf found)")
    d, box, n_steps = float(diameter), boundary.box, len(positions) - 1
    offsets = boundary.offset(times)
    picked = np.unique(np.linspace(0, n_steps, min(structure_frames, n_steps + 1)).astype(int))
    at = positions[picked]
    r, gr = radial_distribution(at, box, GR_MAX_D * d, round(GR_MAX_D / GR_BIN_D), offsets[picked])
    steps, x_mid = frame_steps(positions, offsets, boundary)
    fit = fit_profile(steps, x_mid, boundary)
    dt = float(np.mean(np.diff(times)))
    x_bins, vz, _ = velocity_profile(  # the trajectory as one window after its first frame
        positions[None, 1:], positions[:1], box, offsets[None, 1:], dt, PROFILE_BINS
    )
    non_affine = steps.copy()
    non_affine[..., 2] -= profile_basis(x_mid, boundary) @ fit
    lags = default_lags(n_steps) if lags is None else [int(v) for v in lags]
    starts = range(0, n_steps, max(1, n_steps // 100))
    msd = [lag_msd(steps / d, starts, lag) for lag in lags]
    na_msd = [lag_msd(non_affine / d, starts, lag) for lag in lags]
    notes = []
    diffusion = None
    if n_steps >= DIFFUSION_LAGS[1]:
        diffusion = diffusion_coefficients(positions, positions, times, boundary, d)
    else:
        notes.append(
            f"self-diffusion needs {DIFFUSION_LAGS[1]} frames (fit over lags {DIFFUSION_LAGS}); "
            f"this trajectory has {n_steps}"
        )
    return TrajectoryPhysics(
        frames=len(positions),
        particles=positions.shape[1],
        profile_kind=profile_kind(boundary),
        gr_r_over_d=r / d,
        gr=gr,
        coordination=coordination_number(at, box, CONTACT_FACTOR * d, offsets[picked]),
        overlap_fraction=overlap_fraction(at, box, d, offsets[picked]),
        profile_x_over_d=x_bins / d,
        profile_vz=vz,
        profile=(float(fit[0] / dt), float(fit[1] / dt)),
        lags=np.asarray(lags),
        msd_over_d2=np.asarray(msd),
        non_affine_msd_over_d2=np.asarray(na_msd),
        diffusion=diffusion,
        notes=notes,
    )
