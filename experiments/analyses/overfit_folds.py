"""How far does ``tests/models/test_module.py::test_overfits_one_window`` get, per number of
Adam steps, on any CPU and thread count? The fold of every decoder mode (first loss over the
lowest of the 20 losses before step N) under ATEN_CPU_CAPABILITY = default | avx2 | avx512 and
1 | 2 torch threads, read off one 200-step run per combination (the loss trace up to step N is
the trace of an N-step run).

    python experiments/analyses/overfit_folds.py [--workdir DIR] [--steps 100 120 150 200]
        [--out experiments/results/test_suite/overfit_folds]

Each combination runs in its own process (``--workdir`` keeps its JSON: a finished combination
is read back, not run again). The test's step count and fold bound are chosen from this table:
the smallest fold measured at the chosen step count is at least twice the bound.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "experiments" / "benchmarks"))
sys.path.insert(0, str(ROOT / "experiments" / "analyses"))
from benchlib import machine_line, markdown_table, write_report  # noqa: E402
from threshold_spread import cpu_capabilities  # noqa: E402

TOTAL_STEPS = 200


def folds_of_every_mode(steps: list[int]) -> dict[str, dict[str, float]]:
    """In this process: the test's setup, 200 steps per mode, the fold at each of ``steps``."""
    sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "models")]
    from hydra import compose, initialize_config_dir
    from test_module import MODES, overfit_losses

    from gripdem.config_files import config_dir
    from gripdem.dem.output import ensure_scene_dataset

    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose("simulate", overrides=["scene=lebc", "preset=tiny"])  # the test's scene
    path = ensure_scene_dataset(cfg.scene, cfg.preset, sims=cfg.sims, seed=cfg.seed)
    out = {}
    for mode, encoding, shift, encoder in MODES:  # as the test builds and trains each
        losses = overfit_losses(path, mode, encoding, shift, encoder, TOTAL_STEPS)
        name = f"{mode}/{encoding}/{shift}/{encoder}"
        out[name] = {str(n): losses[0] / min(losses[n - 20 : n]) for n in steps}
    return out


def run_combination(cap: str, threads: int, steps: list[int], workdir: Path) -> dict:
    path = workdir / f"folds_{cap}_{threads}.json"
    if not path.exists():
        env = {**os.environ, "ATEN_CPU_CAPABILITY": cap, "OMP_NUM_THREADS": str(threads)}
        env["GRIPDEM_FOLD_THREADS"] = str(threads)
        cmd = [sys.executable, __file__, "--one", str(path), "--steps", *map(str, steps)]
        subprocess.run(cmd, cwd=ROOT, env=env, check=True)
    return json.loads(path.read_text())


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", type=Path, default=None)
    parser.add_argument("--steps", type=int, nargs="+", default=[100, 120, 150, 200])
    parser.add_argument(
        "--out", type=Path, default=ROOT / "experiments/results/test_suite/overfit_folds"
    )
    parser.add_argument("--one", type=Path, help=argparse.SUPPRESS)  # a combination's process
    args = parser.parse_args(argv)
    if any(not 20 <= n <= TOTAL_STEPS for n in args.steps):
        parser.error(f"--steps: each between 20 and {TOTAL_STEPS}")
    if args.one is not None:
        import torch

        torch.set_num_threads(int(os.environ.get("GRIPDEM_FOLD_THREADS", "1")))
        args.one.write_text(json.dumps(folds_of_every_mode(args.steps)))
        return
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="overfit_folds_"))
    workdir.mkdir(parents=True, exist_ok=True)
    combos = [(cap, t) for cap in cpu_capabilities() for t in (1, 2)]
    runs = {f"{cap}/{t}t": run_combination(cap, t, args.steps, workdir) for cap, t in combos}
    modes = list(next(iter(runs.values())))
    text = [
        "# Overfitting one window: the fold reached per Adam step count, every CPU path\n",
        machine_line() + "\n",
        f"`python experiments/analyses/overfit_folds.py` ({', '.join(runs)}). Fold: the first "
        "loss over the lowest of the 20 losses before the step count, as "
        "`test_overfits_one_window` reads it.\n",
    ]
    rows = []
    for mode in modes:
        row = [mode]
        for n in args.steps:
            values = [run[mode][str(n)] for run in runs.values()]
            row.append(f"{min(values):.2f}-{max(values):.2f}")
        rows.append(row)
    text.append(markdown_table(["mode", *(f"{n} steps" for n in args.steps)], rows))
    worst = {n: min(run[m][str(n)] for run in runs.values() for m in modes) for n in args.steps}
    text.append(
        "\nSmallest fold of all modes and combinations: "
        + ", ".join(f"{worst[n]:.2f} after {n} steps" for n in args.steps)
        + ".\n"
    )
    write_report(args.out, "\n".join(text), {"runs": runs, "smallest": worst})


if __name__ == "__main__":
    main()
