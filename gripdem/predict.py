"""Apply a trained model to a dataset and roll it out: ``python -m gripdem.predict``.

    python -m gripdem.predict CHECKPOINT DATA.h5 [--start FRAME] [--frames N] [--sims S ...]
        [--step M] [--out PRED.h5] [--trajectory TRAJ.h5] [--report REPORT.json]
        [--overlap-margin F] [--no-overlap] [--members M] [--seed S] [--device cpu]
        [--threads T] [--precision auto|fp32|bf16] [--overwrite]

The model (encoding, normaliser, history length, horizon, graph cut-off, fitted AR baseline)
comes from the checkpoint; the scene's conventions (box, LE sign and time origin) from the data,
once :func:`check_compatible` has accepted the pair. ``--start`` is the first observed frame: the
model reads frames ``start .. start+K`` and predicts ``N`` frames after them (default: its
horizon ``f``), chaining its own predictions beyond ``f`` (:mod:`gripdem.inference.rollout`).

Writes (atomically; existing files are kept unless ``--overwrite``):

- ``PRED.h5`` (``--out``, default ``predictions.h5``): the ``predictions.h5`` layout of
  :mod:`gripdem.evaluation.predictions` for the predicted frames that have a truth in the data, one
  window per simulation, with the baselines (stay, constant velocity, linear AR, mean flow) rolled
  out from the same observed frames in one go;
- ``TRAJ.h5`` (default ``PRED_trajectory.h5``): the observed frames followed by all predicted
  ones as a gripdem dataset, the input of :mod:`gripdem.handback` (and of this command again);
- ``REPORT.json`` (default ``PRED_rollout.json``): per predicted frame the RMSE and the CRPS of
  the model and of each baseline where a truth exists (an ensemble: its mean's RMSE, its
  members' CRPS, each member's RMSE, the spread/skill ratio and the rank histogram), the
  divergence checks, and what was decided;
- ``PRED_ensemble.h5`` (``--members M > 1``): the members' mean position and spread per frame.

An ensemble model (``model=ensemble``) rolls out ``--members M`` members per simulation, each a
sample contact-corrected like any trajectory, reproducible from ``--seed``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

# light imports only: torch and the model code load inside run_command (a Ctrl-C or SIGTERM
# while they load is answered in one line)
from gripdem.runner.console import run_command


def _outputs(args) -> tuple[Path, Path, Path]:
    out = Path(args.out)
    stem = out.with_suffix("")
    traj = Path(args.trajectory) if args.trajectory else Path(f"{stem}_trajectory.h5")
    report = Path(args.report) if args.report else Path(f"{stem}_rollout.json")
    paths = [out, traj, report]
    if args.members > 1:
        from gripdem.inference.apply import ensemble_path

        paths.append(ensemble_path(out))
    for path in paths:
        if path.exists() and not args.overwrite:
            raise FileExistsError(f"{path}: exists; refusing to overwrite it (pass --overwrite)")
    return out, traj, report


def predict(args: argparse.Namespace) -> dict[str, Any]:
    """Run the command; returns the report written to ``REPORT.json`` (and ``_lines`` to print)."""
    from gripdem.inference.apply import apply_checkpoint

    out, traj_path, report_path = _outputs(args)
    report = apply_checkpoint(args, out, traj_path, report_path)
    report["_lines"] = _summary_lines(report, report.pop("_divergence_lines"), report_path)
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
        lines.append("CRPS / d (a point forecast's: its absolute error) at the same frames:")
        for name, values in report["crps_over_d"].items():
            lines.append(f"  {name:18s} " + "  ".join(f"{values[m - 1]:.4g}" for m in marks))
        if "spread_skill" in report:
            ratio = report["spread_skill"]
            hist = report["rank_histogram_frames_1_100"]
            lines.append(
                f"ensemble of {report['members']}: spread/skill "
                + "  ".join(f"{ratio[m - 1]:.3f}" for m in marks)
                + f" (1: calibrated); rank histogram (frames 1-100) bins "
                f"{min(hist) * len(hist):.2f}-{max(hist) * len(hist):.2f} of uniform"
            )
    lines += [f"divergence: {line}" for line in divergence]
    lines += [f"note: {note}" for note in report["notes"]]
    outputs = report["outputs"]
    written = (outputs["predictions"], outputs["trajectory"], outputs.get("ensemble"))
    lines.append("wrote " + ", ".join(str(p) for p in written if p) + f", {path}")
    return lines


def build_parser() -> argparse.ArgumentParser:
    from gripdem.inference.rollout_limits import OVERLAP_MARGIN

    p = argparse.ArgumentParser(
        prog="python -m gripdem.predict",
        description="Apply a trained model (a Lightning checkpoint of gripdem.run) to a gripdem "
        "dataset of a compatible scene, chaining its predictions for as many frames as asked.",
    )
    p.add_argument(
        "checkpoint",
        type=Path,
        help="a .ckpt checkpoint, a .safetensors model file (outputs/.../checkpoints/best.*) "
        "or a shipped model: pretrained:pbc, pretrained:lebc, pretrained:pbc-ensemble, "
        "pretrained:lebc-ensemble",
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
    p.add_argument(
        "--no-correction",
        action="store_true",
        help="keep the model's frames as predicted (no contact correction after each frame)",
    )
    p.add_argument(
        "--contact-distance",
        type=float,
        default=1.0,
        metavar="D",
        help="contact correction: closest centre distance allowed, in diameters (default 1)",
    )
    p.add_argument(
        "--correction-tolerance",
        type=float,
        metavar="F",
        help="contact correction: overlaps below this fraction of the contact distance are "
        "left (default 1e-4, the built-in DEM's own overlaps; 1e-3 is 5-12 %% faster per "
        "frame, but its states are unfit to hand back to a DEM)",
    )
    p.add_argument(
        "--contact-capture",
        type=float,
        metavar="GAP",
        help="contact correction of a cohesive scene: pairs closer than GAP contact distances "
        "are pulled into contact, as the DEM's cohesion snaps them shut (0: off; default: the "
        "model's own, recorded in its file)",
    )
    p.add_argument(
        "--members",
        type=int,
        default=1,
        metavar="M",
        help="an ensemble model: roll out M members per simulation (each a valid trajectory, "
        "rows s*M+m of the trajectory file; PRED_ensemble.h5 holds their mean and spread, "
        "predictions.h5 their mean); a deterministic model has one",
    )
    p.add_argument(
        "--noise-scale",
        type=float,
        metavar="F",
        help="an ensemble model: its members' latent noise times F (default: the model's own "
        "inflation, recorded in its file; 1: as trained)",
    )
    p.add_argument(
        "--seed",
        type=int,
        metavar="S",
        help="seed of the members' noise (the same seed, the same members; default: random)",
    )
    p.add_argument("--device", default="cpu", help="torch device (cpu, cuda)")
    p.add_argument(
        "--precision",
        default="auto",
        choices=["auto", "fp32", "bf16"],
        help="the encoder's arithmetic (default auto: bf16 where the device computes it "
        "natively: CPU avx512_bf16 or AMX, CUDA 8.0+; fp32 elsewhere; the same 190-10 accuracy "
        "to 4 digits, experiments/analyses/precision_accuracy.py); the report records it",
    )
    p.add_argument("--threads", type=int, metavar="T", help="torch CPU threads")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    return p


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = build_parser()
    args = parser.parse_args(argv)
    for name in ("frames", "step", "threads", "members"):
        value = getattr(args, name)
        if value is not None and value < 1:
            parser.error(f"--{name} must be a positive integer, got {value}")
    if args.start < 0:
        parser.error(f"--start must be a frame index >= 0, got {args.start}")
    if not args.overlap_margin >= 0:
        parser.error(f"--overlap-margin must be >= 0, got {args.overlap_margin}")
    if args.correction_tolerance is not None and not 0 < args.correction_tolerance < 1:
        parser.error(
            f"--correction-tolerance must lie in (0, 1) contact distances, "
            f"got {args.correction_tolerance}"
        )
    if args.noise_scale is not None and not 0 < args.noise_scale < float("inf"):
        parser.error(f"--noise-scale must be a positive number, got {args.noise_scale}")
    if args.contact_capture is not None:
        from gripdem.models.ensemble import MAX_CONTACT_CAPTURE

        if not 0 <= args.contact_capture <= MAX_CONTACT_CAPTURE:
            parser.error(
                f"--contact-capture must lie in [0, {MAX_CONTACT_CAPTURE:g}] contact distances, "
                f"got {args.contact_capture}"
            )
        if args.contact_capture and args.no_correction:
            parser.error(
                "--contact-capture works inside the contact correction: drop --no-correction"
            )
    return args


def main(argv: list[str] | None = None) -> int:
    def body() -> int:
        args = parse_args(argv)
        if args.threads:
            import torch

            torch.set_num_threads(int(args.threads))
        report = predict(args)
        for line in report["_lines"]:
            print(line)
        return 0

    return run_command(
        "gripdem.predict",
        body,
        "nothing half-written is left (predictions, trajectory and report are each written "
        "under a temporary name and renamed when complete)",
    )


if __name__ == "__main__":
    sys.exit(main())
