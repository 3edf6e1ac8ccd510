"""The ensemble ablation: one row per model variant and scene, the same columns for all, from the
runs' own outputs (never re-measured here).

    python experiments/analyses/ensemble_ablation.py \\
        --row "pbc|deterministic|runs/pbc_det/metrics.json|bench/pbc.json|pbc (reference)" \\
        --row "pbc|ensemble, CRPS|runs/pbc_ens/metrics.json|bench/pbc.json|pbc" ...
        [--out experiments/results/ensembles/ensemble_ablation]

A row is ``SCENE|LABEL|METRICS.json|SURROGATE.json|ENTRY``: the run's ``metrics.json``
(``python -m gripdem.run``: 190-10 test windows, out of sample; an ensemble's RMSE is its
8-member mean's) and the entry of a ``surrogate_rollout.py`` report (2000 frames of a new DEM
simulation; the worst block, and for an ensemble the worst over the members with
block statistics). The last two may be empty (``||``) when a variant has no surrogate run.

Columns: 190-10 RMSE ÷ CV, CRPS / d, spread/skill at step 1 and step 10, the rank histogram's
extreme bins over uniform; and over 2000 frames: the worst |ratio - 1| of the non-affine MSD at
lags 1, 10, 100, of the RMS non-affine step, of the contacts within 1.01 d, of the flow profile,
the worst g(r) L1, the worst |D / D_truth - 1| over the axes, the spread/skill range over frames
1-100, and the model's ms per member and frame. Writes ``OUT.md`` (the result header, then the
table and its sources) and ``OUT.json`` (the header's fields under ``header``) and prints the table.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "experiments" / "benchmarks"))
from benchlib import machine_line, markdown_table, write_report  # noqa: E402

from gripdem.evaluation.rollout_stats import SURROGATE_TARGETS  # noqa: E402
from gripdem.provenance import relative  # noqa: E402

#: the targets the description line names: (key of SURROGATE_TARGETS, label)
TARGET_LABELS = (
    ("msd", "MSD within"),
    ("coordination", "contacts within"),
    ("profile", "profile within"),
    ("gr_l1", "g(r) L1 at most"),
    ("diffusion", "D within"),
    ("overlap", "overlap at most"),
    ("spread_skill", "spread/skill"),
    ("rank_over_uniform", "rank bins"),
)


def _target(value) -> str:
    """A target as the description line writes it: a bound, or a range ``low-high``."""
    return f"{value[0]:g}-{value[1]:g}" if isinstance(value, tuple) else f"{value:g}"


HEADERS = [
    "scene",
    "variant",
    "190-10 RMSE ÷ CV",
    "CRPS / d",
    "spread/skill step 1 / 10",
    "rank bins ÷ uniform",
    "MSD 1/10/100 dev.",
    "RMS non-aff. dev.",
    "contacts dev.",
    "profile dev.",
    "g(r) L1",
    "D dev.",
    "spread/skill fr. 1-100",
    "rank bins fr. 1-100",
    "overlap % (worst frame)",
    "ms / member / frame (members together; load varied)",
]


def _fmt(value: float, digits: int = 3) -> str:
    return (
        "–"
        if value is None or (isinstance(value, float) and math.isnan(value))
        else (f"{value:.{digits}g}")
    )


def _range(blocks: list[dict], key: str) -> list[float]:
    values = [b[key] for b in blocks if not math.isnan(b.get(key, math.nan))]
    return [min(values), max(values)] if values else [math.nan, math.nan]


def statistics_ranges(entry: dict) -> dict:
    """Ranges ``[low, high]`` of a ``surrogate_rollout.py`` entry's statistics over its blocks
    and members (model / truth ratios; g(r) L1 and overlap % their largest; spread/skill and
    the rank histogram's bins ÷ uniform over frames 1-100, absent for a single member)."""
    blocks = entry["blocks"]["blocks"] + [b for m in entry.get("member_blocks", []) for b in m]
    out = {f"msd_{lag}": _range(blocks, f"ratio/msd_{lag}_over_d2") for lag in (1, 10, 100)}
    for name in ("rms_non_affine_over_d", "coordination", "profile"):
        out[name] = _range(blocks, f"ratio/{name}")
    out["gr_l1"] = max(b["gr_l1"] for b in blocks)
    out["overlap_pct"] = 100 * max(b["model/overlap_max"] for b in blocks)
    if "diffusion" in entry:
        truth = entry["diffusion"]["truth"]
        ratios = [
            v / t for m in entry["diffusion"]["members"] for v, t in zip(m, truth, strict=True)
        ]
        out["diffusion"] = [min(ratios), max(ratios)]
    if entry.get("spread_skill"):
        out["spread_skill"] = [min(entry["spread_skill"]), max(entry["spread_skill"])]
    rank = entry.get("rank_histogram")
    if rank:
        out["rank_over_uniform"] = [min(rank) * len(rank), max(rank) * len(rank)]
    return out


def _dev(span: list[float] | None) -> float:
    """The worst |ratio - 1| of a range."""
    return math.nan if span is None else max(abs(span[0] - 1), abs(span[1] - 1))


def _span(span: list[float] | None) -> str:
    return "–" if span is None else f"{span[0]:.2f}-{span[1]:.2f}"


def run_columns(metrics: dict) -> list[str]:
    ss = [metrics.get(f"test/spread_skill_step/{s:03d}") for s in (1, 10)]
    rank = (metrics.get("test/rank_min_over_uniform"), metrics.get("test/rank_max_over_uniform"))
    return [
        _fmt(metrics["test/rmse_ratio_constant_velocity"]),
        _fmt(metrics["test/crps_over_d"]),
        "–" if ss[0] is None else f"{ss[0]:.2f} / {ss[1]:.2f}",
        "–" if rank[0] is None else f"{rank[0]:.2f}-{rank[1]:.2f}",
    ]


def surrogate_columns(entry: dict | None) -> list[str]:
    if entry is None:
        return ["–"] * 10
    r = statistics_ranges(entry)
    return [
        " / ".join(_fmt(_dev(r[f"msd_{lag}"]), 2) for lag in (1, 10, 100)),
        _fmt(_dev(r["rms_non_affine_over_d"]), 2),
        _fmt(_dev(r["coordination"]), 2),
        _fmt(_dev(r["profile"]), 2),
        _fmt(r["gr_l1"], 2),
        _fmt(_dev(r.get("diffusion")), 2),
        _span(r.get("spread_skill")),
        _span(r.get("rank_over_uniform")),
        _fmt(r["overlap_pct"], 2),
        _fmt(entry["model_ms_per_frame"], 3),
    ]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--row", action="append", required=True, metavar="SCENE|LABEL|M|S|E")
    parser.add_argument(
        "--out", type=Path, default=ROOT / "experiments/results/ensembles/ensemble_ablation"
    )
    args = parser.parse_args(argv)
    rows, sources, blocks = [], [], set()
    for spec in args.row:
        scene, label, metrics_path, surrogate_path, entry_name = spec.split("|")
        metrics = json.loads(Path(metrics_path).read_text())
        entry = None
        if surrogate_path:
            entry = json.loads(Path(surrogate_path).read_text())["scenes"][entry_name]
            blocks.add(entry["blocks"]["block"])
        rows.append([scene, label, *run_columns(metrics), *surrogate_columns(entry)])
        sources.append(
            f"- {scene}, {label}: {relative(metrics_path)}"
            + (f", {relative(surrogate_path)} [{entry_name}]" if entry else "")
        )
    if len(blocks) > 1:
        raise SystemExit(f"error: the rows' surrogate runs use different blocks {sorted(blocks)}")
    block = blocks.pop() if blocks else 0
    text = "\n".join(
        [
            machine_line(),
            "",
            "Ensemble ablation (seed 0 unless the row says; 190-10 test windows out of sample; "
            f"2000-frame surrogate runs on a new DEM simulation, worst {block}-frame block and "
            "worst member; dev.: the worst |model / truth - 1|). "
            "Targets (`gripdem.evaluation.rollout_stats.SURROGATE_TARGETS`): "
            + ", ".join(
                f"{label} {_target(SURROGATE_TARGETS[key])}" for key, label in TARGET_LABELS
            )
            + ".",
            "",
            markdown_table(HEADERS, rows),
            "",
            "Sources:",
            *sources,
            "",
        ]
    )
    write_report(args.out, text, {"headers": HEADERS, "rows": rows})


if __name__ == "__main__":
    main()
