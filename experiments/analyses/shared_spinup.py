"""Can several simulations share one spin-up? Two branches of one spun-up state, each with its
own fluctuating velocities, and how many frames they take to forget each other.

    python experiments/analyses/shared_spinup.py [--scenes pbc lebc] [--frames 300] [--seed 21]
        [--out experiments/results/dem_data/shared_spinup]

A shared spin-up would pack and spin up one state and start several simulations from it, each
after ``D`` frames of decorrelation with velocities of its own. Per scene (default preset, one
process per scene): pack and spin up as the generator does (``simulate_one``), then restart
two branches from that state with the mean flow kept and the fluctuating velocities drawn anew
(Gaussian, each component's own RMS; seeds of their own), and run both ``--frames`` frames.
Per frame since the branch point:

- velocity correlation: Pearson's r between the branches' fluctuating velocities (each
  particle's velocity less its x-slab's mean, 16 slabs), all particles and components; two
  independent simulations give 0 within ``2 / sqrt(3 N)``;
- shared contacts: the fraction of contacts (pairs within 1.01 d, Lees-Edwards images
  included) present in both branches; independent packings share ``z / (N - 1)`` by chance.

The branches have forgotten each other from the frame where shared contacts stay below
``CHANCE_FACTOR`` times chance; a shared spin-up pays for itself only if that is shorter than
the spin-up it replaces (the table's last columns: a worker's frames for three simulations
each way).
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from benchlib import markdown_table, write_report  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
#: contacts: pairs within this many diameters (as spinup_plateau.py)
CONTACT = 1.01
#: x-slabs for the mean flow subtracted before correlating velocities
SLABS = 16
#: branches have forgotten each other once shared contacts stay below this many times chance
CHANCE_FACTOR = 3.0
#: simulations per worker in the default dataset (6 simulations, 2 workers)
SIMS_PER_WORKER = 3


def fluctuations(positions: np.ndarray, velocities: np.ndarray, lx: float) -> np.ndarray:
    """Velocities ``(n, 3)`` less the mean of their x-slab."""
    slab = np.clip((positions[:, 0] / lx * SLABS).astype(int) % SLABS, 0, SLABS - 1)
    out = velocities.copy()
    for s in range(SLABS):
        members = slab == s
        if members.any():
            out[members] -= velocities[members].mean(axis=0)
    return out


def contact_set(positions: np.ndarray, sim) -> set[tuple[int, int]]:
    """Pairs ``(i < j)`` within ``CONTACT`` d at the simulation's current time."""
    from gripdem.boundary import neighbour_pairs

    i, j, _ = neighbour_pairs(positions, sim.box, sim.offset(), CONTACT * 2 * sim.radius.max())
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    return set(zip(lo.tolist(), hi.tolist(), strict=True))


def branch(config, positions, velocities, omega, step, seed):
    """A simulation restarted at ``step`` from the state with fluctuating velocities redrawn."""
    from gripdem.dem.engine import Simulation

    rng = np.random.default_rng(seed)
    fluct = fluctuations(positions, velocities, config.box.lx)
    mean_flow = velocities - fluct
    drawn = rng.standard_normal(fluct.shape) * fluct.std(axis=0)
    return Simulation(config, positions, mean_flow + drawn, omega, step=step)


def run_scene(scene: str, frames: int, seed: int, preset: str = "default") -> dict:
    """Spin up one state of ``scene`` (``preset``), branch it twice, compare per frame."""
    import time

    from benchlib import load_yaml

    from gripdem.dem.config import GeneratorConfig
    from gripdem.dem.engine import Simulation
    from gripdem.dem.packing import random_packing
    from gripdem.dem.scenes import initial_velocities

    config = GeneratorConfig.from_mappings(
        load_yaml("scene", scene), load_yaml("preset", preset), seed=seed
    )
    rng = np.random.default_rng(seed)
    start = time.perf_counter()
    pos = random_packing(
        config.preset.particles,
        config.box,
        config.scene.diameter,
        rng,
        insert_fraction=config.preset.pack_volume_fraction,
    )
    sim = Simulation(config, pos, initial_velocities(config, pos))
    per_frame = config.steps_per_frame
    sim.run(per_frame * config.spinup_frames)
    spinup_s = time.perf_counter() - start
    pos, vel, om = sim.snapshot()
    branches = [branch(config, pos, vel, om, sim.step, seed + k + 1) for k in range(2)]
    n = config.preset.particles
    vcorr, shared, contacts = [], [], []
    start = time.perf_counter()
    for f in range(frames):
        if f:
            for b in branches:
                b.run(per_frame)
        snaps = [b.snapshot() for b in branches]
        fl = [fluctuations(p, v, config.box.lx).ravel() for p, v, _ in snaps]
        vcorr.append(float(np.corrcoef(fl[0], fl[1])[0, 1]))
        sets = [contact_set(p, b) for (p, _, _), b in zip(snaps, branches, strict=True)]
        mean_count = 0.5 * (len(sets[0]) + len(sets[1]))
        shared.append(len(sets[0] & sets[1]) / mean_count)
        contacts.append(2.0 * mean_count / n)
    branch_s = (time.perf_counter() - start) / (2 * frames)
    return {
        "scene": scene,
        "particles": n,
        "preset": preset,
        "spinup_frames": config.spinup_frames,
        "frames": config.preset.frames,
        "velocity_correlation": vcorr,
        "shared_contacts": shared,
        "contacts_per_particle": contacts,
        "chance": float(np.mean(contacts)) / (n - 1),
        "velocity_noise": 2.0 / np.sqrt(3 * n),
        "seconds_per_frame": branch_s,
        "spinup_seconds": spinup_s,
        "strain_per_frame": (
            config.scene.shear_rate * config.preset.frame_interval
            if config.scene.boundary == "lees_edwards"
            else None
        ),
    }


def first_below(series: list[float], level: float) -> int | None:
    """The first frame from which ``series`` stays below ``level`` to the end (None: never)."""
    above = np.nonzero(np.asarray(series) >= level)[0]
    if len(above) and above[-1] == len(series) - 1:
        return None
    return int(above[-1] + 1) if len(above) else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", nargs="+", default=["pbc", "lebc"])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--seed", type=int, default=21)
    parser.add_argument("--preset", default="default")
    parser.add_argument(
        "--out", type=Path, default=ROOT / "experiments/results/dem_data/shared_spinup"
    )
    args = parser.parse_args(argv)
    with ProcessPoolExecutor(len(args.scenes)) as pool:
        results = list(
            pool.map(
                run_scene,
                args.scenes,
                [args.frames] * len(args.scenes),
                [args.seed] * len(args.scenes),
                [args.preset] * len(args.scenes),
            )
        )
    rows = []
    for r in results:
        velocity_frame = first_below(
            [abs(v) for v in r["velocity_correlation"]], r["velocity_noise"]
        )
        half = first_below(r["shared_contacts"], 0.5)
        tenth = first_below(r["shared_contacts"], 0.1)
        forgot = first_below(r["shared_contacts"], CHANCE_FACTOR * r["chance"])
        r.update(
            velocity_frame=velocity_frame, half_frame=half, tenth_frame=tenth, forgot_frame=forgot
        )
        own = SIMS_PER_WORKER * (r["spinup_frames"] + r["frames"])
        shared = (
            None
            if forgot is None
            else r["spinup_frames"] + SIMS_PER_WORKER * (forgot + r["frames"])
        )
        r.update(own_spinup_frames=own, shared_spinup_frames=shared)

        def cell(frame, strain=r["strain_per_frame"]):
            if frame is None:
                return f"not within {args.frames}"
            return f"{frame}" + (f" (strain {frame * strain:.2f})" if strain else "")

        rows.append(
            [
                r["scene"],
                f"{r['velocity_correlation'][0]:.3f} → {r['velocity_correlation'][-1]:.3f}",
                cell(velocity_frame),
                f"{r['shared_contacts'][0]:.3f} → {r['shared_contacts'][-1]:.3f}",
                f"{r['chance']:.4f}",
                cell(half),
                cell(tenth),
                cell(forgot),
                own,
                "more than today" if shared is None else shared,
            ]
        )
    text = (
        "# Shared spin-up: how long two branches of one spun-up state stay alike\n\n"
        "One state per scene packed and spun up as the generator does "
        f"({args.preset} preset), then two "
        "branches restarted from it, each with the mean flow kept and its fluctuating velocities "
        f"drawn anew, run {args.frames} frames. Velocity correlation: Pearson's r of the "
        "branches' fluctuating velocities (within ±2/√(3N) for independent simulations). "
        f"Shared contacts: the fraction of contacts (pairs within {CONTACT} d) present in both "
        "branches (chance: z/(N-1)). A frame column gives the first frame since the branch "
        "point from which the statistic stays below its level to the run's end. Frames per "
        f"worker: {SIMS_PER_WORKER} simulations each with its own spin-up (today) against one "
        f"spin-up shared, each simulation after decorrelating until shared contacts stay below "
        f"{CHANCE_FACTOR:g}x chance.\n\n"
        + markdown_table(
            [
                "scene",
                "velocity r (first → last frame)",
                "velocity r within noise from frame",
                "shared contacts (first → last)",
                "chance",
                "shared < 0.5 from frame",
                "shared < 0.1 from frame",
                f"shared < {CHANCE_FACTOR:g}x chance from frame",
                "frames per worker, own spin-up",
                "frames per worker, shared spin-up",
            ],
            rows,
        )
    )
    write_report(args.out, text, {r["scene"]: r for r in results})
    figure = args.out.parent / f"{args.out.name}.png"
    from gripdem.plots.common import new_figure, save_figure

    fig = new_figure(10.0, 4.0)
    axes = fig.subplots(1, 2)
    for r in results:
        axes[0].plot(r["velocity_correlation"], label=r["scene"])
        axes[1].semilogy(r["shared_contacts"], label=r["scene"])
        axes[1].axhline(
            CHANCE_FACTOR * r["chance"], ls=":", lw=1, color=axes[1].lines[-1].get_color()
        )
    axes[0].axhline(0.0, color="k", lw=0.5)
    axes[0].set_xlabel("frames since the branch point")
    axes[0].set_ylabel("velocity correlation between branches")
    axes[1].set_xlabel("frames since the branch point")
    axes[1].set_ylabel(f"shared contacts (dotted: {CHANCE_FACTOR:g}x chance)")
    for ax in axes:
        ax.legend(fontsize=8)
    save_figure(fig, figure)
    print(f"wrote {figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
