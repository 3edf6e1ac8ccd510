"""How long does the README's test command take? Runs the default tier as ``.ci/run`` does
(``python -m pytest -n auto``, after the install) and writes its wall time, CPU time and
outcome counts.

    python experiments/benchmarks/end_to_end/test_command.py
        [--out experiments/results/test_suite/test_command] [PYTEST_ARGS...]

The install is not timed (it depends on the package index's cache); run it on a checkout whose
``.venv`` is set up. Writes ``OUT.md`` and ``OUT.json`` with the result header (date, commit,
CPU model, threads, command).

``--against DIR`` times the same command in another checkout (its own ``DIR/.venv``, e.g. a
clone at the previous release) and in this one, alternately for ``--rounds`` rounds (the order
swapped each round), and writes each run and the ratio of the medians: on a shared machine,
whose speed drifts by a fifth from hour to hour, a before/after is measured side by side.

``--census`` adds where the time goes: each test's CPU time (its worker's and that of the
processes it started), summed by test folder, the ten costliest tests, and every Python process
the run started (how many imported torch and Lightning), from the pytest plugin and the
``sitecustomize`` in ``suite_census/`` (``PYTHONPATH``; both do nothing outside a census).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchlib import available_cpus, cpu_model, markdown_table, write_report  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
OUTCOMES = ("passed", "failed", "skipped", "deselected", "xfailed", "errors")
CENSUS = Path(__file__).resolve().parent / "suite_census"


def suite_group(nodeid: str) -> str:
    """``tests/runner/test_x.py::t`` -> ``tests/runner``; a top-level file is its own group."""
    parts = nodeid.split("::")[0].split("/")
    return "/".join(parts[:2]) if len(parts) > 2 else parts[-1]


def read_census(folder: Path, root_pid: int) -> dict:
    """The tests' and processes' records of a census folder, summed; ``root_pid``: pytest's
    own process (it and its xdist workers, its children with ``PYTEST_XDIST_WORKER`` set, are
    not counted as processes the tests started)."""
    tests = [json.loads(line) for p in folder.glob("tests-*.jsonl") for line in p.open()]
    for test in tests:
        test["total_cpu_s"] = test["cpu_s"] + test["children_cpu_s"]
    groups: dict[str, list[float]] = defaultdict(lambda: [0, 0.0])
    for test in tests:
        groups[suite_group(test["test"])][0] += 1
        groups[suite_group(test["test"])][1] += test["total_cpu_s"]

    ended = [json.loads(p.read_text()) for p in folder.glob("end-*.json")]
    pytest_own = {root_pid} | {
        e["pid"] for e in ended if e["ppid"] == root_pid and e.get("xdist_env")
    }
    started = [
        r
        for p in folder.glob("start-*.json")
        if (r := json.loads(p.read_text()))["pid"] not in pytest_own
    ]
    others = [e for e in ended if e["pid"] not in pytest_own]
    return {
        "tests": len(tests),
        "tests_cpu_min": sum(t["total_cpu_s"] for t in tests) / 60,
        "groups": {
            name: {"tests": n, "cpu_min": cpu / 60}
            for name, (n, cpu) in sorted(groups.items(), key=lambda kv: -kv[1][1])
        },
        "costliest": sorted(tests, key=lambda t: -t["total_cpu_s"])[:10],
        # every test, costliest first (the JSON's full record; the page shows the ten above)
        "every_test": sorted(tests, key=lambda t: -t["total_cpu_s"]),
        "processes_started": len(started),
        "processes_killed": len(started) - len(others),
        "processes_lightning": sum(e["lightning"] for e in others),
        "processes_torch": sum(e["torch"] for e in others),
        "processes_cpu_min": sum(e["cpu_s"] for e in others) / 60,
    }


def census_text(census: dict) -> str:
    groups = markdown_table(
        ["test folder or file", "tests", "CPU-minutes"],
        [[f"`{g}`", v["tests"], f"{v['cpu_min']:.2f}"] for g, v in census["groups"].items()],
    )
    costliest = markdown_table(
        ["test", "CPU s (its processes')", "wall s"],
        [
            [
                f"`{t['test']}`",
                f"{t['total_cpu_s']:.1f} ({t['children_cpu_s']:.1f})",
                f"{t['wall_s']:.1f}",
            ]
            for t in census["costliest"]
        ],
    )
    return (
        f"\n\n## Where the CPU time goes\n\n{census['tests']} tests, "
        f"{census['tests_cpu_min']:.1f} CPU-minutes inside tests (the rest of the total is the "
        "workers' start, collection and the session fixtures' first users' share).\n\n"
        f"{groups}\n\nThe ten costliest tests (CPU time of the test and of the processes it "
        f"started):\n\n{costliest}\n\nPython processes started by tests: "
        f"{census['processes_started']} ({census['processes_killed']} killed before their exit "
        f"was recorded); of those that exited, {census['processes_torch']} imported torch and "
        f"{census['processes_lightning']} Lightning, {census['processes_cpu_min']:.1f} "
        "CPU-minutes in all.\n"
    )


def run_suite(root: Path, python: str, pytest_args: list[str], env: dict) -> tuple[dict, str, int]:
    """One run of ``python -m pytest -n auto -q PYTEST_ARGS`` in ``root``: its row (wall, CPU
    of it and its processes, outcome counts, CPU model), its output (for a failure) and the
    pytest process's id (the census tells its own processes from the tests' by it)."""
    command = [python, "-m", "pytest", "-n", "auto", "-q", *pytest_args]
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    proc = subprocess.Popen(
        command, cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
    )
    out, err = proc.communicate()
    wall = time.perf_counter() - start
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = usage.ru_utime + usage.ru_stime - used.ru_utime - used.ru_stime
    summary = out.strip().splitlines()[-1] if out.strip() else ""
    counts = {k: int(n) for n, k in re.findall(r"(\d+) (\w+)", summary) if k in OUTCOMES}
    minutes, seconds = divmod(round(wall), 60)
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True
    ).stdout.strip()
    row = {
        "command": "python -m pytest -n auto",
        "commit": commit,
        "wall_s": round(wall, 1),
        "wall": f"{minutes} min {seconds:02d} s",
        "cpu_min": round(cpu / 60, 1),
        "cpus": available_cpus(),
        "cpu_model": cpu_model(),
        "returncode": proc.returncode,
        **counts,
    }
    return row, out[-4000:] + "\n" + err[-2000:], proc.pid


def outcome_cells(row: dict) -> list:
    failed = row.get("failed", 0) + row.get("errors", 0)
    status = "ok" if row["returncode"] == 0 else f"exit {row['returncode']}"
    return [row.get("passed", 0), row.get("skipped", 0), failed, status]


def side_by_side(against: Path, rounds: int, pytest_args: list[str], env: dict):
    """Alternate runs in ``against`` (before) and this checkout (after); the text and rows."""
    sides = {"before": (against, str(against / ".venv" / "bin" / "python")),
             "after": (ROOT, sys.executable)}  # fmt: skip
    runs = []
    for round_ in range(rounds):
        for label in ("before", "after") if round_ % 2 == 0 else ("after", "before"):
            row, output, _ = run_suite(*sides[label], pytest_args, env)
            runs.append({"side": label, "round": round_ + 1, **row})
            if row["returncode"] != 0:
                print(f"{label} run failed:\n{output}", file=sys.stderr)
    median = {side: statistics.median(r["wall_s"] for r in runs if r["side"] == side)
              for side in sides}  # fmt: skip
    table = markdown_table(
        ["run", "checkout", "commit", "wall", "CPU-minutes", "passed", "skipped", "failed",
         "status"],
        [[f"{r['round']} {r['side']}", f"`{sides[r['side']][0].name}`", r["commit"], r["wall"],
          f"{r['cpu_min']:.1f}", *outcome_cells(r)] for r in runs],
    )  # fmt: skip
    text = (
        f"The default test tier (`python -m pytest -n auto`), install excluded, run alternately "
        f"in two checkouts on {runs[0]['cpu_model']} ({runs[0]['cpus']} CPUs), each with its "
        f"own virtualenv.\n\n{table}\n\nMedian wall: before {median['before']:.0f} s, after "
        f"{median['after']:.0f} s; after / before = {median['after'] / median['before']:.2f}.\n"
    )
    return text, {"runs": runs, "median_wall_s": median}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--out", type=Path, default=ROOT / "experiments/results/test_suite/test_command"
    )
    parser.add_argument(
        "--census", action="store_true", help="also record where the CPU time goes (slower)"
    )
    parser.add_argument("--against", type=Path, help="another checkout to time side by side")
    parser.add_argument("--rounds", type=int, default=2, help="rounds of --against")
    args, pytest_args = parser.parse_known_args(argv)
    env = dict(os.environ)
    if args.against:
        text, rows = side_by_side(args.against.resolve(), args.rounds, pytest_args, env)
        write_report(args.out, text, rows)
        return max(r["returncode"] for r in rows["runs"])
    census_dir = Path(tempfile.mkdtemp(prefix="suite-census-")) if args.census else None
    if census_dir:
        pytest_args = [*pytest_args, "-p", "census_plugin"]
        env["GRIPDEM_CENSUS_DIR"] = str(census_dir)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(CENSUS), env.get("PYTHONPATH")]))
    row, output, pid = run_suite(ROOT, sys.executable, pytest_args, env)
    table = markdown_table(
        ["command", "CPU", "wall", "CPU-minutes", "passed", "skipped", "failed", "status"],
        [[f"`{row['command']}`", f"{row['cpu_model']} ({row['cpus']} CPUs)", row["wall"],
          f"{row['cpu_min']:.1f}", *outcome_cells(row)]],
    )  # fmt: skip
    text = f"The default test tier, install excluded.\n\n{table}"
    if census_dir:
        row["census"] = read_census(census_dir, pid)
        shutil.rmtree(census_dir, ignore_errors=True)
        text += census_text(row["census"])
    write_report(args.out, text, row)
    if row["returncode"] != 0:
        print(output, file=sys.stderr)
    return row["returncode"]


if __name__ == "__main__":
    sys.exit(main())
