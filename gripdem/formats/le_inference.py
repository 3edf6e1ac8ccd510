"""Infer (or verify) a Lees-Edwards sign convention and time origin from wrapped trajectories.

Importers of foreign data (the authors' Fordatis files, later LAMMPS dumps) know the shear rate
from the user but not the sign convention of the producing code nor the time at which its
offset delta was 0. Both are read off the particles that cross the x faces: with the right
settings every frame-to-frame displacement, taken as the LE-aware minimum image with the LATER
frame's offset (docs/spec/conventions.md#which-offset), is as small as the moves of the particles
that do not cross. With the wrong sign a crosser's z jumps by ``2*delta`` (mod lz), with a wrong
origin by the offset error.

"Small" is ``max(SMALL_FACTOR * largest non-crosser displacement, SMALL_FLOOR * diameter)``: a
crosser is a particle near an x face, so the non-crossers near the faces move as much as it
does when the settings are right.

The "small" test alone cannot see an origin or rate error smaller than that threshold, so each
crossing also implies the offset at its time (its z jump, corrected for the mean flow at the
face): :func:`fit_offsets` compares those with the settings. A wrong origin leaves a constant
error (the origin is then estimated from them), a wrong shear rate a drift in time (refused,
with the rate the crossers fit).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from gripdem.boundary import Box, LeesEdwards, lattice_shift, minimum_image, wrap_coordinate
from gripdem.data.schema import DatasetError

SMALL_FACTOR = 3.0
SMALL_FLOOR = 0.05
#: a time origin agrees with the crossers when the mean offset error it leaves is below
#: max(3 standard errors, ORIGIN_FLOOR diameters)
ORIGIN_FLOOR = 0.02
#: the given shear rate agrees with the crossers when the relative rate error their offsets
#: imply is below max(4 standard errors, RATE_RTOL)
RATE_RTOL = 0.02


def check_le_options(
    shear_rate: float | None, le_sign: int | None, time_origin: float | None, units: str
) -> None:
    """The Lees-Edwards options every importer takes, checked with the option named:
    ``--shear-rate`` positive (in ``units``; the flow direction is the sign), ``--le-sign``
    +1 or -1, ``--time-origin`` finite."""
    if shear_rate is not None and not (np.isfinite(shear_rate) and shear_rate > 0):
        raise ValueError(
            f"--shear-rate must be a positive rate ({units}), got {shear_rate!r} (the flow "
            "direction is the LE sign, inferred from the data or given with --le-sign)"
        )
    if le_sign is not None and le_sign not in (1, -1):
        raise ValueError(f"--le-sign must be +1 or -1, got {le_sign!r}")
    if time_origin is not None and not np.isfinite(time_origin):
        raise ValueError(f"--time-origin must be finite, got {time_origin!r}")


@dataclass
class Crossings:
    """Frame-to-frame moves of all simulations, split into x-face crossers and the rest.

    vectors: ``(m, 3)`` raw ``later - earlier`` positions of the m crossing moves; n_x: ``(m,)``
    their x image counts (-1: left through +x); t_later, dt: ``(m,)`` time of the later frame
    and the frame interval; where: ``(m, 3)`` (simulation, earlier frame, particle);
    max_other: largest periodic minimum-image displacement of every other move (length units).
    """

    vectors: np.ndarray
    n_x: np.ndarray
    t_later: np.ndarray
    dt: np.ndarray
    where: np.ndarray
    max_other: float
    n_moves: int
    describe_move: Callable[[int, int, int], str] = field(repr=False)

    @property
    def n(self) -> int:
        return self.vectors.shape[0]

    def describe(self, i: int) -> str:
        """Where crossing ``i`` happens, for messages."""
        return self.describe_move(*(int(v) for v in self.where[i]))

    def largest(self, box: Box, le: LeesEdwards | None) -> tuple[float, int]:
        """Largest crosser displacement with settings ``le`` (None: periodic), using the later
        frame's offset, and the index of that crossing (-1 when there is none)."""
        if self.n == 0:
            return 0.0, -1
        offset = None if le is None else le.offset(box, self.t_later)
        norms = np.linalg.norm(minimum_image(self.vectors, box, offset), axis=-1)
        i = int(np.argmax(norms))
        return float(norms[i]), i


def find_crossings(
    trajectories: Sequence[tuple[np.ndarray, np.ndarray]],
    box: Box,
    describe_move: Callable[[int, int, int], str],
) -> Crossings:
    """Collect x-face crossings of ``(positions (frames, particles, 3), times (frames,))``
    pairs, one simulation at a time. ``describe_move(sim, frame, particle)`` names a move."""
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("v", "nx", "t", "dt", "where")}
    max_other, n_moves = 0.0, 0
    for s, (positions, times) in enumerate(trajectories):
        moves = positions[1:] - positions[:-1]
        n_x = lattice_shift(moves, box)[..., 0]
        cross = n_x != 0
        other = minimum_image(moves[~cross], box)
        if other.size:
            max_other = max(max_other, float(np.linalg.norm(other, axis=-1).max()))
        frame, particle = np.nonzero(cross)
        parts["v"].append(moves[cross])
        parts["nx"].append(n_x[cross])
        parts["t"].append(times[1:][frame])
        parts["dt"].append(np.diff(times)[frame])
        parts["where"].append(np.stack([np.full_like(frame, s), frame, particle], axis=-1))
        n_moves += moves.shape[0] * moves.shape[1]
    return Crossings(
        vectors=np.concatenate(parts["v"]).reshape(-1, 3),
        n_x=np.concatenate(parts["nx"]),
        t_later=np.concatenate(parts["t"]),
        dt=np.concatenate(parts["dt"]),
        where=np.concatenate(parts["where"]).reshape(-1, 3),
        max_other=max_other,
        n_moves=n_moves,
        describe_move=describe_move,
    )


@dataclass(frozen=True)
class OffsetFit:
    """How well the LE settings (sign, ``t0``) explain the crossers' z jumps.

    offset_error: circular mean of (offset a crossing implies) - (offset from the settings),
    length units; standard_error: its standard error; estimate: the origin that removes the
    mean error (origins a whole offset period ``lz/(shear_rate*lx)`` apart are equivalent);
    rate_error: relative shear-rate error implied by a linear drift of the residuals in time,
    with its standard error (inf where fewer than 3 crossings or one crossing time).
    """

    t0: float
    offset_error: float
    standard_error: float
    estimate: float
    rate_error: float
    rate_standard_error: float


def fit_offsets(found: Crossings, box: Box, shear_rate: float, sign: int, t0: float) -> OffsetFit:
    """Compare the settings (``sign``, ``t0``) with the offsets the crossers imply.

    A crosser's raw z jump is ``dz - n_x*delta(t)`` (mod lz); its true ``dz`` at the face is
    the mean flow there, ``-n_x*v*dt/2`` with ``v = sign*shear_rate*lx``, so each crossing
    implies ``delta(t) = n_x*r_z + v*dt/2``. With the right settings these agree with
    ``v*(t - t0)`` up to the crossers' own random motion; a wrong origin shifts all of them by
    the same amount, a wrong shear rate makes them drift in time.
    """
    use = np.abs(found.n_x) == 1
    m = int(use.sum())
    le = LeesEdwards(shear_rate, sign, t0)
    v = le.image_velocity(box)
    if m == 0:
        return OffsetFit(t0, 0.0, np.inf, t0, 0.0, np.inf)
    implied = found.n_x[use] * found.vectors[use, 2] + 0.5 * v * found.dt[use]
    residual = wrap_coordinate(implied - le.offset(box, found.t_later[use]), box.lz)
    angle = np.angle(np.mean(np.exp(2j * np.pi * residual / box.lz)))
    error = float(angle * box.lz / (2 * np.pi))
    spread = wrap_coordinate(residual - error, box.lz)
    se = float(np.std(spread, ddof=1) / np.sqrt(m)) if m >= 3 else np.inf
    t = found.t_later[use] - found.t_later[use].mean()
    rate, rate_se = 0.0, np.inf
    if m >= 3 and (t != 0).any():
        slope = float(np.sum(t * spread) / np.sum(t * t))
        dev = spread - spread.mean() - slope * t
        rate = slope / v
        rate_se = float(np.sqrt(np.sum(dev**2) / (m - 2) / np.sum(t * t)) / abs(v))
    return OffsetFit(t0, error, se, t0 - error / v, rate, rate_se)


@dataclass
class LeEvidence:
    """How the boundary was decided: crossings, displacements, time origin (lengths in m)."""

    diameter: float
    n_crossers: int
    n_moves: int
    max_other: float
    threshold: float
    max_crosser: dict[str, float] = field(default_factory=dict)
    origin: str = ""
    shear_rate: str = ""
    worst: str = ""

    def lines(self) -> list[str]:
        d = self.diameter
        out = [
            f"{self.n_crossers} x-face crossing(s) in {self.n_moves} frame-to-frame moves",
            f"largest displacement of the other moves: {self.max_other / d:.3g} d; a crosser's "
            f"displacement counts as small below {self.threshold / d:.3g} d",
        ]
        out += [
            f"largest crosser displacement with {label}: {value / d:.3g} d"
            for label, value in self.max_crosser.items()
        ]
        out += [f"time origin: {self.origin}"] if self.origin else []
        out += [f"shear rate: {self.shear_rate}"] if self.shear_rate else []
        out += [f"largest crosser: {self.worst}"] if self.worst else []
        return out


def infer_lees_edwards(
    found: Crossings,
    box: Box,
    diameter: float,
    shear_rate: float | None,
    le_sign: int | None = None,
    time_origin: float | None = None,
    candidates: Sequence[tuple[float, str]] = ((0.0, "0: frame times taken as absolute"),),
    where: str | None = None,
) -> tuple[LeesEdwards | None, LeEvidence]:
    """Decide the boundary of a dataset from its crossings; raise :class:`DatasetError`
    (naming ``where``) when the data does not allow a clear decision.

    - ``shear_rate=None``: periodic; verified (crossers must not jump in z, else the data looks
      sheared and the user is asked for ``--shear-rate``).
    - No crossers: ``le_sign`` is required; the origin is ``time_origin`` or 0, unverified.
    - Sign: the one under which every crosser's displacement is small at one of the origins
      tried (``time_origin`` if given, else ``candidates`` in turn, then origins estimated
      from the crossers). When both fit (crossings only where delta is near 0 or lz/2) the
      user is asked for ``--le-sign``; a given sign is verified the same way.
    - Origin: the first of ``time_origin``/``candidates`` whose offsets agree with the ones the
      crossers imply (within ``max(3 standard errors, ORIGIN_FLOOR d)``), else the estimate.
      A given origin that disagrees is refused.
    """
    threshold = max(SMALL_FACTOR * found.max_other, SMALL_FLOOR * diameter)
    evidence = LeEvidence(diameter, found.n, found.n_moves, found.max_other, threshold)
    if shear_rate is None:
        largest, i = found.largest(box, None)
        evidence.max_crosser["periodic boundaries"] = largest
        if largest > threshold:
            raise DatasetError(
                where,
                "Coords_2",
                f"particles crossing the x faces jump by up to "
                f"{largest / diameter:.3g} d ({found.describe(i)}), more than the "
                f"{threshold / diameter:.3g} d a frame-to-frame move may take: this looks like "
                "Lees-Edwards data; give --shear-rate",
            )
        return None, evidence
    if found.n == 0:
        if le_sign is None:
            raise DatasetError(
                where,
                "Coords_0",
                f"no particle crosses the x faces in {found.n_moves} "
                "frame-to-frame moves, so the Lees-Edwards sign cannot be inferred; pass "
                "--le-sign +1 (gripdem: +x image shifted by +delta, u_z = +shear_rate*x) or -1 "
                "(the authors' scripts: +x image shifted by -delta)",
            )
        t0 = 0.0 if time_origin is None else time_origin
        how = "given" if time_origin is not None else "default"
        evidence.origin = f"{t0:.6g} s ({how}; unverified: no crossers)"
        return LeesEdwards(shear_rate, le_sign, t0), evidence

    d = diameter
    signs = (1, -1) if le_sign is None else (le_sign,)
    origins = [(time_origin, "given")] if time_origin is not None else list(candidates)
    tried: list[str] = []

    def maxima(t0: float, how: str) -> dict[int, float]:
        out = {s: found.largest(box, LeesEdwards(shear_rate, s, t0))[0] for s in (1, -1)}
        tried.append(
            f"t0={t0:.6g} s ({how}): sign +1 -> {out[1] / d:.3g} d, sign -1 -> {out[-1] / d:.3g} d"
        )
        return out

    def fail(what: str) -> DatasetError:
        return DatasetError(
            where,
            "Coords_2",
            f"{what} ({found.n} crossing(s); a displacement is small below "
            f"{threshold / d:.3g} d): "
            + "; ".join(tried)
            + ". Check --shear-rate"
            + ("" if le_sign is None else " and --le-sign")
            + ("" if time_origin is None else " and --time-origin"),
        )

    # 1. the sign
    sign, origin0 = None, origins[0][0]
    estimates = (
        []
        if time_origin is not None
        else [
            (fit_offsets(found, box, shear_rate, s, 0.0).estimate, f"estimated for sign {s:+d}")
            for s in signs
        ]
    )
    for t0, how in origins + estimates:
        fits = [s for s, value in maxima(t0, how).items() if s in signs and value <= threshold]
        if len(fits) == 2:
            raise DatasetError(
                where,
                "Coords_2",
                f"both Lees-Edwards signs fit all {found.n} crossing(s) "
                f"({tried[-1]}; small below {threshold / d:.3g} d): the crossings happen where "
                "delta is near 0 or lz/2; pass --le-sign",
            )
        if fits:
            sign, origin0 = fits[0], t0
            break
    if sign is None:
        raise fail(
            "no Lees-Edwards setting makes every crosser's frame-to-frame displacement small"
        )

    # 2. the time origin for that sign, then the shear rate against the crossers' drift
    fit = fit_offsets(found, box, shear_rate, sign, origin0)
    tolerance = max(3 * fit.standard_error, ORIGIN_FLOOR * d)
    period = box.lz / (shear_rate * box.lx)
    agree = [
        (t0, how)
        for t0, how in origins
        if abs(fit_offsets(found, box, shear_rate, sign, t0).offset_error) <= tolerance
    ]
    if agree:
        t0, how = agree[0]
    elif time_origin is not None:
        off = fit_offsets(found, box, shear_rate, sign, time_origin).offset_error
        raise DatasetError(
            where,
            "Coords_2",
            f"the crossers put the time origin at {fit.estimate:.6g} s "
            f"(modulo {period:.6g} s); the given {time_origin:.6g} s leaves an offset error of "
            f"{off / d:.3g} d (tolerance {tolerance / d:.3g} d); check --time-origin",
        )
    else:
        t0, how = fit.estimate, "estimated from the crossers"
    fit = fit_offsets(found, box, shear_rate, sign, t0)
    rate_tolerance = max(4 * fit.rate_standard_error, RATE_RTOL)
    if abs(fit.rate_error) > rate_tolerance:
        raise DatasetError(
            where,
            "Coords_2",
            f"the offsets the {found.n} crossing(s) imply drift against "
            f"--shear-rate {shear_rate:g} 1/s: they fit {shear_rate * (1 + fit.rate_error):.6g} "
            f"1/s (relative error {fit.rate_error:+.3g} +- {fit.rate_standard_error:.2g}, "
            f"tolerance {rate_tolerance:.2g}); check --shear-rate",
        )
    final = maxima(t0, how)
    if final[sign] > threshold:
        raise fail(
            f"with sign {sign:+d} and time origin {t0:.6g} s a crosser still moves "
            f"{final[sign] / d:.3g} d"
        )
    le = LeesEdwards(shear_rate, sign, t0)
    evidence.max_crosser = {f"sign {s:+d}": final[s] for s in (1, -1)}
    evidence.origin = (
        f"{t0:.6g} s ({how}); the crossers imply {fit.estimate:.6g} s (origins "
        f"{period:.6g} s apart are equivalent): offset error {fit.offset_error / d:.3g} d "
        f"+- {fit.standard_error / d:.2g} d, tolerance {tolerance / d:.3g} d"
    )
    evidence.shear_rate = (
        f"{shear_rate:g} 1/s; the crossers fit {shear_rate * (1 + fit.rate_error):.6g} 1/s "
        f"(relative {fit.rate_error:+.2g} +- {fit.rate_standard_error:.2g}, tolerance "
        f"{rate_tolerance:.2g})"
    )
    evidence.worst = found.describe(found.largest(box, le)[1])
    return le, evidence
