"""``python -m gripdem.claims SWEEP_DIR...``: the paper's claims (docs/spec/evaluation.md#claims)
tested over seeds as hypotheses, written to ``claims.md`` (:mod:`gripdem.evaluation.claims`)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from gripdem.data.h5io import atomic_write_text
from gripdem.evaluation.claims import evaluate, to_markdown
from gripdem.evaluation.sweep_summary import runs_by_group
from gripdem.runner.console import run_command


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m gripdem.claims", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("sweeps", nargs="+", help="multirun folders (seeds may be spread)")
    parser.add_argument("--grip", default="grip", help="model name standing for GRIP++")
    parser.add_argument("--pct", default="pct", help="model name standing for PCT")
    parser.add_argument("--vct", default="vct", help="model name standing for VCT")
    parser.add_argument("--out", default=None, help="folder for claims.md (default: first sweep)")
    args = parser.parse_args(argv)
    return run_command(
        "gripdem.claims", lambda: _claims(args), "claims.md not written", error_status=2
    )


def _claims(args) -> int:
    groups = runs_by_group(args.sweeps)
    if not groups:
        print(f"error: no finished runs in {', '.join(args.sweeps)}", file=sys.stderr)
        return 2
    markdown = to_markdown(evaluate(groups, args.grip, args.pct, args.vct))
    path = atomic_write_text(Path(args.out or args.sweeps[0]) / "claims.md", markdown, True)
    print(markdown)
    print(f"written: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
