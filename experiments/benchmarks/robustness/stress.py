"""Numerical-stability stress cases too slow for the test suite (the fast ones are in
``tests/stress/``). Each case says what was tried, whether it held, and what was measured.

    python experiments/benchmarks/robustness/stress.py --quick   # smoke models trained here
    python experiments/benchmarks/robustness/stress.py RUN_OR_SWEEP_DIR... [--frames 1000] \
        [--windows N]
        [--rollout-splits 190-10 100-100] [--rollout-scenes pbc lebc] [--json F]

Cases:

- **long rollouts**: a trained model chained ``--frames`` (1000) frames on its own
  predictions from the first frames of its test simulation
  (:func:`gripdem.inference.rollout.rollout`, links of its horizon), for every given run whose split
  is 190-10 or 100-100 (``--quick``: smoke models of horizon 5 and 50 on the tiny scenes). Held:
  every frame finite, inside ``[-l/2, l/2)``, no particle stepping more than a quarter box; the
  first frame where the overlap check fires is reported (the packing degrading is the known limit,
  not a failure).
- **bf16 autocast on CPU, trained models**: test windows under ``torch.autocast("cpu",
  bfloat16)`` against float32. Held: positions within 2 % (RMS) of the network's correction
  to constant velocity and RMSE within 1 % (the tolerances of the fast test).
- **bf16-mixed training on CPU** (Lightning ``trainer.precision=bf16-mixed``, smoke preset):
  held if it trains to a finite model whose test RMSE / d is within 5 % of float32 training's.
- **SI units against a unit box, trained**: the smoke preset trained with one seed on the tiny
  dataset in SI units and rescaled to a unit box and a unit frame interval
  (:func:`gripdem.data.units.rescale`). Held: baselines' RMSE / d agree to 1e-9, the trained
  model's to 1e-6 (float32 training on inputs normalised from magnitudes 1e5 apart; measured
  ~1e-11: the normalised inputs agree to float32 round-off and training does not amplify it).
- fp16/bf16 on a GPU: run only where torch sees a CUDA device (not measured otherwise).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np
import torch

sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # benchlib: it adds the groups
from benchlib import machine_line, markdown_table, scene_dataset, set_threads, train_run  # noqa: E402
from time_vs_error import find_runs, load_run  # noqa: E402
from time_vs_error_timing import test_windows  # noqa: E402

from gripdem.boundary import minimum_image  # noqa: E402
from gripdem.data.batch import collate_windows  # noqa: E402
from gripdem.data.dataset_io import read_dataset, read_meta, write_dataset  # noqa: E402
from gripdem.data.units import rescale  # noqa: E402
from gripdem.evaluation.metrics import position_residuals, rmse  # noqa: E402
from gripdem.inference.checkpoint import load_checkpoint_model, load_model  # noqa: E402
from gripdem.inference.rollout import rollout  # noqa: E402

BF16_CORRECTION_TOLERANCE = 0.02
BF16_RMSE_TOLERANCE = 0.01
BF16_TRAINING_TOLERANCE = 0.05
UNITS_MODEL_TOLERANCE = 1e-6
UNITS_BASELINE_TOLERANCE = 1e-9


def case(name: str, tried: str, held: bool, measured: str) -> dict:
    line = {"case": name, "tried": tried, "held": bool(held), "measured": measured}
    print(json.dumps(line), flush=True)
    return line


# --------------------------------------------------------------------------------------------
# long rollouts
# --------------------------------------------------------------------------------------------
def long_rollout(checkpoint: Path, data_path: Path, frames: int, label: str) -> dict:
    """Chain the model ``frames`` frames from the first observed frames of the data's last
    simulation (the test simulation of the default protocol)."""
    meta = read_meta(data_path)
    model = load_model(checkpoint, meta)
    k, f = int(model.hparams.history_len), int(model.hparams.horizon)
    sim = meta.n_sims - 1
    with h5py.File(data_path, "r") as h5:
        observed = np.asarray(h5["positions"][sim : sim + 1, : k + 1], np.float64)
        times = np.asarray(h5["times"][sim : sim + 1, : k + 1], np.float64)
    start = time.perf_counter()
    run = rollout(model, meta, observed, times, frames)
    seconds = time.perf_counter() - start
    pos = run.predicted
    half = 0.5 * meta.box.lengths
    finite = bool(np.isfinite(pos).all())
    inside = finite and bool(((pos >= -half) & (pos < half)).all())
    div = run.divergence
    escaped = int(sum(div.escaped))
    complete = run.n_predicted == frames
    overlap = div.first.get("overlap")
    worst = int(np.argmax(div.overlap))
    measured = (
        f"{run.n_predicted} frames in {seconds:.0f} s; finite {finite}, inside {inside}, "
        f"escapes {escaped}; largest single step {max(div.max_step_over_d):.3g} d (at the end "
        f"{div.max_step_over_d[-1]:.3g} d); particles within 0.98 d of a neighbour: "
        f"{div.overlap_start:.3f} observed, {div.overlap[worst]:.3f} at most (frame {worst + 1}), "
        f"{div.overlap[-1]:.3f} at the end; overlap flag (observed + 0.05) from frame "
        f"{overlap if overlap else 'never'}"
    )
    return case(
        f"long rollout: {label}",
        f"{frames} frames chained in links of {f} (history {k}), {meta.boundary.kind}, "
        f"{meta.n_particles} particles",
        finite and inside and escaped == 0 and complete,
        measured,
    )


# --------------------------------------------------------------------------------------------
# bf16
# --------------------------------------------------------------------------------------------
def first_link(batch, frames: int):
    """``batch`` cut to its first ``frames`` target frames (one forward pass of the model)."""
    end = batch.history_len + 1 + frames
    return dataclasses.replace(
        batch,
        target_deltas=batch.target_deltas[:, :, :frames],
        target_positions=batch.target_positions[:, :, :frames],
        times=batch.times[:, :end],
        offsets=batch.offsets[:, :end],
        crossing_mask=None,
    )


@torch.no_grad()
def bf16_case(run_dir: Path, n_windows: int | None, device: str = "cpu") -> dict:
    """Test windows of a trained run under autocast against float32."""
    run = load_run(run_dir)
    model = load_checkpoint_model(run.checkpoint).to(device)
    model.eval()
    dm = test_windows(run, model)
    # a model shorter than the split's horizon is chained over the test windows; compare the
    # precisions on one forward pass over the validation windows' first link (with rollout
    # training a validation window spans several links: the frames beyond the first are cut)
    part = "test" if dm.model_horizon == dm.split.horizon else "val"
    link = dm.model_horizon
    dataset = dm.datasets[part]
    n = len(dataset) if n_windows is None else min(n_windows, len(dataset))
    dtypes = {"float32": None, "bfloat16": torch.bfloat16}
    if device == "cuda":
        dtypes["float16"] = torch.float16
    preds = {name: [] for name in dtypes}
    trues, offs, cvs = [], [], []
    for i in range(n):
        batch = first_link(collate_windows([dataset[i]]).to(device), link)
        for name, dtype in dtypes.items():
            with torch.autocast(device, dtype=dtype or torch.bfloat16, enabled=dtype is not None):
                out = model(batch)
            preds[name].append(model.decode(out, batch).cpu())
        trues.append(batch.target_positions.double().transpose(1, 2).cpu())
        offs.append(batch.target_offsets.double().cpu())
        cvs.append(model.predict_baselines(batch)["constant_velocity"].cpu())
    dm.teardown()
    box, le = model.boundary.box, model.boundary.is_lees_edwards
    true, off, cv = torch.cat(trues), torch.cat(offs), torch.cat(cvs)
    off3 = off[..., None] if le else None
    p32 = torch.cat(preds["float32"])
    correction = rmse(minimum_image(p32 - cv, box, off3))
    r32 = rmse(position_residuals(p32, true, box, off if le else None))
    lines, held = [], True
    for name in dtypes:
        if name == "float32":
            continue
        p = torch.cat(preds[name])
        change = rmse(minimum_image(p - p32, box, off3)) / correction
        ratio = rmse(position_residuals(p, true, box, off if le else None)) / r32
        held &= change <= BF16_CORRECTION_TOLERANCE and abs(ratio - 1) <= BF16_RMSE_TOLERANCE
        lines.append(
            f"{name} on {device}: change {100 * change:.2g} % of the correction to CV, "
            f"RMSE x {ratio:.6f}"
        )
    return case(
        f"{'/'.join(n for n in dtypes if n != 'float32')} autocast ({device}): {run.label} "
        f"{run.scene} {run.split}",
        f"{n} {part} windows under autocast against float32 (network correction to CV: "
        f"{correction / r32:.3g} of its RMSE)",
        held,
        "; ".join(lines) + f"; float32 RMSE / d {r32 / model.diameter:.4g}",
    )


def bf16_training_case(work: Path) -> dict:
    """Smoke training in bf16-mixed against 32-true on the tiny periodic scene."""
    results = {}
    for precision in ("32-true", "bf16-mixed"):
        run = train_run(
            work / f"precision_{precision}",
            ["experiment=smoke", "scene=pbc", "torch_threads=1", f"trainer.precision={precision}"],
        )
        results[precision] = json.loads((run / "metrics.json").read_text())
    a, b = results["32-true"], results["bf16-mixed"]
    ratio = b["test/rmse_over_d"] / a["test/rmse_over_d"]
    cv_ratio = b["test/rmse_ratio_constant_velocity"]
    return case(
        "bf16-mixed training on CPU (smoke, pbc)",
        "trainer.precision=bf16-mixed against 32-true, same seed",
        np.isfinite(b["test/rmse"]) and abs(ratio - 1) <= BF16_TRAINING_TOLERANCE,
        f"test RMSE / d {b['test/rmse_over_d']:.5g} vs {a['test/rmse_over_d']:.5g} (x "
        f"{ratio:.4f}); bf16 model / CV {cv_ratio:.4f}; training {b['train_seconds']:.1f} s vs "
        f"{a['train_seconds']:.1f} s",
    )


# --------------------------------------------------------------------------------------------
# SI units against a unit box, trained
# --------------------------------------------------------------------------------------------
def units_case(scene: str, work: Path) -> dict:
    si_path = scene_dataset(scene, "tiny")
    si = read_dataset(si_path)
    unit_path = write_dataset(
        work / f"{scene}_unit.h5", rescale(si, si.box.lx, si.frame_interval), overwrite=True
    )
    metrics = {}
    for name, path in (("si", si_path), ("unit", unit_path)):
        overrides = ["experiment=smoke", f"scene={scene}", "torch_threads=1", f"data.path={path}"]
        run = train_run(work / f"units_{scene}_{name}", overrides)
        metrics[name] = json.loads((run / "metrics.json").read_text())
    keys = ["test/rmse_over_d"] + [
        k for k in metrics["si"] if k.startswith("test/rmse_") and k.endswith("_over_d")
    ]
    worst_baseline, lines = 0.0, []
    for key in dict.fromkeys(keys):
        a, b = metrics["si"][key], metrics["unit"][key]
        rel = abs(b / a - 1)
        if key != "test/rmse_over_d":
            worst_baseline = max(worst_baseline, rel)
        lines.append(f"{key.removeprefix('test/').removesuffix('_over_d')} {a:.5g} / {b:.5g}")
    model_rel = abs(metrics["unit"]["test/rmse_over_d"] / metrics["si"]["test/rmse_over_d"] - 1)
    return case(
        f"SI units vs unit box, trained ({scene})",
        "smoke preset trained with seed 0 on the tiny dataset in SI units and rescaled to box 1, "
        "frame interval 1",
        model_rel <= UNITS_MODEL_TOLERANCE and worst_baseline <= UNITS_BASELINE_TOLERANCE,
        f"RMSE / d SI / unit: {', '.join(lines)}; model differs by {model_rel:.2g}, baselines by "
        f"at most {worst_baseline:.2g} (relative)",
    )


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="*", type=Path, help="run or sweep directories")
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--windows", type=int, default=None, help="test windows for bf16 (all)")
    ap.add_argument("--rollout-splits", nargs="+", default=["190-10", "100-100"])
    ap.add_argument(
        "--rollout-scenes",
        nargs="+",
        default=["pbc", "lebc"],
        help="scenes whose runs are rolled out (the docs' 1000-frame lebc rollout of the "
        "default model exists: --rollout-scenes pbc reuses it)",
    )
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    set_threads(args.threads)
    work = Path(tempfile.mkdtemp(prefix="gripdem-stress-"))
    cases = []
    if args.runs:
        runs = find_runs(args.runs)
    elif args.quick:
        runs = []
        for scene in ("pbc", "lebc"):
            base = ["experiment=smoke", f"scene={scene}", "torch_threads=1"]
            runs.append(load_run(train_run(work / f"smoke_{scene}", base)))
            long = [*base, "split.horizon=50", "trainer.max_epochs=4"]
            runs.append(load_run(train_run(work / f"smoke_{scene}_h50", long)))
    else:
        ap.error("give run or sweep directories (or --quick to train smoke models)")
    for run in runs:
        if run.scene in args.rollout_scenes and (args.quick or run.split in args.rollout_splits):
            label = f"{run.label} {run.scene} {run.split}"
            cases.append(long_rollout(run.checkpoint, run.data_path, args.frames, label))
    for run in runs:
        cases.append(bf16_case(run.path, args.windows))
        if torch.cuda.is_available():
            cases.append(bf16_case(run.path, args.windows, device="cuda"))
    cases.append(bf16_training_case(work))
    for scene in ("pbc", "lebc"):
        cases.append(units_case(scene, work))
    header = machine_line()
    rows = [[c["case"], c["tried"], "yes" if c["held"] else "NO", c["measured"]] for c in cases]
    print(f"\n{header}{' (QUICK)' if args.quick else ''}\n")
    print(markdown_table(["case", "tried", "held", "measured"], rows))
    if not torch.cuda.is_available():
        print("\nfp16/bf16 on a GPU: not measured (torch sees no CUDA device)")
    report = {"machine": header, "quick": args.quick, "cases": cases}
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    failed = [c["case"] for c in cases if not c["held"]]
    if failed:
        print(f"\ncases that did not hold: {failed}")
        sys.exit(1)
    return report


if __name__ == "__main__":
    main(sys.argv[1:])
