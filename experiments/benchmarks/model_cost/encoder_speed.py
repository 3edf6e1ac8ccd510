"""The contact encoder's forward pass: what each lever costs, side by side in one process.

    python experiments/benchmarks/model_cost/encoder_speed.py [--scene pbc] [--sizes 2000 32000]
        [--threads 1] [--repeats 5] [--chunks 2048 8192] [--json out.json]
        [--out experiments/results/model_cost/encoder_speed]
    python experiments/benchmarks/model_cost/encoder_speed.py --quick
        # tiny scene, 400 and 1600 particles

On the scene's default dataset (tiled along y and z for more particles, as in
``surrogate_speed.py``), one observed state's contact graph at each cut-off, and the default
encoder's shape (64 channels, 4 rounds, history 10, untrained weights: the same operations and
time as trained ones), the fastest of ``--repeats`` forward passes without gradients, in ms
per pass and per particle, for:

- ``reference``: 64-channel pair latents, edge updates, all edges at once, fp32;
- the levers one by one and together: edge updates off, narrower pair latents
  (``pair_channels``), the 1.15 d cut-off, edges in cache-sized blocks (``edge_chunk``), bf16
  weights (where the CPU has bf16 units: ``gripdem.inference.precision``).

Each row also prints its largest deviation from the same weights' reference-order output where
that exists (the chunked rounds and bf16 against the same model unchunked in fp32).
``--out STEM`` writes ``STEM.md`` (the result header, then the printed tables) and
``STEM.json``; ``--json`` the JSON alone (with the header's fields under ``header``).
"""

from __future__ import annotations

import argparse
import json
import sys
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
    result_fields,
    scene_dataset,
    set_threads,
    tile_frames,
    write_report,
)

from gripdem.boundary import lattice_continuous_steps, neighbour_pairs  # noqa: E402
from gripdem.data.dataset_io import read_meta  # noqa: E402
from gripdem.inference.precision import bf16_supported  # noqa: E402
from gripdem.nn.contact import ContactEncoder, ContactGraph  # noqa: E402

HISTORY = 10


def state(scene: str, factor: int, preset: str = "default"):
    """``(history (1, N, K, 3) float32 in unit-ish velocity scale, positions (N, 3), LE offset,
    meta, boundary)`` of the last frames of the scene's test simulation, tiled ``factor``
    times."""
    path = scene_dataset(scene, preset)
    meta = read_meta(path)
    with h5py.File(path, "r") as h5:
        pos = np.asarray(h5["positions"][meta.n_sims - 1, -(HISTORY + 1) :], np.float64)
        times = np.asarray(h5["times"][meta.n_sims - 1, -(HISTORY + 1) :], np.float64)
    tiled, boundary = tile_frames(pos, meta.boundary, factor, times)
    offsets = boundary.offset(times)
    # (N, K, 3): the model's steps (LE-exact across the x faces), in units of their spread
    steps = lattice_continuous_steps(
        tiled.transpose(1, 0, 2), boundary.box, offsets if boundary.is_lees_edwards else None
    )
    history = steps / max(float(np.std(steps)), 1e-30)
    offset = float(offsets[-1])
    return torch.from_numpy(history[None].astype(np.float32)), tiled[-1], offset, meta, boundary


def contact_graph(positions, boundary, offset: float, cutoff: float, d: float) -> ContactGraph:
    i, j, vec = neighbour_pairs(positions, boundary.box, offset, cutoff * d)
    i, j, vec = np.concatenate([i, j]), np.concatenate([j, i]), np.concatenate([vec, -vec]) / d
    order = np.argsort(i, kind="stable")
    i, j, vec = i[order], j[order], vec[order]
    gap = np.sqrt((vec**2).sum(1)) - 1.0
    return ContactGraph(
        torch.from_numpy(np.stack([i, j]).astype(np.int64)),
        torch.from_numpy(vec.astype(np.float32)),
        torch.from_numpy(gap.astype(np.float32)),
        cutoff,
        len(positions),
    )


def best_ms(encoder, history, static, graph, repeats: int) -> tuple[float, torch.Tensor]:
    with torch.no_grad():
        out = encoder(history, static, graph)
        walls = []
        for _ in range(repeats):
            start = time.perf_counter()
            encoder(history, static, graph)
            walls.append(time.perf_counter() - start)
    return 1e3 * min(walls), out.float()


def variants(bf16: bool) -> list[tuple[str, dict, float, int, bool]]:
    """(label, encoder options, cut-off, edge chunk, bf16)."""
    ref = {"channels": 64, "rounds": 4, "edge_updates": True, "pair_channels": None}
    lean = {**ref, "edge_updates": False, "pair_channels": 32}
    rows = [
        ("reference (64 pair ch., edge updates, 1.3 d)", ref, 1.3, 0, False),
        ("chunked rounds (4096 edges)", ref, 1.3, 4096, False),
        ("edge updates off", {**ref, "edge_updates": False}, 1.3, 0, False),
        ("pair channels 32", {**ref, "pair_channels": 32}, 1.3, 0, False),
        ("cut-off 1.15 d", ref, 1.15, 0, False),
        ("off + 32 ch.", lean, 1.3, 0, False),
        ("off + 32 ch. + chunked", lean, 1.3, 4096, False),
        ("off + 32 ch. + 1.15 d + chunked", lean, 1.15, 4096, False),
    ]
    if bf16:
        rows += [
            ("reference, bf16", ref, 1.3, 0, True),
            ("off + 32 ch. + chunked, bf16", lean, 1.3, 4096, True),
            ("off + 32 ch. + 1.15 d + chunked, bf16", lean, 1.15, 4096, True),
        ]
    return rows


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="pbc", choices=["pbc", "lebc"])
    ap.add_argument("--sizes", type=int, nargs="+", default=[2000, 32000])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument(
        "--chunks", type=int, nargs="*", default=[],
        help="also time the default encoder (32 pair channels, no edge updates, 1.15 d, bf16 "
        "where native) with these chunks",
    )  # fmt: skip
    ap.add_argument("--quick", action="store_true", help="tiny scene, 400 and 1600 particles")
    ap.add_argument("--json", type=Path, default=None, help="the JSON alone")
    ap.add_argument("--out", type=Path, default=None, help="STEM: STEM.md and STEM.json")
    args = ap.parse_args(argv)
    set_threads(args.threads)
    preset = "tiny" if args.quick else "default"
    n0 = read_meta(scene_dataset(args.scene, preset)).n_particles
    if args.quick:
        args.sizes, args.repeats = [n0, 4 * n0], 1
    bf16 = bf16_supported()
    report = {"scene": args.scene, "bf16_supported": bf16, "rows": []}
    tables = []
    for n in args.sizes:
        if n % n0:
            raise ValueError(f"--sizes: {n} is not a multiple of the data's {n0} particles")
        history, positions, offset, meta, boundary = state(args.scene, n // n0, preset)
        static = None
        graphs = {
            c: contact_graph(positions, boundary, offset, c, meta.diameter) for c in (1.3, 1.15)
        }
        rows, reference = [], {}
        lean = variants(False)[5][1]  # the default encoder's shape ("off + 32 ch.")
        half = ", bf16" if bf16 else ""
        rows_spec = variants(bf16) + [
            (f"off + 32 ch. + 1.15 d, chunk {c}{half}", lean, 1.15, c, bf16) for c in args.chunks
        ]
        for label, options, cutoff, chunk, half in rows_spec:
            torch.manual_seed(0)
            encoder = ContactEncoder(HISTORY, 0, edge_history=3, **options).eval()
            key = (tuple(sorted(options.items(), key=str)), cutoff)
            encoder.edge_chunk = chunk
            if half:
                encoder.to(torch.bfloat16)
            ms, out = best_ms(encoder, history, static, graphs[cutoff], args.repeats)
            if key not in reference:
                reference[key] = out
            deviation = (out - reference[key]).abs().max().item() / reference[key].abs().max()
            edges = graphs[cutoff].edge_index.shape[1]
            rows.append([label, fmt(ms), fmt(1e3 * ms / n), edges, f"{deviation.item():.1e}"])
            report["rows"].append(
                {
                    "particles": n,
                    "variant": label,
                    "ms": ms,
                    "edges": edges,
                    "relative_deviation": float(deviation),
                }
            )
            print(f"{n} {label}: {ms:.2f} ms", flush=True)
        base = report["rows"][-len(rows)]["ms"]
        for row, rec in zip(rows, report["rows"][-len(rows) :], strict=True):
            row.insert(2, fmt(base / rec["ms"]))
        tables.append(
            f"### {args.scene}, {n} particles, {args.threads} thread(s)\n\n"
            + markdown_table(
                ["encoder", "ms / pass", "speed-up", "us / particle", "edges", "max dev / max"],
                rows,
            )
        )
    machine = machine_line() + f"; bf16 units: {'yes' if bf16 else 'no'}"
    text = machine + "\n\n" + "\n\n".join(tables)
    print("\n" + text)
    report["machine"] = machine
    if args.out:
        write_report(args.out, text, report, echo=False)
    if args.json:
        atomic_write(args.json, json.dumps({"header": result_fields(), **report}, indent=2) + "\n")
    return report


if __name__ == "__main__":
    main(sys.argv[1:])
