"""One table across the jobs of a multirun: ``python -m gripdem.summary SWEEP_DIR``.

A job is a folder under ``SWEEP_DIR`` holding Hydra's ``.hydra/`` record; its metrics are its
``metrics.json`` (nested mappings are flattened with ``/``). Rows are jobs in sweep order
(``hydra.job.num``); columns are the job folder (named by what differs:
:mod:`gripdem.runner.run_names`), the overrides whose values differ between jobs (every
override for a single job; from ``.hydra/overrides.yaml``, or the flattened
``.hydra/config.yaml`` when a job has no overrides file), then the key metrics, chosen by glob
patterns (:data:`DEFAULT_METRICS`, per-step RMSEs left out). A job without ``metrics.json``
(failed or still running) keeps its row with status ``no metrics.json``.

When jobs differ by ``seed``, a second table groups the jobs that differ only by seed and gives
``mean ± std`` (sample standard deviation) of every metric over the seeds, with the number of
seeds: claims comparing models need several seeds.

Writes ``summary.md`` and ``summary.csv`` (and ``summary_seeds.csv`` for the grouped table) into
``SWEEP_DIR`` (atomically, replacing an older summary) and prints the Markdown tables.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from gripdem.data.h5io import atomic_write_text

#: metric columns, in this order; a pattern that matches nothing adds no column
DEFAULT_METRICS = (
    "test/rmse",
    "test/rmse_over_d",
    "test/rmse_ratio_constant_velocity",
    "test/rmse_ratio_linear_ar",
    "test/rmse_constant_velocity_over_d",
    "test/rmse_linear_ar_over_d",
    "test/rmse_stay_over_d",
    "test/rmse_mean_flow_over_d",
    "test/rmse_crossers",
    "test/rmse_constant_velocity_crossers",
    "test/rmse_linear_ar_crossers",
    "test/n_crossers",
    "val/rmse_best",
    "val/rmse_ratio_constant_velocity_best",
    "study/state",
    "study/pruned_at_step",
    "steps",
    "test/crossers/model/ci_low_over_d",
    "test/crossers/model/ci_high_over_d",
    "test/physics/model/overlap_fraction",
    "test/physics/truth/overlap_fraction",
    "test/physics/model/gr_distance",
    "test/physics/constant_velocity/gr_distance",
    "test/physics/model/non_affine_rms_over_d",
    "test/physics/truth/non_affine_rms_over_d",
    "train_seconds",
    "epochs",
    "in_sample",
)
EXCLUDE = ("*rmse_step*",)
#: the overrides that tie a study's trial to its study (the same in every trial but its number)
STUDY_TRIAL_KEYS = "study_trial."


@dataclass(frozen=True)
class SeedStats:
    """Mean and sample standard deviation of one metric over ``n`` seeds (std NaN for n=1)."""

    mean: float
    std: float
    n: int

    @classmethod
    def of(cls, values: Sequence[float]) -> SeedStats | None:
        values = [
            float(v) for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)
        ]
        if not values:
            return None
        n = len(values)
        mean = sum(values) / n
        std = math.sqrt(sum((v - mean) ** 2 for v in values) / (n - 1)) if n > 1 else math.nan
        return cls(mean, std, n)


@dataclass
class Job:
    """One job of a sweep: its folder (relative to the sweep), parameters and metrics."""

    name: str
    params: dict[str, Any]
    metrics: dict[str, Any] | None
    #: the job's error line (``error.txt``, written by a job that failed in a multirun)
    error: str | None = None

    @property
    def status(self) -> str:
        if self.error is not None:
            return f"failed: {self.error}"
        return "ok" if self.metrics is not None else "no metrics.json"


#: a job that failed in a multirun leaves its error line here (gripdem.run)
ERROR_FILE = "error.txt"


def flatten(tree: Any, prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1}}`` -> ``{"a/b": 1}``; lists of scalars become strings."""
    if isinstance(tree, Mapping):
        out: dict[str, Any] = {}
        for key, value in tree.items():
            out.update(flatten(value, f"{prefix}{key}/"))
        return out
    if isinstance(tree, list):
        return {prefix[:-1]: json.dumps(tree)}
    return {prefix[:-1]: tree}


def parse_overrides(lines: Iterable[str]) -> dict[str, str]:
    """Hydra override strings (``key=value``, ``+key=value``, ``++key=value``, ``~key``)."""
    out: dict[str, str] = {}
    for line in lines:
        line = str(line).strip()
        if line.startswith("~"):
            out[line[1:].split("=", 1)[0]] = "<deleted>"
            continue
        key, _, value = line.lstrip("+").partition("=")
        out[key] = value
    return out


def _load_yaml(path: Path) -> Any:
    """Plain containers from a YAML file, interpolations left as written."""
    return OmegaConf.to_container(OmegaConf.load(path), resolve=False)


def _job_number(name: str) -> tuple:
    """Sort key: numeric path parts as numbers (job 10 after job 9)."""
    return tuple((0, int(p), "") if p.isdigit() else (1, 0, p) for p in Path(name).parts)


def _sweep_order(hydra_dir: Path, name: str) -> tuple:
    """Sort key of a job: its number in the sweep (``hydra.job.num``, recorded by Hydra in
    ``.hydra/hydra.yaml``; folders are named by what differs), else its folder name."""
    record = hydra_dir / "hydra.yaml"
    if record.exists():
        num = OmegaConf.select(OmegaConf.load(record), "hydra.job.num", default=None)
        if isinstance(num, int):
            return (0, num, _job_number(name))
    return (1, 0, _job_number(name))


def collect(sweep_dir: str | os.PathLike) -> list[Job]:
    """Every job under ``sweep_dir`` (a folder with ``.hydra/``), in job order."""
    sweep_dir = Path(sweep_dir)
    if not sweep_dir.is_dir():
        raise FileNotFoundError(f"{sweep_dir}: no such sweep folder")
    jobs = []
    for hydra_dir in sweep_dir.rglob(".hydra"):
        folder = hydra_dir.parent
        name = folder.relative_to(sweep_dir).as_posix() or "."
        overrides = hydra_dir / "overrides.yaml"
        config = hydra_dir / "config.yaml"
        if overrides.exists():
            params = parse_overrides(_load_yaml(overrides) or [])
            # a study trial's link to its study (gripdem.study.trial), not a setting
            params = {k: v for k, v in params.items() if not k.startswith(STUDY_TRIAL_KEYS)}
        elif config.exists():
            params = flatten(_load_yaml(config) or {})
        else:
            params = {}
        metrics_file = folder / "metrics.json"
        metrics = None
        if metrics_file.exists():
            try:
                metrics = flatten(json.loads(metrics_file.read_text()))
            except json.JSONDecodeError as exc:
                raise ValueError(f"{metrics_file}: not valid JSON ({exc})") from None
        error_file = folder / ERROR_FILE
        error = error_file.read_text().strip() if error_file.exists() else None
        jobs.append((_sweep_order(hydra_dir, name), Job(name, params, metrics, error)))
    return [job for _, job in sorted(jobs, key=lambda pair: pair[0])]


def runs_by_group(sweeps: Iterable[str | os.PathLike]) -> dict[tuple[str, str, str], list[dict]]:
    """``{(scene, split, model): [flattened metrics of each finished job]}`` over one or more
    sweep folders, keyed by the run's own record (``hparams/...`` in ``metrics.json``), so that
    seeds of one configuration in different sweeps land in one group."""
    groups: dict[tuple[str, str, str], list[dict]] = {}
    for sweep in sweeps:
        for job in collect(sweep):
            m = job.metrics
            if not m or "hparams/model" not in m:
                continue
            key = (str(m["hparams/scene"]), str(m["hparams/split"]), str(m["hparams/model"]))
            groups.setdefault(key, []).append(m)
    return groups


def varying_params(jobs: Sequence[Job]) -> list[str]:
    """Parameter keys whose values differ between jobs (all keys for a single job), in
    first-seen order."""
    keys: list[str] = []
    for job in jobs:
        keys.extend(k for k in job.params if k not in keys)
    if len(jobs) <= 1:
        return keys
    return [k for k in keys if len({repr(job.params.get(k)) for job in jobs}) > 1]


def metric_columns(
    jobs: Sequence[Job],
    patterns: Sequence[str] = DEFAULT_METRICS,
    exclude: Sequence[str] = EXCLUDE,
) -> list[str]:
    """Metric keys present in any job that match ``patterns``, ordered by the first pattern
    they match, then by first appearance; keys matching ``exclude`` are dropped."""
    present: list[str] = []
    for job in jobs:
        present.extend(k for k in (job.metrics or {}) if k not in present)
    columns: list[str] = []
    for pattern in patterns:
        for key in present:
            if (
                key not in columns
                and fnmatchcase(key, pattern)
                and not any(fnmatchcase(key, e) for e in exclude)
            ):
                columns.append(key)
    return columns


def table(
    jobs: Sequence[Job], patterns: Sequence[str] = DEFAULT_METRICS
) -> tuple[list[str], list[list[Any]]]:
    """Header and rows: ``job``, varying parameters, ``status``, metric columns."""
    params = varying_params(jobs)
    metrics = metric_columns(jobs, patterns)
    header = ["job", *params, "status", *metrics]
    rows = []
    for job in jobs:
        status = job.status
        values = [(job.metrics or {}).get(k) for k in metrics]
        rows.append([job.name, *(job.params.get(k) for k in params), status, *values])
    return header, rows


SEED_KEY = "seed"


def seed_groups(
    jobs: Sequence[Job], patterns: Sequence[str] = DEFAULT_METRICS
) -> tuple[list[str], list[list[Any]]] | None:
    """Header and rows of the jobs grouped by every varying parameter except ``seed``: the
    group's parameters, ``seeds`` (how many finished), then :class:`SeedStats` per metric.
    None when the jobs do not differ by seed."""
    varying = varying_params(jobs)
    if SEED_KEY not in varying:
        return None
    params = [k for k in varying if k != SEED_KEY]
    metrics = [m for m in metric_columns(jobs, patterns) if m != "in_sample"]
    groups: dict[tuple, list[Job]] = {}
    for job in jobs:
        groups.setdefault(tuple(repr(job.params.get(k)) for k in params), []).append(job)
    header = [*params, "seeds", *metrics]
    rows = []
    for members in groups.values():
        done = [j for j in members if j.metrics is not None]
        stats = [SeedStats.of([j.metrics.get(m) for j in done]) for m in metrics]
        first = members[0]
        rows.append([*(first.params.get(k) for k in params), len(done), *stats])
    return header, rows


def seed_csv(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """The grouped table as CSV, a ``_mean`` and a ``_std`` column per metric."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    first_metric = header.index("seeds") + 1
    out_header = list(header[:first_metric])
    for name in header[first_metric:]:
        out_header += [f"{name}_mean", f"{name}_std"]
    writer.writerow(out_header)
    for row in rows:
        cells = [_cell(v, True) for v in row[:first_metric]]
        for stat in row[first_metric:]:
            cells += ["", ""] if stat is None else [repr(stat.mean), repr(stat.std)]
        writer.writerow(cells)
    return buf.getvalue()


def _cell(value: Any, precise: bool) -> str:
    if value is None:
        return ""
    if isinstance(value, SeedStats):
        if math.isnan(value.std):
            return f"{value.mean:.4g}"
        return f"{value.mean:.4g} ± {value.std:.2g}"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        return repr(value) if precise else f"{value:.4g}"
    return str(value)


def to_markdown(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    def esc(text: str) -> str:
        return re.sub(r"([|])", r"\\\1", text)

    lines = [
        "| " + " | ".join(esc(h) for h in header) + " |",
        "|" + "|".join("---" for _ in header) + "|",
    ]
    lines += ["| " + " | ".join(esc(_cell(v, False)) for v in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def to_csv(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    writer.writerows([[_cell(v, True) for v in row] for row in rows])
    return buf.getvalue()


def write_summary(
    sweep_dir: str | os.PathLike,
    out_dir: str | os.PathLike | None = None,
    patterns: Sequence[str] = DEFAULT_METRICS,
) -> tuple[Path, Path, str]:
    """Collect the jobs of a sweep and write ``summary.md`` and ``summary.csv`` (into
    ``out_dir``, default the sweep folder). Returns both paths and the Markdown text."""
    jobs = collect(sweep_dir)
    if not jobs:
        raise FileNotFoundError(f"{sweep_dir}: no Hydra job folders (with .hydra/) found")
    header, rows = table(jobs, patterns)
    out = Path(sweep_dir if out_dir is None else out_dir)
    markdown = to_markdown(header, rows)
    grouped = seed_groups(jobs, patterns)
    if grouped is not None:
        markdown += "\n## Mean ± std over seeds\n\n" + to_markdown(*grouped)
        atomic_write_text(out / "summary_seeds.csv", seed_csv(*grouped), overwrite=True)
    md = atomic_write_text(out / "summary.md", markdown, overwrite=True)
    csv_path = atomic_write_text(out / "summary.csv", to_csv(header, rows), overwrite=True)
    return md, csv_path, markdown
