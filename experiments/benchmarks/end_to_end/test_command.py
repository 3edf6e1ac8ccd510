"""How long does the README's test command take? Runs the default tier as ``.ci/run`` does
(``python -m pytest -n auto``, after the install) and writes its wall time, CPU time and
outcome counts.

    python experiments/benchmarks/end_to_end/test_command.py
        [--out experiments/results/test_suite/test_command] [PYTEST_ARGS...]

The install is not timed (it depends on the package index's cache); run it on a checkout whose
``.venv`` is set up. Writes ``OUT.md`` and ``OUT.json`` with the result header (date, commit,
CPU model, threads, command).
"""

from __future__ import annotations

import argparse
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchlib import available_cpus, cpu_model, markdown_table, write_report  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
OUTCOMES = ("passed", "failed", "skipped", "deselected", "xfailed", "errors")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--out", type=Path, default=ROOT / "experiments/results/test_suite/test_command"
    )
    args, pytest_args = parser.parse_known_args(argv)
    command = [sys.executable, "-m", "pytest", "-n", "auto", "-q", *pytest_args]
    start = time.perf_counter()
    proc = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - start
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    summary = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else ""
    counts = {k: int(n) for n, k in re.findall(r"(\d+) (\w+)", summary) if k in OUTCOMES}
    minutes, seconds = divmod(round(wall), 60)
    row = {
        "command": "python -m pytest -n auto",
        "wall_s": round(wall, 1),
        "wall": f"{minutes} min {seconds:02d} s",
        "cpu_min": round((usage.ru_utime + usage.ru_stime) / 60, 1),
        "cpus": available_cpus(),
        "cpu_model": cpu_model(),
        "returncode": proc.returncode,
        **counts,
    }
    table = markdown_table(
        ["command", "CPU", "wall", "CPU-minutes", "passed", "skipped", "failed", "status"],
        [
            [
                f"`{row['command']}`",
                f"{row['cpu_model']} ({row['cpus']} CPUs)",
                row["wall"],
                f"{row['cpu_min']:.1f}",
                counts.get("passed", 0),
                counts.get("skipped", 0),
                counts.get("failed", 0) + counts.get("errors", 0),
                "ok" if proc.returncode == 0 else f"exit {proc.returncode}",
            ]
        ],
    )
    write_report(args.out, f"The default test tier, install excluded.\n\n{table}", row)
    if proc.returncode != 0:
        print(proc.stdout[-4000:], proc.stderr[-2000:], sep="\n", file=sys.stderr)
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())
