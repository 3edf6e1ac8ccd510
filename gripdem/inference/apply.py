"""Apply a trained model to a dataset (the work of ``python -m gripdem.predict``): read the
observed frames, roll the model out (:mod:`gripdem.inference.rollout`), roll every baseline out
from the same frames, and write the predictions file (where a truth exists), the trajectory as a
gripdem dataset and the per-frame report (RMSE, divergence checks, in-sample check)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import torch

from gripdem.data.dataset_io import read_meta, write_dataset
from gripdem.data.h5io import atomic_h5_write, atomic_write_text
from gripdem.data.schema import DatasetMeta, TrajectoryData
from gripdem.evaluation.ensemble_scores import (
    crps_per_step,
    ensemble_mean_and_spread,
    rank_histogram,
    spread_skill_per_step,
)
from gripdem.evaluation.metrics import position_residuals, rmse_per_step
from gripdem.evaluation.predictions import Predictions, write_predictions
from gripdem.inference.checkpoint import check_compatible, load_model
from gripdem.inference.contacts import CORRECTION_TOLERANCE
from gripdem.inference.in_sample import training_overlap
from gripdem.inference.rollout import rollout
from gripdem.inference.stepper import StepperSettings
from gripdem.models.baselines import predict_baseline


def _read_frames(path: Path, sims: list[int], start: int, stop: int, name="positions"):
    with h5py.File(path, "r") as h5:
        return np.stack([np.asarray(h5[name][s, start:stop], np.float64) for s in sims])


def _baselines(model, observed, observed_times, target_times, meta: DatasetMeta):
    """Every baseline of the model rolled out in one go over the target frames:
    ``name -> (S, n, N, 3)``."""
    obs = torch.from_numpy(observed)
    in_off = torch.from_numpy(meta.boundary.offset(observed_times))
    out_off = torch.from_numpy(meta.boundary.offset(target_times))
    return {
        name: predict_baseline(
            name, obs, in_off, out_off, meta.box, model.profile, model.linear_ar, model.boundary
        ).numpy()
        for name in model.baselines
    }


def _per_step(pred, true, times, meta: DatasetMeta) -> list[float]:
    offsets = meta.boundary.offset(times)
    res = position_residuals(pred, true, meta.box, offsets)
    return [float(v) / meta.diameter for v in rmse_per_step(res)]


def ensemble_path(out: Path) -> Path:
    return out.with_name(f"{out.with_suffix('').name}_ensemble.h5")


def _write_ensemble(path: Path, run, meta: DatasetMeta, info: dict, overwrite: bool) -> None:
    """``PRED_ensemble.h5``: per simulation and frame (observed and predicted), the members'
    mean position ``mean_positions (S, T, N, 3)`` and spread ``spread (S, T, N)`` (m: square
    root of the unbiased member variance summed over the axes), with ``times (S, T)``."""
    members = run.by_member(run.positions).swapaxes(0, 1)
    times = run.times[:: run.members]
    mean, spread = ensemble_mean_and_spread(members, meta.box, meta.boundary.offset(times))
    with atomic_h5_write(path, overwrite=overwrite) as h5:
        h5.create_dataset("mean_positions", data=mean)
        h5.create_dataset("spread", data=spread)
        h5.create_dataset("times", data=times)
        h5.attrs["members"] = run.members
        h5.attrs["n_observed"] = run.n_observed
        h5.attrs["description"] = (
            "ensemble mean position and spread (m, sqrt of the unbiased member variance summed "
            "over x, y, z) per simulation, frame and particle; the members are the "
            "trajectory file's rows"
        )
        h5.attrs["info"] = json.dumps(info)


def _ensemble_scores(member_pred, true, times, meta: DatasetMeta, baselines) -> dict[str, Any]:
    """Per predicted frame with a truth: the CRPS / d of the model (its members' fair CRPS) and
    of every baseline (their absolute error), each member's RMSE / d, and for an ensemble the
    spread/skill ratio and the rank histogram over the first 100 frames."""
    offsets = meta.boundary.offset(times)
    d = meta.diameter

    def crps(res) -> list[float]:
        return [float(v) / d for v in crps_per_step(res)]

    res = position_residuals(member_pred, true, meta.box, offsets)  # (M, S, n, N, 3)
    out: dict[str, Any] = {"crps_over_d": {"model": crps(res)}}
    for name, values in baselines.items():
        out["crps_over_d"][name] = crps(position_residuals(values, true, meta.box, offsets))
    if len(member_pred) < 2:
        return out
    out["member_rmse_over_d"] = [[float(v) / d for v in rmse_per_step(r)] for r in res]
    out["spread_skill"] = [float(v) for v in spread_skill_per_step(res)]
    out["rank_histogram_frames_1_100"] = rank_histogram(res, slice(0, 100)).tolist()
    return out


def check_cohesive(data_path: Path, meta, capture: float | None) -> float | None:
    """``--contact-capture`` as given, refused (ValueError naming the option and the file) where
    the data's provenance does not record a cohesive contact law: capturing pairs into contact
    stands in for the DEM's cohesion, which a scene without one (or of unknown law: data from
    another code) does not have."""
    if not capture:
        return capture
    scene = ((meta.provenance or {}).get("parameters") or {}).get("scene") or {}
    hamaker = scene.get("hamaker")
    if hamaker is None:
        raise ValueError(
            f"--contact-capture {capture:g}: {data_path} does not record its contact law (no "
            "provenance parameters.scene.hamaker: not made by the built-in DEM), so whether its "
            "contacts are cohesive is unknown; drop --contact-capture or pass 0"
        )
    if not float(hamaker) > 0:
        raise ValueError(
            f"--contact-capture {capture:g}: {data_path}'s scene has no cohesion (hamaker = "
            f"{hamaker}): its contacts open freely; drop --contact-capture or pass 0"
        )
    return capture


def apply_checkpoint(
    args: argparse.Namespace, out: Path, traj_path: Path, report_path: Path
) -> dict[str, Any]:
    """Apply ``args.checkpoint`` to ``args.data`` as ``python -m gripdem.predict`` does (its
    options in ``args``), write the predictions, the trajectory and the report; returns the
    report written to ``report_path``."""
    data_path = Path(args.data)
    meta = read_meta(data_path)
    hp, notes = check_compatible(args.checkpoint, meta)
    k, f = int(hp["history_len"]), int(hp["horizon"])
    sims = list(range(meta.n_sims)) if args.sims is None else [int(s) for s in args.sims]
    bad = [s for s in sims if not 0 <= s < meta.n_sims]
    if bad:
        raise ValueError(f"--sims {bad}: {data_path} holds simulations 0..{meta.n_sims - 1}")
    frames = f if args.frames is None else int(args.frames)
    if frames < 1:
        raise ValueError(f"--frames must be >= 1, got {frames}")
    start = int(args.start)
    if not 0 <= start <= meta.n_frames - (k + 1):
        raise ValueError(
            f"--start {start}: the model reads {k + 1} observed frames (history_len {k}), so "
            f"the start must lie in 0..{meta.n_frames - k - 1} for {data_path} "
            f"({meta.n_frames} frames)"
        )
    model = load_model(args.checkpoint, meta)
    if getattr(args, "noise_scale", None) is not None:
        if not model.is_ensemble:
            raise ValueError(
                f"--noise-scale {args.noise_scale:g}: {args.checkpoint} is a deterministic model "
                "(no latent noise to scale)"
            )
        model.hparams.noise_scale = float(args.noise_scale)
    with h5py.File(data_path, "r") as h5:
        all_times = np.asarray(h5["times"][()], np.float64)[sims]
        radii = np.asarray(h5["radii"][()]) if "radii" in h5 else None
    observed = _read_frames(data_path, sims, start, start + k + 1)
    settings = StepperSettings(
        link=args.step,
        contact_correction=not getattr(args, "no_correction", False),
        contact_distance=float(getattr(args, "contact_distance", 1.0)),
        correction_tolerance=getattr(args, "correction_tolerance", None) or CORRECTION_TOLERANCE,
        contact_capture=check_cohesive(data_path, meta, getattr(args, "contact_capture", None)),
        precision=str(getattr(args, "precision", "fp32")),
    )
    members = int(getattr(args, "members", 1) or 1)
    seed = getattr(args, "seed", None)
    run = rollout(
        model.to(args.device),
        meta,
        observed,
        all_times[:, start : start + k + 1],
        frames,
        settings,
        args.overlap_margin,
        not args.no_overlap,
        members=members,
        seed=seed,
    )
    first = start + k + 1
    n_truth = max(0, min(run.n_predicted, meta.n_frames - first))
    in_sample, protocol, overlap_note = training_overlap(args.checkpoint, data_path, sims, first)
    notes.append(overlap_note)
    info = {
        "checkpoint": str(args.checkpoint),
        "data": str(data_path),
        "sims": sims,
        "start": start,
        "observed_frames": [start, start + k],
        "predicted_frames": [first, first + run.n_predicted - 1],
        "frames_requested": frames,
        "frames_predicted": run.n_predicted,
        "truth_frames": n_truth,
        "history_len": k,
        "horizon": f,
        "step": f if args.step is None else int(args.step),
        "settings": settings.to_dict(),
        # as applied: the model's own capture unless given, the observed resting overlap
        "contact_capture": run.stepper.capture,
        "contact_overlap": run.stepper.overlap,
        "noise_scale": float(model.hparams.get("noise_scale", 1.0)) if model.is_ensemble else None,
        "precision": run.stepper.precision,
        "encoding": hp["encoding"],
        "decoder_mode": hp["decoder_mode"],
        "encoder": model.encoder_name,
        "ensemble": bool(model.is_ensemble),
        "members": members,
        "seed": seed,
    }
    per_step: dict[str, list[float]] = {}
    scores: dict[str, Any] = {}
    mean_path = ensemble_path(out) if members > 1 else None
    if members > 1:
        _write_ensemble(mean_path, run, meta, info, args.overwrite)
    if n_truth:
        true = _read_frames(data_path, sims, first, first + n_truth)
        times = run.times[:: run.members, k + 1 : k + 1 + n_truth]
        member_pred = run.by_member(run.predicted[:, :n_truth]).swapaxes(0, 1)  # (M, S, ...)
        pred = ensemble_mean_and_spread(member_pred, meta.box, meta.boundary.offset(times))[0]
        baselines = _baselines(model, observed, run.times[:: run.members, : k + 1], times, meta)
        per_step["model"] = _per_step(pred, true, times, meta)
        for name, values in baselines.items():
            per_step[name] = _per_step(values, true, times, meta)
        scores = _ensemble_scores(member_pred, true, times, meta, baselines)
        predictions = Predictions(
            pred_positions=pred,
            true_positions=true,
            last_positions=observed[:, -1],
            times=times,
            boundary=meta.boundary,
            radius=meta.radius,
            frame_interval=meta.frame_interval,
            in_sample=in_sample,
            protocol=protocol,
            sim_index=np.asarray(sims),
            window_start=np.full(len(sims), start),
            baselines=baselines,
            body_force_amplitude=meta.body_force_amplitude,
            info=info,
        )
        write_predictions(out, predictions, overwrite=args.overwrite)
    else:
        notes.append(f"no predicted frame has a truth in {data_path}: {out} not written")
    trajectory = TrajectoryData(
        positions=run.positions,
        times=run.times,
        boundary=meta.boundary,
        radius=meta.radius,
        body_force_amplitude=meta.body_force_amplitude,
        radii=radii,
        provenance={
            "generator": "gripdem.predict",
            "parameters": {
                **info,
                "rows": "simulation s, member m is row s * members + m",
                "notes": notes,
                "source_provenance": meta.provenance,
            },
        },
    )
    write_dataset(traj_path, trajectory, overwrite=args.overwrite)
    div = run.divergence
    report = {
        **info,
        "in_sample": in_sample,
        "protocol": protocol,
        "outputs": {
            "predictions": str(out) if n_truth else None,
            "trajectory": str(traj_path),
            "ensemble": None if mean_path is None else str(mean_path),
        },
        "frame_interval": meta.frame_interval,
        "diameter": meta.diameter,
        "rmse_over_d": per_step,
        **scores,
        "divergence": {
            "first": div.first,
            "stopped": div.stopped,
            "overlap_start": div.overlap_start,
            "overlap_margin": args.overlap_margin,
            "overlap": div.overlap,
            "max_step_over_d": div.max_step_over_d,
            "escaped": div.escaped,
        },
        "notes": notes,
    }
    atomic_write_text(report_path, json.dumps(report, indent=1), overwrite=args.overwrite)
    report["_divergence_lines"] = div.lines(args.overlap_margin)
    return report
