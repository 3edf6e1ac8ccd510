"""A state handed back to a DEM engine (:mod:`gripdem.handback`): one frame of a gripdem
dataset as a LAMMPS data file, as extended XYZ with the Lees-Edwards lattice, and a trajectory
as a LAMMPS dump in LAMMPS's axes (ours (x, y, z) = LAMMPS (y, z, x) in a sheared box, the LE
offset as the xy tilt).

Velocities: the file's own where it stores them, else the mean velocity over the last frame
interval, ``lattice-continuous step (F-1 -> F) / dt`` in the image cell each particle occupies at
frame F (a particle that just crossed an LE face carries the jumped velocity).
"""

from __future__ import annotations

import io
from typing import Any

import numpy as np

from gripdem.boundary import lattice_continuous_steps, wrap_into_sheared_cell
from gripdem.data.schema import TrajectoryData
from gripdem.formats.lammps.dump import FLOAT, dump_text
from gripdem.formats.lammps.series import AxisMap


def find_value(tree: Any, key: str) -> Any:
    """First value stored under ``key`` anywhere in nested dicts/lists (None if absent)."""
    if isinstance(tree, dict):
        if key in tree:
            return tree[key]
        tree = list(tree.values())
    if isinstance(tree, list):
        for item in tree:
            found = find_value(item, key)
            if found is not None:
                return found
    return None


class State:
    """One frame of a dataset in gripdem's axes: positions ``(N, 3)`` inside the sheared LE
    cell, velocities ``(N, 3)``, time, LE offset and the source of the velocities."""

    def __init__(self, data: TrajectoryData, sim: int, frame: int, where: str):
        if not 0 <= sim < data.n_sims:
            raise ValueError(f"--sim {sim}: {where} holds simulations 0..{data.n_sims - 1}")
        frames = data.n_frames
        if not -frames <= frame < frames:
            raise ValueError(f"--frame {frame}: {where} holds frames 0..{frames - 1}")
        self.frame = frame % frames
        self.data, self.sim = data, sim
        self.time = float(data.times[sim, self.frame])
        offsets = data.offsets()[sim]
        self.offset = float(offsets[self.frame])
        positions = data.positions[sim, self.frame]
        self.positions = wrap_into_sheared_cell(positions, data.box, self.offset)
        if data.velocities is not None:
            self.velocities = data.velocities[sim, self.frame]
            self.velocity_source = "stored in the file"
        elif self.frame == 0:
            raise ValueError(
                f"{where}: frame 0 has no earlier frame to estimate velocities from and the "
                "file stores none; choose a later --frame"
            )
        else:
            pair = data.positions[sim, self.frame - 1 : self.frame + 1].transpose(1, 0, 2)
            le = data.boundary.is_lees_edwards
            off = offsets[None, self.frame - 1 : self.frame + 1] if le else None
            step = lattice_continuous_steps(pair, data.box, off, anchor=-1)[:, 0]
            self.velocities = step / data.frame_interval
            self.velocity_source = (
                f"mean over the last frame interval (frames {self.frame - 1} -> {self.frame})"
            )


def lammps_axes(data: TrajectoryData, axes: str | None) -> AxisMap:
    """``yzx`` for a sheared box (the only map that makes our LE offset LAMMPS's xy tilt),
    ``axes`` or the identity for a periodic one."""
    if data.boundary.is_lees_edwards:
        needed = AxisMap.for_tilt(0)
        if axes is not None and AxisMap.parse(axes) != needed:
            raise ValueError(
                f"--axes {axes}: a sheared box goes to LAMMPS as a box tilted in xy, which needs "
                f"ours (x, y, z) = LAMMPS (y, z, x) (--axes {needed.name})"
            )
        return needed
    return AxisMap.parse(axes or "xyz")


def _tilt(data: TrajectoryData, offsets: np.ndarray) -> np.ndarray | None:
    """``(frames, 3)`` LAMMPS ``xy xz yz`` for our offsets (None: periodic box)."""
    if not data.boundary.is_lees_edwards:
        return None
    tilt = np.zeros((np.size(offsets), 3))
    tilt[:, 0] = offsets
    return tilt


def data_file_text(
    state: State, axes: AxisMap, atom_style: str, density: float | None, mass: float | None
) -> str:
    """LAMMPS data file of ``state`` (see the module doc)."""
    data = state.data
    n = data.n_particles
    lengths = axes.to_lammps(data.box.lengths)
    lo = -0.5 * lengths
    pos = axes.to_lammps(state.positions)
    vel = axes.to_lammps(state.velocities)
    diameters = 2.0 * (data.radii if data.radii is not None else np.full(n, data.radius))
    buf = io.StringIO()
    le = data.boundary.lees_edwards
    buf.write(
        f"LAMMPS data file from gripdem.handback: simulation {state.sim}, frame {state.frame}, "
        f"t = {state.time!r}, ours (x, y, z) = LAMMPS ({', '.join(axes.name)})"
        + ("" if le is None else f", LE offset {state.offset!r}")
        + "\n\n"
    )
    buf.write(f"{n} atoms\n1 atom types\n\n")
    for axis, name in enumerate("xyz"):
        low, high = float(lo[axis]), float(lo[axis] + lengths[axis])
        buf.write(f"{low!r} {high!r} {name}lo {name}hi\n")
    if le is not None:
        buf.write(f"{state.offset!r} 0.0 0.0 xy xz yz\n")
    ids = np.arange(1, n + 1)
    zeros = np.zeros((n, 3), dtype=int)
    if atom_style == "atomic":
        buf.write(f"\nMasses\n\n1 {mass!r}\n")
        buf.write("\nAtoms # atomic\n\n")
        table = np.column_stack([ids, np.ones(n), pos, zeros])
        np.savetxt(buf, table, fmt=f"%d %d {FLOAT} {FLOAT} {FLOAT} %d %d %d")
        buf.write("\nVelocities\n\n")
        np.savetxt(buf, np.column_stack([ids, vel]), fmt=f"%d {FLOAT} {FLOAT} {FLOAT}")
    else:
        buf.write("\nAtoms # sphere\n\n")
        table = np.column_stack([ids, np.ones(n), diameters, np.full(n, density), pos, zeros])
        np.savetxt(buf, table, fmt=f"%d %d {FLOAT} {FLOAT} {FLOAT} {FLOAT} {FLOAT} %d %d %d")
        buf.write("\nVelocities\n\n")
        np.savetxt(buf, np.column_stack([ids, vel]), fmt=f"%d {FLOAT} {FLOAT} {FLOAT} 0 0 0")
    return buf.getvalue()


def extxyz_state_text(state: State) -> str:
    """Extended XYZ of ``state`` in gripdem's axes with the LE lattice (see the module doc)."""
    data = state.data
    lx, ly, lz = (float(v) for v in data.box.lengths)
    n = data.n_particles
    radius = data.radii if data.radii is not None else np.full(n, data.radius)
    header = (
        f'Lattice="{lx!r} 0.0 {state.offset!r} 0.0 {ly!r} 0.0 0.0 0.0 {lz!r}" '
        f'Origin="{-lx / 2!r} {-ly / 2!r} {-lz / 2!r}" pbc="T T T" '
        "Properties=species:S:1:pos:R:3:velo:R:3:radius:R:1:id:I:1 "
        f"Time={state.time!r} frame={state.frame} simulation={state.sim} "
        f"boundary={data.boundary.kind} le_offset={state.offset!r}"
    )
    buf = io.StringIO()
    buf.write(f"{n}\n{header}\n")
    table = np.column_stack([state.positions, state.velocities, radius, np.arange(1, n + 1)])
    np.savetxt(buf, table, fmt="P " + " ".join([FLOAT] * 7) + " %d")
    return buf.getvalue()


def trajectory_dump_text(
    data: TrajectoryData, sim: int, frames: slice, axes: AxisMap, timestep: float
) -> str:
    """LAMMPS dump of frames ``frames`` of simulation ``sim`` (LAMMPS axes, tilted cell)."""
    positions = data.positions[sim, frames]
    times = data.times[sim, frames]
    if positions.shape[0] == 0:
        raise ValueError(f"--dump-frames selects no frame of {data.n_frames}")
    steps = times / timestep
    if np.abs(steps - np.round(steps)).max() > 1e-6:
        raise ValueError(
            f"--timestep {timestep:g} does not divide the frame times (e.g. {times[0]!r}): "
            "TIMESTEP = time / timestep must be whole"
        )
    offsets = data.boundary.offset(times)
    inside = wrap_into_sheared_cell(positions, data.box, offsets[:, None])
    lengths = axes.to_lammps(data.box.lengths)
    radius = data.radii if data.radii is not None else np.full(data.n_particles, data.radius)
    return dump_text(
        np.round(steps).astype(np.int64),
        -0.5 * lengths,
        lengths,
        axes.to_lammps(inside),
        _tilt(data, offsets),
        {"radius": radius},
    )
