"""Hand a (predicted) state back to a DEM engine: ``python -m gripdem.handback``.

    python -m gripdem.handback TRAJ.h5 [--sim S] [--frame F] [--data OUT.data] [--xyz OUT.xyz]
        [--dump OUT.dump[.gz]] [--dump-frames A:B] [--timestep DT] [--axes yzx]
        [--atom-style sphere|atomic] [--density RHO] [--mass M] [--overwrite]

Input: any gripdem dataset, typically the trajectory ``gripdem.predict`` writes (observed frames,
then predicted ones). The state of simulation ``S`` at frame ``F`` (default: the last) is
written as

- a LAMMPS data file (``--data``) that ``read_data`` loads to continue: box and tilt, atoms
  (``atom_style sphere``: id, type, diameter, density, x, y, z; or ``atomic`` with a mass) and
  velocities. In a sheared box the axes follow LAMMPS's shear (ours (x, y, z) = LAMMPS (y, z, x),
  tilt ``xy`` = the LE offset of that frame, within ``[-Lx/2, Lx/2)``, atoms inside the tilted
  cell); continue with ``fix deform ... xy erate RATE remap v`` where ``RATE`` is printed
  (``le_sign * shear_rate`` in LAMMPS's convention, whose tilt grows at ``erate * Ly``);
- extended XYZ (``--xyz``): the same state with the LE lattice ``(lx, 0, delta), (0, ly, 0),
  (0, 0, lz)`` as ``Lattice`` (gripdem's axes), positions, velocities (``velo``), radius, id;
- a LAMMPS text dump of frames ``A:B`` (``--dump``, default all frames; TIMESTEP = time /
  ``--timestep``, default the frame interval), which ``python -m gripdem.convert lammps`` reads
  back to the same positions.

Velocities: the file's own where it stores them, else the mean velocity over the last frame
interval, ``lattice-continuous step (F-1 -> F) / dt`` in the image cell each particle occupies at
frame F (so a particle that just crossed an LE face carries the jumped velocity). The engine's
drag relaxes what a frame-averaged velocity misses within about one relaxation time. Angular
velocities are not predicted and written as 0. Units are the data's (SI for gripdem scenes).
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path
from typing import Any

import numpy as np

from gripdem.boundary import lattice_continuous_steps, wrap_into_sheared_cell
from gripdem.data.h5io import atomic_write_text
from gripdem.data.lammps_dump import FLOAT, dump_text, write_dump
from gripdem.data.lammps_series import AxisMap
from gripdem.data.schema import TrajectoryData, read_dataset

ATOM_STYLES = ("sphere", "atomic")


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


def _slice(text: str | None) -> slice:
    if not text:
        return slice(None)
    try:
        parts = [int(p) if p else None for p in text.split(":")]
    except ValueError:
        raise ValueError(f"--dump-frames expects A:B (frame indices), got {text!r}") from None
    return slice(*parts[:3])


def handback(args: argparse.Namespace) -> list[str]:
    """Write the requested files; returns the lines to print."""
    outputs = [p for p in (args.data_file, args.xyz, args.dump) if p]
    if not outputs:
        raise ValueError("nothing to write: give --data, --xyz and/or --dump")
    for path in outputs:
        if Path(path).exists() and not args.overwrite:
            raise FileExistsError(f"{path}: exists; refusing to overwrite it (pass --overwrite)")
    if args.atom_style not in ATOM_STYLES:
        raise ValueError(f"--atom-style must be one of {ATOM_STYLES}, got {args.atom_style!r}")
    data = read_dataset(args.trajectory)
    axes = lammps_axes(data, args.axes)
    state = State(data, args.sim, args.frame, str(args.trajectory))
    lines = [
        f"state: simulation {state.sim}, frame {state.frame} of {data.n_frames}, "
        f"t = {state.time:.9g}, {data.n_particles} particles, {data.boundary.kind}",
        f"velocities: {state.velocity_source}",
    ]
    if args.data_file:
        density, mass = args.density, args.mass
        if args.atom_style == "sphere" and density is None:
            density = find_value(data.provenance, "density")
            if density is None:
                raise ValueError(
                    f"{args.trajectory}: atom_style sphere needs a density and the file's "
                    "provenance names none: give --density"
                )
            lines.append(f"density {density:g} from the dataset's provenance")
        if args.atom_style == "atomic" and mass is None:
            raise ValueError("--atom-style atomic needs --mass")
        text = data_file_text(state, axes, args.atom_style, density, mass)
        atomic_write_text(args.data_file, text, args.overwrite)
        lines.append(
            f"wrote {args.data_file}: LAMMPS data file (atom_style {args.atom_style}), ours "
            f"(x, y, z) = LAMMPS ({', '.join(axes.name)})"
        )
        le = data.boundary.lees_edwards
        if le is not None:
            rate = le.sign * le.shear_rate
            lines.append(
                f"continue the shear with: fix ID all deform 1 xy erate {rate:.9g} remap v "
                f"(tilt xy = {state.offset:.9g} now; flow along LAMMPS x, gradient along y)"
            )
    if args.xyz:
        atomic_write_text(args.xyz, extxyz_state_text(state), args.overwrite)
        lines.append(f"wrote {args.xyz}: extended XYZ with the LE lattice")
    if args.dump:
        timestep = args.timestep or data.frame_interval
        text = trajectory_dump_text(data, args.sim, _slice(args.dump_frames), axes, timestep)
        write_dump(args.dump, text, args.overwrite)
        lines.append(
            f"wrote {args.dump}: LAMMPS dump (TIMESTEP = time / {timestep:g}); read it back with "
            f"python -m gripdem.convert lammps {args.dump} OUT.h5 --diameter {data.diameter:g} "
            f"--timestep {timestep:g}"
        )
    return lines


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m gripdem.handback",
        description="Write a state of a gripdem dataset (e.g. the last predicted frame of "
        "gripdem.predict) as a LAMMPS data file, extended XYZ and/or a LAMMPS dump.",
    )
    p.add_argument("trajectory", type=Path, help="gripdem HDF5 dataset (e.g. PRED_trajectory.h5)")
    p.add_argument("--sim", type=int, default=0, help="simulation (default 0)")
    p.add_argument("--frame", type=int, default=-1, help="frame (default -1: the last)")
    p.add_argument("--data", dest="data_file", metavar="OUT.data", help="LAMMPS data file")
    p.add_argument("--xyz", metavar="OUT.xyz", help="extended XYZ of the state")
    p.add_argument("--dump", metavar="OUT.dump", help="LAMMPS dump of the trajectory (.gz ok)")
    p.add_argument("--dump-frames", metavar="A:B", help="frames of the dump (default: all)")
    p.add_argument("--timestep", type=float, metavar="DT", help="engine time step of the dump")
    p.add_argument("--axes", metavar="ABC", help="LAMMPS axes of our x, y, z (sheared: yzx)")
    p.add_argument("--atom-style", default="sphere", choices=ATOM_STYLES)
    p.add_argument("--density", type=float, help="particle density (sphere; default: provenance)")
    p.add_argument("--mass", type=float, help="particle mass (atomic)")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        lines = handback(args)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for line in lines:
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
