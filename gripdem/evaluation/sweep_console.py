"""The sweep summary a terminal shows: one short row per job (and per group of seeds), within
100 columns. The full tables stay in ``summary.md`` / ``summary.csv``
(:func:`gripdem.evaluation.sweep_summary.write_summary`).

Columns (a study's trials: the state, the validation RMSE over constant velocity's, steps and
minutes): the swept keys (values shown as the run names show them, :func:`shown_value`, cut to
fit), the status, the test RMSE over constant velocity's (``÷ CV``) and over the linear AR
filter's (``÷ AR``), the overlapping fraction of particles at the last predicted frame
(``overlap %``) and the job's wall minutes; grouped over seeds, the mean ± std of each.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from gripdem.evaluation.sweep_summary import SEED_KEY, Job, SeedStats, varying_params

#: the terminal width the console summary keeps to
WIDTH = 100
#: (column title, metric key, scale): the numbers a sweep's console shows per job
COLUMNS = (
    ("÷ CV", "test/rmse_ratio_constant_velocity", 1.0),
    ("÷ AR", "test/rmse_ratio_linear_ar", 1.0),
    ("overlap %", "test/physics/model/overlap_fraction", 100.0),
    ("min", "run_seconds", 1 / 60),
)
#: the columns of a study's trials (``study/state`` in their metrics): ranked on validation,
#: never tested (gripdem.study)
STUDY_COLUMNS = (
    ("val ÷ CV", "val/rmse_ratio_constant_velocity_best", 1.0),
    ("steps", "steps", 1.0),
    ("min", "run_seconds", 1 / 60),
)
#: the widest a swept value's cell may be before it is cut (with "…")
MAX_VALUE = 24


def shown_value(value: Any) -> str:
    """A swept value as run names and the console show it: a number to 4 significant figures
    (an integer as written), a path by its file name (two alike: the run name adds the job
    number), anything else as written."""
    value = str(value)
    try:
        number = float(value)
    except ValueError:
        return value.rstrip("/").rsplit("/", 1)[-1] or value.replace("/", ".")
    if value.strip().lstrip("+-").isdigit():
        return value.strip()
    return f"{number:.4g}"


def _number(value: float | None, digits: int = 3) -> str:
    return "–" if value is None else f"{value:.{digits}g}"


def _stats(stats: SeedStats | None) -> str:
    if stats is None:
        return "–"
    if stats.n < 2:
        return _number(stats.mean)
    return f"{stats.mean:.3g} ± {stats.std:.1g}"


def _cut(text: str, width: int) -> str:
    return text if len(text) <= width else text[: width - 1] + "…"


def _value(job: Job, key: str, scale: float) -> float | None:
    value = (job.metrics or {}).get(key)
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) * scale


def _render(header: list[str], rows: list[list[str]], width: int) -> list[str]:
    """Columns padded to their widest cell (the first left-aligned, the rest right-aligned);
    the first column, the swept values, is cut so that a line keeps to ``width``."""
    widths = [max(len(row[i]) for row in [header, *rows]) for i in range(len(header))]
    over = sum(widths) + 2 * (len(widths) - 1) - width
    if over > 0:
        widths[0] = max(8, widths[0] - over)
    lines = []
    for row in [header, *rows]:
        cells = [_cut(row[0], widths[0]).ljust(widths[0])]
        cells += [cell.rjust(w) for cell, w in zip(row[1:], widths[1:], strict=True)]
        lines.append("  ".join(cells).rstrip())
    return lines


def console_summary(jobs: Sequence[Job], width: int = WIDTH) -> str:
    """The jobs' rows (and, when they differ by seed, the groups' mean ± std), each line at most
    ``width`` characters."""
    keys = varying_params(jobs)
    study = any("study/state" in (job.metrics or {}) for job in jobs)
    columns = STUDY_COLUMNS if study else COLUMNS
    titles = [title for title, _, _ in columns]

    def swept(job: Job, names: Sequence[str]) -> str:
        values = [_cut(f"{k}={shown_value(job.params.get(k))}", MAX_VALUE) for k in names]
        return " ".join(values) or job.name

    rows = []
    for job in jobs:
        status = "ok" if job.status == "ok" else _cut(job.status, 30)
        if study and job.status == "ok":
            status = str((job.metrics or {}).get("study/state", "ok"))
        numbers = [_number(_value(job, key, scale)) for _, key, scale in columns]
        rows.append([job.name if study else swept(job, keys), status, *numbers])
    lines = _render(["job", "status", *titles], rows, width)
    if SEED_KEY in keys and len(jobs) > 1:
        group_keys = [k for k in keys if k != SEED_KEY]
        groups: dict[tuple, list[Job]] = {}  # by the full values (two may share a cut form)
        for job in jobs:
            groups.setdefault(tuple(repr(job.params.get(k)) for k in group_keys), []).append(job)
        grouped = []
        for members in groups.values():
            name = swept(members[0], group_keys) if group_keys else "all"
            done = [j for j in members if j.metrics is not None]
            cells = [
                _stats(SeedStats.of([_value(j, key, scale) for j in done]))
                for _, key, scale in columns
            ]
            grouped.append([name, str(len(done)), *cells])
        lines += ["", "mean ± std over seeds:"]
        lines += _render(["group", "seeds", *titles], grouped, width)
    return "\n".join(line[:width] for line in lines)
