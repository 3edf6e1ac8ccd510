"""One simulation's snapshots from LAMMPS dump files, checked and stacked (LAMMPS axes), and
the axis permutation between LAMMPS and gripdem.

:func:`read_series` reads the snapshots of a group of dump files, orders them by TIMESTEP,
drops repeated snapshots with identical coordinates (a restarted run writes its first snapshot
again), orders particles by ``id`` and checks what must not change between snapshots: the set
of ids, the columns, the box (periodic, same lengths and origin; the tilt may change), equal
TIMESTEP spacing. Errors are :class:`~gripdem.formats.lammps.dump.DumpError` naming the file and
the snapshot.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gripdem.formats.lammps.dump import COORDINATE_KINDS, VELOCITIES, DumpError, read_dump

#: box lengths and origins must agree between snapshots to this fraction of the box
BOX_RTOL = 1e-6
#: coordinates (unwrapped ones included) farther than this many box lengths from the box are
#: refused: another unit or a corrupted dump (and beyond float64's range for wrapping)
FAR = 1e6
#: a tilt factor below this fraction of the flow length counts as zero
TILT_ZERO = 1e-12
_TILTS = ("xy", "xz", "yz")
#: tilt component -> (flow axis, gradient axis) in LAMMPS axes: tilt "ab" shifts the image
#: across the b faces along a
_TILT_AXES = {0: (0, 1), 1: (0, 2), 2: (1, 2)}


@dataclass(frozen=True)
class AxisMap:
    """Permutation of axes: ours[i] = LAMMPS[order[i]] (``name`` "yzx": ours x = LAMMPS y)."""

    order: tuple[int, int, int]

    @property
    def name(self) -> str:
        return "".join("xyz"[i] for i in self.order)

    @classmethod
    def parse(cls, text: str) -> AxisMap:
        text = str(text).strip().lower()
        if sorted(text) != ["x", "y", "z"]:
            raise ValueError(
                f"--axes must be a permutation of 'xyz' naming the LAMMPS axis of our x, y and "
                f"z (e.g. 'yzx' for a box sheared in xy), got {text!r}"
            )
        return cls(tuple("xyz".index(c) for c in text))

    @classmethod
    def for_tilt(cls, component: int) -> AxisMap:
        """The map that turns tilt ``component`` into gripdem's LE lattice: ours x = the
        gradient axis, ours z = the flow axis, ours y = the third."""
        flow, gradient = _TILT_AXES[component]
        other = 3 - flow - gradient
        return cls((gradient, other, flow))

    @classmethod
    def choose(cls, axes: str | None, component: int | None, label: str) -> AxisMap:
        """``axes`` when given (checked against the tilt), else the default: the tilt's map for
        a sheared box, the identity for an orthogonal one."""
        if component is None:
            return cls.parse(axes or "xyz")
        needed = cls.for_tilt(component)
        if axes is not None and cls.parse(axes) != needed:
            flow, gradient = _TILT_AXES[component]
            raise ValueError(
                f"--axes {axes}: {label} is tilted in {_TILTS[component]} (flow along LAMMPS "
                f"{'xyz'[flow]}, gradient along {'xyz'[gradient]}); gripdem's gradient axis is "
                f"x and flow axis z, so the axes must be {needed.name} (ours (x, y, z) = "
                f"LAMMPS ({', '.join(needed.name)}))"
            )
        return needed

    def to_ours(self, values: np.ndarray) -> np.ndarray:
        """``(..., 3)`` LAMMPS axes -> ours."""
        return np.asarray(values)[..., list(self.order)]

    def to_lammps(self, values: np.ndarray) -> np.ndarray:
        """``(..., 3)`` ours -> LAMMPS axes."""
        return np.asarray(values)[..., list(np.argsort(self.order))]


@dataclass
class DumpSeries:
    """Snapshots of one simulation, ordered by TIMESTEP, particles by id (LAMMPS axes).

    positions ``(frames, atoms, 3)``: the image LAMMPS stores (``x``, scaled ``xs`` through the
    cell, or unwrapped minus image flags times the cell) where known, else the unwrapped
    coordinates (``velocity_image_known`` False); velocities likewise or None; tilt
    ``(frames, 3)`` ``xy xz yz``; lo, lengths ``(3,)`` of the cell; radii ``(atoms,)`` or None.
    """

    files: list[str]
    timesteps: np.ndarray
    ids: np.ndarray
    kind: str
    positions: np.ndarray
    velocities: np.ndarray | None
    velocity_image_known: bool
    has_image_flags: bool
    radii: np.ndarray | None
    lo: np.ndarray
    lengths: np.ndarray
    tilt: np.ndarray
    duplicates: int = 0
    notes: list[str] = field(default_factory=list)

    @property
    def label(self) -> str:
        if len(self.files) == 1:
            return self.files[0]
        return f"{self.files[0]} (+{len(self.files) - 1} more file(s))"

    @property
    def n_frames(self) -> int:
        return int(self.timesteps.size)

    @property
    def step_interval(self) -> int:
        return int(self.timesteps[1] - self.timesteps[0]) if self.n_frames > 1 else 0

    @property
    def coordinate_columns(self) -> tuple[str, ...]:
        return COORDINATE_KINDS[self.kind]

    @property
    def centre(self) -> np.ndarray:
        """``(3,)`` centre of the cell's orthogonal extent (LAMMPS axes)."""
        return self.lo + 0.5 * self.lengths

    def reference_positions(self) -> np.ndarray:
        """``(frames, atoms, 3)`` positions re-centred at the origin (LAMMPS axes)."""
        return self.positions - self.centre

    def describe(self) -> str:
        files = ", ".join(Path(f).name for f in self.files[:3])
        more = f" and {len(self.files) - 3} more" if len(self.files) > 3 else ""
        dup = f", {self.duplicates} repeated snapshot(s) dropped" if self.duplicates else ""
        return (
            f"{files}{more}: TIMESTEP {int(self.timesteps[0])}..{int(self.timesteps[-1])} every "
            f"{self.step_interval} ({self.n_frames} snapshots){dup}"
        )

    def tilt_component(self, others: Sequence[DumpSeries] = ()) -> int | None:
        """Which tilt factor is used (None: orthogonal). Two at once cannot be gripdem's LE."""
        used = set()
        for s in (self, *others):
            scale = float(s.lengths.max())
            used |= {int(i) for i in np.nonzero(np.abs(s.tilt).max(axis=0) > TILT_ZERO * scale)[0]}
        if len(used) > 1:
            raise DumpError(
                self.label,
                "ITEM: BOX BOUNDS",
                f"the box is tilted in {[_TILTS[i] for i in sorted(used)]}: gripdem's Lees-Edwards "
                "cell shears one axis along one other (one tilt factor)",
            )
        return used.pop() if used else None


def _sorted_frame(frame, first):
    """Particles of one snapshot ordered by id; checked against the first snapshot."""
    ids = frame.data["id"]
    order = np.argsort(ids, kind="stable")
    ids = ids[order]
    if ids.size > 1 and (np.diff(ids) == 0).any():
        raise DumpError(
            frame.source,
            "ITEM: ATOMS column id",
            f"{frame.where}: id {int(ids[np.nonzero(np.diff(ids) == 0)[0][0]])} appears twice",
        )
    kind = frame.coordinate_kind()
    if first is not None:
        if ids.size != first["ids"].size:
            raise DumpError(
                frame.source,
                "ITEM: NUMBER OF ATOMS",
                f"{frame.where}: expected {first['ids'].size} atoms like {first['where']}, got "
                f"{ids.size} (the atom count must not change)",
            )
        if not np.array_equal(ids, first["ids"]):
            missing = np.setdiff1d(first["ids"], ids)[:5].tolist()
            extra = np.setdiff1d(ids, first["ids"])[:5].tolist()
            raise DumpError(
                frame.source,
                "ITEM: ATOMS column id",
                f"{frame.where}: expected the ids of {first['where']}; missing {missing}, "
                f"new {extra}",
            )
        if frame.columns != first["columns"]:
            raise DumpError(
                frame.source,
                "ITEM: ATOMS",
                f"{frame.where}: columns {list(frame.columns)} differ from {first['where']} "
                f"({list(first['columns'])})",
            )
    positions = frame.positions(kind)[order]
    far = np.abs(positions - (frame.lo + 0.5 * frame.lengths)) > FAR * frame.lengths.max()
    if far.any():
        atom, axis = (int(i) for i in np.argwhere(far)[0])
        raise DumpError(
            frame.source,
            f"ITEM: ATOMS column {COORDINATE_KINDS[kind][axis]}",
            f"{frame.where}: expected coordinates within {FAR:g} box lengths of the box, found "
            f"{positions[atom, axis]:g} for id {int(ids[atom])}",
        )
    flags = frame.image_flags()
    known = not kind.endswith("unwrapped") or flags is not None
    if kind.endswith("unwrapped") and flags is not None:
        positions = positions - flags[order] @ frame.cell
    velocities = None
    if all(c in frame.data for c in VELOCITIES):
        velocities = np.stack([frame.data[c] for c in VELOCITIES], axis=-1)[order]
    radii = None
    if "radius" in frame.data:
        radii = frame.data["radius"][order]
    elif "diameter" in frame.data:
        radii = 0.5 * frame.data["diameter"][order]
    return {
        "ids": ids,
        "kind": kind,
        "columns": frame.columns,
        "where": f"{frame.where} of {frame.source}",
        "positions": positions,
        "velocities": velocities,
        "known": known,
        "flags": flags is not None,
        "radii": radii,
    }


def _check_box(frame, first_frame) -> None:
    if frame.flags and any(f != "pp" for f in frame.flags):
        raise DumpError(
            frame.source,
            "ITEM: BOX BOUNDS",
            f"{frame.where}: expected a periodic box ('pp pp pp'), got boundary flags "
            f"{' '.join(frame.flags)}",
        )
    if first_frame is None:
        return
    scale = BOX_RTOL * float(first_frame.lengths.max())
    for what, a, b in (
        ("lengths", frame.lengths, first_frame.lengths),
        ("origin", frame.lo, first_frame.lo),
    ):
        if np.abs(a - b).max() > scale:
            raise DumpError(
                frame.source,
                "ITEM: BOX BOUNDS",
                f"{frame.where}: box {what} {a.tolist()} differ from {b.tolist()} of "
                f"{first_frame.where} in {first_frame.source} (a gripdem scene has one fixed "
                "box; only the tilt of a sheared box may change)",
            )


def read_series(paths: Sequence[Path]) -> DumpSeries:
    """Read and check the snapshots of ``paths`` as one simulation (see the module doc)."""
    records, first, first_frame, units = [], None, None, set()
    for path in paths:
        for frame in read_dump(path):
            _check_box(frame, first_frame)
            record = _sorted_frame(frame, first)
            if first is None:
                first, first_frame = record, frame
            record.update(
                timestep=frame.timestep,
                tilt=frame.tilt,
                source=frame.source,
                where=frame.where,
            )
            units |= {frame.items["UNITS"]} if "UNITS" in frame.items else set()
            records.append(record)
    records.sort(key=lambda r: r["timestep"])
    kept, duplicates = [records[0]], 0
    for r in records[1:]:
        prev = kept[-1]
        if r["timestep"] != prev["timestep"]:
            kept.append(r)
        elif np.array_equal(r["positions"], prev["positions"]):
            duplicates += 1
        else:
            raise DumpError(
                r["source"],
                "ITEM: TIMESTEP",
                f"{r['where']} appears twice with different coordinates (also in "
                f"{prev['source']}): are these dumps of different runs? (use --split-files to "
                "import every file as its own simulation)",
            )
    timesteps = np.array([r["timestep"] for r in kept], dtype=np.int64)
    steps = np.diff(timesteps)
    if steps.size and (steps != steps[0]).any():
        k = int(np.nonzero(steps != steps[0])[0][0])
        raise DumpError(
            kept[k + 1]["source"],
            "ITEM: TIMESTEP",
            f"expected equidistant snapshots every {int(steps[0])} steps; TIMESTEP "
            f"{int(timesteps[k])} is followed by {int(timesteps[k + 1])} (a missing file or "
            "snapshot?)",
        )
    velocities = None
    if all(r["velocities"] is not None for r in kept):
        velocities = np.stack([r["velocities"] for r in kept])
    notes = [f"dump units: {', '.join(sorted(units))}"] if units else []
    radii = first["radii"]
    if radii is not None and any(not np.allclose(r["radii"], radii, rtol=1e-9) for r in kept):
        raise DumpError(
            str(paths[0]), "ITEM: ATOMS column radius", "particle radii change between snapshots"
        )
    return DumpSeries(
        files=[str(p) for p in paths],
        timesteps=timesteps,
        ids=first["ids"],
        kind=first["kind"],
        positions=np.stack([r["positions"] for r in kept]),
        velocities=velocities,
        velocity_image_known=first["known"],
        has_image_flags=first["flags"],
        radii=radii,
        lo=first_frame.lo,
        lengths=first_frame.lengths,
        tilt=np.stack([r["tilt"] for r in kept]),
        duplicates=duplicates,
        notes=notes,
    )
