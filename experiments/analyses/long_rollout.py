"""A long chained rollout of a trained model against the truth and the baselines.

    python experiments/analyses/long_rollout.py CHECKPOINT DATA.h5 [--frames 1000] [--start 0]
        [--sim 0] [--steps 0 1] [--workdir DIR] [--figure experiments/figures/NAME.png]

Runs ``python -m gripdem.predict`` once per link length in ``--steps`` (the model chains its
own predictions, that many frames per link; 0: its horizon; the baselines roll out from the
same observed frames in one go), then prints and plots,
per predicted frame: the RMSE / d of the model and every baseline, the model / CV ratio, the
fraction of particles with a neighbour closer than 0.98 d for the model, constant velocity and
the truth, the mean-flow strain and the RMS step of the model's frames against the truth's, and
the largest single-particle step. ``DATA.h5`` needs ``start + history_len + 1 + frames`` frames
for a truth at every predicted frame (``python -m gripdem.simulate scene=lebc
preset.frames=1100 sims=1 seed=1234 out=...`` for 1000 frames of the default LE scene, out of
sample).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from gripdem.boundary import affine_flow_strain, displacement  # noqa: E402
from gripdem.evaluation.physics import overlap_fraction  # noqa: E402
from gripdem.evaluation.predictions import read_predictions  # noqa: E402
from gripdem.predict import build_parser, predict  # noqa: E402

COLORS = {
    "model": "k",
    "stay": "C7",
    "constant_velocity": "C1",
    "linear_ar": "C2",
    "mean_flow": "C3",
    "truth": "C0",
}


def step_statistics(positions, times, p) -> tuple[np.ndarray, np.ndarray]:
    """Per step of a trajectory ``(frames, N, 3)``: the mean-flow strain it implies (slope of
    the z step against x at the step's middle; imposed: ``shear_rate * dt``) and the RMS step
    length. Steps are LE minimum images with the later frame's offset
    (docs/spec/conventions.md#which-offset)."""
    offsets = p.boundary.offset(times)
    steps = displacement(positions[1:], positions[:-1], p.box, offsets[1:, None])
    x = positions[:-1, :, 0] + 0.5 * steps[..., 0]
    strain = np.array([np.polyfit(x[j], steps[j, :, 2], 1)[0] for j in range(len(steps))])
    return strain, np.sqrt((steps**2).sum(-1).mean(-1))


def run_once(args, step: int | None, work: Path) -> dict:
    """One ``gripdem.predict`` rollout; the model's curves (and the predictions file)."""
    argv = [args.checkpoint, args.data, "--frames", str(args.frames), "--start", str(args.start)]
    argv += ["--sims", str(args.sim), "--out", str(work / "pred.h5"), "--overwrite"]
    argv += [] if step is None else ["--step", str(step)]
    started = time.perf_counter()
    report = predict(build_parser().parse_args(argv))
    seconds = time.perf_counter() - started
    print("\n".join(report["_lines"]) + f"\n({seconds:.0f} s)\n")
    p = read_predictions(work / "pred.h5")
    times = np.concatenate([[p.times[0, 0] - p.frame_interval], p.times[0]])
    imposed = affine_flow_strain(p.boundary, p.frame_interval)
    model = step_statistics(np.concatenate([p.last_positions[:1], p.pred_positions[0]]), times, p)
    truth = step_statistics(np.concatenate([p.last_positions[:1], p.true_positions[0]]), times, p)
    return {
        "label": f"model, links of {report['step']}",
        "p": p,
        "report": report,
        "rmse": np.array(report["rmse_over_d"]["model"]),
        "overlap": np.array(report["divergence"]["overlap"][: p.horizon]),
        "speed": model[1] / truth[1],
        "strain": model[0] / imposed,
        "strain_truth": truth[0] / imposed,
        "max_step": np.array(report["divergence"]["max_step_over_d"]),
        "first": report["divergence"]["first"],
        "seconds": seconds,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("data")
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--start", type=int, default=0)
    parser.add_argument("--sim", type=int, default=0)
    parser.add_argument(
        "--steps", type=int, nargs="+", default=[0], help="link lengths (0: the horizon)"
    )
    parser.add_argument("--workdir", type=Path)
    parser.add_argument("--figure", type=Path, default=Path("experiments/figures/long_rollout.png"))
    args = parser.parse_args()
    work = args.workdir or Path(tempfile.mkdtemp(prefix="gripdem-rollout-"))
    runs = []
    for step in args.steps:
        (work / f"step{step}").mkdir(parents=True, exist_ok=True)
        runs.append(run_once(args, step or None, work / f"step{step}"))
    p, report = runs[0]["p"], runs[0]["report"]
    n = p.horizon
    baselines = {k: np.array(v) for k, v in report["rmse_over_d"].items() if k != "model"}
    cv = baselines["constant_velocity"]
    offsets = p.offsets()[0]
    overlap = {
        name: np.array(
            [overlap_fraction(pos[0, j], p.box, p.diameter, offsets[j]) for j in range(n)]
        )
        for name, pos in (
            ("constant_velocity", p.baselines["constant_velocity"]),
            ("truth", p.true_positions),
        )
    }
    marks = [m for m in (1, 10, 30, 100, 300, 1000) if m <= n]
    print("RMSE / d at predicted frame (overlap: fraction of particles closer than 0.98 d)")
    print("frame " + "".join(f"{k:>19s}" for k in baselines) + "".join(
        f"{r['label']:>26s}" for r in runs) + "   overlap CV/truth")  # fmt: skip
    for m in marks:
        row = f"{m:5d} " + "".join(f"{baselines[k][m - 1]:19.4g}" for k in baselines)
        for r in runs:
            cell = f"{r['rmse'][m - 1]:.4g} ({r['rmse'][m - 1] / cv[m - 1]:.2f} CV)"
            row += f"{cell:>26s}"
        row += f"   {overlap['constant_velocity'][m - 1]:.3f}/{overlap['truth'][m - 1]:.3f}"
        print(row)
    for r in runs:
        print(f"\n{r['label']} ({r['seconds']:.0f} s):")
        for name in ("constant_velocity", "linear_ar", "mean_flow"):
            behind = np.nonzero(r["rmse"] > baselines[name])[0]
            print(f"  worse than {name} from predicted frame "
                  f"{behind[0] + 1 if behind.size else 'never'}")  # fmt: skip
        for key, what in (
            ("overlap", "overlap fraction"),
            ("speed", "RMS step / truth's"),
            ("strain", "mean-flow strain / imposed"),
            ("max_step", "largest single-particle step (d)"),
        ):
            print(f"  {what} at frames {marks}: "
                  + ", ".join(f"{r[key][m - 1]:.3g}" for m in marks))  # fmt: skip
        print(f"  divergence flags (first predicted frame): {json.dumps(r['first'])}")

    frames = np.arange(1, n + 1)
    fig, axes = plt.subplots(2, 2, figsize=(13, 9))
    axes = axes.ravel()
    dashes = ["-", "--", ":", "-."]
    for name, values in baselines.items():
        axes[0].loglog(frames, values, label=name, color=COLORS[name], lw=1)
    for r, ls in zip(runs, dashes, strict=False):
        axes[0].loglog(frames, r["rmse"], label=r["label"], color="k", ls=ls, lw=2)
        axes[1].semilogx(frames, r["rmse"] / cv, label=f"{r['label']} / CV", color="k", ls=ls)
        axes[2].semilogx(frames, r["overlap"], label=r["label"], color="k", ls=ls)
        axes[3].loglog(
            frames, r["speed"], color="k", ls=ls, label=f"RMS step / truth, {r['label']}"
        )
    axes[0].set(xlabel="predicted frame", ylabel="RMSE / d", title="error against the truth")
    for name in ("linear_ar", "mean_flow"):
        axes[1].semilogx(frames, baselines[name] / cv, label=f"{name} / CV", color=COLORS[name])
    axes[1].axhline(1.0, color=COLORS["constant_velocity"], lw=0.8)
    axes[1].set(xlabel="predicted frame", ylabel="RMSE ratio to CV", title="relative to CV")
    for name, values in overlap.items():
        axes[2].semilogx(frames, values, label=name, color=COLORS[name])
    axes[2].set(
        xlabel="predicted frame",
        ylabel="fraction of particles",
        title="overlap: a neighbour closer than 0.98 d",
    )
    for r, ls in zip(runs, dashes, strict=False):
        axes[3].loglog(
            frames, r["strain"], color="C4", ls=ls, label=f"mean-flow strain, {r['label']}"
        )
    axes[3].loglog(
        frames, runs[0]["strain_truth"], color=COLORS["truth"], label="mean-flow strain, truth"
    )
    axes[3].axhline(1.0, color="grey", lw=0.8)
    axes[3].set(
        xlabel="predicted frame",
        ylabel="ratio",
        title="motion per frame (strain: / imposed shear x dt)",
    )
    for ax in axes:
        ax.legend(fontsize=8)
    info = p.info
    fig.suptitle(
        f"{n}-frame chained rollouts (horizon {info['horizon']}, history {info['history_len']}), "
        f"{p.boundary.kind}, {p.n_particles} particles, "
        f"{'in' if p.in_sample else 'out of'} sample"
    )
    fig.tight_layout()
    args.figure.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.figure, dpi=110)
    print(f"figure: {args.figure}")


if __name__ == "__main__":
    main()
