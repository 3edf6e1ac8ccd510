"""A sweep and its comparison: a Hydra multirun over two decoder modes (GRIP++ and VCT), the
summary table it writes, and the same numbers read back as TensorBoard shows them (runs named
by what differs, HParams with the settings and the hp/ metrics). The mission's sweep is the
same command at full size: ``python -m gripdem.run -m split=190-10,100-100 model=vct``.

    python examples/sweep_tensorboard.py [--out OUT] [--models grip,vct]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

from gripdem.evaluation.tensorboard_runs import read_runs


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("outputs/examples/sweep"))
    parser.add_argument("--models", default="grip,vct")
    args = parser.parse_args(argv)

    command = [
        sys.executable, "-m", "gripdem.run", "-m", f"model={args.models}", "experiment=smoke",
        f"hydra.sweep.dir={args.out}",
    ]  # fmt: skip
    print("$ python " + " ".join(command[1:]))
    subprocess.run(command, check=True)  # the runner prints the sweep's summary table

    # TensorBoard on the folder above the sweep: each run is named <sweep>/<what differs>
    print("as TensorBoard reads them:")
    for name, run in read_runs(args.out.parent).items():
        if not name.startswith(f"{args.out.name}/"):
            continue  # another sweep in the same folder
        hp = {k: v[-1][1] for k, v in run.scalars.items() if k.startswith("hp/")}
        print(
            f"  run {name} (model {run.hparams['model']}): test RMSE / CV's "
            f"{hp['hp/ratio_cv']:.3f}, / AR's {hp['hp/ratio_ar']:.3f}, "
            f"{hp['hp/seconds_training']:.1f} s of training"
        )
    print(f"compare them: tensorboard --logdir {args.out.parent}")


if __name__ == "__main__":
    main()
