"""Scaling: inference and one training step against particle count, history length and threads.

    python experiments/benchmarks/model_cost/scaling.py [--scene pbc] [--ops sparse dense contact]
        [--sizes 2000 4000 8000 16000 32000 64000] [--histories 10 50 190]
        [--threads 1 2] [--memory-budget-gb 8] [--max-seconds 120] [--json out.json]
        [--out experiments/results/model_cost/scaling]
    python experiments/benchmarks/model_cost/scaling.py --quick
        # tiny scene: 400 and 1600 particles

Three forms of the model, each the real :class:`~gripdem.models.module.TrajectoryModule` at
the default preset's widths (untrained: the same operations and time as trained):

- ``sparse``: ``model=grip_paper``, the paper's graph-conv encoder with the sparse graph operation
  (G_fixed + learned edge weights on the edge list; cut-off 3 d, ~107 neighbours);
- ``dense``: the same with ``model.encoder.trainable_graph=dense``: a learned n x n matrix per
  block beside G_fixed (the paper's form; O(n^2) memory and time);
- ``contact``: ``model=contact``, the default contact encoder (cut-off 1.15 d, ~6.5 neighbours).

States are the scene's default dataset tiled along y and z (2000 x 2^m particles, the same
neighbourhoods), windows built by the training code (:class:`WindowDataset`). Per case:
inference (forward + decode, no gradients) and one training step (forward, loss, backward,
Adam step), best of ``--repeats`` (the first run warms up), and its memory: the weights
(with gradients and Adam's two moments for a training step), counted, plus the peak resident
memory of the step above the level before it (activations and temporaries), sampled in one
more run (the sampling thread would slow the timed ones). Three sweeps keep the count of
cases sane: particle count (history 10, first thread count), history length (smallest
size) and threads (the size 4x the smallest, history 10).

Memory is estimated before every case (from the previous size of the same case scaled by n,
or n^2 for ``dense``, else from a formula) and a case over ``--memory-budget-gb`` is skipped;
a case whose time estimate (the previous size's, scaled the same way) exceeds
``--max-seconds`` is skipped too.

``--out STEM`` writes ``STEM.md`` (the result header, then the printed table) and ``STEM.json``;
``--json`` the JSON alone (with the header's fields under ``header``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np
import torch

sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # benchlib: it adds the groups
from benchlib import (  # noqa: E402
    GIB,
    PeakMemory,
    atomic_write,
    fmt,
    machine_line,
    markdown_table,
    release_freed_memory,
    result_fields,
    scene_dataset,
    set_threads,
    tile_frames,
    write_report,
)

from gripdem.data.batch import collate_windows  # noqa: E402
from gripdem.data.dataset import WindowDataset  # noqa: E402
from gripdem.data.dataset_io import read_meta, write_dataset  # noqa: E402
from gripdem.data.schema import TrajectoryData  # noqa: E402
from gripdem.data.windows import Segment, WindowIndex  # noqa: E402
from gripdem.inference.checkpoint import data_scene  # noqa: E402
from gripdem.models.module import TrajectoryModule  # noqa: E402

OPS = {
    "sparse": ["model=grip_paper"],
    "dense": ["model=grip_paper", "model.encoder.trainable_graph=dense"],
    "contact": ["model=contact"],
}
#: exponent of n in memory and time: the dense n x n matrices dominate at scale
POWER = {"sparse": 1, "dense": 2, "contact": 1}


def base_model(scene: str, data_path: Path, op: str, k: int, split: str) -> TrajectoryModule:
    """The model of ``op`` at history ``k`` built by :mod:`gripdem.runner.experiment` on the data
    (normaliser and AR baseline fitted there)."""
    from hydra import compose, initialize_config_dir

    from gripdem.run import CONFIG_DIR
    from gripdem.runner.experiment import build_datamodule, build_model

    h, f = split.split("-")
    overrides = [
        f"scene={scene}",
        f"data.path={data_path}",
        "split=custom",
        f"split.history={h}",
        f"split.horizon={f}",
        f"data.history_len={k}",
        *OPS[op],
    ]
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose("config", overrides=overrides)
    dm = build_datamodule(cfg, data_path)
    model = build_model(cfg, dm)
    dm.teardown()
    return model


def tiled_batch(data_path: Path, factor: int, frames: int, model, work: Path):
    """A one-window batch of the last ``frames`` frames of the data's last simulation, tiled
    ``factor`` times, and its meta."""
    meta0 = read_meta(data_path)
    with h5py.File(data_path, "r") as h5:
        sim = meta0.n_sims - 1
        pos = np.asarray(h5["positions"][sim, -frames:], np.float64)
        times = np.asarray(h5["times"][sim, -frames:], np.float64)
    tiled, boundary = tile_frames(pos, meta0.boundary, factor, times)
    data = TrajectoryData(
        tiled[None],
        times[None],
        boundary,
        meta0.radius,
        body_force_amplitude=meta0.body_force_amplitude,
        provenance={"generator": "bench_scaling tiling", "factor": factor},
    )
    path = write_dataset(work / f"tiled_{factor}_{frames}.h5", data, overwrite=True)
    meta = read_meta(path)
    k, f = int(model.hparams.history_len), int(model.hparams.horizon)
    dataset = WindowDataset(
        _Memory(tiled[None]),
        meta,
        times[None],
        WindowIndex([Segment(0, 0, 1, 1)], k, f),
        model.encoding,
        model.normalizer,
        float(model.hparams.graph_cutoff) * meta.diameter,
        graph_cache_mb=0.0,
    )
    return collate_windows([dataset[0]]), meta


class _Memory:
    """Frames from memory with the file reader's interface."""

    def __init__(self, positions):
        self.positions = positions

    def read(self, sim: int, start: int, stop: int) -> np.ndarray:
        return self.positions[sim, start:stop]

    def close(self) -> None:
        pass


def sized_model(model: TrajectoryModule, meta, n: int) -> TrajectoryModule:
    """``model``'s configuration in the tiled box with ``n`` particles, freshly initialised
    (untrained; the dense form needs new n x n matrices)."""
    torch.manual_seed(0)
    hp = {**dict(model.hparams), "scene": data_scene(meta), "n_particles": n}
    return TrajectoryModule(**hp)


def formula_bytes(op: str, n: int, k: int, train: bool, neighbours: float) -> float:
    """A first memory estimate before anything was measured (float32 activations; training
    keeps them for the backward pass, parameters add gradients and two Adam moments)."""
    if op == "contact":
        edges = n * neighbours
        act = 4.0 * (edges * 64 * 40 + n * 64 * 30 + n * k * 3 * 4)
    else:
        edges = n * (neighbours + 1)
        act = 4.0 * (n * k * 32 * 30 + edges * 16 * 6 + n * k * 32 * 2 * 12)
    dense = 4.0 * 3 * n * n * (5 if train else 2) if op == "dense" else 0.0
    return (act if train else act / 3) + dense


def run_case(model, batch, train: bool, repeats: int) -> tuple[float, int]:
    """(best seconds, peak bytes above the level before the step, bytes of the weights with
    their gradients and Adam moments when training) of inference or one training step."""
    if train:
        model.train()
        opt = torch.optim.Adam(model.parameters(), lr=1e-4)

        def step():
            opt.zero_grad()
            loss = model._loss(model(batch), batch)  # what training_step minimises
            loss.backward()
            opt.step()

    else:
        model.eval()

        def step():
            with torch.no_grad():
                model.decode(model(batch), batch)

    best = math.inf
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        step()
        best = min(best, time.perf_counter() - start)
    with PeakMemory() as mem:  # a run of its own: the sampling thread slows small ops down
        step()
    weights = sum(p.numel() * p.element_size() for p in model.parameters())
    return best, mem.peak, weights * (4 if train else 1)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="pbc")
    ap.add_argument("--ops", nargs="+", default=list(OPS), choices=list(OPS))
    ap.add_argument("--sizes", type=int, nargs="+", default=None)
    ap.add_argument("--histories", type=int, nargs="+", default=None)
    ap.add_argument("--threads", type=int, nargs="+", default=None)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--memory-budget-gb", type=float, default=8.0)
    ap.add_argument("--max-seconds", type=float, default=120.0)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", type=Path, default=None, help="the JSON alone")
    ap.add_argument("--out", type=Path, default=None, help="STEM: STEM.md and STEM.json")
    args = ap.parse_args(argv)
    if args.quick:
        preset, split = "tiny", "20-5"
        sizes, histories, threads = args.sizes or [400, 1600], args.histories or [5, 10], [1]
    else:
        preset, split = "default", "190-10"
        sizes = args.sizes or [2000, 4000, 8000, 16000, 32000, 64000]
        histories, threads = args.histories or [10, 50, 190], args.threads or [1, 2]
    f = int(split.split("-")[1])
    data_path = scene_dataset(args.scene, preset)
    n0 = read_meta(data_path).n_particles
    work = Path(tempfile.mkdtemp(prefix="gripdem-scaling-"))
    base_k = 10 if 10 in histories else histories[0]
    cases = [(n, base_k, threads[0]) for n in sizes]
    cases += [(sizes[0], k, threads[0]) for k in histories if k != base_k]
    n_threads = 4 * sizes[0] if 4 * sizes[0] in sizes else sizes[-1]
    cases += [(n_threads, base_k, t) for t in threads[1:]]
    results, previous = [], {}
    for op in args.ops:
        models = {}
        for n, k, t in cases:
            set_threads(t)
            if k not in models:
                models[k] = base_model(args.scene, data_path, op, k, split)
            base = models[k]
            for train in (False, True):
                key = (op, k, t, train)
                last = previous.get(key)
                scale = None if last is None else (n / last["n"]) ** POWER[op]
                neighbours = 107.0 if op != "contact" else 9.0
                est_mem = (
                    formula_bytes(op, n, k, train, neighbours)
                    if last is None
                    else max(last["bytes"], 1.0) * scale
                )
                est_s = None if last is None else last["seconds"] * scale
                row = {
                    "op": op,
                    "particles": n,
                    "history": k,
                    "threads": t,
                    "mode": "train step" if train else "inference",
                    "estimate_bytes": est_mem,
                }
                if est_mem > args.memory_budget_gb * GIB:
                    row["skipped"] = f"memory estimate {est_mem / GIB:.1f} GiB"
                elif est_s is not None and est_s > args.max_seconds:
                    row["skipped"] = f"time estimate {est_s:.0f} s"
                else:
                    batch, meta = tiled_batch(data_path, n // n0, k + 1 + f, base, work)
                    model = sized_model(base, meta, n)
                    seconds, peak, state = run_case(model, batch, train, args.repeats)
                    row.update(
                        seconds=seconds,
                        peak_bytes=peak,
                        state_bytes=state,
                        edges=int(batch.edge_index.shape[1]),
                    )
                    previous[key] = {"n": n, "bytes": peak + state, "seconds": seconds}
                    del model, batch
                    release_freed_memory()
                results.append(row)
                print(json.dumps(row), flush=True)
    machine = machine_line()
    rows = []
    for r in results:
        rows.append(
            [
                r["op"],
                r["particles"],
                r["history"],
                r["threads"],
                r["mode"],
                r.get("skipped") or fmt(r["seconds"]),
                "–" if "skipped" in r else fmt(r["state_bytes"] / 2**20),
                "–" if "skipped" in r else fmt(r["peak_bytes"] / 2**20),
                fmt(r["estimate_bytes"] / 2**20),
                r.get("edges", "–"),
            ]
        )
    text = markdown_table(
        [
            "form",
            "particles",
            "history",
            "threads",
            "case",
            "seconds",
            "weights (+grads, Adam) MiB",
            "step peak MiB",
            "estimate MiB",
            "edges",
        ],
        rows,
    )
    text = (
        f"{machine}\n\nscene {args.scene}, split {split}{' (QUICK)' if args.quick else ''}\n\n"
        + text
    )
    print("\n" + text)
    report = {"machine": machine, "quick": args.quick, "scene": args.scene, "rows": results}
    if args.out:
        write_report(args.out, text, report, echo=False)
    if args.json:
        atomic_write(args.json, json.dumps({"header": result_fields(), **report}, indent=2) + "\n")
    return report


if __name__ == "__main__":
    main(sys.argv[1:])
