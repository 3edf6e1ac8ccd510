"""Which Optuna storage survives a killed study best: the journal file or SQLite?

    python experiments/benchmarks/studies/storage_kill.py [--rounds 40]
        [--out experiments/results/studies/storage_kill]

Each round starts a writer process that opens the study and does what a study's processes do,
as fast as it can: ask a trial, record heartbeats and validation reports, tell it complete; then
the writer is SIGKILLed at a random moment (10-400 ms after its first write). After each kill the
storage is opened again and checked: does it open, is every trial the writer had finished
(its own record, written after each tell) still complete with its value, and how long does the
next process wait before it can write (a lock the killed writer held)? Both storages run the
same rounds, alternately, on the same disk.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchlib import fmt, markdown_table, write_report  # noqa: E402

from gripdem.study.storage import JOURNAL_LOCK_GRACE_SECONDS, open_storage  # noqa: E402

WRITER = textwrap.dedent(
    """
    import json, sys, time
    import optuna
    from gripdem.study.storage import open_storage, beat
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    url, record = sys.argv[1], sys.argv[2]
    study = optuna.create_study(storage=open_storage(url), study_name="kill", load_if_exists=True)
    print("ready", flush=True)
    while True:
        trial = study.ask()
        x = trial.suggest_float("x", 0.0, 1.0)
        for step in range(5):
            beat(study._storage, trial._trial_id)
            trial.report(x + step, step)
        study.tell(trial, x)
        with open(record, "a") as f:  # what the writer knows it finished
            f.write(json.dumps([trial.number, x]) + "\\n")
            f.flush()
    """
)


def one_round(url: str, record: Path, rng: random.Random) -> dict:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    writer = subprocess.Popen(
        [sys.executable, "-c", WRITER, url, str(record)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=env,
    )
    assert writer.stdout.readline().strip() == "ready"
    time.sleep(rng.uniform(0.01, 0.4))
    writer.send_signal(signal.SIGKILL)
    writer.wait()
    result = {"opens": True, "lost": 0, "wrong": 0, "finished": 0, "next_write_s": None}
    try:
        import optuna

        study = optuna.load_study(study_name="kill", storage=open_storage(url))
        trials = {t.number: t for t in study.get_trials(deepcopy=False)}
    except Exception as exc:  # noqa: BLE001 - the measurement: a storage that will not open
        result.update(opens=False, error=str(exc).splitlines()[0])
        return result
    done = [json.loads(line) for line in record.read_text().splitlines() if line.strip()]
    result["finished"] = len(done)
    for number, value in done:
        trial = trials.get(number)
        if trial is None or trial.state.name != "COMPLETE":
            result["lost"] += 1
        elif trial.value != value:
            result["wrong"] += 1
    started = time.perf_counter()
    trial = study.ask()  # the next writer: a lock left by the killed one makes it wait
    study.tell(trial, state=optuna.trial.TrialState.FAIL)
    result["next_write_s"] = time.perf_counter() - started
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--out", type=Path, default=Path("experiments/results/studies/storage_kill")
    )
    args = parser.parse_args()
    rng = random.Random(args.seed)
    rows, data = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        stores = {
            "journal file": str(Path(tmp) / "study.journal"),
            "SQLite": f"sqlite:///{Path(tmp) / 'study.db'}",
        }
        outcomes: dict[str, list[dict]] = {name: [] for name in stores}
        for _ in range(args.rounds):
            for name, url in stores.items():
                record = Path(tmp) / f"{name.replace(' ', '_')}.done"
                outcomes[name].append(one_round(url, record, rng))
        for name, results in outcomes.items():
            waits = [r["next_write_s"] for r in results if r["next_write_s"] is not None]
            row = {
                "storage": name,
                "kills": len(results),
                "opened after every kill": all(r["opens"] for r in results),
                "trials finished before the kills": results[-1]["finished"],
                "finished trials lost": sum(r["lost"] for r in results),
                "values changed": sum(r["wrong"] for r in results),
                "next write, median s": sorted(waits)[len(waits) // 2] if waits else None,
                "next write, max s": max(waits) if waits else None,
            }
            rows.append([fmt(v) if isinstance(v, float) else str(v) for v in row.values()])
            headers = list(row)
            data[name] = {"summary": row, "rounds": results}
    text = (
        f"A writer doing what a study's processes do (ask, heartbeats, reports, tell) was "
        f"SIGKILLed {args.rounds} times per storage at a random moment; after each kill the "
        "storage was opened again and the trials the writer had finished were checked, and the "
        "next write was timed (a lock left by the killed writer makes it wait).\n\n"
        + markdown_table(headers, rows)
        + "\n\nThe writer writes without a pause (the trials it finished before the kills, in "
        "the same rounds, say how fast each storage writes), so a kill nearly always lands while "
        "it holds the journal's lock, and the next process takes the lock over after "
        f"{JOURNAL_LOCK_GRACE_SECONDS} s (gripdem.study.storage.JOURNAL_LOCK_GRACE_SECONDS; "
        "Optuna's default is 30 s). A study's processes write a few times per validation and "
        "heartbeat, so a killed study seldom leaves the lock behind."
    )
    write_report(args.out, text, data)


if __name__ == "__main__":
    main()
