"""The paper's seq2seq GRU decoder: the cell-by-cell loop against the batched loop, side by side.

    python experiments/benchmarks/model_cost/decoder_loop.py \
        [--threads 1] [--repeats 3] [--json out.json]
        [--out experiments/results/model_cost/decoder_loop]
    python experiments/benchmarks/model_cost/decoder_loop.py --quick   # 200 particles, one repeat

:class:`gripdem.nn.seq2seq.TrajectoryDecoder` with the same weights, run two ways in one
process: ``reference_forward`` (each head's own loop, one ``nn.GRU`` call per step, as before)
and ``forward`` (every head at once, :mod:`gripdem.nn.stacked_gru`). Each row is one forward
and backward pass (training's cost), the fastest of ``--repeats``, at the paper's shape: 2
heads of 2 GRU layers, the graph-conv encoder's 32 features over ``history`` = 10 observed
steps (the default preset's history), state and output of the paper's sin/cos modes (6 channels),
at the horizons of 190-10 and 100-100 and hidden 32 (the default preset) and 350 (the paper).
``max |Δ|``: the largest difference between the two outputs and between their gradients,
relative to the largest value (float32 round-off: identical outputs). ``--out STEM`` writes
``STEM.md`` (the result header, then the printed report) and ``STEM.json``; ``--json`` the JSON
alone (with the header's fields under ``header``).
"""

from __future__ import annotations

import argparse
import datetime
import json
import subprocess
import sys
import time
from pathlib import Path

import torch

sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # benchlib: it adds the groups
from benchlib import (  # noqa: E402
    atomic_write,
    fmt,
    machine_line,
    markdown_table,
    result_fields,
    set_threads,
    write_report,
)

from gripdem.nn.seq2seq import TrajectoryDecoder  # noqa: E402

HISTORY, FEATURES, CHANNELS = 10, 32, 6
#: (split, horizon, hidden, particles): hidden 350 at 100 steps costs ~2.6 TFLOP per pass at
#: 2000 particles, so that row runs 500 (every op is linear in the particle count at that width)
CASES = (
    ("190-10", 10, 32, 2000),
    ("100-100", 100, 32, 2000),
    ("190-10", 10, 350, 2000),
    ("100-100", 100, 350, 500),
)


def decoder(hidden: int) -> TrajectoryDecoder:
    torch.manual_seed(0)
    fold = 0.1 * torch.randn(CHANNELS, CHANNELS)
    dec = TrajectoryDecoder(
        FEATURES, CHANNELS, CHANNELS, hidden, 2, 2, fold=fold, shift=0.01 * torch.randn(CHANNELS)
    )
    for p in dec.parameters():  # trained-looking weights (the heads start at zero)
        torch.nn.init.normal_(p, std=1.0 / hidden**0.5)
    return dec


def one_pass(forward, dec, inputs, horizon):
    features, state, base = inputs
    out = forward(features, state, base, horizon)
    grads = torch.autograd.grad(out.square().mean(), [features, *dec.parameters()])
    return out.detach(), grads


def fastest(forward, dec, inputs, horizon, repeats):
    best, result = float("inf"), None
    for _ in range(repeats):
        start = time.perf_counter()
        result = one_pass(forward, dec, inputs, horizon)
        best = min(best, time.perf_counter() - start)
    return best, result


def relative_gap(a, b) -> float:
    return float((a - b).abs().max() / b.abs().max().clamp_min(1e-30))


def run_case(split, horizon, hidden, particles, repeats):
    dec = decoder(hidden)
    torch.manual_seed(1)
    features = torch.randn(1, particles, HISTORY, FEATURES, requires_grad=True)
    state = torch.randn(1, particles, CHANNELS)
    base = 0.1 * torch.randn(1, particles, CHANNELS)
    inputs = (features, state, base)
    t_ref, (out_ref, g_ref) = fastest(dec.reference_forward, dec, inputs, horizon, repeats)
    t_new, (out_new, g_new) = fastest(dec.forward, dec, inputs, horizon, repeats)
    gap = max(
        relative_gap(out_new, out_ref),
        *(relative_gap(a, b) for a, b in zip(g_new, g_ref, strict=True)),
    )
    return {
        "split": split,
        "horizon": horizon,
        "hidden": hidden,
        "particles": particles,
        "reference_s": t_ref,
        "batched_s": t_new,
        "speedup": t_ref / t_new,
        "max_relative_gap": gap,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="200 particles, one repeat")
    parser.add_argument("--json", type=Path, default=None, help="the JSON alone")
    parser.add_argument("--out", type=Path, default=None, help="STEM: STEM.md and STEM.json")
    args = parser.parse_args(argv)
    set_threads(args.threads)
    cases = [(s, f, h, 200 if args.quick else n) for s, f, h, n in CASES]
    repeats = 1 if args.quick else args.repeats
    rows = [run_case(*case, repeats) for case in cases]
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False
    ).stdout.strip()
    machine = machine_line()
    text = "\n".join(
        [
            f"# Decoder loop: forward + backward, {datetime.date.today()}, commit {commit}",
            machine,
            markdown_table(
                [
                    "split",
                    "hidden",
                    "particles",
                    "cell-by-cell (s)",
                    "batched (s)",
                    "speed-up",
                    "max rel. |Δ|",
                ],
                [
                    [
                        r["split"],
                        r["hidden"],
                        r["particles"],
                        fmt(r["reference_s"]),
                        fmt(r["batched_s"]),
                        f"{r['speedup']:.2f}x",
                        f"{r['max_relative_gap']:.1e}",
                    ]
                    for r in rows
                ],
            ),
        ]
    )
    print(text)
    report = {"machine": machine, "rows": rows}
    if args.out:
        write_report(args.out, text, report, echo=False)
    if args.json:
        payload = {"header": result_fields(), **report}
        atomic_write(args.json, json.dumps(payload, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
