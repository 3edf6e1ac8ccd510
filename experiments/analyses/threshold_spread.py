"""Do the tests' thresholds hold on any CPU and thread count? The suite run under every
combination of ATEN_CPU_CAPABILITY and torch threads, with every numeric check written down.

    python experiments/analyses/threshold_spread.py [--capabilities default avx2 avx512]
        [--threads 1 2] [--workers 2] [--workdir DIR]
        [--out experiments/results/test_suite/threshold_spread]
        [TESTS...]

For each combination the default test tier (or the TESTS given) runs in a subprocess with
``ATEN_CPU_CAPABILITY``, ``GRIPDEM_TEST_THREADS`` (torch threads in the test process, see
tests/conftest.py) and ``OMP_NUM_THREADS`` / ``NUMBA_NUM_THREADS`` set, and with the plugin
``tests/support/threshold_log.py``, which records every comparing ``assert`` (pytest's
explanation: the values on both sides) and every ``assert_close`` / ``assert_allclose`` (the
largest difference beside the tolerance). Capabilities the CPU lacks are skipped (torch would
fall back silently and the column would repeat another).

Printed and written (``OUT.md``, ``OUT.json``): passes and failures per combination; every
numeric check whose measured value moves between combinations, with its values per combination
and the worst margin to its threshold (how many times the measured value fits under the bound,
or the bound under the value for ``>``); the tightest margins of all checks.
"""

from __future__ import annotations

import argparse
import ast
import json
import operator
import os
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "experiments" / "benchmarks"))
from benchlib import machine_line, markdown_table, write_report  # noqa: E402

_OPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul}
_OPS.update({ast.Div: operator.truediv, ast.Pow: operator.pow})
_COMPARE = {ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">", ast.GtE: ">="}


def cpu_capabilities() -> list[str]:
    """The ATEN_CPU_CAPABILITY values this CPU can run."""
    flags = ""
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        pass
    found = ["default"]
    if " avx2" in flags:
        found.append("avx2")
    if " avx512f" in flags and " avx512bw" in flags and " avx512vl" in flags:
        found.append("avx512")
    return found


def _number(node) -> float:
    """A numeric expression of literals and + - * / ** (what pytest prints), else ValueError."""
    if isinstance(node, ast.Constant) and isinstance(node.value, int | float):
        return float(node.value)
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        return -_number(node.operand)
    if isinstance(node, ast.BinOp) and type(node.op) in _OPS:
        return _OPS[type(node.op)](_number(node.left), _number(node.right))
    raise ValueError("not a numeric expression")


def parse_comparison(values: str) -> tuple[float, str, float] | None:
    """``(left, op, right)`` of a printed comparison such as ``0.034 < (0.53 / 20)``."""
    try:
        tree = ast.parse(values.strip(), mode="eval").body
    except SyntaxError:
        return None
    if not isinstance(tree, ast.Compare) or len(tree.ops) != 1 or type(tree.ops[0]) not in _COMPARE:
        return None
    try:
        return _number(tree.left), _COMPARE[type(tree.ops[0])], _number(tree.comparators[0])
    except (ValueError, ZeroDivisionError, OverflowError):
        return None


def margin(record: dict) -> float | None:
    """How many times the measured value fits inside its bound (1 = on the bound, < 1 fails)."""
    if record["kind"] == "assert":
        parsed = parse_comparison(record.get("values", ""))
        if parsed is None:
            return None
        left, op, right = parsed
        small, large = (left, right) if op in ("<", "<=") else (right, left)
        if small <= 0 or large <= 0:
            return None
        return large / small
    value = record.get("margin")
    return float(value) if isinstance(value, int | float) and value == value else None


def measured(record: dict) -> str:
    if record["kind"] == "assert":
        parsed = parse_comparison(record.get("values", ""))
        return f"{parsed[0]:.4g}" if parsed else record.get("values", "")[:40]
    return f"{record.get('abs_diff', float('nan')):.3g}"


def check_name(record: dict, index: int) -> str:
    if record["kind"] == "assert":
        return f"line {record.get('line')}: {record.get('assert', '')[:70]}"
    return f"{record['kind']} #{index} (atol {record.get('atol')}, rtol {record.get('rtol')})"


def run_combination(cap: str, threads: int, workers: int, tests: list[str], tmp: Path) -> dict:
    """One pytest run under ``cap`` and ``threads`` (read back from ``tmp`` when a finished
    run of this combination is already there: ``--workdir`` resumes an interrupted spread)."""
    log = tmp / f"asserts_{cap}_{threads}.jsonl"
    junit = tmp / f"junit_{cap}_{threads}.xml"
    seconds_file = tmp / f"seconds_{cap}_{threads}.txt"
    if junit.exists() and seconds_file.exists():
        return _read_run(junit, tmp, cap, threads, 0, float(seconds_file.read_text()))
    env = {
        **os.environ,
        "ATEN_CPU_CAPABILITY": cap,
        "GRIPDEM_TEST_THREADS": str(threads),
        "OMP_NUM_THREADS": str(threads),
        "NUMBA_NUM_THREADS": str(threads),
        "GRIPDEM_ASSERT_LOG": str(log),
    }
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "threshold_log"]
    cmd += ["-o", "enable_assertion_pass_hook=true", f"--junitxml={junit}"]
    cmd += ["--hypothesis-seed=0", "-n", str(workers if workers > 1 else 0)]  # same examples
    for stale in tmp.glob(f"asserts_{cap}_{threads}.jsonl*"):
        stale.unlink()
    started = time.perf_counter()
    proc = subprocess.run(cmd + tests, cwd=ROOT, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - started
    seconds_file.write_text(f"{seconds}")
    return _read_run(junit, tmp, cap, threads, proc.returncode, seconds)


def _read_run(junit: Path, tmp: Path, cap: str, threads: int, rc: int, seconds: float) -> dict:
    outcomes = {}
    if junit.exists():
        for case in ET.parse(junit).getroot().iter("testcase"):
            name = f"{case.get('classname')}::{case.get('name')}"
            failed = case.find("failure") is not None or case.find("error") is not None
            outcomes[name] = (
                "failed" if failed else "skipped" if case.find("skipped") is not None else "passed"
            )
    records = []
    for path in sorted(tmp.glob(f"asserts_{cap}_{threads}.jsonl*")):
        records += [json.loads(line) for line in path.read_text().splitlines() if line]
    return {"rc": rc, "seconds": seconds, "outcomes": outcomes, "records": records}


def key_records(records: list[dict]) -> dict[tuple, dict]:
    """Records keyed by (test, check): asserts by line and text, closeness calls by order."""
    keyed, counts = {}, defaultdict(int)
    for record in records:
        if record["kind"] == "assert" and (
            record.get("line") is None or parse_comparison(record.get("values", "")) is None
        ):
            continue  # a failure report (counted in the outcomes), or no numbers compared
        base = (record["test"], record["kind"], record.get("line"), record.get("assert"))
        counts[base] += 1
        keyed[(*base, counts[base])] = record
    return keyed


def report(runs: dict[str, dict]) -> tuple[str, dict]:
    combos = list(runs)
    lines = [f"# Thresholds across CPUs and thread counts\n\n{machine_line()}\n"]
    rows = []
    for combo, run in runs.items():
        counts = defaultdict(int)
        for outcome in run["outcomes"].values():
            counts[outcome] += 1
        failed = sorted(t for t, o in run["outcomes"].items() if o == "failed")
        rows.append(
            [combo, counts["passed"], counts["failed"], counts["skipped"], f"{run['seconds']:.0f}"]
            + ["; ".join(failed) or "-"]
        )
    lines.append("## Passes and failures\n")
    lines.append(
        markdown_table(["combination", "passed", "failed", "skipped", "s", "failed"], rows)
    )
    keyed = {combo: key_records(run["records"]) for combo, run in runs.items()}
    keys = sorted(set().union(*keyed.values()), key=str)
    moving, everything = [], []
    for key in keys:
        present = [keyed[c][key] for c in combos if key in keyed[c]]
        margins = [m for m in (margin(r) for r in present) if m is not None]
        shown = [measured(keyed[c][key]) if key in keyed[c] else "-" for c in combos]
        worst = min(margins) if margins else None
        row = [
            key[0],
            check_name(present[0], key[-1]),
            *shown,
            "-" if worst is None else f"{worst:.3g}",
        ]
        everything.append((worst, row))
        if len({s for s in shown if s != "-"}) > 1:
            moving.append((worst, row))
    headers = ["test", "check", *combos, "worst margin"]
    lines.append(
        f"\n## Checks whose measured value moves between combinations ({len(moving)} of "
        f"{len(keys)} numeric checks)\n\nMargin: how many times the measured value fits inside "
        "its bound in the worst combination (1 = on the bound; for assert_close and "
        "assert_allclose the smallest (atol + rtol |expected|) / |difference|).\n"
    )
    moving.sort(key=lambda item: (item[0] is None, item[0] or 0))
    lines.append(markdown_table(headers, [row for _, row in moving[:150]]))
    if len(moving) > 150:
        lines.append(f"\n({len(moving) - 150} more in OUT.json)")
    tight = sorted(
        ((m, row) for m, row in everything if m is not None and m < 10), key=lambda x: x[0]
    )
    lines.append(f"\n## The tightest margins of all checks (below 10x: {len(tight)})\n")
    lines.append(markdown_table(headers, [row for _, row in tight[:60]]))
    data = {
        combo: {"rc": run["rc"], "seconds": run["seconds"], "outcomes": run["outcomes"]}
        for combo, run in runs.items()
    }
    data["moving_checks"] = [row for _, row in moving]
    return "\n".join(lines) + "\n", data


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tests", nargs="*", help="test paths (default: the default tier)")
    parser.add_argument("--capabilities", nargs="+", default=None)
    parser.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    parser.add_argument(
        "--workers", type=int, default=1, help="cores to use: pytest-xdist workers x torch threads"
    )
    parser.add_argument("--workdir", help="keep the runs' logs here (and reuse finished ones)")
    parser.add_argument(
        "--out", default=str(ROOT / "experiments/results/test_suite/threshold_spread")
    )
    args = parser.parse_args()
    available = cpu_capabilities()
    caps = [c for c in (args.capabilities or available) if c in available]
    print(machine_line(), flush=True)
    runs = {}
    with tempfile.TemporaryDirectory() as scratch:
        tmp = Path(args.workdir or scratch)
        tmp.mkdir(parents=True, exist_ok=True)
        for cap in caps:
            for threads in args.threads:
                combo = f"{cap}/{threads}t"
                workers = args.workers // threads  # one core per torch thread
                runs[combo] = run_combination(cap, threads, workers, args.tests, tmp)
                run = runs[combo]
                failed = sum(o == "failed" for o in run["outcomes"].values())
                print(
                    f"{combo}: rc {run['rc']}, {failed} failed, {run['seconds']:.0f} s", flush=True
                )
    text, data = report(runs)
    write_report(args.out, text, data)


if __name__ == "__main__":
    main()
