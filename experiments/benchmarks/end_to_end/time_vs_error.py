"""Run time against error: trained models vs the DEM solver vs the baselines, per scene and split.

    python experiments/benchmarks/end_to_end/time_vs_error.py RUN_OR_SWEEP_DIR... [--dem-frames N]
        [--windows N] [--threads 1] [--out-dir experiments/results/time_vs_error]
    python experiments/benchmarks/end_to_end/time_vs_error.py --quick   # two smoke models first

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

Writes ``time_vs_error.md`` (the result header, then one table per scene and split, the machine
line above them), ``time_vs_error.json`` (the header's fields under ``header``) and the Pareto
plot ``pareto_time_vs_error.png`` (wall time on a log axis against RMSE / d, the non-dominated
points joined) into ``--out-dir``. ``--quick`` (the slow test tier): two windows, three DEM
frames, and without run directories it first trains the smoke preset (``experiment=smoke``, tiny
scene, seconds) on both scenes.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # benchlib: it adds the groups
from benchlib import machine_line, set_threads, train_run, write_report  # noqa: E402
from omegaconf import OmegaConf  # noqa: E402
from time_vs_error_report import Row, break_even, plot, replot, table  # noqa: E402
from time_vs_error_timing import (  # noqa: E402
    Run,
    data_seconds,
    dem_seconds_per_frame,
    read_seconds,
    rmse_over_d,
    test_windows,
    time_baseline,
    time_model,
)

from gripdem.inference.checkpoint import load_checkpoint_model  # noqa: E402
from gripdem.models.autoregressive import fit_on_training_frames  # noqa: E402

BASELINE_NAMES = ("stay", "constant_velocity", "mean_flow", "linear_ar")


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


# --------------------------------------------------------------------------------------------
# one scene/split
# --------------------------------------------------------------------------------------------
def evaluate_run(run: Run, n_windows: int | None, with_baselines: bool) -> tuple[list, dict]:
    model = load_checkpoint_model(run.checkpoint)
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
        else Path("experiments/results/time_vs_error")
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
    write_report(out / "time_vs_error", text, report, echo=False)
    figure = out / "pareto_time_vs_error.png"
    plot(groups, figure, " (QUICK: a few test windows, DEM extrapolated)" if args.quick else "")
    print(f"wrote {out / 'time_vs_error.md'}, {out / 'time_vs_error.json'}, {figure}")
    return report


if __name__ == "__main__":
    main(sys.argv[1:])
