"""The README's commands, timed end to end and per job as a user runs them: the split sweep
``python -m gripdem.run -m split=190-10,100-100 model=vct`` (``--command split-sweep``, the
default) and the first run, ``python -m gripdem.run`` on the default scene (``--command
first-run``, with ``--fresh-data`` as on a fresh clone).

    python experiments/benchmarks/end_to_end/split_sweep.py [--command split-sweep|first-run]
        [--variant default sequential] [--repo DIR] [--extra trainer.max_steps=100]
        [--fresh-data] [--out DIR] [--name NAME]

Each variant runs the command once in a subprocess (in ``--repo``, default this checkout,
with that checkout's own ``.venv``) into a temporary sweep folder and reports its wall time
and, per job (from the job's ``metrics.json``): training seconds, optimiser steps and steps per
second, the rest of the job (data loading, the AR fit, validation, the chained test and the
outputs), and the test RMSE over constant velocity's and the linear AR filter's with the
overlap at the last predicted frame.

- ``default``: the checkout's own launcher (here: jobs side by side, one torch thread each on
  2 cores; before the parallel launcher: Hydra's basic one, one after another);
- ``sequential``: ``hydra.launcher.n_jobs=1`` (one job after another with every thread).

``--fresh-data`` points ``GRIPDEM_DATA`` at an empty folder, so the first job generates the
scene with the built-in DEM (a fresh clone's first sweep); by default the cached dataset is
used. ``--extra`` adds overrides to every variant, e.g. ``trainer.max_steps=100`` to time a
slow older checkout on a short budget (its per-step rate then extrapolates to the full budget:
the report says so). Writes ``NAME.md`` / ``.json`` into ``--out`` (default
``experiments/results/split_sweep/split_sweep`` or ``experiments/results/first_run/first_run``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # benchlib: it adds the groups
from benchlib import machine_line, markdown_table, write_report  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
#: the README's commands: the split sweep (several jobs) and the first run (one job)
COMMANDS = {"split-sweep": ["-m", "split=190-10,100-100", "model=vct"], "first-run": []}
#: default: the checkout's own launcher (this one's: jobs side by side; older ones: one after
#: another); sequential: one job at a time with every thread (the parallel launcher's n_jobs=1)
VARIANTS = {"default": [], "sequential": ["hydra.launcher.n_jobs=1"]}


def run_variant(
    repo: Path, command_name: str, variant: str, extra: list[str], data_root: str | None
) -> dict:
    sweep = Path(tempfile.mkdtemp(prefix=f"gripdem-{command_name}-{variant}-"))
    env = dict(os.environ)
    if data_root is not None:
        env["GRIPDEM_DATA"] = data_root
    python = repo / ".venv" / "bin" / "python"
    command = [str(python if python.exists() else sys.executable), "-m", "gripdem.run"]
    arguments = COMMANDS[command_name]
    if "-m" in arguments:
        command += [*arguments, *VARIANTS[variant], *extra, f"hydra.sweep.dir={sweep}"]
    else:  # one job: its folder inside the temporary one, read as a sweep's job
        command += [*arguments, *extra, f"hydra.run.dir={sweep / '0'}"]
    start = time.perf_counter()
    proc = subprocess.run(command, cwd=repo, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        raise RuntimeError(f"{variant}: exit {proc.returncode}\n{proc.stderr[-3000:]}")
    jobs = []
    for job_dir in sorted(p for p in sweep.iterdir() if (p / "metrics.json").exists()):
        metrics = json.loads((job_dir / "metrics.json").read_text())
        jobs.append(
            {
                "job": job_dir.name,
                "split": metrics["hparams"]["split"],
                "train_s": metrics["train_seconds"],
                "data_s": metrics.get("data_seconds", float("nan")),
                "run_s": metrics.get("run_seconds", float("nan")),
                "steps": metrics["steps"],
                "ratio_cv": metrics["test/rmse_ratio_constant_velocity"],
                "ratio_ar": metrics["test/rmse_ratio_linear_ar"],
                "overlap": metrics["test/physics/model/overlap_fraction"],
            }
        )
    return {"variant": variant, "wall_s": wall, "jobs": jobs}  # the temporary folder: no name


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--command", default="split-sweep", choices=list(COMMANDS))
    parser.add_argument("--variant", nargs="+", default=None, choices=list(VARIANTS))
    parser.add_argument("--repo", type=Path, default=ROOT)
    parser.add_argument("--extra", nargs="*", default=[])
    parser.add_argument("--fresh-data", action="store_true")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--name", default=None)
    args = parser.parse_args(argv)
    folder = args.command.replace("-", "_")
    args.out = args.out or ROOT / "experiments" / "results" / folder
    args.name = args.name or folder
    sweep_command = "-m" in COMMANDS[args.command]
    args.variant = args.variant or (list(VARIANTS) if sweep_command else ["default"])
    commit = subprocess.run(
        ["git", "-C", str(args.repo), "rev-parse", "--short", "HEAD"],
        capture_output=True,
        text=True,
        check=False,
    ).stdout.strip()
    results = []
    for variant in args.variant:
        data_root = tempfile.mkdtemp(prefix="gripdem-data-") if args.fresh_data else None
        results.append(run_variant(args.repo, args.command, variant, args.extra, data_root))
    rows = []
    for r in results:
        for j in r["jobs"]:
            rows.append(
                [
                    r["variant"],
                    f"{r['wall_s'] / 60:.2f}",
                    j["split"],
                    f"{j['run_s']:.0f}",
                    f"{j['data_s']:.0f}",
                    f"{j['train_s']:.0f}",
                    f"{j['run_s'] - j['data_s'] - j['train_s']:.0f}",
                    j["steps"],
                    f"{j['steps'] / j['train_s']:.1f}",
                    f"{j['ratio_cv']:.3f}",
                    f"{j['ratio_ar']:.3f}",
                    f"{100 * j['overlap']:.2f}",
                ]
            )
    lines = [
        f"# `{' '.join(['python -m gripdem.run', *COMMANDS[args.command]])}`",
        "",
        f"{'the sweep' if sweep_command else 'the run'} at commit {commit}, "
        f"{'fresh data (DEM included)' if args.fresh_data else 'cached data'}"
        + (f", extra overrides: {' '.join(args.extra)}" if args.extra else ""),
        "",
        machine_line(),
        "",
        markdown_table(
            [
                "launcher",
                "wall (min)",
                "job",
                "job (s)",
                "data (s)",
                "train (s)",
                "rest (s)",
                "steps",
                "steps/s",
                "÷ CV",
                "÷ AR",
                "overlap %",
            ],
            rows,
        ),
        "",
    ]
    text = "\n".join(lines)
    args.out.mkdir(parents=True, exist_ok=True)
    write_report(args.out / args.name, text, {"commit": commit, "runs": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
