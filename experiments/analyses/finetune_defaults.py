"""Which optimiser settings should fine-tuning use? The shipped model fine-tuned on scenes unlike
its training scene, with today's from-scratch settings and with candidate fine-tuning settings.

    python experiments/analyses/finetune_defaults.py [--source pretrained:pbc]
        [--scenes phi045 drive500] [--candidates 5e-4/0.2 2e-4/0.2] [--steps 600] [--sims 4]
        [--threads 1] [--candidates-only]

Each scene is the built-in DEM's periodic scene with one thing changed (``phi045``: volume
fraction 0.45 instead of 0.5, a larger box and a weaker cohesion network; ``drive500``: the body
force halved, a peak shear rate of 500 1/s instead of 1000), generated once into the dataset
cache (``--sims`` simulations of the default preset: train / val / test are different
simulations). Per scene, ``python -m gripdem.run model.init_from=SOURCE`` runs

- with today's settings (the default preset's ``model.lr`` 2e-3, warm-up 0.05, its step budget of
  1820 steps; ``finetune.*=null``),
- with the same learning rate at ``--steps`` steps,
- with each candidate ``LR/WARMUP`` at ``--steps`` steps,

all from the same seed, and the table shows the source as it is and each run's test RMSE ÷ CV
(out of sample), the best validation RMSE against the start's, whether the run kept the start
(training did not beat it on validation), the trained model's own test RMSE then, and the
training time. Output: ``experiments/results/fine_tuning/finetune_defaults.{md,json}``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "experiments" / "benchmarks"))
from benchlib import machine_line, markdown_table, write_report  # noqa: E402

SCENES = {
    "phi045": ["scene.volume_fraction=0.45"],
    "drive500": ["scene.body_force_shear_rate=500"],
}
TODAY = ["finetune.lr=null", "finetune.warmup_fraction=null", "finetune.max_steps=null"]


def run(out: Path, overrides: list[str]) -> dict:
    """``python -m gripdem.run`` into ``out``; its metrics.json."""
    cmd = [sys.executable, "-m", "gripdem.run", f"hydra.run.dir={out}", *overrides]
    cmd += ["outputs.figures=false", "outputs.export_xyz=false", "outputs.predictions=false"]
    started = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{proc.stderr[-3000:]}")
    metrics = json.loads((out / "metrics.json").read_text())
    metrics["wall_seconds"] = time.perf_counter() - started
    return metrics


def row(scene: str, name: str, m: dict) -> list:
    cv = m["test/rmse_constant_velocity"]
    trained = m.get("finetune/trained_test_rmse")
    return [
        scene,
        name,
        f"{m['test/rmse'] / cv:.4f}",
        f"{m['val/rmse_best'] / m['finetune/start_val_rmse']:.4f}",
        "yes" if m.get("finetune/kept_start") else "no",
        "-" if trained is None else f"{trained / cv:.4f}",
        m["steps"],
        f"{m['train_seconds']:.0f}",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", default="pretrained:pbc")
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    parser.add_argument("--candidates", nargs="+", default=["5e-4/0.2", "2e-4/0.2"])
    parser.add_argument("--steps", type=int, default=600)
    parser.add_argument("--sims", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--candidates-only", action="store_true", help="only the candidates (no run at today's lr)"
    )
    parser.add_argument("--threads", type=int, default=1, help="torch threads of each run")
    parser.add_argument(
        "--out", default=str(ROOT / "experiments/results/fine_tuning/finetune_defaults")
    )
    args = parser.parse_args()
    print(machine_line(), flush=True)
    settings = []
    if not args.candidates_only:
        settings.append(("today (lr 2e-3, warm-up 0.05, 1820 steps)", TODAY))
        settings.append(
            (
                f"lr 2e-3, warm-up 0.05, {args.steps} steps",
                [*TODAY[:2], f"finetune.max_steps={args.steps}"],
            )
        )
    for candidate in args.candidates:
        lr, warmup = candidate.split("/")
        settings.append(
            (
                f"lr {lr}, warm-up {warmup}, {args.steps} steps",
                [f"finetune.lr={lr}", f"finetune.warmup_fraction={warmup}"]
                + [f"finetune.max_steps={args.steps}"],
            )
        )
    rows, results = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for scene in args.scenes:
            base = [f"model.init_from={args.source}", f"seed={args.seed}", *SCENES[scene]]
            base += [f"preset.sims={args.sims}", f"torch_threads={args.threads}"]
            for i, (name, overrides) in enumerate(settings):
                m = run(Path(tmp) / f"{scene}_{i}", base + overrides)
                if i == 0:  # the source as it is, on the same test windows
                    cv = m["test/rmse_constant_velocity"]
                    as_is = m["before/test/rmse"] / cv
                    rows.append(
                        [scene, "as is (no fine-tuning)", f"{as_is:.4f}", "-", "-", "-", 0, 0]
                    )
                rows.append(row(scene, name, m))
                results[f"{scene}/{name}"] = m
                print(" | ".join(str(c) for c in rows[-1]), flush=True)
    headers = [
        "scene",
        "fine-tuning",
        "test RMSE / CV",
        "best val / start val",
        "kept start",
        "trained test / CV",
        "steps",
        "train s",
    ]
    text = (
        f"# Fine-tuning defaults\n\n{machine_line()}\n\nSource: `{args.source}`; seed "
        f"{args.seed}; {args.sims} simulations per scene (train / val / test different "
        "simulations, out of sample).\n\n" + markdown_table(headers, rows) + "\n"
    )
    write_report(args.out, text, results)


if __name__ == "__main__":
    main()
