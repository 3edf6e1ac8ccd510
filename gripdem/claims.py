"""``python -m gripdem.claims SWEEP_DIR...``: the paper's claims (docs/spec/evaluation.md#claims)
tested over seeds as hypotheses, written to ``claims.md`` (:mod:`gripdem.evaluation.claims`)
after the result header (:func:`gripdem.provenance.result_header`)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from gripdem.evaluation.claims import evaluate, to_markdown
from gripdem.evaluation.sweep_summary import runs_by_group
from gripdem.provenance import result_fields, write_result
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
    command = [__file__, *(sys.argv[1:] if argv is None else argv)]
    return run_command(
        "gripdem.claims", lambda: _claims(args, command), "claims.md not written", error_status=2
    )


def _claims(args, command: list[str]) -> int:
    groups = runs_by_group(args.sweeps)
    if not groups:
        print(f"error: no finished runs in {', '.join(args.sweeps)}", file=sys.stderr)
        return 2
    markdown = to_markdown(evaluate(groups, args.grip, args.pct, args.vct))
    path = Path(args.out or args.sweeps[0]) / "claims.md"
    write_result(path, markdown, result_fields(command))
    print(markdown)
    print(f"written: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
