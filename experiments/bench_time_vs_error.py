"""Run time against error: trained models vs the DEM solver vs the baselines, per scene and split.

    python experiments/bench_time_vs_error.py RUN_OR_SWEEP_DIR... [--dem-frames N]
        [--windows N] [--threads 1] [--out-dir experiments/results]
    python experiments/bench_time_vs_error.py --quick          # trains two smoke models first

Every ``RUN_OR_SWEEP_DIR`` is a ``python -m gripdem.run`` output directory (``metrics.json``,
``checkpoints/best.ckpt``, ``.hydra/config.yaml``) or a folder holding such directories (a
multirun sweep). For each run, on its own test windows (the windows its ``metrics.json``
was scored on, rebuilt from its config):

- **model**: wall time to prepare every test window (HDF5 read, encoding, graph) and to
  predict and decode its horizon, one window at a time, and the resulting RMSE / d (checked
  against the run's ``test/rmse`` when every window is timed); its training time
  (``train_seconds`` of the run) and the **break-even**: the number of predicted frames
  after which training has paid for itself against simulating those frames with the DEM,
  ``train_seconds / (DEM s per frame - model s per frame)``, also counting the DEM time that
  generated its training and validation simulations (from the dataset's provenance);
- **baselines** on the same windows (stay, constant velocity, mean flow, linear AR; the AR's
  fit on the training frames is its training time);
- **DEM solver** (the built-in generator that made the data): restarted from the test
  simulation's stored state at the first test window's last observed frame (positions,
  velocities, absolute time so the LE offset is right; angular velocities and tangential
  springs are not stored and start at zero) and timed over ``--dem-frames`` frames (default:
  as many as the test windows predict); its error is 0 by definition.

Writes ``time_vs_error.md`` (one table per scene and split, the machine line above them),
``time_vs_error.json`` and the Pareto plot ``pareto_time_vs_error.png`` (wall time on a log
axis against RMSE / d, the non-dominated points joined) into ``--out-dir``. ``--quick``
(the slow test tier): two windows, three DEM frames, and without run directories it first trains
the smoke preset (``experiment=smoke``, tiny scene, seconds) on both scenes.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from benchlib import fmt, machine_line, markdown_table, set_threads, train_run  # noqa: E402
from omegaconf import OmegaConf  # noqa: E402

from gripdem.data.batch import collate_windows  # noqa: E402
from gripdem.data.datamodule import TrajectoryDataModule  # noqa: E402
from gripdem.dem.config import GeneratorConfig  # noqa: E402
from gripdem.dem.engine import Simulation  # noqa: E402
from gripdem.evaluation.metrics import position_residuals, rmse  # noqa: E402
from gripdem.models.autoregressive import fit_on_training_frames
from gripdem.models.module import TrajectoryModule  # noqa: E402

BASELINE_NAMES = ("stay", "constant_velocity", "mean_flow", "linear_ar")


@dataclass
class Run:
    """One trained run: its folder, composed config, metrics and a label."""

    path: Path
    cfg: object
    metrics: dict
    preset: str

    @property
    def scene(self) -> str:
        return str(self.cfg.scene.name)

    @property
    def split(self) -> str:
        return str(self.cfg.split.name)

    @property
    def label(self) -> str:
        return f"{self.metrics['hparams']['model']} ({self.preset}, seed {self.cfg.seed})"

    @property
    def checkpoint(self) -> Path:
        return self.path / "checkpoints" / "best.ckpt"

    @property
    def data_path(self) -> Path:
        return Path(self.metrics["data"]["path"])


@dataclass
class Row:
    """One line of a table: a method's times (s) on all test windows and its error."""

    method: str
    kind: str  # dem | model | baseline
    prep_s: float
    predict_s: float
    frames: int
    rmse_over_d: float
    train_s: float | None = None
    data_s: float | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def total_s(self) -> float:
        return self.prep_s + self.predict_s

    @property
    def per_frame_s(self) -> float:
        return self.total_s / self.frames


# --------------------------------------------------------------------------------------------
# runs
# --------------------------------------------------------------------------------------------
def find_runs(paths: list[Path]) -> list[Run]:
    """Every run directory at or below ``paths`` (``metrics.json`` + ``checkpoints/best.ckpt``
    + ``.hydra/config.yaml``), in a stable order."""
    found = []
    for root in paths:
        for metrics in sorted(Path(root).rglob("metrics.json")):
            run = metrics.parent
            if (run / "checkpoints" / "best.ckpt").exists() and (
                run / ".hydra" / "config.yaml"
            ).exists():
                found.append(load_run(run))
    if not found:
        raise FileNotFoundError(
            f"no run directories (metrics.json + checkpoints/best.ckpt + .hydra/config.yaml) "
            f"under {[str(p) for p in paths]}"
        )
    return found


def load_run(path: Path) -> Run:
    cfg = OmegaConf.load(path / ".hydra" / "config.yaml")
    metrics = json.loads((path / "metrics.json").read_text())
    preset = "fast"  # conf/config.yaml's default experiment
    overrides = path / ".hydra" / "overrides.yaml"
    if overrides.exists():
        for item in OmegaConf.load(overrides):
            if str(item).startswith("experiment="):
                preset = str(item).split("=", 1)[1]
    return Run(path, cfg, metrics, preset)


def train_smoke_runs(out: Path, scenes: list[str]) -> list[Path]:
    """The smoke preset trained in this process on each scene's tiny dataset (seconds)."""
    dirs = []
    for scene in scenes:
        print(f"training the smoke preset on {scene} into {out / f'smoke_{scene}'}", flush=True)
        overrides = ["experiment=smoke", f"scene={scene}", "torch_threads=1"]
        dirs.append(train_run(out / f"smoke_{scene}", overrides))
    return dirs


# --------------------------------------------------------------------------------------------
# timing
# --------------------------------------------------------------------------------------------
def test_windows(run: Run, model: TrajectoryModule):
    """The run's test windows (rebuilt from its config, its own normaliser; graphs never
    cached, so every window pays for its graph)."""
    dm = TrajectoryDataModule.from_config(
        run.cfg.data, run.cfg.split, path=str(run.data_path), graph_cache_mb=0.0
    )
    dm.load_state_dict({"normalizer": model.normalizer.to_dict(), "encoding": dm.encoding_name})
    dm.setup("fit")
    return dm


@torch.no_grad()
def time_model(model: TrajectoryModule, dataset, n: int) -> tuple[float, float, list, list]:
    """(prep s, predict s, batches, predicted positions) over the first ``n`` windows."""
    warm = collate_windows([dataset[0]])
    model.decode(model(warm), warm)  # first call: lazy initialisation, not timed
    prep = predict = 0.0
    batches, preds = [], []
    for i in range(n):
        start = time.perf_counter()
        batch = collate_windows([dataset[i]])
        mid = time.perf_counter()
        positions = model.decode(model(batch), batch)
        predict += time.perf_counter() - mid
        prep += mid - start
        batches.append(batch)
        preds.append(positions)
    return prep, predict, batches, preds


def time_baseline(model: TrajectoryModule, name: str, batches: list) -> tuple[float, list]:
    """(s, predictions) of one baseline on the already read windows."""
    from gripdem.models.baselines import predict_baseline

    box, out = model.boundary.box, []
    start = time.perf_counter()
    for b in batches:
        observed = b.input_positions.double().transpose(1, 2)
        out.append(
            predict_baseline(
                name,
                observed,
                b.input_offsets.double(),
                b.target_offsets.double(),
                box,
                model.profile,
                model.linear_ar,
                model.boundary,
            )
        )
    return time.perf_counter() - start, out


def read_seconds(dataset, n: int) -> float:
    """HDF5 read of the first ``n`` windows' frames (what a baseline needs as input)."""
    start = time.perf_counter()
    for i in range(n):
        w = dataset.windows[i]
        dataset.reader.read(w.sim, w.start, w.stop)
    return time.perf_counter() - start


def rmse_over_d(preds: list, batches: list, model: TrajectoryModule) -> float:
    pred = torch.cat(preds)
    true = torch.cat([b.target_positions.double().transpose(1, 2) for b in batches])
    offsets = torch.cat([b.target_offsets.double() for b in batches])
    offsets = offsets if model.boundary.is_lees_edwards else None
    return rmse(position_residuals(pred, true, model.boundary.box, offsets)) / model.diameter


def dem_seconds_per_frame(data_path: Path, sim: int, frame: int, frames: int) -> dict:
    """The built-in DEM restarted from a stored frame of ``data_path``, timed over ``frames``
    frames (after one untimed step: numba's cached kernels load on first use)."""
    with h5py.File(data_path, "r") as h5:
        params = json.loads(h5.attrs["provenance"])["parameters"]
        positions = np.asarray(h5["positions"][sim, frame], np.float64)
        velocities = np.asarray(h5["velocities"][sim, frame], np.float64)
        t = float(h5["times"][sim, frame])
    config = GeneratorConfig.from_mappings(params["scene"], params["preset"], sims=1)
    sim_ = Simulation(config, positions, velocities, step=round(t / config.dt))
    sim_.run(1)
    start = time.perf_counter()
    for _ in range(frames):
        sim_.run(config.steps_per_frame)
    wall = time.perf_counter() - start
    return {
        "s_per_frame": wall / frames,
        "frames_timed": frames,
        "dt": config.dt,
        "steps_per_frame": config.steps_per_frame,
        "max_overlap_d": sim_.max_overlap,
    }


def data_seconds(run: Run, parts: tuple[str, ...]) -> float | None:
    """DEM wall time (dataset provenance) that generated the run's simulations of ``parts``
    (``sims_train``, ``sims_val``); None when not recorded or not split by simulation."""
    with h5py.File(run.data_path, "r") as h5:
        walls = json.loads(h5.attrs["provenance"]).get("wall_time_s")
    summary = run.metrics["data"]
    if not walls or any(part not in summary for part in parts):
        return None
    return float(sum(walls[s] for part in parts for s in summary[part]))


def break_even(train_s: float | None, per_frame: float, dem_per_frame: float) -> float:
    """Predicted frames after which ``train_s`` is paid back (inf: never)."""
    if train_s is None:
        return math.nan
    gain = dem_per_frame - per_frame
    return train_s / gain if gain > 0 else math.inf


# --------------------------------------------------------------------------------------------
# one scene/split
# --------------------------------------------------------------------------------------------
def evaluate_run(run: Run, n_windows: int | None, with_baselines: bool) -> tuple[list, dict]:
    model = TrajectoryModule.load_from_checkpoint(str(run.checkpoint), map_location="cpu").eval()
    dm = test_windows(run, model)
    dataset = dm.datasets["test"]
    n = len(dataset) if n_windows is None else min(n_windows, len(dataset))
    prep, predict, batches, preds = time_model(model, dataset, n)
    f = int(model.hparams.horizon)
    frames = n * f
    model_rmse = rmse_over_d(preds, batches, model)
    row = Row(run.label, "model", prep, predict, frames, model_rmse, run.metrics["train_seconds"])
    row.data_s = data_seconds(run, ("sims_train", "sims_val"))
    if n == len(dataset):
        logged = run.metrics["test/rmse_over_d"]
        if abs(model_rmse - logged) > 1e-4 * logged:
            row.notes.append(f"RMSE differs from the run's test/rmse ({logged:.4g})")
    rows = [row]
    info = {
        "windows": n,
        "of_windows": len(dataset),
        "horizon": f,
        "history_len": int(model.hparams.history_len),
        "first_window": dataset.windows[0],
        "particles": dm.meta.n_particles,
    }
    if with_baselines:
        read = read_seconds(dataset, n)
        lags = run.cfg.baselines.ar_lags
        lags = min(int(dm.plan.history_len), 10) if lags is None else int(lags)
        start = time.perf_counter()
        fit_on_training_frames(dm, lags, float(run.cfg.baselines.ar_ridge))
        ar_fit = time.perf_counter() - start
        for name in BASELINE_NAMES:
            if name not in model.baselines:
                continue
            seconds, out = time_baseline(model, name, batches)
            rows.append(
                Row(
                    name,
                    "baseline",
                    read,
                    seconds,
                    frames,
                    rmse_over_d(out, batches, model),
                    ar_fit if name == "linear_ar" else None,
                    data_seconds(run, ("sims_train",)) if name == "linear_ar" else None,
                )
            )
    dm.teardown()
    return rows, info


def table(rows: list[Row], dem: Row) -> str:
    headers = [
        "method",
        "training (s)",
        "prepare windows (s)",
        "predict (s)",
        "per frame (ms)",
        "speed-up vs DEM",
        "RMSE / d",
        "break-even frames (training)",
        "(training + its DEM data)",
    ]
    body = []
    for r in [dem, *rows]:
        even = break_even(r.train_s, r.per_frame_s, dem.per_frame_s)
        even_data = (
            break_even(r.train_s + r.data_s, r.per_frame_s, dem.per_frame_s)
            if r.data_s is not None and r.train_s is not None
            else math.nan
        )
        body.append(
            [
                r.method + ("; " + "; ".join(r.notes) if r.notes else ""),
                fmt(r.train_s),
                "–" if r.kind == "dem" else fmt(r.prep_s),
                fmt(r.predict_s),
                fmt(1e3 * r.per_frame_s),
                "1" if r.kind == "dem" else fmt(dem.per_frame_s / r.per_frame_s),
                "0 (the truth)" if r.kind == "dem" else fmt(r.rmse_over_d),
                "–" if r.kind == "dem" else ("never" if even == math.inf else fmt(even)),
                "–" if r.kind == "dem" else ("never" if even_data == math.inf else fmt(even_data)),
            ]
        )
    return markdown_table(headers, body)


def pareto(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the non-dominated points (no other is both faster and more accurate),
    ordered by time."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], math.inf
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def plot(groups: dict, path: Path, note: str = "") -> None:
    """One panel per scene and split: wall time (log) against RMSE / d (log); the DEM, whose
    error is 0, as a vertical line at its time; the Pareto front of the others joined."""
    keys = sorted(groups)
    ncols = min(4, len(keys))
    nrows = -(-len(keys) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(5.6 * ncols, 4.6 * nrows), squeeze=False)
    for ax in axes.flat[len(keys) :]:
        ax.set_visible(False)
    markers = "osD^v<>px*h"
    colors = {"stay": "C1", "constant_velocity": "C2", "mean_flow": "C4", "linear_ar": "C0"}
    for ax, key in zip(axes.flat, keys, strict=False):  # spare panels hidden above
        rows = [r for r in groups[key]["rows"] if r.kind != "dem"]
        dem = next(r for r in groups[key]["rows"] if r.kind == "dem")
        pts = [(r.total_s, r.rmse_over_d) for r in rows]
        for k, (r, (x, y)) in enumerate(zip(rows, pts, strict=True)):
            color = colors.get(r.method, ("C3", "C5", "C6", "C8", "C9")[k % 5])
            ax.scatter(
                x, y, color=color, marker=markers[k % len(markers)], zorder=3, label=r.method
            )
        front = pareto(pts)
        ax.step(
            [pts[i][0] for i in front] + [dem.total_s],
            [pts[i][1] for i in front] + [pts[front[-1]][1]],
            where="post",
            color="0.5",
            lw=1,
            zorder=1,
            label="Pareto front",
        )
        ax.axvline(dem.total_s, color="k", ls="--", lw=1.2, label="DEM solver (error 0)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        info = groups[key]["info"]
        ax.set(
            xlabel=f"wall time for {info['windows']} test windows x {info['horizon']} frames (s)",
            ylabel="RMSE / d",
            title=f"{key[0]} {key[1]} ({info['particles']} particles)",
        )
        ax.legend(fontsize=7)
    fig.suptitle(f"run time against error{note}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def replot(path: Path) -> dict:
    """The Pareto plot of a written ``time_vs_error.json``, next to it (nothing is re-timed)."""
    report = json.loads(path.read_text())
    fields = ("method", "kind", "prep_s", "predict_s", "frames", "rmse_over_d", "train_s", "data_s")
    groups = {
        (g["scene"], g["split"]): {
            "info": g["info"],
            "rows": [Row(**{k: r[k] for k in fields}) for r in g["rows"]],
        }
        for g in report["groups"]
    }
    figure = path.with_name("pareto_time_vs_error.png")
    plot(
        groups, figure, " (QUICK: a few test windows, DEM extrapolated)" if report["quick"] else ""
    )
    print(f"wrote {figure}")
    return report


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="*", type=Path, help="run or sweep directories")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--windows", type=int, default=None, help="test windows timed (all)")
    ap.add_argument("--dem-frames", type=int, default=None, help="DEM frames timed (all)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out-dir", type=Path, default=None)
    ap.add_argument(
        "--replot", type=Path, default=None, help="redraw the Pareto plot of a time_vs_error.json"
    )
    args = ap.parse_args(argv)
    if args.replot:
        return replot(args.replot)
    set_threads(args.threads)
    if args.quick:
        args.windows = args.windows or 2
        args.dem_frames = args.dem_frames or 3
    out = args.out_dir or (
        Path(tempfile.mkdtemp(prefix="gripdem-time-vs-error-"))
        if args.quick
        else Path("experiments/results")
    )
    out.mkdir(parents=True, exist_ok=True)
    run_dirs = args.runs
    if not run_dirs:
        if not args.quick:
            ap.error("give run or sweep directories (or --quick to train smoke models)")
        run_dirs = train_smoke_runs(out / "runs", ["pbc", "lebc"])
    runs = find_runs(run_dirs)
    header = machine_line()
    print(header, flush=True)

    groups: dict[tuple[str, str], dict] = {}
    dem_cache: dict[tuple[str, int, int], dict] = {}
    for run in runs:
        key = (run.scene, run.split)
        first = key not in groups
        print(f"{run.path}: {run.label}, {run.scene} {run.split}", flush=True)
        rows, info = evaluate_run(run, args.windows, with_baselines=first)
        if first:
            groups[key] = {"rows": [], "info": info, "runs": []}
        at = sum(r.kind == "model" for r in groups[key]["rows"])  # models first, in run order
        groups[key]["rows"][at:at] = [r for r in rows if r.kind == "model"]
        groups[key]["rows"] += [r for r in rows if r.kind == "baseline"]
        groups[key]["runs"].append(str(run.path))
        w = info["first_window"]
        frames_needed = info["windows"] * info["horizon"]
        timed = min(args.dem_frames or frames_needed, frames_needed)
        dem_key = (str(run.data_path), w.sim, timed)
        if dem_key not in dem_cache:
            dem_cache[dem_key] = dem_seconds_per_frame(
                run.data_path, w.sim, w.start + w.history_len, timed
            )
        groups[key]["dem"] = dem_cache[dem_key]

    lines = [
        "# Run time against error",
        "",
        header,
        "",
        "Times are wall-clock seconds for every timed test window's whole horizon, one window "
        "at a time, measured in one process side by side; model times include preparing the "
        "window (HDF5 read, encoding, graph), baseline times the HDF5 read. Break-even: "
        "predicted frames after which the training time (and the DEM time that generated the "
        "training and validation simulations) is paid back by not simulating those frames.",
        "",
    ]
    report = {"machine": header, "quick": bool(args.quick), "groups": []}
    for key in sorted(groups):
        g = groups[key]
        info, d = g["info"], g["dem"]
        frames = info["windows"] * info["horizon"]
        dem = Row(
            f"DEM solver (dt {d['dt']:.3g} s, {d['steps_per_frame']} steps per frame)",
            "dem",
            0.0,
            d["s_per_frame"] * frames,
            frames,
            0.0,
        )
        g["rows"].insert(0, dem)
        extrapolated = (
            f" (timed over {d['frames_timed']} frames, x {frames / d['frames_timed']:.3g})"
            if d["frames_timed"] < frames
            else ""
        )
        lines += [
            f"## {key[0]}, split {key[1]}: {info['windows']} of {info['of_windows']} test "
            f"windows x {info['horizon']} frames, {info['particles']} particles, history "
            f"{info['history_len']}{' (QUICK)' if args.quick else ''}",
            "",
            f"DEM: {1e3 * d['s_per_frame']:.4g} ms per frame{extrapolated}; restart overlap "
            f"max {d['max_overlap_d']:.2g} d.",
            "",
            table(g["rows"][1:], dem),
            "",
        ]
        report["groups"].append(
            {
                "scene": key[0],
                "split": key[1],
                "info": {k: v for k, v in info.items() if k != "first_window"},
                "dem": d,
                "runs": g["runs"],
                "rows": [
                    {
                        "method": r.method,
                        "kind": r.kind,
                        "prep_s": r.prep_s,
                        "predict_s": r.predict_s,
                        "frames": r.frames,
                        "rmse_over_d": r.rmse_over_d,
                        "train_s": r.train_s,
                        "data_s": r.data_s,
                        "break_even_frames": break_even(r.train_s, r.per_frame_s, dem.per_frame_s),
                    }
                    for r in g["rows"]
                ],
            }
        )
    text = "\n".join(lines)
    print("\n" + text)
    (out / "time_vs_error.md").write_text(text + "\n")
    (out / "time_vs_error.json").write_text(json.dumps(report, indent=2, default=str))
    figure = out / "pareto_time_vs_error.png"
    plot(groups, figure, " (QUICK: a few test windows, DEM extrapolated)" if args.quick else "")
    print(f"wrote {out / 'time_vs_error.md'}, {out / 'time_vs_error.json'}, {figure}")
    return report


if __name__ == "__main__":
    main(sys.argv[1:])
