"""Benchmark of the built-in DEM generator (issue 3).

Prints particle-steps per second and wall time per written frame for n = 500, 2000, 8000
particles (O(n) scaling: particle-steps/s should stay flat), and the wall time of one default
2000-particle x 201-frame simulation (spin-up included) per scene; ``--dataset`` also times
the whole default dataset (all its simulations, in worker processes).

    python experiments/benchmarks/surrogate/dem_speed.py [--sizes 500 2000 8000] [--scenes lebc pbc]
        [--backend numba|torch --device cpu|cuda] [--no-full] [--dataset] [--json out.json]

Timings depend on what else runs on the machine: the load average is printed with them.
``--json`` writes the numbers with the result header's fields under ``header``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from gripdem.dem.config import GeneratorConfig
from gripdem.dem.engine import Simulation
from gripdem.dem.output import generate_dataset
from gripdem.dem.packing import random_packing
from gripdem.dem.scenes import initial_velocities, simulate_one
from gripdem.provenance import atomic_write, result_fields

CONF = Path(__file__).resolve().parents[3] / "conf"


def load(scene: str, preset: str = "default", **overrides) -> GeneratorConfig:
    s = yaml.safe_load((CONF / "scene" / f"{scene}.yaml").read_text())
    p = yaml.safe_load((CONF / "preset" / f"{preset}.yaml").read_text())
    p.update(overrides)
    return GeneratorConfig.from_mappings(s, p, sims=1)


def bench_size(scene: str, n: int, frames: int, warmup: int, backend: str, device: str) -> dict:
    """Steady-ish stepping cost for n particles (after a short driven warm-up)."""
    cfg = load(scene, particles=n)
    pos = random_packing(n, cfg.box, cfg.scene.diameter, np.random.default_rng(0))
    sim = Simulation(cfg, pos, initial_velocities(cfg, pos), backend=backend, device=device)
    sim.run(warmup * cfg.steps_per_frame)
    rebuilds = sim.rebuilds
    start = time.perf_counter()
    for _ in range(frames):
        sim.run(cfg.steps_per_frame)
        sim.snapshot()
    wall = time.perf_counter() - start
    steps = frames * cfg.steps_per_frame
    return {
        "scene": scene,
        "particles": n,
        "ms_per_step": 1e3 * wall / steps,
        "particle_steps_per_s": n * steps / wall,
        "s_per_frame": wall / frames,
        "pairs": len(sim.pairs),
        "rebuilds_per_frame": (sim.rebuilds - rebuilds) / frames,
    }


def bench_full(scene: str, backend: str, device: str) -> dict:
    """One default simulation: packing, spin-up and 201 frames."""
    cfg = load(scene)
    if backend != cfg.backend:
        cfg = GeneratorConfig(cfg.scene, cfg.preset, 1, 0, backend)
    start = time.perf_counter()
    result = simulate_one(cfg, np.random.default_rng(0), device=device)
    wall = time.perf_counter() - start
    return {
        "scene": scene,
        "wall_s": wall,
        "steps": result.steps,
        "ms_per_step": 1e3 * wall / result.steps,
        "max_overlap_d": result.max_overlap,
    }


def bench_dataset(scene: str, workers: int | None) -> dict:
    """The whole default dataset as ``python -m gripdem.simulate`` makes it (incl. validation)."""
    cfg = load(scene)
    cfg = GeneratorConfig(cfg.scene, cfg.preset, cfg.preset.sims, 0, cfg.backend)
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        _, report = generate_dataset(cfg, Path(tmp) / "bench.h5", progress=False, workers=workers)
        wall = time.perf_counter() - start
    return {"scene": scene, "sims": cfg.sims, "wall_s": wall, "passed": report["passed"]}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[500, 2000, 8000])
    ap.add_argument("--scenes", nargs="+", default=["lebc", "pbc"])
    ap.add_argument("--frames", type=int, default=5, help="timed frames per size")
    ap.add_argument("--warmup", type=int, default=4, help="untimed frames per size")
    ap.add_argument("--backend", default="numba", choices=["numba", "torch"])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--no-full", action="store_true", help="skip the 2000 x 201 simulation")
    ap.add_argument("--dataset", action="store_true", help="also time the default dataset")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)

    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    out: dict = {"backend": args.backend, "device": args.device, "cpus": cpus, "sizes": []}
    print(f"backend {args.backend} on {args.device}, {cpus} CPUs, load {os.getloadavg()}")
    print("\n| scene | particles | ms/step | particle-steps/s | s per written frame | pairs |")
    print("|---|---:|---:|---:|---:|---:|")
    for scene in args.scenes:
        for n in args.sizes:
            r = bench_size(scene, n, args.frames, args.warmup, args.backend, args.device)
            out["sizes"].append(r)
            print(
                f"| {scene} | {n} | {r['ms_per_step']:.3f} | {r['particle_steps_per_s']:.3g} | "
                f"{r['s_per_frame']:.3f} | {r['pairs']} |",
                flush=True,
            )
    if not args.no_full:
        out["full"] = []
        print("\n| scene | default simulation (2000 x 201, spin-up incl.) | steps | ms/step |")
        print("|---|---:|---:|---:|")
        for scene in args.scenes:
            r = bench_full(scene, args.backend, args.device)
            out["full"].append(r)
            print(
                f"| {scene} | {r['wall_s']:.1f} s | {r['steps']} | {r['ms_per_step']:.3f} |",
                flush=True,
            )
    if args.dataset:
        out["dataset"] = []
        print("\n| scene | default dataset | wall time | validation |")
        print("|---|---:|---:|---|")
        for scene in args.scenes:
            r = bench_dataset(scene, args.workers)
            out["dataset"].append(r)
            print(
                f"| {scene} | {r['sims']} sims | {r['wall_s']:.1f} s | "
                f"{'passed' if r['passed'] else 'FAILED'} |",
                flush=True,
            )
    out["load_after"] = os.getloadavg()
    print(f"\nload average after: {out['load_after']}")
    if args.json:
        atomic_write(args.json, json.dumps({"header": result_fields(), **out}, indent=2) + "\n")
    return out


if __name__ == "__main__":
    main(sys.argv[1:])
