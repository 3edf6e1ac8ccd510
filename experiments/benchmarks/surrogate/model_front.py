"""The time-vs-error front of model sizes: which model gives which accuracy at which speed?

    python experiments/benchmarks/surrogate/model_front.py RUN_DIR... [--frames 60] [--threads 1 2]
        [--links 10 1] [--out-dir experiments/results/model_cost] [--name model_front]
    python experiments/benchmarks/surrogate/model_front.py --quick   # two smoke models, tiny scene

Every ``RUN_DIR`` is a ``python -m gripdem.run`` output directory of one configuration (width,
message rounds, cut-off, history, decoder; trained on the same data with the same budget:
``experiments/analyses/model_front.sh`` trains the grid). For each: its test RMSE against
constant velocity and linear AR (out of sample, from ``metrics.json``), its training time, its
number of weights, and the in-memory stepper's wall time per predicted frame on 2000 particles
of the scene's test simulation, at every link length and thread count asked for (the stable
setting: contact correction on), with the breakdown of the frame's time. The DEM's time per
frame is measured in the same run. Writes ``NAME.md`` (the result header, then the table),
``NAME.json`` (the rows, a list: the header is the Markdown file's) and ``NAME.png`` (the front:
milliseconds per frame against RMSE / CV).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np
import torch

sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # benchlib: it adds the groups
from benchlib import (  # noqa: E402
    atomic_write,
    fmt,
    machine_line,
    markdown_table,
    set_threads,
    train_run,
    write_result,
)
from surrogate_handback import dem_seconds_per_frame, generator_config  # noqa: E402

from gripdem.data.dataset_io import read_meta  # noqa: E402
from gripdem.inference.checkpoint import load_model  # noqa: E402
from gripdem.inference.stepper import PARTS, Stepper, StepperSettings  # noqa: E402
from gripdem.plots.common import new_figure, save_figure  # noqa: E402


def describe(hp: dict) -> str:
    enc = hp.get("encoder") or {}
    parts = [
        f"{enc.get('name', 'graph_conv')} c{enc.get('channels')} r{enc.get('rounds', '-')}",
        f"cut {hp.get('graph_cutoff')}",
        f"K {hp.get('history_len')}",
        f"{hp.get('decoder', 'gru')} {hp.get('hidden')}",
    ]
    return ", ".join(parts)


def time_stepper(model, observed, times, frames: int, link: int) -> tuple[float, dict]:
    """Best of two: seconds per frame over ``frames`` frames after a warm-up link."""
    best, parts = np.inf, {}
    for _ in range(2):
        stepper = Stepper(model, observed, times, StepperSettings(link=link))
        stepper.advance(stepper.link)
        stepper.seconds = dict.fromkeys(PARTS, 0.0)
        start = time.perf_counter()
        stepper.advance(frames)
        seconds = (time.perf_counter() - start) / frames
        if seconds < best:
            best, parts = seconds, {k: v / frames for k, v in stepper.seconds.items()}
    return best, parts


def measure(run: Path, args) -> dict:
    metrics = json.loads((run / "metrics.json").read_text())
    data_path = Path(metrics["data"]["path"])
    meta = read_meta(data_path)
    model = load_model(run / "checkpoints" / "best.ckpt", meta)
    hp = dict(model.hparams)
    k = int(hp["history_len"])
    sim = metrics["data"]["sims_test"][0]
    with h5py.File(data_path, "r") as h5:
        truth = np.asarray(h5["positions"][sim], np.float64)
        times = np.asarray(h5["times"][sim], np.float64)
    row = {
        "run": str(run),
        "model": describe(hp),
        "scene": metrics["hparams"]["scene"],
        "rmse_over_cv": metrics["test/rmse_ratio_constant_velocity"],
        "rmse_over_ar": metrics.get("test/rmse_ratio_linear_ar"),
        "rmse_over_d": metrics["test/rmse_over_d"],
        "train_seconds": metrics["train_seconds"],
        "steps": metrics.get("steps"),
        "weights": int(sum(p.numel() for p in model.parameters())),
        "timing": {},
    }
    for threads in args.threads:
        set_threads(threads)
        for link in args.links:
            link = min(link, int(hp["horizon"]))
            seconds, parts = time_stepper(
                model, truth[None, : k + 1], times[None, : k + 1], args.frames, link
            )
            row["timing"][f"{threads}t/link{link}"] = {
                "ms": 1e3 * seconds,
                "parts_ms": {p: 1e3 * v for p, v in parts.items()},
            }
    set_threads(1)
    row["dem_ms"] = 1e3 * dem_seconds_per_frame(generator_config(data_path), truth, times)
    return row


def plot_front(rows: list[dict], path: Path, key: str) -> None:
    fig = new_figure(7.0, 4.8)
    ax = fig.add_subplot()
    for scene, marker in (("pbc", "o"), ("lebc", "s")):
        sel = [r for r in rows if r["scene"] == scene and key in r["timing"]]
        if not sel:
            continue
        x = [r["timing"][key]["ms"] for r in sel]
        y = [r["rmse_over_cv"] for r in sel]
        ax.scatter(x, y, marker=marker, label=f"{scene} ({key})")
        for r, xi, yi in zip(sel, x, y, strict=True):
            ax.annotate(
                r["model"].split(",")[0],
                (xi, yi),
                fontsize=6,
                xytext=(3, 3),
                textcoords="offset points",
            )
        dem = np.median([r["dem_ms"] for r in sel])
        ax.axvline(dem / 50, color="C1", ls="--", lw=1)
    ax.axvline(np.nan, color="C1", ls="--", lw=1, label="DEM time / 50")
    ax.set(
        xscale="log",
        xlabel="ms per predicted frame (2000 particles, stepper)",
        ylabel="test RMSE / constant velocity (190-10)",
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    save_figure(fig, path)


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="*", type=Path)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--threads", type=int, nargs="+", default=[1])
    parser.add_argument("--links", type=int, nargs="+", default=[10, 1])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out-dir", type=Path, default=Path("experiments/results/model_cost"))
    parser.add_argument("--name", default="model_front")
    args = parser.parse_args(argv)
    runs = list(args.runs)
    if args.quick:
        work = Path(tempfile.mkdtemp(prefix="front_"))
        for name, extra in (("c8", ["model.encoder.channels=8"]), ("c16", [])):
            runs.append(train_run(work / name, ["experiment=smoke", *extra]))
        args.frames = min(args.frames, 10)
    if not runs:
        parser.error("give run directories (or --quick)")
    rows = [measure(run, args) for run in runs]
    keys = list(dict.fromkeys(key for r in rows for key in r["timing"]))  # in the asked order
    table = [
        [
            r["scene"],
            r["model"],
            fmt(r["rmse_over_cv"]),
            fmt(r["rmse_over_ar"] or np.nan),
            fmt(r["train_seconds"]),
            r["weights"],
            fmt(r["dem_ms"]),
        ]
        + [fmt(r["timing"][k]["ms"]) if k in r["timing"] else "–" for k in keys]
        + [fmt(r["dem_ms"] / r["timing"][keys[0]]["ms"])]
        for r in rows
    ]
    headers = (
        ["scene", "model", "RMSE/CV", "RMSE/AR", "train s", "weights", "DEM ms"]
        + [f"ms/frame {k}" for k in keys]
        + [f"speed-up ({keys[0]})"]
    )
    markdown = f"machine: {machine_line()}\n\n" + markdown_table(headers, table) + "\n"
    write_result(args.out_dir / f"{args.name}.md", markdown)
    atomic_write(args.out_dir / f"{args.name}.json", json.dumps(rows, indent=1) + "\n")
    plot_front(rows, args.out_dir / f"{args.name}.png", keys[0])
    print(markdown)
    return rows


if __name__ == "__main__":
    torch.set_grad_enabled(False)
    main(sys.argv[1:])
