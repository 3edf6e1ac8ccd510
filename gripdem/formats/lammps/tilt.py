"""Lees-Edwards settings of a LAMMPS box sheared by a tilt factor (:mod:`gripdem.formats.lammps`).

LAMMPS's restricted triclinic cell ``a = (Lx, 0, 0), b = (xy, Ly, 0), c = (xz, yz, Lz)`` with one
tilt factor ``t`` is gripdem's LE lattice ``(lx, 0, delta), (0, ly, 0), (0, 0, lz)`` once the axes
are permuted (:class:`~gripdem.formats.lammps.series.AxisMap`), with ``delta = t`` (mod lz). A box
flip (``fix deform ... flip yes``) changes the tilt by one flow length, which is the same
lattice. :func:`tilt_lees_edwards` undoes the flips, fits the continuous tilt against time
(rate ``sign * shear_rate * lx``, zero at the time origin), checks the fit, the given options
and every snapshot; :func:`check_crossers` then asks the particles: with those settings a
crosser of the x faces must move as little as everyone else.
"""

from __future__ import annotations

import numpy as np

from gripdem.boundary import Box, LeesEdwards, wrap_coordinate
from gripdem.formats.lammps.dump import DumpError
from gripdem.formats.lammps.series import DumpSeries
from gripdem.formats.le_inference import SMALL_FACTOR, SMALL_FLOOR, Crossings, LeEvidence

#: the continuous tilt must lie on a line in time within this fraction of the flow length
TILT_RTOL = 1e-6
#: a given shear rate must match the tilt's rate within this relative tolerance
RATE_RTOL = 1e-3


def tilt_lees_edwards(
    series: list[DumpSeries],
    n_frames: int,
    component: int,
    box: Box,
    timestep: float,
    shear_rate: float | None,
    le_sign: int | None,
    time_origin: float | None,
) -> tuple[LeesEdwards, list[np.ndarray], list[str], list[str]]:
    """LE settings from the tilt factor ``component`` (0: xy, 1: xz, 2: yz) of every
    simulation; returns them, per-simulation times (shifted to a common time origin), report
    lines and notes."""
    name = ("xy", "xz", "yz")[component]
    lines, notes, fits = [], [], []
    for s in series:
        times = s.timesteps[:n_frames] * timestep
        tilt = s.tilt[:n_frames, component]
        folded = wrap_coordinate(np.diff(tilt), box.lz)
        flips = int(np.count_nonzero(np.round((np.diff(tilt) - folded) / box.lz)))
        continuous = tilt[0] + np.concatenate([[0.0], np.cumsum(folded)])
        rate, intercept = np.polyfit(times - times[0], continuous, 1)
        residual = continuous - (intercept + rate * (times - times[0]))
        worst = float(np.abs(residual).max())
        if worst > TILT_RTOL * box.lz + 1e-12 * abs(rate) * float(np.ptp(times)):
            raise DumpError(
                s.label,
                f"ITEM: BOX BOUNDS tilt {name}",
                f"the tilt (flips undone) does not grow linearly in time: off a line by up to "
                f"{worst:.3g} ({worst / box.lz:.2g} of the box) at TIMESTEP "
                f"{int(s.timesteps[int(np.argmax(np.abs(residual)))])}; Lees-Edwards data needs "
                "a constant shear rate (fix deform ... erate)",
            )
        if abs(rate) * float(np.ptp(times)) <= TILT_RTOL * box.lz:
            raise DumpError(
                s.label,
                f"ITEM: BOX BOUNDS tilt {name}",
                f"the box is tilted ({name} = {tilt[0]:.6g}) but not sheared (the tilt does not "
                "change): a static tilted box is not a gripdem scene",
            )
        period = box.lz / abs(rate)  # origins a whole offset period apart are equivalent
        origin = float(wrap_coordinate(np.asarray(times[0] - intercept / rate), period))
        origin = 0.0 if abs(origin) < 1e-12 * period else origin  # rounding of a zero origin
        fits.append((rate, origin, times, flips))
        lines.append(
            f"{s.label}: {name} from {tilt[0]:.6g} to {tilt[-1]:.6g}, {flips} flip(s) undone, "
            f"rate {rate:.6g} per unit time ({rate / box.lx:+.6g} x lx), zero at t = "
            f"{origin:.6g}, off a line by at most {worst / box.lz:.2g} of the box"
        )
    rate = fits[0][0]
    for s, (other, *_rest) in zip(series[1:], fits[1:], strict=True):
        if abs(other - rate) > RATE_RTOL * abs(rate):
            raise DumpError(
                s.label,
                f"ITEM: BOX BOUNDS tilt {name}",
                f"the tilt grows at {other:.6g} per unit time, {series[0].label} at {rate:.6g}: "
                "one shear rate per dataset",
            )
    sign, measured = (1 if rate > 0 else -1), abs(rate) / box.lx
    if shear_rate is not None and abs(measured - shear_rate) > RATE_RTOL * shear_rate:
        raise DumpError(
            series[0].label,
            f"ITEM: BOX BOUNDS tilt {name}",
            f"the tilt grows at {rate:.6g} per unit time = shear rate {measured:.6g} x box "
            f"length {box.lx:.6g} (gradient axis), not --shear-rate {shear_rate:g} "
            f"(relative tolerance {RATE_RTOL:g}); check --shear-rate and --timestep",
        )
    if le_sign is not None and le_sign != sign:
        raise DumpError(
            series[0].label,
            f"ITEM: BOX BOUNDS tilt {name}",
            f"the tilt {'grows' if sign > 0 else 'shrinks'} in time: LE sign {sign:+d}, not the "
            f"given --le-sign {le_sign:+d}",
        )
    origin = fits[0][1] if time_origin is None else float(time_origin)
    le = LeesEdwards(shear_rate if shear_rate is not None else measured, sign, origin)
    out_times = []
    for s, (_rate, own, times, _flips) in zip(series, fits, strict=True):
        if time_origin is None and own != origin:
            shift = wrap_coordinate(np.asarray(origin - own), box.lz / (measured * box.lx))
            times = times + float(shift)
            if shift != 0:
                notes.append(
                    f"{s.label}: times shifted by {float(shift):.6g} so that its tilt is zero at "
                    f"the common time origin {origin:.6g} (only the LE offset depends on time)"
                )
        error = wrap_coordinate(le.offset(box, times) - s.tilt[:n_frames, component], box.lz)
        worst = int(np.argmax(np.abs(error)))
        if abs(error[worst]) > TILT_RTOL * box.lz + 1e-9 * box.lz:
            raise DumpError(
                s.label,
                f"ITEM: BOX BOUNDS tilt {name}",
                f"TIMESTEP {int(s.timesteps[worst])}: tilt {s.tilt[worst, component]:.9g} but "
                f"shear rate {le.shear_rate:g}, sign {sign:+d}, time origin {le.time_origin:.6g} "
                f"give {float(le.offset(box, times[worst])):.9g} (mod {box.lz:.6g})"
                + ("; check --time-origin" if time_origin is not None else ""),
            )
        out_times.append(times)
    if shear_rate is None:
        notes.append(f"shear rate {measured:.6g} read from the tilt (no --shear-rate given)")
    return le, out_times, lines, notes


def check_crossers(
    found: Crossings, box: Box, le: LeesEdwards, diameter: float, where: str
) -> LeEvidence:
    """With the tilt's settings every x-face crosser must move as little as the others."""
    threshold = max(SMALL_FACTOR * found.max_other, SMALL_FLOOR * diameter)
    evidence = LeEvidence(diameter, found.n, found.n_moves, found.max_other, threshold)
    for sign in (le.sign, -le.sign):
        other = LeesEdwards(le.shear_rate, sign, le.time_origin)
        evidence.max_crosser[f"sign {sign:+d}"] = found.largest(box, other)[0]
    largest, i = found.largest(box, le)
    if largest > threshold:
        raise DumpError(
            where,
            "ITEM: ATOMS",
            f"with the box's Lees-Edwards settings a particle crossing the x faces still moves "
            f"{largest / diameter:.3g} d ({found.describe(i)}), more than the "
            f"{threshold / diameter:.3g} d a move may take: are the axes right (--axes), or "
            "the snapshots too far apart?",
        )
    if found.n:
        evidence.worst = found.describe(i)
    return evidence
