"""numba's compile options for the DEM kernels: time per particle-step and the trajectory's
change, each variant beside the shipped kernels in one run.

    python experiments/benchmarks/surrogate/dem_kernel_options.py [--scene pbc] [--frames 5]
        [--rounds 3] [--quick] [--out experiments/results/dem_data/dem_kernel_options]

Each variant is ``gripdem/dem/forces_numba.py`` compiled with other ``numba.njit`` options (the
source read and loaded as a module of its own, nothing of the package changed): the shipped options
(``fastmath`` without ``nnan``/``ninf``, which keeps NaN and Inf semantics: ``FASTMATH``), no
``fastmath`` (the kernels before ``GENERATOR_VERSION`` 2), ``error_model="numpy"`` on top of the
shipped options (no division-by-zero checks), and other ``fastmath`` flag sets (``contract`` only:
fused multiply-adds; all flags). Every variant restarts the same state (the last frame of the
scene's default dataset, its last simulation), is timed over ``--frames`` frames after one untimed
frame (compilation, lists), the rounds alternating the variants, fastest kept; the final state's
largest difference from the shipped kernels' is reported (0: bit-identical).
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # benchlib: it adds the groups
from benchlib import fmt, machine_line, markdown_table, write_report  # noqa: E402
from dem_cost import restart_state  # noqa: E402
from surrogate_speed import engine_state  # noqa: E402

import gripdem.dem.engine as engine  # noqa: E402

KERNELS = Path(engine.__file__).with_name("forces_numba.py")
SHIPPED = "@numba.njit(cache=True, fastmath=FASTMATH)"
SHIPPED_NAME = "shipped (fastmath, NaN/Inf kept)"
#: variant name -> the decorator that replaces the shipped one
VARIANTS = {
    SHIPPED_NAME: SHIPPED,
    "no fastmath (generator version 1)": "@numba.njit()",
    "shipped + error_model numpy": '@numba.njit(error_model="numpy", fastmath=FASTMATH)',
    "fastmath contract only": '@numba.njit(fastmath={"contract"})',
    "fastmath all": "@numba.njit(fastmath=True)",
}


def load_variant(name: str, decorator: str, work: Path):
    """The kernel module compiled with ``decorator`` (the shipped one: the package's own)."""
    if decorator == SHIPPED:
        return engine.forces_numba
    source = KERNELS.read_text()
    if source.count(SHIPPED) < 2:
        raise RuntimeError(f"{KERNELS}: expected the decorator {SHIPPED} on both kernels")
    path = work / f"kernels_{list(VARIANTS).index(name)}.py"
    path.write_text(source.replace(SHIPPED, decorator))
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def time_variant(kernels, config, state, frames: int) -> tuple[float, np.ndarray]:
    """Seconds per frame (fastest of ``frames``) and the final wrapped positions."""
    engine.forces_numba = kernels
    positions, velocities, t = state
    sim = engine.Simulation(config, positions, velocities, step=round(t / config.dt))
    sim.run(config.steps_per_frame)  # compilation, first list
    walls = []
    for _ in range(frames):
        start = time.perf_counter()
        sim.run(config.steps_per_frame)
        walls.append(time.perf_counter() - start)
    return min(walls), sim.snapshot()[0]


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="pbc")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="tiny preset, one frame, one round")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    preset = "tiny" if args.quick else "default"
    if args.quick:
        args.frames, args.rounds = 1, 1
    shipped = engine.forces_numba
    work = Path(__file__).resolve().parent / ".dem_kernel_options"
    work.mkdir(exist_ok=True)
    try:
        meta, params, state = restart_state(args.scene, preset, work)
        config = engine_state(params, meta)
        kernels = {name: load_variant(name, deco, work) for name, deco in VARIANTS.items()}
        walls: dict[str, list[float]] = {name: [] for name in VARIANTS}
        finals: dict[str, np.ndarray] = {}
        for _ in range(args.rounds):
            for name, module in kernels.items():
                wall, final = time_variant(module, config, state, args.frames)
                walls[name].append(wall)
                finals[name] = final
    finally:
        engine.forces_numba = shipped
        for stale in work.iterdir():
            stale.unlink()
        work.rmdir()
    per_step = config.steps_per_frame * meta.n_particles
    base = min(walls[SHIPPED_NAME])
    rows, data = [], []
    for name in VARIANTS:
        fastest = min(walls[name])
        change = float(np.abs(finals[name] - finals[SHIPPED_NAME]).max())
        rows.append(
            [name, fmt(1e6 * fastest / per_step), fmt(fastest / base), fmt(change / meta.diameter)]
        )
        data.append({"variant": name, "decorator": VARIANTS[name], "s_per_frame": walls[name],
                     "state_change_max": change})  # fmt: skip
    text = "\n".join(
        [
            "# numba's compile options for the DEM kernels",
            "",
            machine_line(),
            "",
            f"Scene {args.scene}, {meta.n_particles} particles, restarted from the last frame of "
            f"its {preset} dataset; {args.frames} frames timed per variant after one untimed, the "
            f"fastest of {args.rounds} rounds (variants alternating). Position change: the largest "
            f"difference of a particle's position after {args.frames + 1} frames from the shipped "
            "kernels', over the diameter d (0: bit-identical; a chaotic flow amplifies any "
            "rounding difference with time).",
            "",
            markdown_table(
                ["variant", "µs per particle-step", "÷ shipped", "position change ÷ d"], rows
            ),
        ]
    )
    out = {"scene": args.scene, "frames": args.frames, "rounds": args.rounds, "variants": data}
    write_report(args.out, text, out)
    return out


if __name__ == "__main__":
    main(sys.argv[1:])
