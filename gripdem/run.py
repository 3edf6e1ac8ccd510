"""``python -m gripdem.run``: the experiment runner (Hydra entry point).

Composes ``conf/config.yaml`` (validated by :mod:`gripdem.runner.config_schema`), makes sure the
scene's dataset exists, trains, tests out of sample beside the baselines, writes everything
under the job's output directory and returns ``optimized_metric`` for sweepers (Optuna).

    python -m gripdem.run                                   # default scene, default preset
    python -m gripdem.run -m split=190-10,100-100 model=vct # a multirun sweep
    python -m gripdem.run experiment=smoke scene=lebc       # seconds, tiny scene

A bad option or bad data ends the run with one line ``error: ...`` (exit status 1), Ctrl-C with
one line saying what the output directory keeps (status 130); ``GRIPDEM_TRACEBACK=1`` adds the
traceback (:func:`gripdem.runner.console.run_command`). An option name removed in gripdem 0.2.0
(``experiment=fast``, ...) is refused in one line naming its replacement before Hydra composes
anything (:mod:`gripdem.runner.renamed_options`).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from gripdem.config_files import config_dir
from gripdem.data.windows import Split
from gripdem.runner.config_checks import check_windows_fit_the_file
from gripdem.runner.config_schema import given_data_path, plain, register
from gripdem.runner.console import one_line, run_hydra_command, single_run_errors
from gripdem.runner.renamed_options import refuse_removed_names

CONFIG_DIR = str(config_dir())  # gripdem/conf: the source tree's conf/, or a wheel's copy
register()
#: the output directory of the job running in this process (for the Ctrl-C line)
_OUT_DIRS: list[Path] = []


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="config")
def main(cfg: DictConfig) -> float:
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    _OUT_DIRS.append(out_dir)
    report = None
    with single_run_errors(out_dir), study_trial(cfg) as trial:
        # a wrong data.path, or a split its simulations cannot hold, fails before Lightning's
        # import (seconds)
        path = given_data_path(cfg)
        if path is not None:
            split = Split(int(cfg.split.history), int(cfg.split.horizon))
            check_windows_fit_the_file(path, plain(cfg.data), split)
        from gripdem.runner.experiment import run_experiment

        report = run_experiment(cfg, out_dir, trial)
    if not report:  # a non-zero DDP rank, or a failed job of a multirun (its error.txt)
        return math.nan
    metrics = {k: v for k, v in report.items() if isinstance(v, float)}
    if cfg.optimized_metric not in metrics:
        raise ValueError(
            f"optimized_metric={cfg.optimized_metric!r} is not among the run's metrics; "
            f"choose one of {sorted(metrics)}"
        )
    value = float(metrics[cfg.optimized_metric])
    if trial is not None:  # the study learns the trial's end from the run itself
        trial.prune() if trial.pruned else trial.complete(value)
    return value


@contextmanager
def study_trial(cfg: DictConfig) -> Iterator:
    """The study trial this run is (``study_trial.*``, :mod:`gripdem.study.trial`), or None;
    an error fails the trial with its one line before the run's error handling reports it;
    an interruption leaves it to the study's heartbeat check."""
    if cfg.study_trial.number is None:
        yield None
        return
    from gripdem.study.trial import open_trial

    trial = open_trial(cfg)
    try:
        yield trial
    except Exception as exc:
        trial.fail(one_line(exc))
        raise
    finally:
        trial.close()


def kept() -> str:
    """What a run stopped by Ctrl-C leaves: complete files only, and which."""
    if not _OUT_DIRS or not _OUT_DIRS[-1].exists():
        return "nothing written (no output directory yet; a dataset being generated is not kept)"
    out = _OUT_DIRS[-1]
    files = sorted(
        (str(p.relative_to(out)) for p in out.rglob("*") if p.is_file() and ".tmp-" not in p.name),
        key=lambda name: (name.startswith("."), name),  # Hydra's .hydra/ last
    )
    shown = ", ".join(files[:6]) + (f" and {len(files) - 6} more" if len(files) > 6 else "")
    resume = ""
    if (out / "checkpoints" / "last.ckpt").exists():
        resume = f"; resume with the same overrides plus hydra.run.dir={out} resume=true"
    return f"kept in {out} (complete files only): {shown or 'nothing'}{resume}"


def command() -> None:
    """The command: its command line's removed option names refused (one line, nothing
    written; Hydra would answer a removed config file with a long message of its own), then
    :func:`main`."""
    refuse_removed_names(sys.argv[1:])
    main()


if __name__ == "__main__":
    sys.exit(run_hydra_command("gripdem.run", command, kept))
