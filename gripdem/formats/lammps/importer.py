"""Import LAMMPS / LIGGGHTS text dumps (docs/spec/data.md#lammps) into gripdem's
:class:`TrajectoryData`.

What the importer does (and why):

- Snapshots of all files form one simulation, ordered by TIMESTEP (one or many snapshots per
  file, files in any order; ``split_files=True``: every file is one simulation). Snapshots
  repeated with identical coordinates (a restarted run) are dropped; particles are ordered by
  ``id`` in every snapshot and must be the same set in all of them.
- Coordinates: ``x y z`` (wrapped), ``xs ys zs`` (scaled), ``xu yu zu`` (unwrapped), ``xsu ysu
  zsu``, with or without image flags ``ix iy iz``; the first complete set in that order is used.
  Every form is a lattice translate of the stored position, so wrapping it with the box's
  lattice gives the same wrapped position. Velocities ``vx vy vz`` belong to the image LAMMPS
  stores (x, or xu minus the image flags times the cell): their z jump at an LE face is applied
  with that image.
- Frame times: ``TIMESTEP * timestep``; snapshots must be equidistant in TIMESTEP.
- Box: fully periodic (``pp pp pp``), the same lengths and origin in every snapshot; re-centred
  at the origin. A sheared LAMMPS box tilts one lower axis along a higher one (xy: flow along
  LAMMPS x, gradient along y). gripdem's gradient axis is x and flow axis z, so the axes are
  permuted: ours (x, y, z) = LAMMPS (gradient, other, flow) — for the usual xy tilt (y, z, x)
  (``axes="yzx"``) — and the tilt factor is our LE offset delta: the LAMMPS lattice
  ``a, b, c`` is then gripdem's LE lattice ``(lx, 0, delta), (0, ly, 0), (0, 0, lz)``.
- Lees-Edwards from the tilt: box flips (the tilt jumping by the flow length) are undone, the
  continuous tilt must grow linearly in time; its rate is ``sign * shear_rate * lx``, its zero
  the time origin. ``shear_rate`` (and ``le_sign``/``time_origin``), when given, are checked
  against it, and so is every snapshot's tilt; then particles crossing the x faces must move as
  little as the others (the convention is right). An orthogonal box with ``shear_rate`` is
  treated like the Fordatis files: sign and origin inferred from the crossers
  (:func:`gripdem.formats.le_inference.infer_lees_edwards`); without, it is periodic (checked).

Lengths and times keep the dump's units; gripdem's format and built-in models are SI, so give
``diameter`` and ``timestep`` in the dump's units and use SI dumps (``units si``) for them.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gripdem._version import __version__
from gripdem.boundary import (
    Boundary,
    Box,
    check_volume_fraction,
    wrap_positions,
)
from gripdem.data.schema import TrajectoryData, validate
from gripdem.formats.drive import check_amplitude, check_periodic, drive_lines
from gripdem.formats.lammps.dump import DumpError
from gripdem.formats.lammps.series import AxisMap, DumpSeries, read_series
from gripdem.formats.lammps.tilt import check_crossers, tilt_lees_edwards
from gripdem.formats.le_inference import (
    LeEvidence,
    check_le_options,
    find_crossings,
    infer_lees_edwards,
)


@dataclass
class LammpsReport:
    """What the importer found (printed by ``python -m gripdem.convert lammps``)."""

    series: list[DumpSeries]
    axes: AxisMap
    boundary: Boundary
    diameter: float
    volume_fraction: float
    frame_interval: float
    n_frames: int
    evidence: LeEvidence | None
    tilt: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    drive: list[str] = field(default_factory=list)

    def lines(self) -> list[str]:
        box, first = self.boundary.box, self.series[0]
        out = [f"simulations: {len(self.series)}"]
        for i, s in enumerate(self.series):
            out.append(f"  [{i}] {s.describe()}")
        out += [
            f"frames per simulation: {self.n_frames}",
            f"particles: {first.ids.size} (ordered by id, {first.ids[0]}..{first.ids[-1]})",
            f"columns: {first.kind} coordinates ({' '.join(first.coordinate_columns)})"
            + (", image flags" if first.has_image_flags else "")
            + (", velocities" if first.velocities is not None else "")
            + (", per-particle radius" if first.radii is not None else ""),
            f"axes: ours (x, y, z) = LAMMPS ({', '.join(self.axes.name)})",
            f"box: {box.lx:.6g} x {box.ly:.6g} x {box.lz:.6g} (centred at the origin)",
            f"frame interval: {self.frame_interval:.6g} ({first.step_interval} steps)",
            f"diameter: {self.diameter:.6g}, volume fraction {self.volume_fraction:.4f}",
            f"boundary: {self.boundary.kind}",
        ]
        le = self.boundary.lees_edwards
        if le is not None:
            out += [
                f"shear rate: {le.shear_rate:.6g}",
                f"LE sign: {le.sign:+d} (+x image shifted by {'+' if le.sign > 0 else '-'}delta)",
                f"LE time origin: {le.time_origin:.6g} (delta = 0 there)",
            ]
        out += self.drive
        out += [f"tilt: {line}" for line in self.tilt]
        if self.evidence is not None:
            out += ["evidence: " + line for line in self.evidence.lines()]
        return out + [f"note: {note}" for note in self.notes]


def _check_options(diameter, timestep, shear_rate, le_sign, time_origin) -> None:
    for name, value in (("--diameter", diameter), ("--timestep", timestep)):
        if not (value is not None and np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number (the dump's units), got {value!r}")
    check_le_options(shear_rate, le_sign, time_origin, "the dump's units")


def _combine(series: list[DumpSeries]) -> tuple[int, list[str]]:
    """All simulations must agree on particles, box and interval; returns the common frame
    count (the shortest) and notes."""
    first, notes = series[0], []
    for s in series[1:]:
        if s.ids.size != first.ids.size:
            raise DumpError(
                s.label,
                "ITEM: NUMBER OF ATOMS",
                f"expected {first.ids.size} atoms like {first.label}, got {s.ids.size}",
            )
        scale = float(first.lengths.max())
        if np.abs(s.lengths - first.lengths).max() > 1e-6 * scale:
            raise DumpError(
                s.label,
                "ITEM: BOX BOUNDS",
                f"expected the box of {first.label} ({first.lengths.tolist()}), got "
                f"{s.lengths.tolist()} (one box per dataset)",
            )
        if s.step_interval != first.step_interval:
            raise DumpError(
                s.label,
                "ITEM: TIMESTEP",
                f"expected snapshots every {first.step_interval} steps like {first.label}, "
                f"got {s.step_interval}",
            )
    n_frames = min(s.n_frames for s in series)
    for s in series:
        if s.n_frames > n_frames:
            notes.append(f"{s.label}: trimmed from {s.n_frames} to {n_frames} frames (shortest)")
    return n_frames, notes


def read_lammps(
    paths: Sequence[str | os.PathLike],
    *,
    diameter: float,
    timestep: float,
    shear_rate: float | None = None,
    axes: str | None = None,
    le_sign: int | None = None,
    time_origin: float | None = None,
    split_files: bool = False,
    body_force: float | None = None,
) -> tuple[TrajectoryData, LammpsReport]:
    """Import LAMMPS text dumps; returns the validated dataset and a report. ``body_force``:
    the amplitude A of the periodic drive ``A cos(2 pi x / lx)`` along our z, in the dump's
    units (:mod:`gripdem.formats.drive`; periodic data only). Raises
    :class:`~gripdem.formats.lammps.dump.DumpError` (a ``DatasetError``) naming the file, item
    and snapshot, or ``ValueError`` for a bad option; nothing is written here."""
    _check_options(diameter, timestep, shear_rate, le_sign, time_origin)
    amplitude = check_amplitude(body_force)
    check_periodic(amplitude, shear_rate is not None, f"--shear-rate {shear_rate}: ")
    paths = [Path(p) for p in paths]
    if not paths:
        raise ValueError("give at least one dump file")
    groups = [[p] for p in paths] if split_files else [paths]
    series = [read_series(group) for group in groups]
    n_frames, notes = _combine(series)
    if n_frames < 2:
        raise DumpError(series[0].label, "ITEM: TIMESTEP", "expected at least 2 snapshots")
    component = series[0].tilt_component(others=series[1:])
    axes_map = AxisMap.choose(axes, component, series[0].label)
    box = Box.from_lengths(axes_map.to_ours(series[0].lengths))
    notes += [note for s in series for note in s.notes]
    phi = check_volume_fraction(series[0].ids.size, diameter, box, "--diameter")
    tilt_lines: list[str] = []
    if component is not None:
        le, times, tilt_lines, more = tilt_lees_edwards(
            series, n_frames, component, box, timestep, shear_rate, le_sign, time_origin
        )
        notes += more
    else:
        le, times = None, [s.timesteps[:n_frames] * timestep for s in series]
    boundary = Boundary(box, le)
    reference = np.stack([axes_map.to_ours(s.reference_positions()[:n_frames]) for s in series])
    velocities = None
    if all(s.velocities is not None for s in series):
        velocities = np.stack([axes_map.to_ours(s.velocities[:n_frames]) for s in series])
        if le is not None and not series[0].velocity_image_known:
            velocities = None
            notes.append(
                "velocities not imported: with unwrapped coordinates and no image flags the "
                "image they belong to (and so their z jump at the LE faces) is unknown; dump "
                "ix iy iz or x y z with them"
            )
    times = np.stack(times)

    def describe(s: int, f: int, p: int) -> str:
        ser = series[s]
        return (
            f"TIMESTEP {int(ser.timesteps[f])} -> {int(ser.timesteps[f + 1])}, "
            f"id {int(ser.ids[p])} ({ser.label})"
        )

    if le is not None:
        offsets = boundary.offset(times)[..., None]
        wrapped = wrap_positions(reference, box, offsets, velocities, boundary.image_velocity)
        positions, velocities = wrapped if velocities is not None else (wrapped, None)
        found = find_crossings(list(zip(positions, times, strict=True)), box, describe)
        evidence = check_crossers(found, box, le, diameter, series[0].label)
    else:
        if not series[0].velocity_image_known:  # unwrapped coordinates: crossings show once
            reference = wrap_positions(reference, box)  # the positions are in the box
        found = find_crossings(list(zip(reference, times, strict=True)), box, describe)
        le, evidence = infer_lees_edwards(
            found,
            box,
            diameter,
            shear_rate,
            le_sign,
            time_origin,
            ((0.0, "0: times are TIMESTEP x --timestep"),),
            series[0].label,
        )
        boundary = Boundary(box, le)
        offsets = None if le is None else boundary.offset(times)[..., None]
        wrapped = wrap_positions(reference, box, offsets, velocities, boundary.image_velocity)
        positions, velocities = wrapped if velocities is not None else (wrapped, None)
    check_periodic(amplitude, boundary.is_lees_edwards, f"{series[0].label}: ")
    drive, drive_notes = drive_lines(amplitude, boundary, positions, times)
    notes += drive_notes
    radii = series[0].radii
    if radii is not None:
        if np.allclose(radii, 0.5 * diameter, rtol=1e-6):
            radii = None
        elif np.ptp(radii) <= 1e-6 * radii.max():
            raise DumpError(
                series[0].label,
                "ITEM: ATOMS column radius/diameter",
                f"every particle has diameter {2 * radii[0]:.6g} but --diameter is {diameter:g}",
            )
        else:
            notes.append(
                f"polydisperse: diameters {2 * radii.min():.6g}..{2 * radii.max():.6g} stored "
                f"per particle; models treat particles as of diameter {diameter:g}"
            )
    data = TrajectoryData(
        positions=positions,
        times=times,
        boundary=boundary,
        radius=0.5 * diameter,
        body_force_amplitude=amplitude,
        velocities=velocities,
        radii=radii,
        provenance={
            "generator": "gripdem.formats.lammps",
            "version": __version__,
            "parameters": {
                "files": [[str(p) for p in g] for g in groups],
                "timestep": timestep,
                "diameter": diameter,
                "shear_rate_given": shear_rate,
                "body_force_amplitude": amplitude,
                "axes": axes_map.name,
                "coordinates": series[0].kind,
                "timesteps": [
                    [int(s.timesteps[0]), int(s.timesteps[n_frames - 1])] for s in series
                ],
                "tilt": tilt_lines,
                "le_inference": None if evidence is None else evidence.lines(),
                "centres_lammps_axes": [s.centre.tolist() for s in series],
            },
        },
    )
    validate(data, series[0].label)
    report = LammpsReport(
        series=series,
        axes=axes_map,
        boundary=boundary,
        diameter=diameter,
        volume_fraction=phi,
        frame_interval=float(series[0].step_interval * timestep),
        n_frames=n_frames,
        evidence=evidence,
        tilt=tilt_lines,
        notes=notes,
        drive=drive,
    )
    return data, report
