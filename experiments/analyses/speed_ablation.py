"""The speed levers' ablation table: accuracy and training time of trained runs beside the
encoder's forward time of the same form (``encoder_speed.py``'s JSON).

    python experiments/analyses/speed_ablation.py --runs-root RUNS --encoder-json E.json
        [--out experiments/results/time_vs_error/speed_ablation]

``RUNS`` holds one ``python -m gripdem.run`` output folder per run, named
``<scene>_<variant>_s<seed>`` (``metrics.json`` in each); the variants and their encoder rows are
listed in :data:`VARIANTS`. Per variant and scene: 190-10 test RMSE / CV's (mean ± std over the
seeds present, each seed listed), the training steps and wall time (the machine was shared with
the other runs and benchmarks of the day: read the times as rough), and the encoder's forward
time at 2000 and 32 000 particles (one thread, untrained weights, fp32 and bf16 where measured).
``--out STEM`` writes ``STEM.md`` (the result header, then the table) and ``STEM.json`` (the runs
per variant and scene, the header's fields under ``header``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from gripdem.provenance import write_report

#: run-name variant -> (label, encoder_speed.py's fp32 row, its bf16 row or None)
LEAN_ROW = "off + 32 ch. + 1.15 d + chunked"
VARIANTS = {
    "ref": ("64 pair ch., edge updates, 1.3 d, 1820 steps (before)",
            "reference (64 pair ch., edge updates, 1.3 d)", "reference, bf16"),
    "c115": ("cut-off 1.15 d", "cut-off 1.15 d", None),
    "p32": ("pair channels 32", "pair channels 32", None),
    "off": ("edge updates off", "edge updates off", None),
    "off32": ("edge updates off + pair channels 32", "off + 32 ch.", None),
    "lean": ("lean: off + 32 ch. + 1.15 d, 1820 steps", LEAN_ROW, f"{LEAN_ROW}, bf16"),
    "lean3640": ("lean, 3640 steps (the new default)", LEAN_ROW, f"{LEAN_ROW}, bf16"),
}  # fmt: skip


def collect(root: Path) -> dict:
    runs: dict = {}
    for path in sorted(root.glob("*/metrics.json")):
        scene, *variant, seed = path.parent.name.split("_")
        metrics = json.loads(path.read_text())
        runs.setdefault(("_".join(variant), scene), []).append(
            {
                "seed": int(seed.lstrip("s")),
                "ratio": metrics["test/rmse_ratio_constant_velocity"],
                "seconds": metrics["train_seconds"],
                "steps": metrics["steps"],
            }
        )
    return runs


def encoder_ms(report: dict | None, row_label: str | None, n: int) -> str:
    """The encoder's ms per pass of ``row_label`` at ``n`` particles ("–" where not measured)."""
    for row in (report or {}).get("rows", []):
        if row_label and row["particles"] == n and row["variant"] == row_label:
            return f"{row['ms']:.3g}"
    return "–"


def main(argv: list[str] | None = None) -> str:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs-root", type=Path, required=True)
    ap.add_argument("--encoder-json", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    runs = collect(args.runs_root)
    enc = json.loads(args.encoder_json.read_text()) if args.encoder_json else None
    rows = [
        "| variant | pbc 190-10 ÷ CV (seeds) | lebc 190-10 ÷ CV (seeds) | steps | train s pbc "
        "/ lebc (per seed) | encoder ms 2000 fp32 / bf16 | encoder ms 32 000 fp32 / bf16 |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, (label, fp32_row, bf16_row) in VARIANTS.items():
        cells = []
        for scene in ("pbc", "lebc"):
            found = runs.get((key, scene), [])
            if not found:
                cells.append("–")
                continue
            values = np.array([r["ratio"] for r in found])
            each = ", ".join(f"{r['ratio']:.3f}" for r in sorted(found, key=lambda r: r["seed"]))
            spread = f" ± {values.std(ddof=1):.3f}" if len(values) > 1 else ""
            cells.append(f"{values.mean():.3f}{spread} ({each})")
        pbc = runs.get((key, "pbc"), [])
        if not pbc and not runs.get((key, "lebc")):
            continue
        steps = ", ".join(sorted({str(r["steps"]) for r in pbc})) or "–"
        seconds = " / ".join(
            ", ".join(f"{r['seconds']:.0f}" for r in sorted(runs.get((key, sc), []),
                                                             key=lambda r: r["seed"])) or "–"
            for sc in ("pbc", "lebc")
        )  # fmt: skip
        timing = [
            f"{encoder_ms(enc, fp32_row, n)} / {encoder_ms(enc, bf16_row, n)}"
            for n in (2000, 32000)
        ]
        rows.append(
            f"| {label} | {cells[0]} | {cells[1]} | {steps} | {seconds} | "
            + " | ".join(timing)
            + " |"
        )
    text = (
        "Speed levers: 190-10 test RMSE / CV's (out of sample; mean ± std over the seeds, each "
        "seed in brackets), optimiser steps, training wall time per seed (2 CPU cores; several "
        "runs "
        "shared the machine with benchmarks and other runs: the quiet ones are the former model "
        "304 s (lebc, seed 1) against 166 s for the lean one (lebc, seed 1) and 171 s (pbc, seed "
        "0)), and the encoder's forward pass alone (encoder_speed.md: untrained weights, one "
        "thread, the lean rows with the chunked rounds).\n\n" + "\n".join(rows)
    )
    print(text)
    if args.out:
        write_report(args.out, text, {f"{k[0]}/{k[1]}": v for k, v in runs.items()}, echo=False)
    return text


if __name__ == "__main__":
    main(sys.argv[1:])
