"""Studies side by side: gripdem's study sweeper (stored, pruned, asynchronous) against the Hydra
Optuna sweeper it replaced (in memory, every trial at its full budget, batches of ``n_jobs``), in
the same wall time, same space and sampler seed; then each study's best setting retrained at the
full budget with three seeds.

Run (one after the other on the same machine; the old sweeper from a checkout of gripdem 0.2.0,
commit 33196a0, in a virtualenv with its `sweep` extra: optuna 2.10 and hydra-optuna-sweeper):

    # today's sweeper, stopped after 40 min
    timeout --signal=TERM 2400 OLD/venv/bin/python -m gripdem.run hparams_search=optuna \\
        hydra.sweeper.n_trials=400 hydra.sweep.dir=RUN/old
    # gripdem's study sweeper, stopped after 40 min the same way
    timeout --signal=TERM 2400 python -m gripdem.run hparams_search=optuna \\
        hydra.sweeper.n_trials=400 hydra.sweeper.study_name=compare hydra.sweep.dir=RUN/new
    # (more new studies, e.g. with hydra.sweeper.pruner.reduction_factor=4, the same way)
    # each study's best, retrained at the full budget (model.train_steps), seeds 0-2
    python experiments/benchmarks/studies/study_comparison.py --best RUN/old RUN/new
    python -m gripdem.run -m seed=0,1,2 <its printed overrides> hydra.sweep.dir=RUN/retrain_old
    python -m gripdem.run -m seed=0,1,2 <its printed overrides> hydra.sweep.dir=RUN/retrain_new
    python experiments/benchmarks/studies/study_comparison.py --old RUN/old --new RUN/new \\
        --retrained RUN/retrain_old RUN/retrain_new --wall-minutes 40 \\
        [--loads OLD_LOADAVG.log NEW_LOADAVG.log] \\
        [--out experiments/results/studies/study_comparison]

A trial counts when it finished inside the wall time: the old sweeper's trials by their
``metrics.json``, the new study's by its journal (complete and pruned; failed ones apart).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchlib import fmt, markdown_table, write_report  # noqa: E402

#: the searched keys (conf/hparams_search/optuna.yaml)
KEYS = (
    "model.lr",
    "model.encoder.channels",
    "model.encoder.pair_channels",
    "model.encoder.rounds",
    "model.hidden",
    "data.history_len",
)


def _overrides(folder: Path) -> dict[str, str]:
    lines = yaml.safe_load((folder / ".hydra" / "overrides.yaml").read_text()) or []
    return {k: v for k, _, v in (str(line).partition("=") for line in lines) if k in KEYS}


def old_study(folder: Path) -> dict:
    """The old sweeper's trials: a folder with metrics.json finished; others were cut off."""
    finished, cut = [], 0
    for trial in sorted(folder.glob("trial=*")):
        metrics_file = trial / "metrics.json"
        if not metrics_file.exists():
            cut += 1
            continue
        metrics = json.loads(metrics_file.read_text())
        finished.append((float(metrics["val/rmse_best"]), trial))
    best_value, best_folder = min(finished, key=lambda pair: pair[0])
    return {
        "complete": len(finished),
        "pruned": 0,
        "failed": 0,
        "cut off": cut,
        "best": best_value,
        "best trial": best_folder.name.split(",")[0],
        "best overrides": _overrides(best_folder),
    }


def new_study(folder: Path) -> dict:
    import optuna

    from gripdem.study.storage import count_trials, open_storage

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    journal = folder / "study.journal"
    name = optuna.study.get_all_study_names(open_storage(str(journal)))[0]
    study = optuna.load_study(study_name=name, storage=open_storage(str(journal)))
    counts = count_trials(study)
    best = study.best_trial
    return {
        "complete": counts.complete,
        "pruned": counts.pruned,
        # the trials running when the wall time ran out were failed and queued again: cut off
        "failed": counts.failed - counts.retried,
        "cut off": counts.retried + counts.running,
        "best": best.value,
        "best trial": f"trial={best.number}",
        "best overrides": {
            k: repr(v) if isinstance(v, float) else str(v) for k, v in best.params.items()
        },
    }


def slot_time(folder: Path) -> list[list[str]]:
    """Where the new study's trial slots went: trials by how they ended (complete, or pruned at
    which step), their mean seconds from start to end, and their share of all trial seconds."""
    import optuna

    from gripdem.study.storage import open_storage

    journal = str(folder / "study.journal")
    name = optuna.study.get_all_study_names(open_storage(journal))[0]
    study = optuna.load_study(study_name=name, storage=open_storage(journal))
    groups: dict[str, list[float]] = {}
    for trial in study.trials:
        if trial.datetime_complete is None or trial.state.name == "FAIL":
            continue
        key = "complete" if trial.state.name == "COMPLETE" else f"pruned at step {trial.last_step}"
        seconds = (trial.datetime_complete - trial.datetime_start).total_seconds()
        groups.setdefault(key, []).append(seconds)
    total = sum(sum(v) for v in groups.values())
    order = sorted(groups, key=lambda k: (k == "complete", len(k), k))
    return [
        [k, str(len(groups[k])), fmt(statistics.mean(groups[k])), fmt(sum(groups[k]) / total)]
        for k in order
    ]


def study_window(folder: Path) -> tuple[float, float]:
    """Seconds since the epoch of a study's first trial folder and last finished file."""
    trials = list(folder.glob("trial=*"))
    ends = [p.stat().st_mtime for p in folder.glob("trial=*/*") if p.is_file()]
    return min(p.stat().st_mtime for p in trials), max(ends)


def mean_load(log: Path, window: tuple[float, float]) -> float:
    """The mean 1-minute load average of a log of ``EPOCH LOAD1 LOAD5 ...`` lines (one every
    10 s, from /proc/loadavg) inside ``window``."""
    values = []
    for line in log.read_text().splitlines():
        parts = line.split()
        if len(parts) >= 2 and window[0] <= float(parts[0]) <= window[1]:
            values.append(float(parts[1]))
    return statistics.mean(values) if values else float("nan")


def retrained(folder: Path) -> dict:
    values, ratios, tests = [], [], []
    for metrics_file in sorted(folder.glob("*/metrics.json")):
        metrics = json.loads(metrics_file.read_text())
        values.append(float(metrics["val/rmse_best"]))
        ratios.append(float(metrics["test/rmse_ratio_constant_velocity"]))
        tests.append(float(metrics["test/rmse_over_d"]))
    return {"val": values, "test_ratio_cv": ratios, "test_over_d": tests}


def _mean_std(values: list[float], digits: int = 4) -> str:
    if not values:
        return "–"
    std = statistics.stdev(values) if len(values) > 1 else float("nan")
    return f"{fmt(statistics.mean(values), digits)} ± {fmt(std, 2)} (n={len(values)})"


def pruner_label(folder: Path) -> str:
    """A new study's pruner, as it stored it (``SuccessiveHalvingPruner, reduction_factor 3``)."""
    import json as _json

    import optuna

    from gripdem.study.storage import PRUNER_ATTR, open_storage

    journal = str(folder / "study.journal")
    name = optuna.study.get_all_study_names(open_storage(journal))[0]
    record = optuna.load_study(study_name=name, storage=open_storage(journal)).user_attrs
    pruner = _json.loads(record.get(PRUNER_ATTR, "null"))
    if pruner is None:
        return "no pruner"
    factor = pruner["kwargs"].get("reduction_factor")
    return f"{pruner['name']}" + (f", reduction factor {factor}" if factor else "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--best", nargs="+", type=Path, metavar="STUDY")
    parser.add_argument("--old", type=Path)
    parser.add_argument("--new", nargs="+", type=Path, help="one or more new studies")
    parser.add_argument(
        "--retrained", nargs="+", type=Path, help="the retrained best of --old, then of each --new"
    )
    parser.add_argument("--wall-minutes", type=float, default=40.0)
    parser.add_argument(
        "--loads",
        nargs="+",
        type=Path,
        help="logs of /proc/loadavg taken every 10 s during each study, --old first",
    )
    parser.add_argument(
        "--out", type=Path, default=Path("experiments/results/studies/study_comparison")
    )
    args = parser.parse_args()
    if args.best:  # the old study first, then new ones
        studies = [old_study(args.best[0])] + [new_study(folder) for folder in args.best[1:]]
        for folder, study in zip(args.best, studies, strict=True):
            print(folder, " ".join(f"{k}={v}" for k, v in study["best overrides"].items()))
        return
    if len(args.retrained) != 1 + len(args.new):
        raise SystemExit("--retrained: one folder for --old, then one per --new")
    folders = [args.old, *args.new]
    studies = [old_study(args.old)] + [new_study(folder) for folder in args.new]
    labels = ["Hydra Optuna sweeper (0.2.0: in memory, no pruning, batches of 2)"] + [
        f"gripdem study sweeper (journal, asynchronous; {pruner_label(folder)})"
        for folder in args.new
    ]
    again = [retrained(folder) for folder in args.retrained]
    headers = [
        "sweeper",
        "trials finished",
        "÷ old",
        "complete",
        "pruned",
        "failed",
        "cut off at the end",
        "best val RMSE (m)",
        "best trial",
        "retrained: val RMSE (m), 3 seeds",
        "retrained: val ÷ old's",
        "retrained: test ÷ CV",
    ]
    finished = [s["complete"] + s["pruned"] for s in studies]
    means = [statistics.mean(r["val"]) for r in again]
    rows = []
    for label, study, retrain, count, mean in zip(
        labels, studies, again, finished, means, strict=True
    ):
        rows.append(
            [
                label,
                str(count),
                f"{count / finished[0]:.2f}",
                str(study["complete"]),
                str(study["pruned"]),
                str(study["failed"]),
                str(study["cut off"]),
                fmt(study["best"], 4),
                study["best trial"],
                _mean_std(retrain["val"]),
                f"{mean / means[0]:.3f}",
                _mean_std(retrain["test_ratio_cv"], 3),
            ]
        )
    loads = ""
    if args.loads:
        values = [
            f"{label.split(' (')[0]}{'' if i == 0 else f' #{i}'} "
            f"{mean_load(log, study_window(folder)):.2f}"
            for i, (label, log, folder) in enumerate(zip(labels, args.loads, folders, strict=True))
        ]
        loads = (
            "\n\nThe machine's mean 1-minute load average while each study ran (2 trials at a "
            "time make 2; more is other work beside it): " + ", ".join(values) + "."
        )
    breakdown = "".join(
        f"\n\nWhere the trial time of the study with {pruner_label(folder)} went (start to "
        "end of each trial):\n\n"
        + markdown_table(["ended", "trials", "mean s", "share of trial time"], slot_time(folder))
        for folder in args.new
    )
    settings = "; ".join(
        f"{label.split(' (')[0]}{'' if i == 0 else f' #{i}'}: "
        + " ".join(f"{k}={v}" for k, v in study["best overrides"].items())
        for i, (label, study) in enumerate(zip(labels, studies, strict=True))
    )
    text = (
        f"Studies of the default model's space (conf/hparams_search/optuna.yaml: six keys, TPE "
        f"seed 1234, 1820 steps per trial), each stopped after "
        f"{args.wall_minutes:.0f} minutes on the machine of the header, one after the other in "
        "one session. *Trials finished* counts the trials that ended in that time (complete or "
        "pruned); each study's best setting was then retrained at the full budget "
        "(model.train_steps) with seeds 0-2.\n\n"
        + markdown_table(headers, rows)
        + loads
        + "\n\nThe validation RMSE of a setting is on its own validation windows, which "
        "`data.history_len` changes: it is the studies' objective, and the test ratio beside it "
        "compares the settings out of sample." + breakdown + "\n\nBest settings: " + settings + "."
    )
    write_report(
        args.out,
        text,
        {
            "studies": [
                {"label": label, **study, "retrained": retrain}
                for label, study, retrain in zip(labels, studies, again, strict=True)
            ],
            "trials_ratio": [count / finished[0] for count in finished],
        },
    )


if __name__ == "__main__":
    main()
