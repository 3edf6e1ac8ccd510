"""Several runs of the surrogate speed benchmark side by side: per scene and size, the median
over each group's runs of the model's ms per frame and its speed-up over the built-in DEM and
LAMMPS, each run's value in brackets (never re-measured here).

    python experiments/analyses/speed_runs.py \\
        --group 0.1.0 A.json B.json C.json --group 0.2.0 D.json E.json F.json \\
        [--out experiments/results/surrogate_speed/speed_runs]

Each JSON is a ``surrogate_speed.py`` report. On a shared machine one run's ratio moves with
the load of the moment (the DEM and the model are timed one after the other), so a group's
median over runs is its figure, and the runs in brackets show the spread; groups compare
where their ranges do not overlap.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from benchlib import add_group_option, group_files, markdown_table, write_report  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def run_figures(report: dict) -> dict[tuple[str, int], dict[str, float]]:
    """(scene, particles) -> model ms per frame, ÷ DEM and ÷ LAMMPS (NaN where not timed)."""
    out = {}
    for row in report["rows"]:
        model = row.get("model", {}).get("s_per_frame")
        if model is None:
            continue
        dem = row.get("dem", {}).get("s_per_frame", np.nan)
        lammps = (row.get("lammps") or {}).get("s_per_frame", np.nan)
        out[(row["scene"], int(row["particles"]))] = {
            "model_ms": 1e3 * model,
            "over_dem": dem / model,
            "over_lammps": lammps / model,
        }
    return out


def cell(values: list[float]) -> str:
    """``median (each run)``; one value alone; a dash where none was timed."""
    values = [v for v in values if np.isfinite(v)]
    if not values:
        return "–"
    shown = ", ".join(f"{v:.3g}" for v in values)
    return shown if len(values) == 1 else f"{np.median(values):.3g} ({shown})"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_group_option(parser, "the surrogate_speed.py JSON reports of its runs")
    parser.add_argument(
        "--out", type=Path, default=ROOT / "experiments/results/surrogate_speed/speed_runs"
    )
    args = parser.parse_args(argv)
    groups = {
        label: [run_figures(json.loads(f.read_text())) for f in files]
        for label, files in group_files(parser, args.group).items()
    }
    keys = sorted(
        {key for runs in groups.values() for run in runs for key in run},
        key=lambda k: (k[0] != "pbc", k[0], k[1]),
    )
    headers = ["scene", "particles"]
    for label in groups:
        headers += [f"{label}: model ms", f"{label}: ÷ DEM", f"{label}: ÷ LAMMPS"]
    rows, data = [], []
    for scene, n in keys:
        row = [scene, n]
        entry = {"scene": scene, "particles": n}
        for label, runs in groups.items():
            for name in ("model_ms", "over_dem", "over_lammps"):
                values = [run[(scene, n)][name] for run in runs if (scene, n) in run]
                row.append(cell(values))
                entry[f"{label}/{name}"] = values
        rows.append(row)
        data.append(entry)
    text = (
        "# Surrogate speed over several runs\n\n"
        "`experiments/benchmarks/surrogate/surrogate_speed.py` reports (one thread each; the model "
        "chained through the stepper with the contact correction, the built-in DEM and LAMMPS "
        "restarted from the same state): per group the median over its runs, each run in "
        "brackets, in the order given.\n\n" + markdown_table(headers, rows)
    )
    write_report(args.out, text, {"rows": data})
    return 0


if __name__ == "__main__":
    sys.exit(main())
