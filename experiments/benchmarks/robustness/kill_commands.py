"""Fault injection (issue 24): does a command killed at any moment leave nothing behind?

    python experiments/benchmarks/robustness/kill_commands.py [--kills 20] [--seed 0] [--strict]
        [--commands simulate run multirun predict handback convert] [--work DIR] [--keep]
        [--out-dir experiments/results/test_suite] [--name kill_commands]
    python experiments/benchmarks/robustness/kill_commands.py --quick     # 3 kills of each command

Each command runs on tiny data (the built-in ``preset=tiny``; ``experiment=smoke`` for
``run``), in its own process group, with its own empty ``GRIPDEM_DATA``, output folder and
``TMPDIR``, and with ``GRIPDEM_KILL_TRIAL=<id>`` in its environment (inherited by every process
it starts: workers, Manager processes, resource trackers). At a random moment (seeded) within
its run time, measured once uninterrupted at the start, it gets SIGKILL, SIGTERM (both to the
main process only: a scheduler's or ``kill PID``'s way, which orphans what the main process
does not stop itself) or SIGINT (to the whole group: a terminal's Ctrl-C), in turn. Then:

- **strays**: processes carrying the trial's marker still alive 5 s after the signal;
- **half-written**: every file under a final name in the trial's folders must open and
  validate with its reader (HDF5 through gripdem's readers, JSON, safetensors, PNG, ``.ckpt``
  with ``torch.load(weights_only=True)``, YAML, XYZ, LAMMPS data and dumps, CSV);
  temporary files (``.NAME.tmp-*``, anything in ``TMPDIR``) are counted apart;
- **clean exit**: after SIGTERM / SIGINT, one ``interrupted:`` line, no traceback and status
  143 / 130 (or death by that signal after the line: the same status to a shell); a signal
  that lands outside the command's handler (Python starting, before it, or shutting down,
  after it: nothing being written) ends it by the signal's default action: counted apart;
- **next ok**: the same command again (``--overwrite`` for the commands that refuse to replace
  complete outputs; ``resume=true`` in the same folder for ``run``) completes with status 0,
  and leaves no temporary file in the dataset cache;
- **resume** (``run``): the resumed run's ``test/rmse`` against the uninterrupted reference
  run's; reported, and a failure only with ``--strict``.

Writes ``<out-dir>/<name>.md`` (the result header, then the table and every finding) and
``<name>.json`` (the header's fields under ``header``).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # benchlib: it adds the groups
from benchlib import machine_line, markdown_table, write_report  # noqa: E402
from kill_checks import (  # noqa: E402
    EXIT_WAIT,
    MARKER,
    RESUME_TOLERANCE,
    SIGNALS,
    check_tree,
    exit_kind,
    findings,
    is_temporary,
    kill_marked,
    marked_processes,
    summarise,
)

STRAY_WAIT = 5.0  # s after the signal
LEGEND = (
    "Commands (tiny data): `simulate scene=pbc preset=tiny sims=2 workers=2` into an empty "
    "cache; `run experiment=smoke` (30 epochs, its dataset in the cache); `run -m "
    "experiment=smoke seed=0,1` into an empty cache; `predict` (a smoke model, 60 frames), "
    "`handback` (data, XYZ, dump), `convert lammps` (a 106-frame dump). Landed mid-run: the "
    "signal came before the command ended. Strays: processes of the command alive 5 s after "
    "the signal (or after the next command). Temp files: `.NAME.tmp-*` left by SIGKILL (never "
    "a final name). Default action outside the handler: the signal came while Python started "
    "or shut down, before or after the command's work. Next "
    "command: the same again (`--overwrite` where complete outputs exist; `resume=true` for "
    "`run`). Resumes: the resumed run's test/rmse against an uninterrupted run's."
)
COMMANDS = ("simulate", "run", "multirun", "predict", "handback", "convert")


@dataclass
class Sizes:
    sim_frames: int = 200  # simulate: 2 simulations in 2 worker processes
    epochs: int = 30  # run: training epochs of the smoke experiment
    predict_frames: int = 60


class Bench:
    """The commands, their shared inputs (made once in ``work/setup``) and their trials."""

    def __init__(self, work: Path, sizes: Sizes):
        self.work, self.sizes = work, sizes
        self.setup = work / "setup"
        self.run_id = f"{os.getpid()}-{int(time.time())}"
        self.commands: list[str] = list(COMMANDS)
        self.reference: float | None = None  # test/rmse of the uninterrupted run

    # ---- commands ----------------------------------------------------------------------
    def argv(self, name: str, t: Path) -> list[str]:
        s, out = self.sizes, t / "out"
        if name == "simulate":
            return ["gripdem.simulate", "scene=pbc", "preset=tiny", "sims=2", "workers=2"] + [
                f"preset.frames={s.sim_frames}",
                "progress=false",
                f"hydra.run.dir={out / 'hydra'}",
            ]
        if name == "run":
            return ["gripdem.run", *self.run_overrides(), f"hydra.run.dir={out / 'run'}"]
        if name == "multirun":
            return ["gripdem.run", "-m", "experiment=smoke", "seed=0,1"] + [
                f"hydra.sweep.dir={out / 'sweep'}"
            ]
        if name == "predict":
            return ["gripdem.predict", str(self.model), str(self.data)] + [
                "--frames",
                str(s.predict_frames),
                "--out",
                str(out / "pred.h5"),
            ]
        if name == "handback":
            return ["gripdem.handback", str(self.trajectory)] + [
                *("--data", str(out / "state.data"), "--xyz", str(out / "state.xyz")),
                *("--dump", str(out / "trajectory.dump.gz")),
            ]
        if name == "convert":
            return ["gripdem.convert", "lammps", str(self.dump), str(out / "converted.h5")] + [
                *("--diameter", "2.5e-6", "--timestep", "5e-6"),
            ]
        raise ValueError(name)

    def rerun_argv(self, name: str, t: Path) -> list[str]:
        extra = {"run": ["resume=true"], "predict": ["--overwrite"]}
        extra |= {"handback": ["--overwrite"], "convert": ["--overwrite"]}
        return self.argv(name, t) + extra.get(name, [])

    def run_overrides(self) -> list[str]:
        return ["experiment=smoke", f"trainer.max_epochs={self.sizes.epochs}"]

    def launch(self, argv: list[str], t: Path, marker: str, log: str) -> subprocess.Popen:
        """Start ``python -m argv`` in ``t`` (its own session), output to ``t/<log>.log``."""
        for sub in ("out", "data", "tmp"):
            (t / sub).mkdir(parents=True, exist_ok=True)
        data = getattr(self, "data", None)
        if data is not None and argv[0] == "gripdem.run" and "-m" not in argv:
            for source in data.parent.glob(f"{data.stem}.*"):  # kills land in training
                if source.suffix != ".lock" and not (t / "data" / source.name).exists():
                    shutil.copy2(source, t / "data" / source.name)
        env = {**os.environ, MARKER: marker, "GRIPDEM_DATA": str(t / "data")}
        env |= {"TMPDIR": str(t / "tmp"), "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
        env.pop("GRIPDEM_TRACEBACK", None)
        with open(
            t / f"{log}.log", "a"
        ) as handle:  # the child keeps its own copy of the descriptor
            return subprocess.Popen(
                [sys.executable, "-m", *argv],
                cwd=t,
                env=env,
                stdout=handle,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                preexec_fn=_default_signals,
            )

    def complete(self, argv: list[str], t: Path, log: str, timeout: float = 900) -> float:
        """Run to the end (status 0 or an error with the log's tail); returns the wall time."""
        start = time.monotonic()
        proc = self.launch(argv, t, f"{self.run_id}-{log}", log)
        rc = proc.wait(timeout=timeout)
        kill_marked(f"{self.run_id}-{log}")
        if rc != 0:
            tail = (t / f"{log}.log").read_text()[-3000:]
            raise RuntimeError(f"{' '.join(argv)} exited {rc}:\n{tail}")
        return time.monotonic() - start

    # ---- setup -------------------------------------------------------------------------
    def prepare(self) -> dict[str, float]:
        """The model, the tiny dataset, a trajectory and a LAMMPS dump (inputs of predict,
        handback and convert), then each command once uninterrupted: its run time (and, for
        ``run``, the reference ``test/rmse``)."""
        t = self.setup
        model = t / "out" / "model"
        self.complete(["gripdem.run", "experiment=smoke", f"hydra.run.dir={model}"], t, "model")
        self.model = model / "checkpoints" / "best.safetensors"
        self.data = next((t / "data").glob("pbc-tiny-*.h5"))
        pred = t / "out" / "pred.h5"
        argv = ["gripdem.predict", str(self.model), str(self.data), "--frames", "100"]
        self.complete([*argv, "--out", str(pred)], t, "predict")
        self.trajectory = t / "out" / "pred_trajectory.h5"
        self.dump = t / "out" / "input.dump.gz"
        self.complete(
            ["gripdem.handback", str(self.trajectory), "--dump", str(self.dump)], t, "dump"
        )
        durations = {}
        for name in self.commands:
            c = self.work / "calibration" / name
            durations[name] = self.complete(self.argv(name, c), c, "calibration")
            print(f"  {name}: {durations[name]:.1f} s uninterrupted", flush=True)
        metrics = self.work / "calibration" / "run" / "out" / "run" / "metrics.json"
        self.reference = json.loads(metrics.read_text())["test/rmse"] if metrics.exists() else None
        return durations

    # ---- one trial ---------------------------------------------------------------------
    def trial(self, name: str, index: int, sig: signal.Signals, delay: float) -> dict:
        t = self.work / "trials" / f"{name}-{index:02d}"
        marker = f"{self.run_id}-{name}-{index}-kill"
        proc = self.launch(self.argv(name, t), t, marker, "kill")
        try:
            proc.wait(timeout=delay)
            landed = False  # finished before the signal
        except subprocess.TimeoutExpired:
            landed = True
            if sig == signal.SIGINT:
                os.killpg(proc.pid, sig)
            else:
                os.kill(proc.pid, sig)
        sent = time.monotonic()
        hung = False
        try:
            rc = proc.wait(timeout=EXIT_WAIT)
        except subprocess.TimeoutExpired:
            hung = True
            os.killpg(proc.pid, signal.SIGKILL)
            rc = proc.wait()
        exit_s = time.monotonic() - sent
        time.sleep(max(0.0, sent + STRAY_WAIT - time.monotonic()))
        strays = marked_processes(marker)
        kill_marked(marker)
        files = check_tree([t / "out", t / "data"], t / "tmp")
        files["temporary"] += [str(p) for p in (t / "tmp").rglob("*") if p.is_file()]
        log = (t / "kill.log").read_text(errors="replace")
        row = {
            "command": name,
            "index": index,
            "signal": sig.name,
            "delay_s": round(delay, 2),
            "landed": landed,
            "rc": rc,
            "exit_s": round(exit_s, 2),
            "hung": hung,
            "strays": strays,
            "bad_files": files["bad"],
            "temporary": files["temporary"],
            "unchecked": files["unchecked"],
            "interrupted_lines": sum(line.startswith("interrupted:") for line in log.splitlines()),
            "traceback": "Traceback" in log,
            "had_last_ckpt": (t / "out" / "run" / "checkpoints" / "last.ckpt").exists(),
        }
        row["exit"] = exit_kind(row, sig)
        if row["exit"] == "unclean" or strays or files["bad"] or hung:
            row["log_tail"] = log[-2000:]  # for the findings
        row.update(self.next_command(name, t))
        return row

    def next_command(self, name: str, t: Path) -> dict:
        marker = f"{self.run_id}-{name}-{t.name}-next"
        proc = self.launch(self.rerun_argv(name, t), t, marker, "next")
        try:
            rc = proc.wait(timeout=900)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            rc = proc.wait()
        time.sleep(0.5)
        strays = marked_processes(marker)
        kill_marked(marker)
        out = {"next_rc": rc, "next_strays": strays}
        out["cache_temporary"] = [str(p) for p in (t / "data").rglob("*") if is_temporary(p)]
        metrics = t / "out" / "run" / "metrics.json"
        if name == "run" and rc == 0 and metrics.exists() and self.reference is not None:
            value = json.loads(metrics.read_text())["test/rmse"]
            out["resume_diff"] = abs(value - self.reference) / abs(self.reference)
        return out


def _default_signals() -> None:
    """In the child: SIGINT and SIGTERM as a terminal's shell leaves them (a background
    parent may have them ignored, and an ignored signal stays ignored across exec)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kills", type=int, default=20, help="kills per command")
    parser.add_argument("--quick", action="store_true", help="3 kills per command, short runs")
    parser.add_argument("--commands", nargs="+", choices=COMMANDS, default=list(COMMANDS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--strict", action="store_true", help="fail on a resume mismatch too")
    parser.add_argument("--work", type=Path, help="working folder (default: a new temporary)")
    parser.add_argument("--keep", action="store_true", help="keep the working folder")
    parser.add_argument("--out-dir", type=Path, default=Path("experiments/results/test_suite"))
    parser.add_argument("--name", default="kill_commands")
    args = parser.parse_args(argv)
    sizes = Sizes(sim_frames=120, epochs=15, predict_frames=30) if args.quick else Sizes()
    kills = 3 if args.quick else args.kills
    work = args.work or Path(tempfile.mkdtemp(prefix="gripdem-kill-"))
    print(machine_line(), flush=True)
    print(f"working folder {work}; calibrating (each command once, uninterrupted)", flush=True)
    bench = Bench(work, sizes)
    bench.commands = list(args.commands)
    durations = bench.prepare()
    rng = random.Random(args.seed)
    rows = []
    try:
        for name in args.commands:
            for i in range(kills):
                sig = SIGNALS[i % len(SIGNALS)]
                delay = rng.uniform(0.05, 1.0) * durations[name]
                rows.append(bench.trial(name, i, sig, delay))
                r = rows[-1]
                print(
                    f"  {name} #{i}: {sig.name} at {delay:.1f} s, rc {r['rc']}, {r['exit']}, "
                    f"strays {len(r['strays'])}, half-written {len(r['bad_files'])}, "
                    f"next rc {r['next_rc']}"
                    + (f", resume diff {r['resume_diff']:.2g}" if "resume_diff" in r else ""),
                    flush=True,
                )
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    headers, table = summarise(rows, args.commands)
    text = "\n".join(
        [
            f"# Killed commands ({kills} kills per command, seed {args.seed})",
            "",
            machine_line(),
            "",
            "uninterrupted run times: " + ", ".join(f"{k} {v:.1f} s" for k, v in durations.items()),
            "",
            markdown_table(headers, table),
            "",
            LEGEND,
            "",
            "## Findings",
            "",
            *(findings(rows) or ["none"]),
            "",
        ]
    )
    print("\n" + text)
    report = {"durations": durations, "rows": rows, "reference": bench.reference}
    write_report(args.out_dir / args.name, text, report, echo=False)
    failed = any(r[3] or r[4] for r in table) or any(r["next_rc"] != 0 for r in rows)
    if args.strict:
        failed |= any(r.get("resume_diff", 0.0) > RESUME_TOLERANCE for r in rows)
        failed |= any(r["exit"] == "unclean" or r["cache_temporary"] for r in rows)
    if failed:
        sys.exit(1)
    return report


if __name__ == "__main__":
    main(sys.argv[1:])
