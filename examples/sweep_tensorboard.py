"""A sweep and its comparison: a Hydra multirun over two models, the summary table it writes,
and the same numbers read back from the runs' TensorBoard event files (what ``tensorboard
--logdir`` plots side by side). The mission's sweep is the same command at full size:
``python -m gripdem.run -m split=190-10,100-100 model=vct``.

    python examples/sweep_tensorboard.py [--out OUT] [--models grip,interaction]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

from tensorboard.backend.event_processing.event_accumulator import EventAccumulator


def scalars(run: Path, tags: tuple[str, ...]) -> dict[str, float]:
    """The last value of each of ``tags`` in a run's TensorBoard event files."""
    out: dict[str, float] = {}
    for events in sorted((run / "tensorboard").glob("events.out.tfevents*")):
        acc = EventAccumulator(str(events))
        acc.Reload()
        for tag in tags:
            if tag in acc.Tags()["scalars"]:
                out[tag] = acc.Scalars(tag)[-1].value
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("outputs/examples/sweep"))
    parser.add_argument("--models", default="grip,interaction")
    args = parser.parse_args(argv)

    command = [
        sys.executable, "-m", "gripdem.run", "-m", f"model={args.models}", "experiment=smoke",
        f"hydra.sweep.dir={args.out}",
    ]  # fmt: skip
    print("$ python " + " ".join(command[1:]))
    subprocess.run(command, check=True)  # the runner prints the sweep's summary table

    tags = ("hp/test_rmse", "hp/test_rmse_cv_baseline", "val/rmse_over_d")
    print("from the TensorBoard event files:")
    for run in sorted(p for p in args.out.iterdir() if (p / "tensorboard").is_dir()):
        values = scalars(run, tags)
        ratio = values["hp/test_rmse"] / values["hp/test_rmse_cv_baseline"]
        model = (run / ".hydra" / "overrides.yaml").read_text().split("model=")[1].split()[0]
        print(
            f"  job {run.name} ({model}): test RMSE / CV's {ratio:.3f}, last validation "
            f"RMSE {values['val/rmse_over_d']:.4g} d"
        )
    print(f"compare them: tensorboard --logdir {args.out}")


if __name__ == "__main__":
    main()
