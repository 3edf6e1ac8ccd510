"""``python -m gripdem.physics_report PREDICTIONS.h5 [--figure PNG] [--json JSON]``: the physics
report of any predictions file (a run's, or ``gripdem.predict``'s) as a table: the truth, the
model and every baseline side by side (:mod:`gripdem.evaluation.physics_report`)."""

from __future__ import annotations

import argparse
import json
import sys

from gripdem.data.h5io import atomic_path
from gripdem.evaluation.physics_report import physics_report, report_table
from gripdem.evaluation.predictions import read_predictions
from gripdem.plots.common import save_figure
from gripdem.plots.physics import plot_physics
from gripdem.runner.console import run_command


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m gripdem.physics_report",
        description="The physics report of a predictions.h5 (truth, model and baselines side "
        "by side): a Markdown table on stdout, optionally the figure and the scalars as JSON.",
    )
    parser.add_argument("predictions", help="a predictions.h5 (gripdem.run or gripdem.predict)")
    parser.add_argument("--figure", help="write the 2 x 2 physics figure here (PNG)")
    parser.add_argument("--json", help="write the scalars here")
    args = parser.parse_args(argv)
    return run_command(
        "gripdem.physics_report", lambda: _report(args), "files being written are not kept"
    )


def _report(args) -> int:
    p = read_predictions(args.predictions)
    report = physics_report(p)
    print(f"physics report: {p.title()}, {p.n_windows} windows x {p.horizon} steps")
    print(report_table(report))
    if args.figure:
        save_figure(plot_physics(report, p.title(), str(p.info.get("model", "model"))), args.figure)
        print(f"figure: {args.figure}")
    if args.json:
        with atomic_path(args.json, overwrite=True) as tmp:
            with open(tmp, "w") as fh:
                json.dump(report.metrics, fh, indent=1, sort_keys=True)
        print(f"scalars: {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
