"""Can the model replace the DEM? A long out-of-sample rollout against the DEM's own simulation.

    python experiments/benchmarks/surrogate/surrogate_rollout.py \
        --checkpoint pbc=RUN/checkpoints/best.ckpt \
        lebc=RUN/checkpoints/best.ckpt [--frames 2000] [--block 100] [--threads 1]
        [--link L] [--no-correction] [--out-dir experiments/results/long_rollouts]
        [--name surrogate_rollout]
    # an ensemble beside the point model
    python experiments/benchmarks/surrogate/surrogate_rollout.py \
        --checkpoint pbc=ENS.safetensors --members 8 --seed 0 --reference pbc=pretrained:pbc
    # smoke models on the tiny scene
    python experiments/benchmarks/surrogate/surrogate_rollout.py --quick

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

An ensemble model (``--members M``) rolls out ``M`` members from the same observed frames
(seeded with ``--seed``). The block statistics above are computed for every member (the tables
show member 0 and the worst over the members); beside them: the self-diffusion coefficient per
axis, the ensemble's spread per block, and over frames 1-100 the CRPS, the spread/skill ratio and
the rank histogram, against the CRPS (absolute error) of CV, AR and a ``--reference`` model (the
deterministic surrogate, rolled out in the same run on the same truth, with the same statistics).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np
import torch

sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # benchlib: it adds the groups
from benchlib import (  # noqa: E402
    load_yaml,
    machine_line,
    scene_dataset,
    set_threads,
    train_run,
    write_report,
)
from surrogate_handback import dem_seconds_per_frame, generator_config, handback_ratios  # noqa: E402
from surrogate_options import add_correction_options, rollout_options, stepper_settings  # noqa: E402
from surrogate_tables import summary_tables  # noqa: E402

from gripdem.data.dataset_io import read_meta  # noqa: E402
from gripdem.dem.output import ensure_scene_dataset  # noqa: E402
from gripdem.evaluation.ensemble_scores import (  # noqa: E402
    crps_per_step,
    ensemble_mean_and_spread,
    rank_histogram,
    spread_skill_per_step,
)
from gripdem.evaluation.metrics import position_residuals, rmse_per_step  # noqa: E402
from gripdem.evaluation.rollout_stats import (  # noqa: E402
    DIFFUSION_LAGS,
    block_statistics,
    diffusion_coefficients,
)
from gripdem.inference.checkpoint import load_model  # noqa: E402
from gripdem.inference.relaxation import DemRelaxation  # noqa: E402
from gripdem.inference.rollout import rollout  # noqa: E402
from gripdem.inference.stepper import PARTS  # noqa: E402
from gripdem.models.baselines import predict_baseline  # noqa: E402
from gripdem.plots.common import save_figure  # noqa: E402
from gripdem.plots.rollout import plot_surrogate  # noqa: E402

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


def short_term(model, meta, members, truth, times, k: int, frames: int) -> dict:
    """Per frame 1..frames: RMSE / d of the model (an ensemble's mean) and of the CV and AR
    baselines, and the CRPS / d of each (the members' fair CRPS; a point forecast's absolute
    error); for an ensemble also the spread/skill ratio and the rank histogram (frames pooled).
    ``members`` ``(M, frames >= n, N, 3)``."""
    observed = torch.from_numpy(truth[None, : k + 1])
    in_off = torch.from_numpy(meta.boundary.offset(times[None, : k + 1]))
    out_off = meta.boundary.offset(times[None, k + 1 : k + 1 + frames])
    true = truth[None, k + 1 : k + 1 + frames]
    members = members[:, None, :frames]  # (M, 1, n, N, 3)
    out = {"model": ensemble_mean_and_spread(members, meta.box, out_off)[0]}
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
    d = meta.diameter
    report = {
        "rmse_over_d": {
            name: (rmse_per_step(position_residuals(pred, true, meta.box, out_off)) / d).tolist()
            for name, pred in out.items()
        }
    }
    forecasts = {**out, "model": members}
    report["crps_over_d"] = {
        name: (crps_per_step(position_residuals(pred, true, meta.box, out_off)) / d).tolist()
        for name, pred in forecasts.items()
    }
    if len(members) > 1:
        res = position_residuals(members, true, meta.box, out_off)
        report["spread_skill"] = spread_skill_per_step(res).tolist()
        report["rank_histogram"] = rank_histogram(res).tolist()
        report["member_rmse_over_d"] = (rmse_per_step(res[0]) / d).tolist()
    return report


def spread_per_block(members, times, meta, block: int) -> list[float]:
    """The members' RMS distance from their mean per block of frames, in diameters."""
    offsets = meta.boundary.offset(times)
    mean, spread = ensemble_mean_and_spread(members, meta.box, offsets)
    per_frame = np.sqrt(np.mean(spread**2, axis=-1) / len(members) * (len(members) - 1))
    return [
        float(per_frame[lo + 1 : lo + 1 + block].mean() / meta.diameter)
        for lo in range(0, len(per_frame) - 1, block)
    ]


def noise_floor(scene: str, preset: str, frames: int, block: int) -> dict:
    """Block statistics between two independent DEM simulations of the scene."""
    path = scene_dataset(scene, preset)
    meta = read_meta(path)
    a, times = read_sim(path, meta.n_sims - 1, frames)
    b, _ = read_sim(path, meta.n_sims - 2, frames)
    return block_statistics(b, a, times, meta.boundary, meta.diameter, block=block)


def member_cost(checkpoint, reference, scene, args, preset, frames: int = 100, repeats: int = 3):
    """ms per member and frame over ``frames`` frames from the truth's start, side by side and
    interleaved (fastest of ``repeats``): the reference model (one member), the ensemble with
    one member, and the ensemble with ``--members`` members advanced together."""
    scene_meta = read_meta(scene_dataset(scene, preset))
    models = {
        name: load_model(path, scene_meta)
        for name, path in (("reference", reference), ("ensemble", checkpoint))
    }
    k = int(models["ensemble"].hparams.history_len)
    path = truth_dataset(scene, preset, k + 1 + args.frames)
    truth, times = read_sim(path, 0, k + 1)
    meta = read_meta(path)
    rollout_options(models["ensemble"], args)
    cases = {
        "reference, 1 member": (models["reference"], 1),
        "ensemble, 1 member": (models["ensemble"], 1),
        f"ensemble, {args.members} members together": (models["ensemble"], args.members),
    }
    best = dict.fromkeys(cases, float("inf"))
    for _ in range(repeats):
        for name, (model, members) in cases.items():
            started = time.perf_counter()
            rollout(
                model,
                meta,
                truth[None],
                times[None],
                frames,
                stepper_settings(args) if model is models["ensemble"] else None,
                check_overlap=False,
                members=members,
                seed=args.seed,
            )
            seconds = (time.perf_counter() - started) / (frames * members)
            best[name] = min(best[name], 1e3 * seconds)
    return best


def evaluate_scene(scene, checkpoint, args, preset, members: int = 1) -> dict:
    model = load_model(checkpoint, read_meta(scene_dataset(scene, preset)))
    k = int(model.hparams.history_len)
    path = truth_dataset(scene, preset, k + 1 + args.frames)
    meta = read_meta(path)
    model = load_model(checkpoint, meta)
    truth, times = read_sim(path, 0)
    config = generator_config(path)
    relaxation = DemRelaxation(config, args.relax_steps) if args.relax_steps else None
    settings = stepper_settings(args, relaxation)
    rollout_options(model, args)
    started = time.perf_counter()
    run = rollout(
        model,
        meta,
        truth[None, : k + 1],
        times[None, : k + 1],
        args.frames,
        settings,
        check_overlap=False,
        members=members,
        seed=args.seed,
    )
    wall = time.perf_counter() - started
    stepper = run.stepper
    n = run.n_predicted
    start = np.broadcast_to(truth[k : k + 1], (members, 1) + truth.shape[1:])
    predicted = np.concatenate([start, run.by_member(run.predicted)[0]], axis=1)  # frame 0
    span = slice(k, k + 1 + n)
    stat_members = min(members, args.stat_members or members)
    member_blocks = [
        block_statistics(
            predicted[m], truth[span], times[span], meta.boundary, meta.diameter, block=args.block
        )
        for m in range(stat_members)
    ]
    per_frame = members * max(n, 1)  # a member's frame: the rows advance together
    report = {
        "scene": scene,
        "checkpoint": str(checkpoint),
        "ensemble": bool(model.is_ensemble),
        "members": members,
        "seed": args.seed,
        "truth": str(path),
        "frames": n,
        "stopped": run.divergence.stopped,
        "settings": settings.to_dict() | {"link": stepper.link},
        "model_ms_per_frame": 1e3 * wall / per_frame,
        "breakdown_ms_per_frame": {p: 1e3 * stepper.seconds[p] / per_frame for p in PARTS},
        "dem_ms_per_frame": 1e3 * dem_seconds_per_frame(config, truth[k:], times[k:]),
        **short_term(model, meta, predicted[:, 1:], truth, times, k, min(100, n)),
        "correction": stepper.report.__dict__,
        "blocks": member_blocks[0],
        "member_blocks": [b["blocks"] for b in member_blocks[1:]],
        "noise_floor": noise_floor(scene, preset, min(201, args.frames + 1), args.block),
        "handback": handback_ratios(
            config,
            predicted[0],
            truth[span],
            times[span],
            [f for f in (10, 100, 1000, 2000) if f <= n],
            args.handback_steps,
        ),
    }
    if members > 1:
        report["spread_over_d"] = spread_per_block(predicted, times[span], meta, args.block)
    if n >= DIFFUSION_LAGS[1]:
        fit = (truth[span], times[span], meta.boundary, meta.diameter)
        report["diffusion"] = {
            "truth": diffusion_coefficients(truth[span], *fit).tolist(),
            "members": [
                diffusion_coefficients(predicted[m], *fit).tolist() for m in range(stat_members)
            ],
        }
    report["speedup"] = report["dem_ms_per_frame"] / report["model_ms_per_frame"]
    return report


def quick_checkpoints(work: Path, model: str = "contact") -> dict[str, Path]:
    out = {}
    for scene in ("pbc", "lebc"):
        run = train_run(
            work / f"{scene}_{model}", ["experiment=smoke", f"scene={scene}", f"model={model}"]
        )
        out[scene] = run / "checkpoints" / "best.ckpt"
    return out


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoint", nargs="+", default=[], metavar="SCENE=PATH")
    parser.add_argument("--frames", type=int, default=2000)
    parser.add_argument("--block", type=int, default=100)
    parser.add_argument("--link", type=int, help="frames kept per forward pass")
    parser.add_argument("--no-correction", action="store_true")
    add_correction_options(parser)
    parser.add_argument("--handback-steps", type=int, default=100)
    parser.add_argument(
        "--relax-steps",
        type=int,
        default=0,
        metavar="N",
        help="the hybrid: the built-in DEM integrates the last N time steps of every predicted "
        "frame in place of the geometric contact correction (0: off)",
    )
    parser.add_argument("--members", type=int, default=1, help="ensemble members per scene")
    parser.add_argument("--seed", type=int, default=0, help="seed of the members' noise")
    parser.add_argument(
        "--stat-members", type=int, help="members with block statistics (default: all)"
    )
    parser.add_argument(
        "--reference",
        nargs="+",
        default=[],
        metavar="SCENE=PATH",
        help="a model to run beside, one member (the deterministic surrogate)",
    )
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out-dir", type=Path, default=Path("experiments/results/long_rollouts"))
    parser.add_argument("--name", default="surrogate_rollout")
    args = parser.parse_args(argv)
    set_threads(args.threads)
    preset = "tiny" if args.quick else "default"
    if args.quick:
        args.frames, args.block = min(args.frames, 40), min(args.block, 20)
        work = Path(tempfile.mkdtemp(prefix="surrogate_"))
        checkpoints = quick_checkpoints(work)
        if args.members > 1:  # smoke ensembles, the smoke point models beside them
            args.reference = [f"{s}={p}" for s, p in checkpoints.items()]
            checkpoints = quick_checkpoints(work, "ensemble")
    else:
        checkpoints = {s: Path(p) for s, p in (c.split("=", 1) for c in args.checkpoint)}
    if not checkpoints:
        parser.error("give --checkpoint pbc=PATH lebc=PATH (or --quick)")
    references = {s: Path(p) for s, p in (c.split("=", 1) for c in args.reference)}
    scenes = {}
    for scene, checkpoint in checkpoints.items():
        if scene in references:
            scenes[f"{scene} (reference)"] = evaluate_scene(scene, references[scene], args, preset)
        scenes[scene] = evaluate_scene(scene, checkpoint, args, preset, args.members)
        if scene in references and args.members > 1:
            scenes[scene]["member_cost_ms"] = member_cost(
                checkpoint, references[scene], scene, args, preset, min(100, args.frames)
            )
    report = {
        "machine": machine_line(),
        "args": {k: str(v) for k, v in vars(args).items()},
        "scenes": scenes,
    }
    args.out_dir.mkdir(parents=True, exist_ok=True)
    markdown = summary_tables(report)
    write_report(args.out_dir / args.name, markdown, report)
    for scene, data in report["scenes"].items():
        run_name = Path(data["checkpoint"]).parent.parent.name or data["checkpoint"]
        title = f"{scene}: {data['frames']} frames out of sample ({run_name})"
        if data["members"] > 1:
            title += f", member 0 of {data['members']}"
        stem = scene.replace(" (reference)", "_reference")
        save_figure(plot_surrogate(data, title), args.out_dir / f"{args.name}_{stem}.png")
    return report


if __name__ == "__main__":
    main(sys.argv[1:])
