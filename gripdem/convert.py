"""Convert foreign trajectory data to the gripdem HDF5 format.

Usage::

    python -m gripdem.convert fordatis ARCHIVE OUT.h5 [--shear-rate K] [--le-sign {+1,-1}]
        [--time-origin T] [--drop-frames N] [--diameter D] [--body-force A] [--overwrite]
    python -m gripdem.convert lammps DUMP [DUMP ...] OUT.h5 --diameter D --timestep DT
        [--shear-rate K] [--axes yzx] [--le-sign {+1,-1}] [--time-origin T] [--split-files]
        [--body-force A] [--overwrite]

``--body-force A`` records the periodic scene's drive ``a_z = A cos(2 pi x / lx)`` (m/s^2 for
SI data) in the dataset's ``body_force_amplitude`` (periodic data only; a model trained with a
drive is applied only to data recorded with it): :mod:`gripdem.formats.drive`.

One subcommand per source format. The
output is written atomically by :func:`gripdem.data.dataset_io.write_dataset` and an existing file
is never replaced without ``--overwrite``. Bad input exits with status 1 and one clear message
(file, field, expectation), no traceback.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

# light imports only: the importers load inside run_command (a Ctrl-C or SIGTERM while they
# load is answered in one line)
from gripdem.runner.console import run_command

if TYPE_CHECKING:
    from gripdem.formats.fordatis import ImportReport


def _fmt(values) -> str:
    return "(" + ", ".join(f"{v:.6g}" for v in values) + ")"


def format_fordatis_report(report: ImportReport) -> list[str]:
    """Human-readable lines: files, frames, particles, box, boundary and its evidence."""
    box = report.boundary.box
    first = report.files[0]
    out = [f"source: {report.source}", f"files (simulations): {len(report.files)}"]
    for i, sim in enumerate(report.files):
        kept = min(report.n_frames, sim.positions.shape[0])
        line = (
            f"  [{i}] {sim.name}: Step#{sim.first_step}..Step#{sim.first_step + sim.n_steps - 1} "
            f"({sim.n_steps} frames), dropped {sim.dropped}, kept {kept}, "
            f"t = {sim.times[0]:.6g} .. {sim.times[kept - 1]:.6g} s"
        )
        if (sim.centre != 0).any():
            line += f", re-centred by {_fmt(-sim.centre)} m"
        out.append(line)
    if report.skipped:
        out.append(f"skipped archive members (OS metadata): {', '.join(report.skipped)}")
    out += [
        f"frames per simulation: {report.n_frames} kept, {first.dropped} dropped at the start",
        f"particles: {first.positions.shape[1]} (ordered by Identifier, "
        f"{first.identifiers[0]}..{first.identifiers[-1]})",
        f"box: {box.lx:.6g} x {box.ly:.6g} x {box.lz:.6g} m (centred at the origin)",
        f"frame interval: {report.frame_interval:.6g} s",
        f"diameter: {report.diameter:.6g} m, volume fraction {report.volume_fraction:.4f}",
        f"boundary: {report.boundary.kind}",
    ]
    le = report.boundary.lees_edwards
    if le is not None:
        whose = "gripdem's convention" if le.sign > 0 else "the authors' convention"
        out += [
            f"shear rate: {le.shear_rate:.6g} 1/s",
            f"LE sign: {le.sign:+d} (+x image shifted by {'+' if le.sign > 0 else '-'}delta: "
            f"{whose})",
            f"LE time origin: {le.time_origin:.6g} s (delta = 0 there)",
        ]
    out += report.drive
    if report.evidence is not None:
        out += ["evidence: " + line for line in report.evidence.lines()]
    out += [f"note: {note}" for note in report.notes]
    return out


def _sign(text: str) -> int:
    value = int(text)
    if value not in (1, -1):
        raise argparse.ArgumentTypeError(f"expected +1 or -1, got {text!r}")
    return value


def _fordatis(args: argparse.Namespace) -> int:
    from gripdem.data.dataset_io import write_dataset
    from gripdem.formats.fordatis import read_fordatis

    if args.output.exists() and not args.overwrite:
        raise FileExistsError(f"{args.output}: exists; refusing to overwrite it (pass --overwrite)")
    data, report = read_fordatis(
        args.archive,
        shear_rate=args.shear_rate,
        le_sign=args.le_sign,
        time_origin=args.time_origin,
        drop_frames=args.drop_frames,
        diameter=args.diameter,
        body_force=args.body_force,
    )
    for line in format_fordatis_report(report):
        print(line)
    path = write_dataset(args.output, data, overwrite=args.overwrite)
    print(
        f"wrote {path}: positions {tuple(data.positions.shape)} (sims, frames, particles, 3), "
        f"{path.stat().st_size / 1e6:.3g} MB"
    )
    return 0


def _lammps(args: argparse.Namespace) -> int:
    from gripdem.data.dataset_io import write_dataset
    from gripdem.formats.lammps import read_lammps

    if len(args.files) < 2:
        raise ValueError(
            "give one or more dump files and then the output file: DUMP [DUMP ...] OUT.h5"
        )
    *dumps, output = (Path(p) for p in args.files)
    if output.suffix not in (".h5", ".hdf5"):
        raise ValueError(f"{output}: the last argument is the output file and must end in .h5")
    if output.exists() and not args.overwrite:
        raise FileExistsError(f"{output}: exists; refusing to overwrite it (pass --overwrite)")
    data, report = read_lammps(
        dumps,
        diameter=args.diameter,
        timestep=args.timestep,
        shear_rate=args.shear_rate,
        axes=args.axes,
        le_sign=args.le_sign,
        time_origin=args.time_origin,
        split_files=args.split_files,
        body_force=args.body_force,
    )
    for line in report.lines():
        print(line)
    path = write_dataset(output, data, overwrite=args.overwrite)
    print(
        f"wrote {path}: positions {tuple(data.positions.shape)} (sims, frames, particles, 3)"
        + (", velocities" if data.velocities is not None else "")
        + f", {path.stat().st_size / 1e6:.3g} MB"
    )
    return 0


def _add_body_force(parser: argparse.ArgumentParser, units: str) -> None:
    parser.add_argument(
        "--body-force",
        type=float,
        metavar="A",
        help=f"periodic data driven by a_z = A cos(2 pi x / lx) along z: the amplitude A ({units}),"
        " recorded as body_force_amplitude (default 0: no drive; Lees-Edwards data has none)",
    )


def _add_lammps(sub) -> None:
    lammps = sub.add_parser(
        "lammps",
        help="LAMMPS / LIGGGHTS text dumps (orthogonal or triclinic, gzip allowed)",
        description="Import LAMMPS/LIGGGHTS text dumps: ITEM: ATOMS with id and x y z, xs ys zs, "
        "xu yu zu (with or without ix iy iz) or xsu ysu zsu, columns and particles in any "
        "order, one or many snapshots per file. A box sheared by a tilt factor becomes "
        "Lees-Edwards data: ours (x, y, z) = LAMMPS (y, z, x) for an xy tilt, the tilt is "
        "the LE offset, box flips are undone and the tilt is checked against --shear-rate "
        "times the time. Lengths and times keep the dump's units.",
    )
    lammps.add_argument(
        "files", nargs="+", metavar="DUMP ... OUT.h5", help="dump files, then the output file"
    )
    lammps.add_argument(
        "--diameter", type=float, required=True, metavar="D", help="particle diameter"
    )
    lammps.add_argument(
        "--timestep",
        type=float,
        required=True,
        metavar="DT",
        help="the engine's time step (frame times are TIMESTEP x DT)",
    )
    lammps.add_argument(
        "--shear-rate",
        type=float,
        metavar="K",
        help="shear rate, checked against the tilt (read from it when omitted); for an "
        "orthogonal box it makes the data Lees-Edwards, sign and origin from the crossers",
    )
    lammps.add_argument(
        "--axes",
        metavar="ABC",
        help="LAMMPS axes of our x, y, z (default: yzx for a box tilted in xy, zyx for xz, zxy "
        "for yz, xyz for an orthogonal box)",
    )
    lammps.add_argument(
        "--le-sign", type=_sign, metavar="{+1,-1}", help="LE convention (checked, or inferred)"
    )
    lammps.add_argument(
        "--time-origin", type=float, metavar="T", help="time at which the LE offset is 0"
    )
    lammps.add_argument(
        "--split-files",
        action="store_true",
        help="every dump file is its own simulation (default: all files are one simulation)",
    )
    _add_body_force(lammps, "the dump's units: m/s^2 with units si")
    lammps.add_argument("--overwrite", action="store_true", help="replace OUT.h5 if it exists")
    lammps.set_defaults(run=_lammps)


def build_parser() -> argparse.ArgumentParser:
    from gripdem.formats.fordatis import DEFAULT_DIAMETER

    parser = argparse.ArgumentParser(
        prog="python -m gripdem.convert",
        description="Convert trajectory data to the gripdem HDF5 format.",
    )
    sub = parser.add_subparsers(dest="format", required=True, metavar="FORMAT")
    fordatis = sub.add_parser(
        "fordatis",
        help="the authors' Fordatis files: tar.gz of HDF5 files (or one HDF5 file)",
        description="Import the authors' Fordatis format: every HDF5 file becomes one "
        "simulation; one group Step#k per frame. Without --shear-rate the data is periodic; "
        "with it, Lees-Edwards, and the sign convention and time origin are inferred from "
        "particles that cross the x faces.",
    )
    fordatis.add_argument(
        "archive", type=Path, help="tar(.gz) archive of HDF5 files, or one HDF5 file"
    )
    fordatis.add_argument("output", type=Path, help="gripdem HDF5 file to write")
    fordatis.add_argument(
        "--shear-rate",
        type=float,
        metavar="K",
        help="Lees-Edwards shear rate in 1/s (the paper: 1000)",
    )
    fordatis.add_argument(
        "--le-sign",
        type=_sign,
        metavar="{+1,-1}",
        help="LE convention: +1 gripdem's (+x image shifted by +delta), -1 the authors' scripts; "
        "inferred (and checked) when omitted, required when no particle crosses the x faces",
    )
    fordatis.add_argument(
        "--time-origin",
        type=float,
        metavar="T",
        help="time (s) at which the LE offset is 0; inferred when omitted (0 tried first)",
    )
    fordatis.add_argument(
        "--drop-frames",
        type=int,
        default=0,
        metavar="N",
        help="frames to drop at the start of every file (the reference scripts dropped 20)",
    )
    fordatis.add_argument(
        "--diameter",
        type=float,
        default=DEFAULT_DIAMETER,
        metavar="D",
        help=f"particle diameter in m (the files carry none; default {DEFAULT_DIAMETER:g}, the "
        "paper's size read as a diameter)",
    )
    _add_body_force(fordatis, "m/s^2")
    fordatis.add_argument("--overwrite", action="store_true", help="replace OUT.h5 if it exists")
    fordatis.set_defaults(run=_fordatis)
    _add_lammps(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parsed: list[argparse.Namespace] = []  # parsed inside run_command (the parser imports)

    def body() -> int:
        parsed.append(build_parser().parse_args(argv))
        return parsed[0].run(parsed[0])

    def command() -> str:
        return "gripdem.convert" + (f" {parsed[0].format}" if parsed else "")

    def not_written() -> str:
        if not parsed:
            return "nothing written"
        args = parsed[0]
        return (
            f"{args.output if args.format == 'fordatis' else args.files[-1]} not written (the "
            "dataset is written under a temporary name and renamed when complete)"
        )

    return run_command(command, body, not_written)


if __name__ == "__main__":
    sys.exit(main())
