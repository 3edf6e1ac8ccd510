"""Hydra callback: after a multirun, one summary table across its jobs (Markdown and CSV), and
a short one on the console (:func:`gripdem.evaluation.sweep_console.console_summary`: the swept
keys, ÷ CV, ÷ AR, overlap and minutes within 100 columns).

Registered in ``conf/config.yaml`` under ``hydra.callbacks``. A job that failed is a row with
its error line, and the command ends with one line naming every failed job with its overrides
(status 1) after the table is written. The table itself is built by
:func:`gripdem.evaluation.sweep_summary.write_summary` (also ``python -m gripdem.summary
SWEEP_DIR``).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from gripdem.evaluation.sweep_console import console_summary
from gripdem.evaluation.sweep_summary import collect, write_summary
from gripdem.runner.console import report_error

log = logging.getLogger(__name__)


def tensorboard_hint(sweep_dir: Path) -> str:
    """The command that shows this sweep's runs beside the sweeps next to it: TensorBoard on
    the folder above, so that each run is named ``<sweep>/<swept values>``."""
    parent = sweep_dir.parent if sweep_dir.parent != Path("") else Path(".")
    return (
        f"compare the runs: tensorboard --logdir {parent} (this sweep's runs: "
        f"{sweep_dir.name}/...; open http://localhost:6006)"
    )


class SweepJobsFailed(ValueError):
    """Some jobs of a multirun failed (the others' results and the summary are complete)."""


class SweepSummary(Callback):
    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        try:
            md, csv_path, _ = write_summary(sweep_dir)
        except FileNotFoundError as exc:  # every job failed before writing anything
            log.warning("no sweep summary: %s", exc)
            return
        jobs = collect(sweep_dir)
        study = (sweep_dir / "study.md").exists()  # a study printed its best trials already
        if not study:
            print(console_summary(jobs))
        print(f"the full tables: {md} and {csv_path}")
        print(tensorboard_hint(sweep_dir))
        # a job failed: its error line (error.txt), or no metrics.json (it crashed)
        failed = [job for job in jobs if job.status != "ok"]
        if failed and study:
            # a trial killed with its study left a folder and ran again under a new number;
            # the study's own table (study.md) says which trials failed and why
            print(f"{len(failed)} trial folder(s) without a result: see {sweep_dir / 'study.md'}")
            return
        if failed:
            named = "; ".join(
                f"job {job.name} ({' '.join(f'{k}={v}' for k, v in job.params.items())}): "
                f"{job.error or 'no metrics.json (see its console.log or run.log)'}"
                for job in failed
            )
            # Hydra turns a callback's exception into a warning: end the command here
            report_error(SweepJobsFailed(f"{len(failed)} job(s) of the sweep failed: {named}"))
            raise SystemExit(1)
