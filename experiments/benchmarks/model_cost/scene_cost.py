"""Skip what a scene doesn't need: the periodic scene against the Lees-Edwards scene, and the
cost LE-only work would add to the periodic scene if it were not skipped.

    python experiments/benchmarks/model_cost/scene_cost.py [--frames 3] [--windows 5] [--repeats 3]
        [--json out.json] [--out experiments/results/model_cost/scene_cost]
    python experiments/benchmarks/model_cost/scene_cost.py --quick   # tiny scene, fewer repetitions

Three stages, each timed side by side in one process (the variants interleaved, best of
``--repeats``, so a load change on a shared machine hits them alike):

- **DEM** (ms per step, neighbour-list rebuilds per frame), restarted from each default
  dataset's stored state: ``pbc``; ``lebc``; ``pbc via the LE path``: the periodic scene run
  as a Lees-Edwards scene of shear rate 1e-12 1/s (offsets ~1e-17 m: the same physics, every
  LE correction evaluated); ``pbc + lubrication``: the term the default scenes switch off,
  evaluated at a viscosity of 1e-30 Pa s (no effect on the motion, its full cost).
- **data preparation** per window (history 10, horizon 10; ms): HDF5 read, the exact frame's
  encoding, the interaction graph (cut-off 1.3 d), the LE crossing mask, and one whole
  DataModule sample: ``pbc``, ``lebc`` and ``pbc via the LE path`` (the periodic data with a
  Lees-Edwards boundary of shear rate 0: offsets all zero, the LE code paths run).
- **model** per window (ms): the default model's forward + decode (untrained: the same
  operations), and the constant-velocity and linear AR baselines, for the same three variants.

The LE-path variants must give the same numbers as the periodic ones (checked: positions to
1e-12 of the box), so the difference is only the cost of work a periodic scene skips.
``--out STEM`` writes ``STEM.md`` (the result header, then the printed tables) and
``STEM.json``; ``--json`` the JSON alone (with the header's fields under ``header``).
"""

from __future__ import annotations

import argparse
import dataclasses
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
    load_yaml,
    machine_line,
    markdown_table,
    result_fields,
    scene_dataset,
    set_threads,
    write_report,
)

from gripdem.boundary import Boundary, LeesEdwards  # noqa: E402
from gripdem.data.batch import collate_windows  # noqa: E402
from gripdem.data.dataset import FrameReader, WindowDataset  # noqa: E402
from gripdem.data.dataset_io import read_meta  # noqa: E402
from gripdem.data.encodings import x_face_crossings  # noqa: E402
from gripdem.data.frames import FrameStore  # noqa: E402
from gripdem.data.graph import build_graph  # noqa: E402
from gripdem.data.windows import Segment, WindowIndex  # noqa: E402
from gripdem.dem.config import GeneratorConfig  # noqa: E402
from gripdem.dem.engine import Simulation  # noqa: E402
from gripdem.inference.checkpoint import data_scene  # noqa: E402
from gripdem.models.baselines import predict_baseline  # noqa: E402
from gripdem.models.module import TrajectoryModule  # noqa: E402

HISTORY, HORIZON = 10, 10


# --------------------------------------------------------------------------------------------
# DEM
# --------------------------------------------------------------------------------------------
def dem_variants(preset: str) -> dict[str, tuple[GeneratorConfig, Path]]:
    """name -> (generator config, dataset whose stored state it restarts from)."""
    pbc, lebc, p = (
        load_yaml("scene", "pbc"),
        load_yaml("scene", "lebc"),
        load_yaml("preset", preset),
    )
    base = GeneratorConfig.from_mappings(pbc, p, sims=1)
    le_path = {
        **pbc,
        "boundary": "lees_edwards",
        "shear_rate": 1e-12,
        "body_force_amplitude": base.body_force_amplitude,
    }
    pbc_path, lebc_path = scene_dataset("pbc", preset), scene_dataset("lebc", preset)
    return {
        "pbc": (base, pbc_path),
        "lebc": (GeneratorConfig.from_mappings(lebc, p, sims=1), lebc_path),
        "pbc via the LE path": (GeneratorConfig.from_mappings(le_path, p, sims=1), pbc_path),
        "pbc + lubrication (1e-30 Pa s)": (
            GeneratorConfig.from_mappings({**pbc, "lubrication_viscosity": 1e-30}, p, sims=1),
            pbc_path,
        ),
    }


def restart(config: GeneratorConfig, path: Path) -> Simulation:
    with h5py.File(path, "r") as h5:
        sim, frame = h5["positions"].shape[0] - 1, h5["positions"].shape[1] - 1
        pos = np.asarray(h5["positions"][sim, frame], np.float64)
        vel = np.asarray(h5["velocities"][sim, frame], np.float64)
        t = float(h5["times"][sim, frame])
    return Simulation(config, pos, vel, step=round(t / config.dt))


def bench_dem(preset: str, frames: int) -> list[list]:
    variants = dem_variants(preset)
    sims = {name: restart(cfg, path) for name, (cfg, path) in variants.items()}
    for s in sims.values():
        s.run(1)  # numba's cached kernels load on first use
    best = {name: np.inf for name in sims}
    rebuilds = {name: sims[name].rebuilds for name in sims}
    for _ in range(frames):
        for name, s in sims.items():  # interleaved: the same load for every variant
            start = time.perf_counter()
            s.run(s.config.steps_per_frame)
            best[name] = min(best[name], time.perf_counter() - start)
    rows = []
    for name, s in sims.items():
        ms = 1e3 * best[name] / s.config.steps_per_frame
        rows.append(
            [
                name,
                fmt(ms),
                fmt(ms / (1e3 * best["pbc"] / sims["pbc"].config.steps_per_frame)),
                fmt((s.rebuilds - rebuilds[name]) / frames),
                len(s.pairs),
            ]
        )
    return rows


# --------------------------------------------------------------------------------------------
# data preparation and model
# --------------------------------------------------------------------------------------------
def default_model(scene: str, data_path: Path) -> TrajectoryModule:
    from hydra import compose, initialize_config_dir

    from gripdem.run import CONFIG_DIR
    from gripdem.runner.experiment import build_datamodule, build_model

    overrides = [
        f"scene={scene}",
        f"data.path={data_path}",
        "split=custom",
        f"split.history={HISTORY}",
        f"split.horizon={HORIZON}",
        f"data.history_len={HISTORY}",
        # the same inputs under either boundary (auto would drop them for the LE path)
        "model.encoder.position_features=" + ("'true'" if scene == "pbc" else "'false'"),
    ]
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose("config", overrides=overrides)
    dm = build_datamodule(cfg, data_path)
    model = build_model(cfg, dm)
    dm.teardown()
    return model.eval()


def variant(model: TrajectoryModule, meta, boundary: Boundary | None):
    """(model, meta) with ``boundary`` instead of the data's (None: unchanged)."""
    if boundary is None:
        return model, meta
    meta = dataclasses.replace(meta, boundary=boundary)
    moved = TrajectoryModule(**{**dict(model.hparams), "scene": data_scene(meta)})
    moved.load_state_dict(model.state_dict())
    return moved.eval(), meta


def window_parts(model, meta, path: Path, n_windows: int) -> dict:
    """Callables for each data-preparation step and the model, on the data's last simulation."""
    with h5py.File(path, "r") as h5:
        times = np.asarray(h5["times"][()], np.float64)
    reader = FrameReader(path)
    sim = meta.n_sims - 1
    span = HISTORY + 1 + HORIZON
    count = min(n_windows, (meta.n_frames - span) // HORIZON + 1)
    windows = WindowIndex([Segment(sim, 0, HORIZON, count)], HISTORY, HORIZON)
    cutoff = float(model.hparams.graph_cutoff) * meta.diameter
    dataset = WindowDataset(
        reader, meta, times, windows, model.encoding, model.normalizer, cutoff, graph_cache_mb=0
    )
    store = FrameStore(  # the training path: the simulation kept in memory, prepared once
        lambda s: reader.read(s, 0, meta.n_frames),
        times,
        meta.boundary,
        model.normalizer,
        cutoff,
        meta.diameter,
        simulation_mb=meta.n_frames * meta.n_particles * 3 * 8 / 2**20,
    )
    in_memory = WindowDataset(
        reader, meta, times, windows, model.encoding, model.normalizer, cutoff,
        graph_cache_mb=0, store=store,
    )  # fmt: skip
    in_memory[0]  # the one-off preparation of the simulation is not a window's cost
    offsets = meta.boundary.offset(times)
    frames = [reader.read(w.sim, w.start, w.stop).transpose(1, 0, 2) for w in windows]
    offs = [offsets[w.sim, w.start : w.stop] for w in windows]
    batches = [collate_windows([dataset[i]]) for i in range(count)]

    def each(fn):
        return lambda: [fn(i) for i in range(count)]

    def baseline(name):
        def run(i):
            b = batches[i]
            return predict_baseline(
                name,
                b.input_positions.double().transpose(1, 2),
                b.input_offsets.double(),
                b.target_offsets.double(),
                meta.box,
                model.profile,
                model.linear_ar,
                model.boundary,
            )

        return each(run)

    @torch.no_grad()
    def predict(i):
        return model.decode(model(batches[i]), batches[i])

    return {
        "count": count,
        "data": {
            "HDF5 read": each(
                lambda i: reader.read(windows[i].sim, windows[i].start, windows[i].stop)
            ),
            "encoding (exact frame)": each(
                lambda i: model.encoding.encode(frames[i], offs[i], anchor=HISTORY)
            ),
            "graph (1.3 d)": each(
                lambda i: build_graph(
                    np.ascontiguousarray(frames[i][:, HISTORY]),
                    meta.box,
                    float(offs[i][HISTORY]),
                    cutoff,
                    length_unit=meta.diameter,
                )
            ),
            "LE crossing mask (periodic: skipped; its cost if not)": each(
                lambda i: x_face_crossings(frames[i][:, HISTORY:], meta.box, offs[i][HISTORY:])
            ),
            "whole sample (read, encode, normalise, graph, mask)": each(
                lambda i: collate_windows([dataset[i]])
            ),
            "whole sample, in-memory frames (data/frames.py; graphs not cached)": each(
                lambda i: collate_windows([in_memory[i]])
            ),
        },
        "model": {
            "model forward + decode": each(predict),
            "constant velocity": baseline("constant_velocity"),
            "linear AR": baseline("linear_ar"),
        },
        "predict": lambda: [predict(i) for i in range(count)],
    }


def bench_pipeline(preset: str, n_windows: int, repeats: int) -> tuple[list, list, float]:
    variants = {}
    for scene in ("pbc", "lebc"):
        path = scene_dataset(scene, preset)
        model, meta = default_model(scene, path), read_meta(path)
        variants[scene] = (model, meta, path)
    model, meta, path = variants["pbc"]
    zero_rate = Boundary(meta.box, LeesEdwards(0.0))
    variants["pbc via the LE path"] = (*variant(model, meta, zero_rate), path)
    parts = {name: window_parts(m, mt, p, n_windows) for name, (m, mt, p) in variants.items()}
    # the LE path must predict the same positions as the periodic one
    same = [
        float((a - b).abs().max())
        for a, b in zip(
            parts["pbc"]["predict"](), parts["pbc via the LE path"]["predict"](), strict=True
        )
    ]
    difference = max(same) / meta.box.lx
    tables = []
    for stage in ("data", "model"):
        best = {(name, step): np.inf for name in parts for step in parts[name][stage]}
        for _ in range(repeats):
            for step in parts["pbc"][stage]:
                for name in parts:  # interleaved
                    start = time.perf_counter()
                    parts[name][stage][step]()
                    best[name, step] = min(best[name, step], time.perf_counter() - start)
        rows = []
        for step in parts["pbc"][stage]:
            ms = {name: 1e3 * best[name, step] / parts[name]["count"] for name in parts}
            rows.append(
                [
                    step,
                    fmt(ms["pbc"]),
                    fmt(ms["lebc"]),
                    fmt(ms["lebc"] / ms["pbc"]),
                    fmt(ms["pbc via the LE path"]),
                    fmt(ms["pbc via the LE path"] / ms["pbc"]),
                ]
            )
        tables.append(rows)
    return tables[0], tables[1], difference


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=3, help="DEM frames per variant")
    ap.add_argument("--windows", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", type=Path, default=None, help="the JSON alone")
    ap.add_argument("--out", type=Path, default=None, help="STEM: STEM.md and STEM.json")
    args = ap.parse_args(argv)
    set_threads(args.threads)
    preset = "tiny" if args.quick else "default"
    frames, windows, repeats = (
        (1, 2, 2) if args.quick else (args.frames, args.windows, args.repeats)
    )
    dem = bench_dem(preset, frames)
    data, model, difference = bench_pipeline(preset, windows, repeats)
    machine = machine_line()
    cols = [
        "per window",
        "pbc (ms)",
        "lebc (ms)",
        "lebc / pbc",
        "pbc via LE path (ms)",
        "LE path / pbc",
    ]
    text = "\n\n".join(
        [
            f"{machine}\n\npreset {preset}{' (QUICK)' if args.quick else ''}: DEM best of {frames} "
            f"frame(s) per variant; data and model best of {repeats} over {windows} windows "
            f"(history {HISTORY}, horizon {HORIZON})",
            markdown_table(["DEM variant", "ms / step", "/ pbc", "rebuilds / frame", "pairs"], dem),
            markdown_table(cols, data),
            markdown_table(cols, model),
            f"pbc via the LE path predicts the periodic positions to {difference:.2g} of the box.",
        ]
    )
    print("\n" + text)
    report = {
        "quick": args.quick,
        "dem": dem,
        "data": data,
        "model": model,
        "le_path_difference": difference,
        "text": text,
    }
    if args.out:
        write_report(args.out, text, report, echo=False)
    if args.json:
        atomic_write(args.json, json.dumps({"header": result_fields(), **report}, indent=2) + "\n")
    return report


if __name__ == "__main__":
    main(sys.argv[1:])
