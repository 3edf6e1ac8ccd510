"""``python -m gripdem.run``: the experiment runner (Hydra entry point).

Composes ``conf/config.yaml`` (validated by :mod:`gripdem.runner.config_schema`), makes sure the
scene's dataset exists, trains, tests out of sample beside the baselines, writes everything
under the job's output directory and returns ``optimized_metric`` for sweepers (Optuna).

    python -m gripdem.run                                   # default scene, fast preset
    python -m gripdem.run -m split=190-10,100-100 model=vct # a multirun sweep
    python -m gripdem.run experiment=smoke scene=lebc       # seconds, tiny scene
"""

from __future__ import annotations

import math
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from gripdem.runner.config_schema import register

CONFIG_DIR = str(Path(__file__).resolve().parent.parent / "conf")
register()


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="config")
def main(cfg: DictConfig) -> float:
    from gripdem.runner.experiment import run_experiment

    out_dir = Path(HydraConfig.get().runtime.output_dir)
    report = run_experiment(cfg, out_dir)
    if not report:  # a non-zero DDP rank
        return math.nan
    metrics = {k: v for k, v in report.items() if isinstance(v, float)}
    if cfg.optimized_metric not in metrics:
        raise KeyError(
            f"optimized_metric={cfg.optimized_metric!r} is not among the run's metrics; "
            f"choose one of {sorted(metrics)}"
        )
    return float(metrics[cfg.optimized_metric])


if __name__ == "__main__":
    main()
