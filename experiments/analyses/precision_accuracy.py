"""A trained run's out-of-sample accuracy with its encoder in fp32 and in bf16, side by side.

    python experiments/analyses/precision_accuracy.py RUN_DIR [RUN_DIR ...] [--json out.json]
        [--out experiments/results/model_cost/precision_accuracy]

Each run directory (``python -m gripdem.run``'s output: ``.hydra/config.yaml`` and
``checkpoints/best.ckpt``) is tested on its own test windows (the runner's test path: Lightning's
test step, or the stepper where the split's horizon is longer than the model's) twice: with the
encoder's weights in fp32, as trained, and cast to bf16 (:mod:`gripdem.inference.precision`; the
encoder's inputs are formed in fp32 and its output cast back). Prints RMSE / CV's for both and
their ratio. bf16 is emulated where the CPU has no bf16 units: slower, the same numbers.
``--out STEM`` writes ``STEM.md`` (the result header, then the table) and ``STEM.json`` (the
header's fields under ``header``, the rows under ``results``); ``--json`` the JSON alone.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import lightning as L
import torch
from omegaconf import OmegaConf

from gripdem.inference.checkpoint import load_checkpoint_model
from gripdem.provenance import atomic_write, result_fields, write_report
from gripdem.runner.experiment import build_datamodule, resolve_data_path, test_model


def accuracy(run: Path) -> dict:
    cfg = OmegaConf.load(run / ".hydra" / "config.yaml")
    dm = build_datamodule(cfg, resolve_data_path(cfg))
    trainer = L.Trainer(
        accelerator="cpu", devices=1, logger=False, enable_progress_bar=False,
        enable_checkpointing=False,
    )  # fmt: skip
    out = {"run": str(run)}
    for precision in ("fp32", "bf16"):
        model = load_checkpoint_model(run / "checkpoints" / "best.ckpt")
        model.encoder.to(torch.bfloat16 if precision == "bf16" else torch.float32)
        metrics = test_model(model, dm, trainer)["metrics"]
        out[precision] = metrics["test/rmse_ratio_constant_velocity"]
    out["bf16_over_fp32"] = out["bf16"] / out["fp32"]
    return out


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", type=Path, nargs="+")
    ap.add_argument("--json", type=Path, default=None, help="the JSON alone")
    ap.add_argument("--out", type=Path, default=None, help="STEM: STEM.md and STEM.json")
    args = ap.parse_args(argv)
    rows = []
    lines = ["| run | fp32 RMSE / CV | bf16 RMSE / CV | bf16 / fp32 |", "|---|---|---|---|"]
    print("\n".join(lines))
    for run in args.runs:
        row = accuracy(run)
        rows.append(row)
        lines.append(
            f"| {run.name} | {row['fp32']:.4f} | {row['bf16']:.4f} | {row['bf16_over_fp32']:.4f} |"
        )
        print(lines[-1])
    if args.out:
        write_report(args.out, "\n".join(lines), rows, echo=False)
    if args.json:
        payload = {"header": result_fields(), "results": rows}
        atomic_write(args.json, json.dumps(payload, indent=2) + "\n")
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
