"""Import the authors' published Fordatis format (docs/spec/data.md#fordatis) into gripdem's
:class:`TrajectoryData`.

Input: a tar archive (``.tar.gz``, ``.tar``, ...) of HDF5 files, or one HDF5 file. Every HDF5
file is one simulation (the reference scripts read only the first). In each file, one group
``Step#k`` per frame (``k`` consecutive, any start) with

- attributes ``Time`` (scalar or 1-element array; absolute), ``Lower`` and ``Upper`` (box corners);
- datasets ``Identifier`` (integers) and ``Coords_0``, ``Coords_1``, ``Coords_2`` (x, y, z),
  particles in any order.

What the importer does (and why):

- particles are ordered by ascending ``Identifier`` in every frame;
- ``--drop-frames N`` drops the first N frames of every file (the reference dropped 20);
- the box is ``Upper - Lower``; when ``Lower != -Upper`` positions are shifted by the box centre
  (a translation, which leaves a Lees-Edwards offset unchanged) and then wrapped;
- files with different frame counts are trimmed to the shortest (kept frames from the start),
  and the report says which were trimmed; files must share particle count, box and frame interval;
- the files carry no particle size: ``diameter`` (default the paper's 2.5e-6 m, read as a
  diameter, docs/spec/conventions.md#size-and-cutoff) sets the radius;
- Lees-Edwards data: the shear rate comes from the user, the sign convention and the time origin
  (time at which delta = 0) are inferred from particles that cross the x faces, and the shear
  rate is checked against them: :func:`gripdem.formats.le_inference.infer_lees_edwards`. Periodic
  data (no shear rate) is checked too: its crossers must not jump in z.

Archive members are copied one at a time into a private temporary directory under a generated
name (the member's own name is never used as a path, so no path traversal) and deleted after
reading; the archive is read as a stream, never held in memory. Every data error is a
:class:`FordatisError` naming the file (``archive[member]``), the group or field and the
expectation.
"""

from __future__ import annotations

import tempfile
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gripdem._version import __version__
from gripdem.boundary import Boundary, Box, check_volume_fraction, wrap_positions
from gripdem.data.schema import TIME_RTOL, TrajectoryData, validate
from gripdem.formats.drive import check_amplitude, check_periodic, drive_lines
from gripdem.formats.fordatis.files import (
    BOX_RTOL,
    FordatisError,
    RawSimulation,
    archive_members,
    read_simulation,
)
from gripdem.formats.le_inference import (
    LeEvidence,
    check_le_options,
    find_crossings,
    infer_lees_edwards,
)

#: the paper's particle size, taken as a diameter (docs/spec/conventions.md#size-and-cutoff)
DEFAULT_DIAMETER = 2.5e-6


@dataclass
class ImportReport:
    """What the importer found (printed by ``python -m gripdem.convert``)."""

    source: str
    files: list[RawSimulation]
    skipped: list[str]
    n_frames: int
    boundary: Boundary
    diameter: float
    volume_fraction: float
    frame_interval: float
    evidence: LeEvidence | None
    notes: list[str] = field(default_factory=list)
    body_force_amplitude: float = 0.0
    drive: list[str] = field(default_factory=list)


# --------------------------------------------------------------------------------------------
# reading one HDF5 file
# --------------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------------
# archives
# --------------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------------
# the importer
# --------------------------------------------------------------------------------------------
def _check_options(shear_rate, le_sign, time_origin, drop_frames, diameter) -> None:
    check_le_options(shear_rate, le_sign, time_origin, "1/s; omit it for periodic data")
    if shear_rate is None and (le_sign is not None or time_origin is not None):
        raise ValueError("--le-sign and --time-origin are for Lees-Edwards data: give --shear-rate")
    if not (isinstance(drop_frames, int) and drop_frames >= 0):
        raise ValueError(f"--drop-frames must be a whole number >= 0, got {drop_frames!r}")
    if not (np.isfinite(diameter) and diameter > 0):
        raise ValueError(f"--diameter must be a positive length in metres, got {diameter!r}")


def _combine(sims: list[RawSimulation]) -> tuple[Box, int, float, list[str]]:
    """Check that all files agree; return box, common frame count, interval and notes."""
    first = sims[0]
    box = Box.from_lengths(first.lengths)
    interval = float(np.median(np.diff(first.times)))
    n = first.positions.shape[1]
    for sim in sims[1:]:
        if sim.positions.shape[1] != n:
            raise FordatisError(
                sim.name,
                "Identifier",
                f"expected {n} particles like {first.name}, got "
                f"{sim.positions.shape[1]} (all files must hold the same number of particles)",
            )
        if np.max(np.abs(sim.lengths - first.lengths)) > BOX_RTOL * np.max(first.lengths):
            raise FordatisError(
                sim.name,
                "Lower/Upper",
                f"expected the box of {first.name} "
                f"{first.lengths.tolist()}, got {sim.lengths.tolist()} (one box per dataset)",
            )
        other = float(np.median(np.diff(sim.times)))
        if abs(other - interval) > TIME_RTOL * interval:
            raise FordatisError(
                sim.name,
                "Time",
                f"expected the frame interval of {first.name} ({interval!r} s) "
                f"within relative tolerance {TIME_RTOL:g}, got {other!r} s",
            )
    n_frames = min(sim.positions.shape[0] for sim in sims)
    notes = [
        f"{sim.name}: trimmed from {sim.positions.shape[0]} to {n_frames} kept frames (files "
        "with different frame counts are cut to the shortest, keeping the first frames)"
        for sim in sims
        if sim.positions.shape[0] > n_frames
    ]
    return box, n_frames, interval, notes


def _origin_candidates(sims: list[RawSimulation], interval: float) -> list[tuple[float, str]]:
    """Time origins to try before estimating one: 0 (absolute times), then the first stored
    and the first kept frame time when all files share them."""
    out = [(0.0, "0: frame times taken as absolute")]
    for values, how in (
        ([sim.first_time for sim in sims], "time of the first stored frame"),
        ([float(sim.times[0]) for sim in sims], "time of the first kept frame"),
    ):
        if np.ptp(values) <= TIME_RTOL * interval and all(
            abs(values[0] - t0) > TIME_RTOL * interval for t0, _ in out
        ):
            out.append((values[0], how))
    return out


def read_fordatis(
    source: str | Path,
    *,
    shear_rate: float | None = None,
    le_sign: int | None = None,
    time_origin: float | None = None,
    drop_frames: int = 0,
    diameter: float = DEFAULT_DIAMETER,
    body_force: float | None = None,
) -> tuple[TrajectoryData, ImportReport]:
    """Import an archive (or one HDF5 file) of the authors' format.

    ``shear_rate=None`` means periodic data (checked: particles crossing the x faces must not
    jump in z). With a shear rate the data is Lees-Edwards; ``le_sign`` and ``time_origin`` are
    inferred when not given, and verified when given. ``body_force``: the amplitude A of the
    periodic drive ``A cos(2 pi x / lx)`` along z (:mod:`gripdem.formats.drive`; periodic data
    only). Returns the validated dataset (positions ``(sims, frames, particles, 3)`` wrapped)
    and a report of what was found.
    """
    _check_options(shear_rate, le_sign, time_origin, drop_frames, diameter)
    amplitude = check_amplitude(body_force)
    check_periodic(amplitude, shear_rate is not None, f"--shear-rate {shear_rate}: ")
    source = Path(source)
    skipped: list[str] = []
    with (
        tempfile.TemporaryDirectory(prefix="gripdem-fordatis-") as tmp,
        closing(archive_members(source, Path(tmp), skipped)) as members,
    ):
        sims = [read_simulation(path, label, drop_frames) for label, path in members]
    if not sims:
        raise FordatisError(source, "<archive>", "expected at least one HDF5 file; found none")
    box, n_frames, interval, notes = _combine(sims)
    positions = np.stack([sim.positions[:n_frames] for sim in sims])
    times = np.stack([sim.times[:n_frames] for sim in sims])
    phi = check_volume_fraction(positions.shape[2], diameter, box, f"{source}: --diameter")
    found = find_crossings(
        [(sim.positions[:n_frames], sim.times[:n_frames]) for sim in sims],
        box,
        lambda s, f, p: (
            f"{sims[s].name} {sims[s].step_name(f)} -> {sims[s].step_name(f + 1)}, "
            f"Identifier {int(sims[s].identifiers[p])}"
        ),
    )
    lees_edwards, evidence = infer_lees_edwards(
        found,
        box,
        diameter,
        shear_rate,
        le_sign,
        time_origin,
        _origin_candidates(sims, interval),
        str(source),
    )
    boundary = Boundary(box, lees_edwards)
    offsets = boundary.offset(times)[..., None]
    positions = wrap_positions(positions, box, offsets if lees_edwards is not None else None)
    drive, drive_notes = drive_lines(amplitude, boundary, positions, times)
    data = TrajectoryData(
        positions=positions,
        times=times,
        boundary=boundary,
        radius=0.5 * diameter,
        body_force_amplitude=amplitude,
        provenance={
            "generator": "gripdem.formats.fordatis",
            "version": __version__,
            "parameters": {
                "source": str(source),
                "files": [sim.name for sim in sims],
                "drop_frames": drop_frames,
                "frames": n_frames,
                "diameter": diameter,
                "shear_rate": shear_rate,
                "body_force_amplitude": amplitude,
                "le_sign_given": le_sign,
                "time_origin_given": time_origin,
                "le_inference": None if evidence is None else evidence.lines(),
                "centres": [sim.centre.tolist() for sim in sims],
                "identifier_ranges": [
                    [int(sim.identifiers[0]), int(sim.identifiers[-1])] for sim in sims
                ],
                "skippedarchive_members": skipped,
            },
        },
    )
    validate(data, source)
    report = ImportReport(
        source=str(source),
        files=sims,
        skipped=skipped,
        n_frames=n_frames,
        boundary=boundary,
        diameter=diameter,
        volume_fraction=phi,
        frame_interval=interval,
        evidence=evidence,
        notes=notes + drive_notes,
        body_force_amplitude=amplitude,
        drive=drive,
    )
    return data, report
