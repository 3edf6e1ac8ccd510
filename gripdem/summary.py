"""``python -m gripdem.summary SWEEP_DIR``: one summary table of a Hydra multirun's jobs
(Markdown and CSV; :mod:`gripdem.evaluation.sweep_summary`)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from gripdem.evaluation.sweep_summary import DEFAULT_METRICS, write_summary
from gripdem.runner.console import run_command


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m gripdem.summary",
        description="Summarise the jobs of a Hydra multirun in one table (Markdown and CSV).",
    )
    parser.add_argument("sweep_dir", help="the multirun folder (e.g. multirun/2025-01-31/12-00-00)")
    parser.add_argument("--out-dir", default=None, help="where to write (default: sweep_dir)")
    parser.add_argument(
        "--metrics",
        nargs="+",
        default=list(DEFAULT_METRICS),
        metavar="PATTERN",
        help="glob patterns of metric keys to show",
    )
    args = parser.parse_args(argv)

    def body() -> int:
        md, csv_path, markdown = write_summary(args.sweep_dir, args.out_dir, args.metrics)
        print(markdown, end="")
        print(f"\nwritten: {md}\n         {csv_path}")
        return 0

    return run_command("gripdem.summary", body, "the summary files are not written", 2)


if __name__ == "__main__":
    sys.exit(main())
