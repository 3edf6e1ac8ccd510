"""Can the model replace the DEM? A long out-of-sample rollout against the DEM's own simulation.

    python experiments/benchmarks/surrogate_rollout.py --checkpoint pbc=RUN/checkpoints/best.ckpt \
        lebc=RUN/checkpoints/best.ckpt [--frames 2000] [--block 100] [--threads 1]
        [--link L] [--no-correction] [--out-dir experiments/results] [--name surrogate_rollout]
    python experiments/benchmarks/surrogate_rollout.py --quick   # smoke models on the tiny scene

For each scene, the truth is one new simulation of the built-in DEM (seed 777, which no training
set uses; cached like every generated dataset), ``K + 1 + frames`` frames long. The model rolls
out from its first ``K + 1`` frames for all ``frames`` frames through the in-memory stepper
(the stable setting unless told otherwise). Reported, as tables, JSON and a figure:

- short term: RMSE / d at frames 1-100 of the model, constant velocity and linear AR;
- per block of ``block`` frames, model beside truth (:mod:`gripdem.evaluation.rollout_stats`):
  overlap, g(r) L1, coordination, mean-flow profile and drift, non-affine MSD at lags 1, 10,
  100, RMS steps, the step distribution's W1 distance;
- the noise floor: the same statistics between two independent DEM simulations of the scene
  (the default dataset's simulations 4 and 5), so each figure shows what "equal" means;
- hand-back: the predicted states at frames 10, 100, 1000 and 2000 restarted in the built-in
  DEM for 100 steps, kinetic energy against the same restart from the true state;
- wall time per predicted frame, the model (with its per-part breakdown) against the DEM
  restarted from the true state, in the same run.
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
from benchlib import load_yaml, machine_line, scene_dataset, set_threads, train_run
from surrogate_handback import dem_seconds_per_frame, generator_config, handback_ratios
from surrogate_tables import summary_tables

from gripdem.data.dataset_io import read_meta
from gripdem.dem.output import ensure_scene_dataset
from gripdem.evaluation.metrics import position_residuals, rmse_per_step
from gripdem.evaluation.rollout_stats import block_statistics
from gripdem.inference.checkpoint import load_model
from gripdem.inference.rollout import rollout
from gripdem.inference.stepper import PARTS, StepperSettings
from gripdem.models.baselines import predict_baseline
from gripdem.plots.common import save_figure
from gripdem.plots.rollout import plot_surrogate

TRUTH_SEED = 777


def truth_dataset(scene: str, preset: str, frames: int) -> Path:
    """The long out-of-sample simulation of a scene (generated once into the cache)."""
    p = load_yaml("preset", preset)
    p["frames"] = frames
    return ensure_scene_dataset(load_yaml("scene", scene), p, sims=1, seed=TRUTH_SEED)


def read_sim(path: Path, sim: int, stop: int | None = None):
    with h5py.File(path, "r") as h5:
        return (
            np.asarray(h5["positions"][sim, :stop], np.float64),
            np.asarray(h5["times"][sim, :stop], np.float64),
        )


def short_term(model, meta, run, truth, times, k: int, frames: int) -> dict:
    """RMSE / d per frame 1..frames of the model and the CV and AR baselines."""
    observed = torch.from_numpy(truth[None, : k + 1])
    in_off = torch.from_numpy(meta.boundary.offset(times[None, : k + 1]))
    out_off = meta.boundary.offset(times[None, k + 1 : k + 1 + frames])
    true = truth[None, k + 1 : k + 1 + frames]
    out = {"model": run.predicted[:, :frames]}
    for name in ("constant_velocity", "linear_ar"):
        out[name] = predict_baseline(
            name,
            observed,
            in_off,
            torch.from_numpy(out_off),
            meta.box,
            model.profile,
            model.linear_ar,
            model.boundary,
        ).numpy()
    return {
        name: (
            rmse_per_step(position_residuals(pred, true, meta.box, out_off)) / meta.diameter
        ).tolist()
        for name, pred in out.items()
    }


def noise_floor(scene: str, preset: str, frames: int, block: int) -> dict:
    """Block statistics between two independent DEM simulations of the scene."""
    path = scene_dataset(scene, preset)
    meta = read_meta(path)
    a, times = read_sim(path, meta.n_sims - 1, frames)
    b, _ = read_sim(path, meta.n_sims - 2, frames)
    return block_statistics(b, a, times, meta.boundary, meta.diameter, block=block)


def evaluate_scene(scene, checkpoint, args, preset) -> dict:
    model = load_model(checkpoint, read_meta(scene_dataset(scene, preset)))
    k = int(model.hparams.history_len)
    path = truth_dataset(scene, preset, k + 1 + args.frames)
    meta = read_meta(path)
    model = load_model(checkpoint, meta)
    truth, times = read_sim(path, 0)
    settings = StepperSettings(link=args.link, contact_correction=not args.no_correction)
    started = time.perf_counter()
    run = rollout(
        model,
        meta,
        truth[None, : k + 1],
        times[None, : k + 1],
        args.frames,
        settings,
        check_overlap=False,
    )
    wall = time.perf_counter() - started
    stepper = run.stepper
    predicted = np.concatenate([truth[k : k + 1], run.predicted[0]])  # frame 0: last observed
    span = slice(k, k + 1 + run.n_predicted)
    config = generator_config(path)
    report = {
        "scene": scene,
        "checkpoint": str(checkpoint),
        "truth": str(path),
        "frames": run.n_predicted,
        "stopped": run.divergence.stopped,
        "settings": settings.to_dict() | {"link": stepper.link},
        "model_ms_per_frame": 1e3 * wall / max(run.n_predicted, 1),
        "breakdown_ms_per_frame": {
            p: 1e3 * stepper.seconds[p] / max(run.n_predicted, 1) for p in PARTS
        },
        "dem_ms_per_frame": 1e3 * dem_seconds_per_frame(config, truth[k:], times[k:]),
        "rmse_over_d": short_term(model, meta, run, truth, times, k, min(100, run.n_predicted)),
        "correction": stepper.report.__dict__,
        "blocks": block_statistics(
            predicted, truth[span], times[span], meta.boundary, meta.diameter, block=args.block
        ),
        "noise_floor": noise_floor(scene, preset, min(201, args.frames + 1), args.block),
        "handback": handback_ratios(
            config,
            predicted,
            truth[span],
            times[span],
            [f for f in (10, 100, 1000, 2000) if f <= run.n_predicted],
            args.handback_steps,
        ),
    }
    report["speedup"] = report["dem_ms_per_frame"] / report["model_ms_per_frame"]
    return report


def quick_checkpoints(work: Path) -> dict[str, Path]:
    out = {}
    for scene in ("pbc", "lebc"):
        run = train_run(work / scene, ["experiment=smoke", f"scene={scene}"])
        out[scene] = run / "checkpoints" / "best.ckpt"
    return out


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoint", nargs="+", default=[], metavar="SCENE=PATH")
    parser.add_argument("--frames", type=int, default=2000)
    parser.add_argument("--block", type=int, default=100)
    parser.add_argument("--link", type=int, help="frames kept per forward pass")
    parser.add_argument("--no-correction", action="store_true")
    parser.add_argument("--handback-steps", type=int, default=100)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out-dir", type=Path, default=Path("experiments/results"))
    parser.add_argument("--name", default="surrogate_rollout")
    args = parser.parse_args(argv)
    set_threads(args.threads)
    preset = "tiny" if args.quick else "default"
    if args.quick:
        args.frames, args.block = min(args.frames, 40), min(args.block, 20)
        checkpoints = quick_checkpoints(Path(tempfile.mkdtemp(prefix="surrogate_")))
    else:
        checkpoints = {s: Path(p) for s, p in (c.split("=", 1) for c in args.checkpoint)}
    if not checkpoints:
        parser.error("give --checkpoint pbc=PATH lebc=PATH (or --quick)")
    report = {
        "machine": machine_line(),
        "args": {k: str(v) for k, v in vars(args).items()},
        "scenes": {s: evaluate_scene(s, c, args, preset) for s, c in checkpoints.items()},
    }
    args.out_dir.mkdir(parents=True, exist_ok=True)
    markdown = summary_tables(report)
    (args.out_dir / f"{args.name}.md").write_text(markdown)
    (args.out_dir / f"{args.name}.json").write_text(json.dumps(report, indent=1, default=float))
    for scene, data in report["scenes"].items():
        run_name = Path(data["checkpoint"]).parent.parent.name
        title = f"{scene}: {data['frames']} frames out of sample ({run_name})"
        save_figure(plot_surrogate(data, title), args.out_dir / f"{args.name}_{scene}.png")
    print(markdown)
    return report


if __name__ == "__main__":
    main(sys.argv[1:])
