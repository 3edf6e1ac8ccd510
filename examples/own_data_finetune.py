"""Your own data, then fine-tuning: arrays from your code written as a gripdem dataset, the
shipped model applied to it as it is, fine-tuned on it, and loaded back from Python.

    python examples/own_data_finetune.py [--out OUT] [--steps 60]

The "own data" here are DEM runs of a rougher material (friction 0.5 instead of the shipped
model's 0.3), made with :func:`gripdem.simulate`; in your work they come from your engine
(LAMMPS dumps: ``python -m gripdem.convert``; anything else: build a :class:`gripdem.Trajectory`
from its arrays, as below). ``--steps``: the fine-tuning budget (tiny here, for a first look;
the fine-tuning defaults and their comparison are in the documentation).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import gripdem


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("outputs/examples/own_data"))
    parser.add_argument("--steps", type=int, default=60)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    # 1. your arrays -> a gripdem dataset (validated, written atomically)
    rough = gripdem.generate("lebc", preset="tiny", sims=3, seed=5, physics={"friction": 0.5})
    mine = gripdem.Trajectory(
        rough.positions, rough.times, rough.scene, provenance={"source": "my engine"}
    )
    path = gripdem.write_trajectory(args.out / "mine.h5", mine, overwrite=True)
    print(f"wrote {path}: {mine.positions.shape}")

    # 2. fine-tune the shipped model on it (a real run: Lightning, Hydra, TensorBoard)
    run_dir = args.out / "run"
    command = [
        sys.executable, "-m", "gripdem.run", "scene=lebc", f"data.path={path}",
        "model.init_from=pretrained:lebc", "split=custom", "split.history=40",
        "split.horizon=10", f"trainer.max_steps={args.steps}", "+trainer.val_check_interval=20",
        "trainer.enable_progress_bar=false", f"hydra.run.dir={run_dir}",
    ]  # fmt: skip
    print("$ " + " ".join(command[1:]))
    subprocess.run(command, check=True)
    metrics = json.loads((run_dir / "metrics.json").read_text())
    d = mine.scene.diameter
    print(
        f"test RMSE / d: before {metrics['before/test/rmse'] / d:.4g}, after "
        f"{metrics['test/rmse'] / d:.4g}, constant velocity "
        f"{metrics['test/rmse_constant_velocity'] / d:.4g} (kept the start: "
        f"{bool(metrics['finetune/kept_start'])})"
    )

    # 3. the run's model file from Python: its card names the data it was trained on
    model = gripdem.load_model(run_dir / "checkpoints" / "best.safetensors")
    print(f"{model}; trained on {model.card['training_data']['file']}")
    k1 = model.history_len + 1
    run = model.rollout(mine.positions[2, :k1], mine.times[2, :k1], frames=20, scene=mine.scene)
    print(f"rolled out {run.n_predicted} frames; divergence: {run.divergence['first'] or 'none'}")


if __name__ == "__main__":
    main()
