"""Export predicted and true trajectories for OVITO, ParaView and LAMMPS users.

Extended XYZ (OVITO and ParaView open it; ASE reads it): one file per trajectory, so the truth
and the prediction load as two pipelines that can be overlaid or compared frame by frame::

    window000_true.xyz   window000_pred.xyz   (and window000_<baseline>.xyz on request)

Frame 0 is the last observed frame (identical in both files), frames 1..f the horizon. Each
frame's comment line::

    Lattice="lx 0 delta 0 ly 0 0 0 lz" Origin="-lx/2 -ly/2 -lz/2" pbc="T T T"
    Properties=species:S:1:pos:R:3:radius:R:1:id:I:1:crosser:I:1[:error:R:1]
    Time=<s> step=<j> window=<w> boundary=<kind> le_offset=<delta>

The cell is the lattice of the periodic images at that frame: in the Lees-Edwards scene the LE
lattice ``(lx, 0, delta), (0, ly, 0), (0, 0, lz)`` with the frame's offset delta (the +x image
is shifted by delta along z; ``le_offset`` repeats it), so a viewer that repeats the cell
(OVITO's Replicate, ASE's neighbour lists) draws and finds the right images across the x
faces; in the periodic scene the box (delta = 0). Positions are moved into that parallelepiped
(:func:`gripdem.boundary.wrap_into_sheared_cell`: only whole lattice vectors added, the same
images), so the atoms lie inside the cell the viewer draws from ``Origin`` (ASE, which ignores
``Origin``, keeps it in ``atoms.info``). ``crosser`` is 1 for particles whose truth crosses an x
face during the horizon, ``error`` (prediction files only) the minimum-image distance to the
truth at that frame. Lengths are in the data's units (metres by default; OVITO's analysis
modifiers call a cell of ~1e-14 m^3 degenerate: scale it first, e.g. an
``AffineTransformationModifier`` by 1e6 for micrometres); particles have species ``P``.

LAMMPS text dumps (``ITEM: ATOMS id type x y z radius``) are written by
:func:`write_lammps_dump`: periodic data in an orthogonal box in gripdem's axes; Lees-Edwards
data as LAMMPS stores a sheared box (the only form its dumps have: a lower axis tilted along a
higher one), in LAMMPS's axes, ours (x, y, z) = LAMMPS (y, z, x), tilt ``xy`` = the frame's
offset, atoms inside the tilted cell: LAMMPS, OVITO, ASE and ``gripdem.convert lammps`` read
it as the LE lattice (as ``python -m gripdem.handback --dump`` writes).
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from gripdem.boundary import Box, wrap_into_sheared_cell
from gripdem.data.h5io import atomic_write_text
from gripdem.evaluation import metrics
from gripdem.evaluation.predictions import Predictions, read_predictions
from gripdem.formats.lammps.dump import dump_text
from gripdem.formats.lammps.series import AxisMap

FLOAT = "%.12g"


def _trajectories(p: Predictions, window: int) -> dict[str, np.ndarray]:
    """``{"true": ..., "pred": ..., <baseline>: ...}``, each ``(horizon + 1, particles, 3)``
    with the last observed frame first."""
    if not 0 <= window < p.n_windows:
        raise IndexError(f"window {window} out of range: the predictions hold {p.n_windows}")
    last = p.last_positions[window][None]
    out = {
        "true": np.concatenate([last, p.true_positions[window]]),
        "pred": np.concatenate([last, p.pred_positions[window]]),
    }
    for name, arr in p.baselines.items():
        out[name] = np.concatenate([last, arr[window]])
    return out


def _frame_info(p: Predictions, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Times and LE offsets of frames 0..f of a window (frame 0 = last observed)."""
    times = np.concatenate([[p.times[window, 0] - p.frame_interval], p.times[window]])
    return times, p.boundary.offset(times)


def extxyz_text(
    positions: np.ndarray,
    p: Predictions,
    window: int,
    errors: np.ndarray | None = None,
    crossers: np.ndarray | None = None,
) -> str:
    """Extended XYZ text of ``positions`` ``(frames, particles, 3)`` of one window."""
    times, offsets = _frame_info(p, window)
    n = positions.shape[1]
    lx, ly, lz = (float(v) for v in p.box.lengths)
    props = "species:S:1:pos:R:3:radius:R:1:id:I:1:crosser:I:1"
    if errors is not None:
        props += ":error:R:1"
    radius = np.full(n, p.radius)
    ids = np.arange(1, n + 1)
    cross = np.zeros(n, int) if crossers is None else crossers.astype(int)
    buf = io.StringIO()
    for j, frame in enumerate(positions):
        delta = float(offsets[j])
        buf.write(f"{n}\n")
        buf.write(
            f'Lattice="{lx!r} 0 {delta!r} 0 {ly!r} 0 0 0 {lz!r}" '
            f'Origin="{-lx / 2!r} {-ly / 2!r} {-lz / 2!r}" pbc="T T T" '
            f"Properties={props} Time={float(times[j])!r} step={j} window={window} "
            f"boundary={p.boundary.kind} le_offset={delta!r}\n"
        )
        frame = wrap_into_sheared_cell(frame, p.box, delta)
        columns = [frame[:, 0], frame[:, 1], frame[:, 2], radius, ids, cross]
        fmt = f"P {FLOAT} {FLOAT} {FLOAT} {FLOAT} %d %d"
        if errors is not None:
            columns.append(errors[j])
            fmt += f" {FLOAT}"
        np.savetxt(buf, np.column_stack(columns), fmt=fmt)
    return buf.getvalue()


def export_extxyz(
    source: str | os.PathLike | Predictions,
    out_dir: str | os.PathLike,
    windows: list[int] | None = None,
    baselines: bool = False,
    overwrite: bool = False,
) -> dict[str, Path]:
    """Write ``window<www>_true.xyz`` and ``window<www>_pred.xyz`` (and one per stored baseline
    with ``baselines=True``) for each window (default: the first only). Returns
    ``{"window000_true": path, ...}``; atomic writes, existing files kept unless
    ``overwrite=True``."""
    p = source if isinstance(source, Predictions) else read_predictions(source)
    out_dir = Path(out_dir)
    written: dict[str, Path] = {}
    all_crossers = metrics.crossing_mask(p.last_positions, p.true_positions, p.box, p.offsets())
    for w in [0] if windows is None else windows:
        series = _trajectories(p, w)
        _, offsets = _frame_info(p, w)
        for name, positions in series.items():
            if name != "true" and name != "pred" and not baselines:
                continue
            errors = None
            if name != "true":
                res = metrics.position_residuals(
                    positions[None], series["true"][None], p.box, offsets[None]
                )[0]
                errors = np.sqrt((res**2).sum(-1))
            key = f"window{w:03d}_{name}"
            text = extxyz_text(positions, p, w, errors, all_crossers[w])
            written[key] = atomic_write_text(out_dir / f"{key}.xyz", text, overwrite)
    return written


def write_lammps_dump(
    path: str | os.PathLike,
    positions: np.ndarray,
    box_lengths: np.ndarray,
    radius: float,
    timesteps: np.ndarray | None = None,
    overwrite: bool = False,
    offsets: np.ndarray | None = None,
) -> Path:
    """LAMMPS text dump of ``positions`` ``(frames, particles, 3)`` (``ITEM: ATOMS id type x y
    z radius``, type 1) in a box centred at the origin: orthogonal in gripdem's axes, or with
    ``offsets`` (the LE offset of every frame) sheared, in LAMMPS's axes (ours (x, y, z) =
    LAMMPS (y, z, x)) with tilt ``xy`` = the offset and the atoms inside the tilted cell."""
    positions = np.asarray(positions, dtype=np.float64)
    frames, n, _ = positions.shape
    steps = np.arange(frames) if timesteps is None else np.asarray(timesteps)
    lengths = np.asarray(box_lengths, dtype=np.float64)
    tilt = None
    if offsets is not None:
        offsets = np.asarray(offsets, dtype=np.float64).reshape(frames)
        axes = AxisMap.for_tilt(0)
        inside = wrap_into_sheared_cell(positions, Box.from_lengths(lengths), offsets[:, None])
        positions, lengths = axes.to_lammps(inside), axes.to_lammps(lengths)
        tilt = np.zeros((frames, 3))
        tilt[:, 0] = offsets
    text = dump_text(
        steps, -0.5 * lengths, lengths, positions, tilt, {"radius": np.full(n, radius)}, None, FLOAT
    )
    return atomic_write_text(path, text, overwrite)


def export_lammps(
    source: str | os.PathLike | Predictions,
    out_dir: str | os.PathLike,
    window: int = 0,
    overwrite: bool = False,
) -> dict[str, Path]:
    """``window<www>_true.dump`` and ``window<www>_pred.dump`` of one window (frame 0 = last
    observed; TIMESTEP = horizon step; a sheared box as :func:`write_lammps_dump` writes it)."""
    p = source if isinstance(source, Predictions) else read_predictions(source)
    out: dict[str, Path] = {}
    _, offsets = _frame_info(p, window)
    for name, positions in _trajectories(p, window).items():
        if name in ("true", "pred"):
            key = f"window{window:03d}_{name}"
            out[key] = write_lammps_dump(
                Path(out_dir) / f"{key}.dump",
                positions,
                p.box.lengths,
                p.radius,
                overwrite=overwrite,
                offsets=offsets if p.boundary.is_lees_edwards else None,
            )
    return out
