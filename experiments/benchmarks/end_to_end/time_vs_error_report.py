"""Tables and the Pareto plot of ``time_vs_error.py`` (a sibling module of the script): one
Markdown table per scene and split, the Pareto front of wall time against RMSE, and ``--replot``
from a saved JSON."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
from dataclasses import dataclass, field

import matplotlib
import matplotlib.pyplot as plt  # noqa: E402

sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # benchlib: it adds the groups
from benchlib import fmt, markdown_table  # noqa: E402

matplotlib.use("Agg")


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


def break_even(train_s: float | None, per_frame: float, dem_per_frame: float) -> float:
    """Predicted frames after which ``train_s`` is paid back (inf: never)."""
    if train_s is None:
        return math.nan
    gain = dem_per_frame - per_frame
    return train_s / gain if gain > 0 else math.inf
