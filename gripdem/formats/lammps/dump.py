"""LAMMPS / LIGGGHTS text dumps: read snapshots as written (writing them:
:mod:`gripdem.formats.lammps.write`).

A dump is a sequence of snapshots, each a set of ``ITEM:`` blocks::

    ITEM: TIMESTEP               one integer
    ITEM: NUMBER OF ATOMS        one integer N
    ITEM: BOX BOUNDS [xy xz yz] [pp pp pp]
    xlo_bound xhi_bound [xy]     three lines, a tilt factor on each for a triclinic box
    ylo_bound yhi_bound [xz]
    zlo_bound zhi_bound [yz]
    ITEM: ATOMS id type x y z ...   N lines, columns in any order

Other items (``ITEM: TIME``, ``ITEM: UNITS`` of ``dump_modify time/units yes``) are kept as
text or skipped. Files may hold one or many snapshots and may be gzip-compressed (by suffix or
content). This module knows the text format only: which columns hold what and how the box is
turned into lattice vectors; :mod:`gripdem.formats.lammps` maps a dump onto gripdem's conventions.

Box of a snapshot (LAMMPS axes): origin ``lo (3,)``, lattice vectors as the rows of
``cell (3, 3)`` = ``a = (Lx, 0, 0)``, ``b = (xy, Ly, 0)``, ``c = (xz, yz, Lz)``; for a triclinic
box the dump writes the bounding box (``xlo_bound = xlo + min(0, xy, xz, xy + xz)``, ...).

Every error is a :class:`DumpError` naming the file, the item or column, the snapshot and what
was expected.
"""

from __future__ import annotations

import gzip
import io
import os
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gripdem.data.schema import DatasetError

# the writers live in lammps_write; importable from here as before
from gripdem.formats.lammps.write import FLOAT, bounds_of, dump_text, write_dump  # noqa: F401

#: coordinate column sets, in the order of preference when a dump holds several
COORDINATE_KINDS = {
    "wrapped": ("x", "y", "z"),
    "scaled": ("xs", "ys", "zs"),
    "unwrapped": ("xu", "yu", "zu"),
    "scaled_unwrapped": ("xsu", "ysu", "zsu"),
}
IMAGE_FLAGS = ("ix", "iy", "iz")
VELOCITIES = ("vx", "vy", "vz")
#: every column read (others are skipped); ``id`` and ``type`` are read as integers
KNOWN_COLUMNS = (
    ("id", "type", "radius", "diameter")
    + tuple(c for cols in COORDINATE_KINDS.values() for c in cols)
    + IMAGE_FLAGS
    + VELOCITIES
)
_INTEGER_COLUMNS = ("id", "type") + IMAGE_FLAGS


class DumpError(DatasetError):
    """Bad dump input: names the file, the item or column, the snapshot and the expectation."""


@dataclass
class DumpFrame:
    """One snapshot as written (LAMMPS axes and units).

    timestep: the ``ITEM: TIMESTEP`` value; bounds: ``(3, 2)`` the box bounds lines;
    tilt: ``(3,)`` ``xy, xz, yz`` (zeros for an orthogonal box; ``triclinic`` says which);
    flags: boundary flags (``("pp", "pp", "pp")``; empty when the header has none);
    columns: the ``ITEM: ATOMS`` column names in file order; data: the known columns present,
    ``(atoms,)`` each (``int64`` for ids, types and image flags, else ``float64``);
    items: other items' text (e.g. ``{"UNITS": "lj"}``).
    """

    source: str
    index: int
    timestep: int
    bounds: np.ndarray
    tilt: np.ndarray
    triclinic: bool
    flags: tuple[str, ...]
    columns: tuple[str, ...]
    data: dict[str, np.ndarray]
    items: dict[str, str] = field(default_factory=dict)

    @property
    def n_atoms(self) -> int:
        return int(self.data["id"].shape[0]) if "id" in self.data else 0

    @property
    def where(self) -> str:
        return f"snapshot {self.index} (TIMESTEP {self.timestep})"

    @property
    def lo(self) -> np.ndarray:
        """``(3,)`` origin of the (tilted) cell: the bounding box corrected for the tilt."""
        xy, xz, yz = self.tilt
        return self.bounds[:, 0] - np.array([min(0.0, xy, xz, xy + xz), min(0.0, yz), 0.0])

    @property
    def lengths(self) -> np.ndarray:
        """``(3,)`` ``Lx, Ly, Lz``: the cell's extent along each LAMMPS axis."""
        xy, xz, yz = self.tilt
        hi = self.bounds[:, 1] - np.array([max(0.0, xy, xz, xy + xz), max(0.0, yz), 0.0])
        return hi - self.lo

    @property
    def cell(self) -> np.ndarray:
        """``(3, 3)`` lattice vectors as rows: ``a = (Lx,0,0), b = (xy,Ly,0), c = (xz,yz,Lz)``."""
        lx, ly, lz = self.lengths
        xy, xz, yz = self.tilt
        return np.array([[lx, 0.0, 0.0], [xy, ly, 0.0], [xz, yz, lz]])

    def coordinate_kind(self) -> str:
        """The first complete coordinate column set (see :data:`COORDINATE_KINDS`)."""
        for kind, cols in COORDINATE_KINDS.items():
            if all(c in self.data for c in cols):
                return kind
        partial = [c for cols in COORDINATE_KINDS.values() for c in cols if c in self.data]
        raise DumpError(
            self.source,
            "ITEM: ATOMS",
            f"{self.where}: expected a complete set of coordinate columns (x y z, xs ys zs, "
            f"xu yu zu or xsu ysu zsu), found {partial or 'none'} among {list(self.columns)}",
        )

    def positions(self, kind: str) -> np.ndarray:
        """``(atoms, 3)`` Cartesian coordinates of column set ``kind`` (scaled ones through
        the cell: ``r = lo + s @ cell``)."""
        cols = COORDINATE_KINDS[kind]
        values = np.stack([self.data[c] for c in cols], axis=-1)
        if kind.startswith("scaled"):
            return self.lo + values @ self.cell
        return values

    def image_flags(self) -> np.ndarray | None:
        """``(atoms, 3)`` integer image flags, or None when the dump has none."""
        if not all(c in self.data for c in IMAGE_FLAGS):
            return None
        return np.stack([self.data[c] for c in IMAGE_FLAGS], axis=-1)


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------
def _open_text(path: Path) -> io.TextIOBase:
    with open(path, "rb") as raw:
        magic = raw.read(2)
    if magic == b"\x1f\x8b" or path.suffix == ".gz":
        return io.TextIOWrapper(gzip.open(path, "rb"), encoding="utf-8", errors="replace")
    return open(path, encoding="utf-8", errors="replace")


class _Lines:
    """Line iterator that knows the line number (for messages)."""

    def __init__(self, handle, label: str):
        self.handle, self.label, self.number = handle, label, 0
        self.pending: str | None = None

    def next(self) -> str | None:
        if self.pending is not None:
            line, self.pending = self.pending, None
            return line
        try:
            line = self.handle.readline()
        except (EOFError, zlib.error, OSError) as exc:  # a truncated or corrupted gzip stream
            raise DumpError(
                self.label, "<file>", f"unreadable after line {self.number} ({exc})"
            ) from None
        if not line:
            return None
        self.number += 1
        if not line.endswith("\n") and line.strip() and self.number > 1:  # LAMMPS ends each
            raise DumpError(
                self.label,
                "<file>",
                f"ends in the middle of line {self.number} ({line[-40:]!r}, no newline): "
                "truncated? (if the file is complete, end it with a newline)",
            )
        return line.rstrip("\r\n")

    def push(self, line: str) -> None:
        self.pending = line

    def value(self, item: str, where: str) -> str:
        line = self.next()
        if line is None or line.startswith("ITEM:"):
            raise DumpError(
                self.label, f"ITEM: {item}", f"{where}: expected a value after line {self.number}"
            )
        return line.strip()


def _int(text: str, label: str, item: str, where: str) -> int:
    try:
        value = int(text.split()[0])
    except (ValueError, IndexError):
        value = None
    if value is None or not 0 <= value < 2**63:
        raise DumpError(
            label,
            f"ITEM: {item}",
            f"{where}: expected a whole number in 0..2^63-1, got {text[:40]!r}",
        )
    return value


def _box(lines: _Lines, header: str, where: str) -> tuple[np.ndarray, np.ndarray, bool, tuple]:
    words = header.split()[3:]  # after "ITEM: BOX BOUNDS"
    if "abc" in words or "origin" in words:
        raise DumpError(
            lines.label,
            "ITEM: BOX BOUNDS",
            f"{where}: general triclinic boxes ('abc origin', dump_modify triclinic/general) "
            "are not supported; dump the restricted triclinic box (the default)",
        )
    triclinic = words[:3] == ["xy", "xz", "yz"]
    flags = tuple(words[3:] if triclinic else words)
    rows = []
    for axis in "xyz":
        line = lines.value("BOX BOUNDS", where)
        try:
            values = [float(v) for v in line.split()]
        except ValueError:
            values = []
        if len(values) != (3 if triclinic else 2):
            raise DumpError(
                lines.label,
                "ITEM: BOX BOUNDS",
                f"{where}: expected '{axis}lo {axis}hi{' tilt' if triclinic else ''}' "
                f"({3 if triclinic else 2} numbers) on line {lines.number}, got {line!r}",
            )
        rows.append(values)
    rows = np.asarray(rows, dtype=np.float64)
    if not (np.isfinite(rows).all() and (rows[:, 1] > rows[:, 0]).all()):
        raise DumpError(
            lines.label,
            "ITEM: BOX BOUNDS",
            f"{where}: expected finite bounds with lo < hi on every axis, got {rows.tolist()}",
        )
    tilt = rows[:, 2].copy() if triclinic else np.zeros(3)
    return rows[:, :2].copy(), tilt, triclinic, flags


def _atoms(lines: _Lines, header: str, n: int, where: str) -> tuple[tuple, dict]:
    columns = tuple(header.split()[2:])
    if len(set(columns)) != len(columns):
        raise DumpError(lines.label, "ITEM: ATOMS", f"{where}: repeated column in {columns}")
    rows = []
    for k in range(n):
        line = lines.next()
        if line is None or line.startswith("ITEM:"):
            raise DumpError(
                lines.label,
                "ITEM: ATOMS",
                f"{where}: expected {n} atom lines (ITEM: NUMBER OF ATOMS), the "
                f"{'file ends' if line is None else 'next ITEM starts'} after {k}: truncated?",
            )
        rows.append(line)
    tokens = " ".join(rows).split()
    if len(tokens) != n * len(columns):
        raise DumpError(
            lines.label,
            "ITEM: ATOMS",
            f"{where}: expected {len(columns)} values per atom line ({' '.join(columns)}), "
            f"got {len(tokens)} values on {n} lines",
        )
    table = np.asarray(tokens, dtype=object).reshape(n, len(columns))
    data = {}
    for j, name in enumerate(columns):
        if name not in KNOWN_COLUMNS:
            continue
        try:
            values = table[:, j].astype(np.float64)
        except ValueError:
            raise DumpError(
                lines.label, f"ITEM: ATOMS column {name}", f"{where}: expected numbers"
            ) from None
        if not np.isfinite(values).all():
            k = int(np.argwhere(~np.isfinite(values))[0][0])
            raise DumpError(
                lines.label,
                f"ITEM: ATOMS column {name}",
                f"{where}: expected finite numbers, found {table[k, j]!r} on atom line {k + 1}",
            )
        if name in _INTEGER_COLUMNS:
            if not np.all((values == np.round(values)) & (np.abs(values) < 2**62)):
                raise DumpError(
                    lines.label, f"ITEM: ATOMS column {name}", f"{where}: expected integers"
                )
            values = values.astype(np.int64)
        data[name] = values
    return columns, data


def read_dump(path: str | os.PathLike) -> Iterator[DumpFrame]:
    """Snapshots of one dump file (gzip allowed), in file order. Raises :class:`DumpError`."""
    path = Path(path)
    label = str(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such dump file")
    with _open_text(path) as handle:
        lines = _Lines(handle, label)
        index = 0
        while True:
            line = lines.next()
            while line is not None and not line.strip():
                line = lines.next()
            if line is None:
                if index == 0:
                    raise DumpError(label, "ITEM: TIMESTEP", "expected a snapshot; file is empty")
                return
            if line.strip() != "ITEM: TIMESTEP":
                raise DumpError(
                    label,
                    "ITEM: TIMESTEP",
                    f"expected 'ITEM: TIMESTEP' to start snapshot {index} on line "
                    f"{lines.number}, got {line[:60]!r}: is this a LAMMPS text dump?",
                )
            where = f"snapshot {index}"
            timestep = _int(lines.value("TIMESTEP", where), label, "TIMESTEP", where)
            where = f"snapshot {index} (TIMESTEP {timestep})"
            n = bounds = None
            items: dict[str, str] = {}
            while True:
                line = lines.next()
                if line is None:
                    raise DumpError(label, "ITEM: ATOMS", f"{where}: file ends before ITEM: ATOMS")
                if not line.startswith("ITEM:"):
                    continue
                name = line[5:].strip()
                if name == "NUMBER OF ATOMS":
                    n = _int(lines.value(name, where), label, name, where)
                elif name.startswith("BOX BOUNDS"):
                    bounds, tilt, triclinic, flags = _box(lines, line, where)
                elif name.startswith("ATOMS"):
                    break
                elif name == "TIMESTEP":
                    raise DumpError(label, "ITEM: ATOMS", f"{where}: next snapshot before ATOMS")
                else:
                    items[name.split()[0]] = lines.value(name, where)
            for item, value in (("NUMBER OF ATOMS", n), ("BOX BOUNDS", bounds)):
                if value is None:
                    raise DumpError(label, f"ITEM: {item}", f"{where}: missing before ITEM: ATOMS")
            columns, data = _atoms(lines, line, n, where)
            if "id" not in data:
                raise DumpError(
                    label,
                    "ITEM: ATOMS column id",
                    f"{where}: expected an 'id' column to follow particles between snapshots, "
                    f"got columns {list(columns)}",
                )
            yield DumpFrame(
                label, index, timestep, bounds, tilt, triclinic, flags, columns, data, items
            )
            index += 1
