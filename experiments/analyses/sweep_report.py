"""Results of a model x split x seed sweep: tables (mean ± std over seeds) and figures.

    python experiments/analyses/sweep_report.py SWEEP_DIR [SWEEP_DIR ...]
        [--out experiments/figures] [--name results]

Reads every job's ``metrics.json`` (through :func:`gripdem.evaluation.sweep_summary.collect`),
groups the jobs by (scene, split, model) over seeds and writes into ``--out`` (file names from
``--name``, default ``results``):

- ``results.md`` (after the result header): per scene, RMSE / d and the ratio to constant
  velocity (CV) and to the linear AR baseline as mean ± std over seeds, beside CV, AR and the
  mean-flow profile, LE crossers separately (model / CV / AR with their count), the model's
  overlap fraction at the last predicted step (particles within 0.98 d of a neighbour; the truth
  has none), training seconds;
- ``results_rmse_by_split.png``: RMSE / d against the split for every model and baseline, both
  scenes (the paper's first figure, out of sample, with seed error bars);
- ``results_ratio_to_cv.png``: RMSE / CV per split and model (below 1: better than CV);
- ``results_time_to_accuracy.png``: validation RMSE / CV against training seconds at the
  shortest split (every seed drawn).

Baselines do not depend on the model or the seed (the same test windows), so their columns are
the mean over the group's jobs.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from gripdem.evaluation.sweep_summary import runs_by_group
from gripdem.plots.common import save_figure
from gripdem.provenance import write_result

SPLIT_ORDER = ("190-10", "180-20", "150-50", "100-100")
BASELINES = ("constant_velocity", "linear_ar", "mean_flow")
LABELS = {"constant_velocity": "CV", "linear_ar": "linear AR", "mean_flow": "mean flow"}


def _stats(values) -> tuple[float, float, int]:
    values = [v for v in values if isinstance(v, (int, float)) and math.isfinite(v)]
    if not values:
        return math.nan, math.nan, 0
    std = statistics.stdev(values) if len(values) > 1 else math.nan
    return statistics.fmean(values), std, len(values)


def _pm(values, digits: int = 3) -> str:
    mean, std, n = _stats(values)
    if n == 0:
        return "–"
    if n == 1 or math.isnan(std):
        return f"{mean:.{digits}g}"
    return f"{mean:.{digits}g} ± {std:.1g}"


def load(sweeps: list[str]) -> dict[tuple[str, str, str], list[dict]]:
    """``{(scene, split, model): [metrics of each finished seed]}``."""
    return runs_by_group(sweeps)


def _split_key(split: str) -> tuple:
    return (SPLIT_ORDER.index(split), split) if split in SPLIT_ORDER else (99, split)


MODEL_ORDER = ("contact", "grip", "pct", "vct")


def _model_key(model: str) -> tuple:
    return (MODEL_ORDER.index(model), "") if model in MODEL_ORDER else (len(MODEL_ORDER), model)


def _models(groups) -> list[str]:
    return sorted({k[2] for k in groups}, key=_model_key)


def _overlap(metrics: dict) -> float:
    """The model's fraction of particles within 0.98 d of a neighbour at the last predicted step
    (the truth has none): the physics report's key, or the one of runs made before it."""
    for key in ("test/physics/model/overlap_fraction", "test/physics/overlap_fraction"):
        if key in metrics:
            return metrics[key]
    return math.nan


def results_markdown(groups) -> str:
    lines = []
    for scene in sorted({k[0] for k in groups}):
        keys = sorted(
            (k for k in groups if k[0] == scene), key=lambda k: (_split_key(k[1]), _model_key(k[2]))
        )
        le = any("test/n_crossers" in m for k in keys for m in groups[k])
        lines += [f"### {scene}", ""]
        header = [
            "split",
            "model",
            "seeds",
            "RMSE / d",
            "÷ CV",
            "÷ AR",
            "CV",
            "AR",
            "mean flow",
        ]
        if le:
            header += ["crossers: model / CV / AR (n)"]
        header += ["overlap %", "train s"]
        lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for key in keys:
            runs = groups[key]
            row = [key[1], key[2], str(len(runs))]
            row.append(_pm([m["test/rmse_over_d"] for m in runs]))
            row.append(_pm([m["test/rmse_ratio_constant_velocity"] for m in runs]))
            row.append(_pm([m.get("test/rmse_ratio_linear_ar", math.nan) for m in runs]))
            for name in BASELINES:
                row.append(f"{_stats([m.get(f'test/rmse_{name}_over_d') for m in runs])[0]:.4g}")
            if le:
                d = runs[0]["test/rmse"] / runs[0]["test/rmse_over_d"]
                model = _pm([m["test/rmse_crossers"] / d for m in runs])
                cv = _stats([m["test/rmse_constant_velocity_crossers"] / d for m in runs])[0]
                ar = _stats([m.get("test/rmse_linear_ar_crossers", math.nan) / d for m in runs])[0]
                n = int(runs[0]["test/n_crossers"])
                row.append(f"{model} / {cv:.3g} / {ar:.3g} ({n})")
            row.append(_pm([100 * _overlap(m) for m in runs], 2))
            row.append(f"{_stats([m['train_seconds'] for m in runs])[0]:.0f}")
            lines.append("| " + " | ".join(row) + " |")
        lines.append("")
    return "\n".join(lines)


def _figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height), dpi=110, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def plot_rmse_by_split(groups, ratio: bool) -> Figure:
    scenes = sorted({k[0] for k in groups})
    fig = _figure(5.2 * len(scenes), 4.2)
    models = _models(groups)
    for col, scene in enumerate(scenes):
        ax = fig.add_subplot(1, len(scenes), col + 1)
        splits = sorted({k[1] for k in groups if k[0] == scene}, key=_split_key)
        x = np.arange(len(splits))
        width = 0.8 / max(1, len(models))
        for i, model in enumerate(models):
            key = "test/rmse_ratio_constant_velocity" if ratio else "test/rmse_over_d"
            stats = [_stats([m[key] for m in groups.get((scene, s, model), [])]) for s in splits]
            mean = np.array([s[0] for s in stats])
            std = np.nan_to_num(np.array([s[1] for s in stats]))
            if ratio:
                ax.bar(x + (i - (len(models) - 1) / 2) * width, mean, width, yerr=std, label=model)
            else:
                ax.errorbar(x, mean, yerr=std, marker="o", capsize=3, lw=2, label=model)
        if ratio:
            ax.axhline(1.0, color="k", lw=1, label="constant velocity")
            cv_over_ar = [
                _stats(
                    [
                        m["test/rmse_constant_velocity"] / m["test/rmse_linear_ar"]
                        for k in groups
                        if k[0] == scene and k[1] == s
                        for m in groups[k]
                    ]
                )[0]
                for s in splits
            ]
            ax.plot(x, 1 / np.array(cv_over_ar), "k--", marker="s", lw=1, label="linear AR")
            ax.set_ylabel("test RMSE / constant velocity's")
            top = ax.get_ylim()[1]
            ax.set_ylim(0, max(1.1, min(top, 1.6)))
        else:
            for name, style in zip(BASELINES, ("--", ":", "-."), strict=True):
                base = [
                    _stats(
                        [
                            m.get(f"test/rmse_{name}_over_d")
                            for k in groups
                            if k[0] == scene and k[1] == s
                            for m in groups[k]
                        ]
                    )[0]
                    for s in splits
                ]
                ax.plot(x, base, style, color="gray", marker="s", lw=1.2, label=LABELS[name])
            ax.set_yscale("log")
            ax.set_ylabel("test RMSE / d (particle diameters)")
        ax.set_xticks(x, splits)
        ax.set_xlabel("split (history-horizon)")
        ax.set_title(f"{scene}: out of sample, mean ± std over seeds", fontsize=10)
        ax.grid(alpha=0.3, axis="y")
        ax.legend(fontsize=7)
    return fig


def plot_time_to_accuracy(groups) -> Figure | None:
    fig = _figure(5.2, 4.0)
    ax = fig.add_subplot()
    drawn = False
    colours = {}
    for (scene, split, model), runs in sorted(groups.items(), key=lambda kv: _model_key(kv[0][2])):
        if split != min((k[1] for k in groups if k[0] == scene), key=_split_key):
            continue
        for run in runs:
            curve = run.get("accuracy_curve")
            if not curve or not isinstance(curve, str):
                continue
            points = np.array(json.loads(curve))
            label = f"{scene} {model}"
            colour = colours.setdefault(model, f"C{len(colours)}")
            ax.plot(
                points[:, 0],
                points[:, 2],
                marker="o" if scene == "pbc" else "s",
                ls="-" if scene == "pbc" else "--",
                ms=3,
                color=colour,
                label=label if label not in ax.get_legend_handles_labels()[1] else None,
            )
            drawn = True
    if not drawn:
        return None
    ax.axhline(1.0, color="k", lw=1)
    ax.set_xlabel("training seconds")
    ax.set_ylabel("validation RMSE / constant velocity's")
    ax.set_title("Time to accuracy (each seed drawn)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return fig


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sweeps", nargs="+", help="multirun folders")
    parser.add_argument("--out", default="experiments/figures", help="output folder")
    parser.add_argument(
        "--name", default="results", help="file stem: NAME.md, NAME_rmse_by_split.png, ..."
    )
    args = parser.parse_args(argv)
    groups = load(args.sweeps)
    if not groups:
        print(
            "error: no finished jobs (metrics.json) in " + ", ".join(args.sweeps), file=sys.stderr
        )
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    markdown = results_markdown(groups)
    write_result(out / f"{args.name}.md", markdown)
    print(markdown)
    figures = {
        f"{args.name}_rmse_by_split": plot_rmse_by_split(groups, ratio=False),
        f"{args.name}_ratio_to_cv": plot_rmse_by_split(groups, ratio=True),
        f"{args.name}_time_to_accuracy": plot_time_to_accuracy(groups),
    }
    for name, fig in figures.items():
        if fig is not None:
            save_figure(fig, out / f"{name}.png")
            print(f"written: {out / name}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
