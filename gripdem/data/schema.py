"""The gripdem HDF5 trajectory format: what a dataset holds and its checks (reading and
writing: :mod:`gripdem.data.dataset_io`).

Layout of one file (all lengths in metres, times in seconds)::

    /positions   (sims, frames, particles, 3) float64  wrapped into [-l/2, l/2)
    /times       (sims, frames)               float64  absolute frame times (need not start at 0)
    /velocities  (sims, frames, particles, 3) float64  optional
    /radii       (particles,)                 float64  optional, per-particle radii
    attrs:
      format = "gripdem", format_version = 1
      box (3,)                 box lengths (lx, ly, lz); the box is centred at the origin
      radius                   particle radius (required unless /radii is present)
      boundary                 "periodic" | "lees_edwards"
      shear_rate               1/s (0 for periodic)
      le_sign                  +1: +x image shifted by +delta (u_z = +shear_rate*x); -1: reverse
      le_time_origin           time at which the LE offset delta is 0
      body_force_amplitude     a in a_z(x) = a*cos(2*pi*x/lx), m/s^2 (0 if none)
      provenance               JSON: {"generator": ..., "version": ..., "parameters": {...}}

Every error raised here is a :class:`DatasetError` naming the file, the field and what was
expected.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gripdem.boundary import (
    RANDOM_CLOSE_PACKING,
    Boundary,
    Box,
)
from gripdem.errors import DatasetError

FORMAT_NAME = "gripdem"
FORMAT_VERSION = 1
#: relative tolerance on the frame interval for "equidistant" frames
TIME_RTOL = 1e-4
#: positions may lie this fraction of the box length outside [-l/2, l/2) (rounding, writers
#: that wrap to (-l/2, l/2])
POSITION_RTOL = 1e-6


@dataclass
class TrajectoryData:
    """Trajectories of one scene held in memory (the unit written and read by this module).

    positions: ``(sims, frames, particles, 3)`` wrapped; times: ``(sims, frames)`` absolute;
    velocities: optional, same shape as positions; radii: optional ``(particles,)``.
    """

    positions: np.ndarray
    times: np.ndarray
    boundary: Boundary
    radius: float
    body_force_amplitude: float = 0.0
    provenance: dict[str, Any] = field(default_factory=dict)
    velocities: np.ndarray | None = None
    radii: np.ndarray | None = None

    @property
    def box(self) -> Box:
        return self.boundary.box

    @property
    def n_sims(self) -> int:
        return self.positions.shape[0]

    @property
    def n_frames(self) -> int:
        return self.positions.shape[1]

    @property
    def n_particles(self) -> int:
        return self.positions.shape[2]

    @property
    def diameter(self) -> float:
        return 2.0 * self.radius

    @property
    def frame_interval(self) -> float:
        return float(np.mean(np.diff(self.times, axis=1)))

    def offsets(self) -> np.ndarray:
        """float64 LE offsets of every frame, ``(sims, frames)`` (zeros if periodic)."""
        return self.boundary.offset(self.times)


@dataclass(frozen=True)
class DatasetMeta:
    """Everything about a file except the big arrays (what a lazy reader needs)."""

    path: Path
    n_sims: int
    n_frames: int
    n_particles: int
    boundary: Boundary
    radius: float
    frame_interval: float
    body_force_amplitude: float
    provenance: dict[str, Any]
    has_velocities: bool

    @property
    def box(self) -> Box:
        return self.boundary.box

    @property
    def diameter(self) -> float:
        return 2.0 * self.radius


# --------------------------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------------------------
def check_shape(path, name: str, array: np.ndarray, shape: tuple, what: str) -> None:
    """Raise unless ``array`` has ``shape`` (``None`` = any length on that axis)."""
    if array.ndim != len(shape) or any(
        s is not None and a != s for a, s in zip(array.shape, shape, strict=True)
    ):
        raise DatasetError(path, name, f"expected shape {what}, got {tuple(array.shape)}")


def check_array(path, name: str, array: np.ndarray, shape: tuple, what: str) -> None:
    """Shape as :func:`check_shape`, and a floating-point dtype."""
    check_shape(path, name, array, shape, what)
    if not np.issubdtype(array.dtype, np.floating):
        raise DatasetError(path, name, f"expected a floating-point array, got dtype {array.dtype}")


#: names of the axes of the arrays of a file, for error messages (first offending entry)
AXIS_NAMES = {
    "positions": ("simulation", "frame", "particle", "axis"),
    "velocities": ("simulation", "frame", "particle", "axis"),
    "times": ("simulation", "frame"),
    "radii": ("particle",),
}
#: below this volume fraction the particle size and the box are taken to be in different units
MIN_VOLUME_FRACTION = 1e-6


def locate(name: str, index: tuple[int, ...]) -> str:
    """``simulation 2, frame 50, particle 7, axis x`` for an index into field ``name``."""
    names = AXIS_NAMES.get(name, ())
    if len(names) != len(index):
        return f"index {tuple(index)}"
    return ", ".join(
        f"{label} {'xyz'[i] if label == 'axis' and i < 3 else i}"
        for label, i in zip(names, index, strict=True)
    )


def check_finite(path, name: str, array: np.ndarray, origin: tuple[int, ...] = ()) -> None:
    """Raise naming the first non-finite entry. ``origin``: when ``array`` is a block of the
    field, the field index of the block's first entry, up to the block's first axis (e.g.
    ``(sim, first_frame)`` for frames of one simulation)."""
    bad = ~np.isfinite(array)
    if bad.any():
        first = np.argwhere(bad)[0]
        value = array[tuple(first)]
        full = tuple(int(i) for i in first)
        if origin:  # the block's first axis is the field's axis len(origin) - 1
            full = (*origin[:-1], origin[-1] + full[0], *full[1:])
        hint = ""
        if name in ("positions", "velocities") and array.ndim >= 2 and bad[tuple(first[:-1])].all():
            hint = (
                "; the whole particle is missing in that frame: particle counts must be constant "
                "(every frame holds every particle)"
            )
        raise DatasetError(
            path,
            name,
            f"expected finite values, found NaN/Inf: {float(value)!r} at {locate(name, full)}"
            + (f" ({int(bad.sum())} non-finite in all)" if not origin else "")
            + hint,
        )


def validate_times(path, times: np.ndarray) -> float:
    """Check ``(sims, frames)`` times: finite, strictly increasing, equidistant, one interval
    shared by all simulations. Returns the frame interval."""
    check_finite(path, "times", times)
    if times.shape[1] < 2:
        raise DatasetError(path, "times", f"expected at least 2 frames, got {times.shape[1]}")
    steps = np.diff(times, axis=1)
    if not (steps > 0).all():
        s, f = (int(i) for i in np.argwhere(steps <= 0)[0])
        raise DatasetError(
            path,
            "times",
            f"expected strictly increasing frame times; simulation {s} has "
            f"t[{f + 1}] = {times[s, f + 1]!r} <= t[{f}] = {times[s, f]!r}",
        )
    interval = float(np.median(steps))
    worst = float(np.max(np.abs(steps - interval)))
    if worst > TIME_RTOL * interval:
        s, f = (int(i) for i in np.unravel_index(np.argmax(np.abs(steps - interval)), steps.shape))
        raise DatasetError(
            path,
            "times",
            f"expected equidistant frames (relative tolerance {TIME_RTOL:g}); "
            f"simulation {s} has interval {steps[s, f]!r} between frames {f} and {f + 1}, "
            f"median interval {interval!r}",
        )
    return interval


def validate_positions(
    path,
    positions: np.ndarray,
    box: Box,
    sim_index: int | None = None,
    field: str = "positions",
    first_frame: int = 0,
) -> None:
    """Finite and inside ``[-l/2, l/2)`` within ``POSITION_RTOL`` per axis. ``positions``:
    ``(frames, particles, 3)`` of simulation ``sim_index`` from frame ``first_frame`` on, or
    any ``(..., 3)`` array (``sim_index=None``)."""
    origin = () if sim_index is None else (sim_index, first_frame)
    check_finite(path, field, positions, origin)
    for axis, length in enumerate(box.lengths):
        coords = positions[..., axis]
        tol = POSITION_RTOL * length
        lo, hi = float(coords.min()), float(coords.max())
        if lo < -0.5 * length - tol or hi > 0.5 * length + tol:
            outside = (coords < -0.5 * length - tol) | (coords > 0.5 * length + tol)
            first = tuple(int(i) for i in np.argwhere(outside)[0])
            if sim_index is None:
                where = f"first at index {first}"
            else:
                full = (sim_index, first_frame + first[0], *first[1:], axis)
                where = f"first at {locate(field, full)}: {float(coords[first])!r}"
            raise DatasetError(
                path,
                field,
                f"expected wrapped coordinates in [-l/2, l/2) = "
                f"[{-0.5 * length:g}, {0.5 * length:g}) on axis {'xyz'[axis]}, found "
                f"values in [{lo:g}, {hi:g}] ({where}); wrap them with "
                "gripdem.boundary.wrap_positions, or check that the box and the positions are "
                "in the same units",
            )


def validate(data: TrajectoryData, path=None) -> float:
    """Check an in-memory dataset; returns the frame interval. Raises :class:`DatasetError`."""
    pos = np.asarray(data.positions)
    check_array(path, "positions", pos, (None, None, None, 3), "(sims, frames, particles, 3)")
    s, f, n, _ = pos.shape
    if min(s, f, n) == 0:
        raise DatasetError(
            path, "positions", f"expected non-empty sims/frames/particles, got {pos.shape}"
        )
    times = np.asarray(data.times)
    check_array(path, "times", times, (s, f), f"(sims, frames) = ({s}, {f})")
    if data.velocities is not None:
        vel = np.asarray(data.velocities)
        check_array(path, "velocities", vel, pos.shape, f"{pos.shape} like positions")
        check_finite(path, "velocities", vel)
    interval = validate_times(path, times)
    check_radii(path, data.radius, data.radii, n)
    check_packing(path, data.boundary.box, n, data.radius, data.radii)
    check_units(path, data.boundary.box, n, data.radius, data.radii)
    for sim in range(s):
        validate_positions(path, pos[sim], data.boundary.box, sim)
    if not np.isfinite(data.body_force_amplitude):
        raise DatasetError(path, "body_force_amplitude", "expected a finite number")
    return interval


def check_radii(path, radius: float, radii: np.ndarray | None, n: int) -> None:
    if radii is not None:
        radii = np.asarray(radii)
        check_array(path, "radii", radii, (n,), f"(particles,) = ({n},)")
        check_finite(path, "radii", radii)
        if not (radii > 0).all():
            raise DatasetError(path, "radii", "expected positive radii")
    if not (np.isfinite(radius) and radius > 0):
        raise DatasetError(
            path, "radius", f"expected a positive particle radius in metres, got {radius!r}"
        )


def check_packing(path, box: Box, n: int, radius: float, radii) -> None:
    with np.errstate(over="ignore"):  # absurd sizes give inf, refused below
        cubes = (
            np.sum(np.asarray(radii, dtype=np.float64) ** 3)
            if radii is not None
            else n * np.float64(radius) ** 3
        )
        volume = (4.0 / 3.0) * np.pi * cubes
    phi = volume / box.volume
    if phi > RANDOM_CLOSE_PACKING:
        raise DatasetError(
            path,
            "radius" if radii is None else "radii",
            f"expected a volume fraction below random close packing ({RANDOM_CLOSE_PACKING}); "
            f"{n} particles of radius {radius:g} in a box of {box.lx:g} x {box.ly:g} x "
            f"{box.lz:g} give {phi:.3g} (is a diameter stored as the radius?)",
        )


def check_units(path, box: Box, n: int, radius: float, radii=None) -> None:
    """Particle size and box plausible in the same units: a particle smaller than half the
    shortest box length (the minimum-image convention needs it) and a volume fraction above
    :data:`MIN_VOLUME_FRACTION` (far below: a size in metres beside a box in micrometres)."""
    name = "radius" if radii is None or radius >= np.max(radii) else "radii"
    diameter = 2.0 * max(float(radius), float(np.max(radii)) if radii is not None else 0.0)
    shortest = float(np.min(box.lengths))
    if diameter >= 0.5 * shortest:
        raise DatasetError(
            path,
            name,
            f"expected a particle diameter below half the shortest box length "
            f"({0.5 * shortest:g}), got {diameter:g}: are the size and the box in the same units?",
        )
    phi = (
        box.volume_fraction(n, diameter)
        if radii is None
        else ((4.0 / 3.0) * np.pi * float(np.sum(np.asarray(radii) ** 3)) / box.volume)
    )
    if phi < MIN_VOLUME_FRACTION:
        raise DatasetError(
            path,
            name,
            f"expected a volume fraction of at least {MIN_VOLUME_FRACTION:g}; {n} particles of "
            f"diameter {diameter:g} in a box of {box.lx:g} x {box.ly:g} x {box.lz:g} give "
            f"{phi:.3g}: are the size and the box in the same units?",
        )


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------
