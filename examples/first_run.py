"""The first run, small: train and test a model on the built-in scene, then look at what the
run wrote. The README's main job is the same command at full size (``python -m gripdem.run``);
``experiment=smoke`` makes it a tiny scene, a tiny model and two epochs.

    python examples/first_run.py [--out OUT] [--scene pbc|lebc]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("outputs/examples/first_run"))
    parser.add_argument("--scene", default="pbc", choices=["pbc", "lebc"])
    args = parser.parse_args(argv)

    command = [sys.executable, "-m", "gripdem.run", f"scene={args.scene}", "experiment=smoke"]
    command.append(f"hydra.run.dir={args.out}")
    print("$ python " + " ".join(command[1:]))
    subprocess.run(command, check=True)

    metrics = json.loads((args.out / "metrics.json").read_text())
    print(f"\nthe run in {args.out}:")
    for path in sorted(args.out.rglob("*")):
        if path.is_file() and not path.name.startswith("."):
            print(f"  {path.relative_to(args.out)}")
    ratio = metrics["test/rmse_ratio_constant_velocity"]
    print(
        f"test RMSE {metrics['test/rmse']:.3g} m = {metrics['test/rmse_over_d']:.4g} d, "
        f"{ratio:.3f} of constant velocity's ({'beats' if ratio < 1 else 'loses to'} it), "
        f"in sample: {metrics['in_sample']}"
    )
    print(f"compare runs: tensorboard --logdir {args.out.parent}")


if __name__ == "__main__":
    main()
