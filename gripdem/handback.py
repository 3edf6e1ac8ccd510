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

OVITO (``ovito.io.import_file``) reads all three, ASE (``ase.io.read``) the extended XYZ, the
dump and ``--atom-style atomic`` data files (its ``lammps-data`` reader has no ``sphere`` style),
each with the LE lattice of the frame (tests/formats/test_viewers.py).

Velocities: the file's own where it stores them, else the mean velocity over the last frame
interval, ``lattice-continuous step (F-1 -> F) / dt`` in the image cell each particle occupies at
frame F (so a particle that just crossed an LE face carries the jumped velocity). The engine's
drag relaxes what a frame-averaged velocity misses within about one relaxation time. Angular
velocities are not predicted and written as 0. Units are the data's (SI for gripdem scenes).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

# light imports only: the readers and writers load inside run_command (a Ctrl-C or SIGTERM
# while they load is answered in one line)
from gripdem.runner.console import run_command

ATOM_STYLES = ("sphere", "atomic")


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
    from gripdem.data.dataset_io import read_dataset
    from gripdem.data.h5io import atomic_write_text
    from gripdem.formats.handback import (
        State,
        data_file_text,
        extxyz_state_text,
        find_value,
        lammps_axes,
        trajectory_dump_text,
    )
    from gripdem.formats.lammps.dump import write_dump

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

    def body() -> int:
        for line in handback(args):
            print(line)
        return 0

    return run_command(
        "gripdem.handback",
        body,
        "files already written are complete, the one being written is not kept",
    )


if __name__ == "__main__":
    sys.exit(main())
