"""Per-frame surrogate time of several model files, side by side in one process.

    python experiments/benchmarks/surrogate/model_ab_speed.py \
        --model shipped=pretrained:pbc --model h20=outputs/.../best.safetensors \
        [--scene pbc] [--frames 60] [--repeats 8] [--threads 1] [--precision auto]
        [--out experiments/results/QUESTION/NAME] [--quick]

The models roll out from the same observed frames of the scene's default dataset (its last
simulation, the test simulation of the default protocol) through
:func:`gripdem.inference.rollout.rollout` with the stepper's defaults (contact correction on),
in turn, ``--repeats`` times: on a shared machine the alternation spreads the other jobs'
load over every model, so the ratios hold where the absolute times drift. Printed per model:
its horizon and history, the fastest and the median ms per frame, and the fastest run's parts.
The accuracy of each model is in its own run's metrics (this script times, it does not score).
Each model runs with the scene (box) of the data, as ``surrogate_speed.py`` moves it.
``--quick``: the tiny scene, 20 frames, 2 repeats (a check that it runs).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # benchlib: it adds the groups
from benchlib import machine_line, markdown_table, scene_dataset, set_threads, write_report  # noqa: E402
from surrogate_speed import model_in_box  # noqa: E402

from gripdem.data.dataset_io import read_meta  # noqa: E402
from gripdem.inference.checkpoint import load_checkpoint_model  # noqa: E402
from gripdem.inference.precision import PRECISIONS  # noqa: E402
from gripdem.inference.rollout import rollout  # noqa: E402
from gripdem.inference.stepper import PARTS, StepperSettings  # noqa: E402


def observed_frames(data_path: Path, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """The last ``frames`` frames of the dataset's last simulation: ``(1, frames, N, 3)``
    positions and ``(1, frames)`` times."""
    import h5py

    meta = read_meta(data_path)
    with h5py.File(data_path, "r") as h5:
        pos = np.asarray(h5["positions"][meta.n_sims - 1, -frames:], np.float64)
        times = np.asarray(h5["times"][meta.n_sims - 1, -frames:], np.float64)
    return pos[None], times[None]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", action="append", required=True, help="NAME=PATH, repeatable")
    ap.add_argument("--scene", default="pbc", choices=["pbc", "lebc"])
    ap.add_argument("--frames", type=int, default=60, help="predicted frames per rollout")
    ap.add_argument("--repeats", type=int, default=8)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--precision", default="auto", choices=PRECISIONS)
    ap.add_argument("--out", type=Path, default=None, help="write OUT.md and OUT.json")
    ap.add_argument("--quick", action="store_true", help="tiny scene, 20 frames, 2 repeats")
    args = ap.parse_args(argv)
    if args.quick:
        args.frames, args.repeats = 20, 2
    if any("=" not in m for m in args.model):
        ap.error("--model: NAME=PATH (e.g. shipped=pretrained:pbc)")
    set_threads(args.threads)
    data_path = scene_dataset(args.scene, "tiny" if args.quick else "default")
    meta = read_meta(data_path)
    settings = StepperSettings(precision=args.precision)
    models = {}
    for item in args.model:
        name, source = item.split("=", 1)
        model = model_in_box(load_checkpoint_model(source), meta)
        k = int(model.hparams.history_len)
        models[name] = (model, *observed_frames(data_path, k + 1))
    for model, obs, times in models.values():  # untimed: the first forward initialises lazily
        rollout(model, meta, obs, times, 1, settings, check_overlap=False)
    walls: dict[str, list[float]] = {name: [] for name in models}
    parts: dict[str, dict[str, float]] = {}
    for _ in range(args.repeats):
        for name, (model, obs, times) in models.items():
            start = time.perf_counter()
            run = rollout(model, meta, obs, times, args.frames, settings, check_overlap=False)
            walls[name].append((time.perf_counter() - start) / args.frames)
            if run.divergence.stopped:
                raise RuntimeError(f"{name}: rollout stopped: {run.divergence.stopped}")
            if walls[name][-1] == min(walls[name]):
                parts[name] = {p: run.stepper.seconds[p] / args.frames for p in PARTS}
    rows = []
    for name, (model, _, _) in models.items():
        fastest, median = min(walls[name]), float(np.median(walls[name]))
        shown = " / ".join(f"{parts[name][p] * 1e3:.2f}" for p in PARTS[:5])
        rows.append([name, int(model.hparams.horizon), int(model.hparams.history_len),
                     f"{fastest * 1e3:.2f}", f"{median * 1e3:.2f}", shown])  # fmt: skip
    text = "\n".join(
        [
            f"# Model files side by side: ms per predicted frame ({args.scene}, "
            f"{meta.n_particles} particles)\n",
            machine_line() + "\n",
            f"{args.repeats} alternating rollouts of {args.frames} frames each, "
            f"{args.threads} thread(s), precision {args.precision}, stepper defaults. Parts: "
            "neighbour list / features / forward / decoding / correction (fastest run).\n",
            markdown_table(
                ["model", "horizon", "history", "fastest", "median", "parts (ms)"], rows
            ),
            "",
        ]
    )
    if args.out is not None:
        write_report(args.out, text, {"walls_s": walls, "parts_s": parts, "models": args.model})
    else:
        print(text)


if __name__ == "__main__":
    main()
