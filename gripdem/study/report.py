"""A study's trials ranked: ``study.md`` and ``study.csv`` in the sweep folder, and the few
lines the sweeper prints at its end.

Rows are every trial of the study (from its storage, so trials run by other workers are in
it too): complete trials best first, then pruned ones by how far they got and their last
value, then failed, running and queued ones. Columns: rank, trial, state, value, the step a
pruned trial stopped at, minutes, the trial it re-runs, the sampled parameters, the error.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import optuna
from optuna.trial import FrozenTrial, TrialState

from gripdem.data.h5io import atomic_write_text
from gripdem.study.storage import ERROR_ATTR, PRUNED_AT_ATTR, RETRY_OF_ATTR, count_trials

_ORDER = {TrialState.COMPLETE: 0, TrialState.PRUNED: 1, TrialState.FAIL: 2}


def ranked(study: optuna.Study) -> list[FrozenTrial]:
    """The study's trials, best first (see the module doc)."""
    sign = -1.0 if study.direction == optuna.study.StudyDirection.MAXIMIZE else 1.0

    def key(trial: FrozenTrial) -> tuple:
        group = _ORDER.get(trial.state, 3)
        if trial.state == TrialState.COMPLETE:
            return (group, sign * trial.value, trial.number)
        if trial.state == TrialState.PRUNED:
            last = (
                trial.intermediate_values.get(trial.last_step, math.inf)
                if trial.last_step is not None
                else math.inf
            )
            return (group, -(trial.last_step or 0), sign * last, trial.number)
        return (group, 0.0, trial.number)

    return sorted(study.get_trials(deepcopy=False), key=key)


def _minutes(trial: FrozenTrial) -> str:
    if trial.datetime_start is None or trial.datetime_complete is None:
        return ""
    return f"{(trial.datetime_complete - trial.datetime_start).total_seconds() / 60:.2f}"


def rows(study: optuna.Study) -> tuple[list[str], list[list[str]]]:
    trials = ranked(study)
    params = sorted({key for trial in trials for key in trial.params})
    header = ["rank", "trial", "state", "value", "pruned at step", "minutes", "re-runs", *params]
    header.append("error")
    table = []
    for rank, trial in enumerate(trials, start=1):
        value = ""
        if trial.state == TrialState.COMPLETE:
            value = f"{trial.value:.5g}"
        elif trial.state == TrialState.PRUNED and trial.last_step is not None:
            value = f"({trial.intermediate_values[trial.last_step]:.5g})"
        pruned_at = trial.user_attrs.get(PRUNED_AT_ATTR, "")
        retry = trial.user_attrs.get(RETRY_OF_ATTR, "")
        shown = [
            str(rank) if trial.state == TrialState.COMPLETE else "",
            str(trial.number),
            trial.state.name.lower(),
            value,
            "" if pruned_at in ("", None) else str(pruned_at),
            _minutes(trial),
            "" if retry in ("", None) else str(retry),
        ]
        for key in params:
            v = trial.params.get(key, "")
            shown.append(f"{v:.4g}" if isinstance(v, float) else str(v))
        shown.append(
            str(trial.user_attrs.get(ERROR_ATTR, "")) if trial.state == TrialState.FAIL else ""
        )
        table.append(shown)
    return header, table


def write_study_report(study: optuna.Study, sweep_dir: Path, storage: str) -> Path:
    """``study.md`` (with a count line) and ``study.csv`` in ``sweep_dir``; returns the md."""
    header, table = rows(study)
    counts = count_trials(study)
    lines = [
        f"Study `{study.study_name}` ({storage}): {counts.complete} complete, {counts.pruned} "
        f"pruned, {counts.failed - counts.retried} failed ({counts.retried} more re-queued and "
        f"run again), {counts.running} running, {counts.waiting} queued. The value is the "
        f"objective ({study.user_attrs.get('gripdem:metric', 'optimized_metric')}); a pruned "
        "trial's is its last validation report, in brackets.",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    lines += ["| " + " | ".join(row) + " |" for row in table]
    md = Path(sweep_dir) / "study.md"
    atomic_write_text(md, "\n".join(lines) + "\n", True)
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(header)
    writer.writerows(table)
    atomic_write_text(Path(sweep_dir) / "study.csv", buffer.getvalue(), True)
    return md


def console_lines(study: optuna.Study, top: int = 5) -> list[str]:
    """The best ``top`` trials, one line each, and the counts."""
    counts = count_trials(study)
    lines = [
        f"study {study.study_name!r}: {counts.complete} complete, {counts.pruned} pruned, "
        f"{counts.failed - counts.retried} failed"
    ]
    best = [t for t in ranked(study) if t.state == TrialState.COMPLETE][:top]
    for rank, trial in enumerate(best, start=1):
        params = " ".join(
            f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in trial.params.items()
        )
        lines.append(f"  {rank}. trial {trial.number}: {trial.value:.4g}  {params}")
    return lines
