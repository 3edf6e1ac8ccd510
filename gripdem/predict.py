"""Apply a trained model to a dataset and roll it out: ``python -m gripdem.predict``.

    python -m gripdem.predict CHECKPOINT DATA.h5 [--start FRAME] [--frames N] [--sims S ...]
        [--step M] [--out PRED.h5] [--trajectory TRAJ.h5] [--report REPORT.json]
        [--overlap-margin F] [--no-overlap] [--device cpu] [--threads T] [--overwrite]

The model (encoding, normaliser, history length, horizon, graph cut-off, fitted AR baseline)
comes from the checkpoint; the scene's conventions (box, LE sign and time origin) from the data,
once :func:`check_compatible` has accepted the pair. ``--start`` is the first observed frame: the
model reads frames ``start .. start+K`` and predicts ``N`` frames after them (default: its
horizon ``f``), chaining its own predictions beyond ``f`` (:mod:`gripdem.rollout`).

Writes (atomically; existing files are kept unless ``--overwrite``):

- ``PRED.h5`` (``--out``, default ``predictions.h5``): the ``predictions.h5`` layout of
  :mod:`gripdem.evaluation.predictions` for the predicted frames that have a truth in the data, one
  window per simulation, with the baselines (stay, constant velocity, linear AR, mean flow) rolled
  out from the same observed frames in one go;
- ``TRAJ.h5`` (default ``PRED_trajectory.h5``): the observed frames followed by all predicted
  ones as a gripdem dataset, the input of :mod:`gripdem.handback` (and of this command again);
- ``REPORT.json`` (default ``PRED_rollout.json``): per predicted frame the RMSE of the model and
  of each baseline where a truth exists, the divergence checks, and what was decided.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import torch

from gripdem.checkpoint import check_compatible, load_model, training_overlap
from gripdem.data.h5io import atomic_write_text
from gripdem.data.schema import DatasetMeta, TrajectoryData, read_meta, write_dataset
from gripdem.evaluation.metrics import position_residuals, rmse_per_step
from gripdem.evaluation.predictions import Predictions, write_predictions
from gripdem.rollout import OVERLAP_MARGIN, rollout


def _read_frames(path: Path, sims: list[int], start: int, stop: int, name="positions"):
    with h5py.File(path, "r") as h5:
        return np.stack([np.asarray(h5[name][s, start:stop], np.float64) for s in sims])


def _baselines(model, observed, observed_times, target_times, meta: DatasetMeta):
    """Every baseline of the model rolled out in one go over the target frames:
    ``name -> (S, n, N, 3)``."""
    from gripdem.models.baselines import predict_baseline

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


def _outputs(args) -> tuple[Path, Path, Path]:
    out = Path(args.out)
    stem = out.with_suffix("")
    traj = Path(args.trajectory) if args.trajectory else Path(f"{stem}_trajectory.h5")
    report = Path(args.report) if args.report else Path(f"{stem}_rollout.json")
    for path in (out, traj, report):
        if path.exists() and not args.overwrite:
            raise FileExistsError(f"{path}: exists; refusing to overwrite it (pass --overwrite)")
    return out, traj, report


def predict(args: argparse.Namespace) -> dict[str, Any]:
    """Run the command; returns the report written to ``REPORT.json``."""
    out, traj_path, report_path = _outputs(args)
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
    with h5py.File(data_path, "r") as h5:
        all_times = np.asarray(h5["times"][()], np.float64)[sims]
        radii = np.asarray(h5["radii"][()]) if "radii" in h5 else None
    observed = _read_frames(data_path, sims, start, start + k + 1)
    run = rollout(
        model,
        meta,
        observed,
        all_times[:, start : start + k + 1],
        frames,
        args.step,
        args.overlap_margin,
        not args.no_overlap,
        args.device,
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
        "encoding": hp["encoding"],
        "decoder_mode": hp["decoder_mode"],
        "encoder": (hp.get("encoder") or {}).get("name", "graph_conv"),
    }
    per_step: dict[str, list[float]] = {}
    if n_truth:
        true = _read_frames(data_path, sims, first, first + n_truth)
        times = run.times[:, k + 1 : k + 1 + n_truth]
        pred = run.predicted[:, :n_truth]
        baselines = _baselines(model, observed, run.times[:, : k + 1], times, meta)
        per_step["model"] = _per_step(pred, true, times, meta)
        for name, values in baselines.items():
            per_step[name] = _per_step(values, true, times, meta)
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
            "parameters": {**info, "notes": notes, "source_provenance": meta.provenance},
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
        },
        "frame_interval": meta.frame_interval,
        "diameter": meta.diameter,
        "rmse_over_d": per_step,
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
    report["_lines"] = _summary_lines(report, div.lines(args.overlap_margin), report_path)
    return report


def _summary_lines(report: dict[str, Any], divergence: list[str], path: Path) -> list[str]:
    lines = [
        f"observed frames {report['observed_frames'][0]}..{report['observed_frames'][1]}, "
        f"predicted {report['frames_predicted']} of {report['frames_requested']} frame(s) "
        f"({report['predicted_frames'][0]}..{report['predicted_frames'][1]}) in links of "
        f"{report['step']}, simulations {report['sims']}",
    ]
    per_step = report["rmse_over_d"]
    if per_step:
        n = len(per_step["model"])
        marks = sorted({m for m in (1, 10, 100, 1000, n) if m <= n})
        lines.append("RMSE / d at predicted frame " + ", ".join(str(m) for m in marks) + ":")
        for name, values in per_step.items():
            lines.append(f"  {name:18s} " + "  ".join(f"{values[m - 1]:.4g}" for m in marks))
    lines += [f"divergence: {line}" for line in divergence]
    lines += [f"note: {note}" for note in report["notes"]]
    outputs = report["outputs"]
    lines.append(
        "wrote "
        + ", ".join(str(p) for p in (outputs["predictions"], outputs["trajectory"]) if p)
        + f", {path}"
    )
    return lines


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m gripdem.predict",
        description="Apply a trained model (a Lightning checkpoint of gripdem.run) to a gripdem "
        "dataset of a compatible scene, chaining its predictions for as many frames as asked.",
    )
    p.add_argument(
        "checkpoint", type=Path, help="checkpoint (e.g. outputs/.../checkpoints/best.ckpt)"
    )
    p.add_argument("data", type=Path, help="gripdem HDF5 dataset")
    p.add_argument("--start", type=int, default=0, metavar="FRAME", help="first observed frame")
    p.add_argument("--frames", type=int, metavar="N", help="frames to predict (default: horizon)")
    p.add_argument("--sims", type=int, nargs="+", metavar="S", help="simulations (default: all)")
    p.add_argument(
        "--step", type=int, metavar="M", help="predicted frames kept per link (default: horizon)"
    )
    p.add_argument("--out", default="predictions.h5", metavar="PRED.h5")
    p.add_argument("--trajectory", metavar="TRAJ.h5", help="default: PRED_trajectory.h5")
    p.add_argument("--report", metavar="REPORT.json", help="default: PRED_rollout.json")
    p.add_argument(
        "--overlap-margin",
        type=float,
        default=OVERLAP_MARGIN,
        metavar="F",
        help="flag overlap when this fraction more particles overlap than at the start",
    )
    p.add_argument("--no-overlap", action="store_true", help="skip the per-frame overlap check")
    p.add_argument("--device", default="cpu", help="torch device (cpu, cuda)")
    p.add_argument("--threads", type=int, metavar="T", help="torch CPU threads")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.threads:
        torch.set_num_threads(int(args.threads))
    try:
        report = predict(args)
    except (ValueError, OSError) as exc:  # DatasetError, IncompatibleError: ValueErrors
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for line in report["_lines"]:
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
