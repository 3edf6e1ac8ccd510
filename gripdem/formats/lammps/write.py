"""Writing LAMMPS / LIGGGHTS text dumps (the format :mod:`gripdem.formats.lammps.dump` reads):
the box bounds of a tilted cell, the dump text of a trajectory, and an atomic write (gzip
when the name ends in ``.gz``). A dump written here reads back to the same float64 values.
"""

from __future__ import annotations

import gzip
import io
import os
from pathlib import Path

import numpy as np

from gripdem.data.h5io import atomic_path, atomic_write_text

FLOAT = "%.17g"  # repr precision: a dump written here reads back to the same float64


def bounds_of(lo: np.ndarray, lengths: np.ndarray, tilt: np.ndarray | None) -> np.ndarray:
    """``(3, 2)`` the ``BOX BOUNDS`` lines (bounding box of a tilted cell) of origin ``lo``,
    extents ``lengths`` and tilt ``xy, xz, yz`` (None: orthogonal)."""
    lo = np.asarray(lo, np.float64)
    hi = lo + np.asarray(lengths, np.float64)
    if tilt is None:
        return np.stack([lo, hi], axis=-1)
    xy, xz, yz = (float(v) for v in tilt)
    low = lo + np.array([min(0.0, xy, xz, xy + xz), min(0.0, yz), 0.0])
    high = hi + np.array([max(0.0, xy, xz, xy + xz), max(0.0, yz), 0.0])
    return np.stack([low, high], axis=-1)


def dump_text(
    timesteps: np.ndarray,
    lo: np.ndarray,
    lengths: np.ndarray,
    positions: np.ndarray,
    tilt: np.ndarray | None = None,
    columns: dict[str, np.ndarray] | None = None,
    ids: np.ndarray | None = None,
    float_format: str = FLOAT,
) -> str:
    """Dump text of ``positions`` ``(frames, atoms, 3)`` (LAMMPS axes, columns ``x y z``).

    ``tilt``: ``(frames, 3)`` ``xy xz yz`` per frame (None: orthogonal box); ``columns``: extra
    per-atom columns ``name -> (frames, atoms)`` or ``(atoms,)``, written after ``x y z``;
    ids default to ``1..N``, type 1."""
    positions = np.asarray(positions, np.float64)
    frames, n, _ = positions.shape
    ids = np.arange(1, n + 1) if ids is None else np.asarray(ids)
    extra = {
        k: np.broadcast_to(np.asarray(v, np.float64), (frames, n))
        for k, v in (columns or {}).items()
    }
    header = "ITEM: ATOMS id type x y z" + "".join(f" {k}" for k in extra) + "\n"
    fmt = "%d %d " + " ".join([float_format] * (3 + len(extra)))
    buf = io.StringIO()
    for j in range(frames):
        t = None if tilt is None else np.asarray(tilt, np.float64)[j]
        buf.write(f"ITEM: TIMESTEP\n{int(timesteps[j])}\nITEM: NUMBER OF ATOMS\n{n}\n")
        buf.write("ITEM: BOX BOUNDS " + ("pp pp pp" if t is None else "xy xz yz pp pp pp") + "\n")
        for axis, (low, high) in enumerate(bounds_of(lo, lengths, t)):
            tail = "" if t is None else f" {float(t[axis])!r}"
            buf.write(f"{float(low)!r} {float(high)!r}{tail}\n")
        buf.write(header)
        table = np.column_stack([ids, np.ones(n), positions[j], *(v[j] for v in extra.values())])
        np.savetxt(buf, table, fmt=fmt)
    return buf.getvalue()


def write_dump(path: str | os.PathLike, text: str, overwrite: bool = False) -> Path:
    """Write dump text atomically (gzip-compressed when ``path`` ends in ``.gz``)."""
    path = Path(path)
    if path.suffix != ".gz":
        return atomic_write_text(path, text, overwrite)
    with atomic_path(path, overwrite) as tmp:
        with gzip.open(tmp, "wt", encoding="utf-8") as handle:
            handle.write(text)
    return path
