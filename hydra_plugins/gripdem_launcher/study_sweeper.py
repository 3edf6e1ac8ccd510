"""``hydra/sweeper=study``: :class:`gripdem.study.sweeper.StudyRun` as a Hydra sweeper plugin
(``hparams_search=optuna`` selects it; the options are documented in
``conf/hparams_search/optuna.yaml``). Nothing heavy is imported here: Hydra imports every
plugin module when it starts."""

from dataclasses import dataclass, field
from typing import Any, Optional

from hydra.core.config_store import ConfigStore
from hydra.plugins.sweeper import Sweeper
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig

# (no `from __future__ import annotations`, and typing.Optional: Hydra's plugin scan runs
# this module before it is in sys.modules, and OmegaConf reads typing's forms only)


@dataclass
class StudySweeperConf:
    _target_: str = "hydra_plugins.gripdem_launcher.study_sweeper.StudySweeper"
    _recursive_: bool = False  # the sampler and pruner stay configs (the study stores them)
    study_name: str = "gripdem"
    # null: the journal file study.journal in the sweep folder; a path: a journal file there;
    # a URL: sqlite:///file.db, postgresql://..., redis://...
    storage: Optional[str] = None  # noqa: UP045
    direction: str = "minimize"
    # trials the study holds when it ends (complete, pruned and failed; a re-queued trial once)
    n_trials: int = 20
    # trials at once (null: one per CPU with gripdem's parallel launcher, else 1)
    n_jobs: Optional[int] = None  # noqa: UP045
    sampler: dict[str, Any] = field(default_factory=dict)
    # an Optuna pruner's config (hydra/sweeper/pruner=successive_halving|median|none)
    pruner: Any = None
    params: Optional[dict[str, str]] = None  # noqa: UP045
    heartbeat_seconds: float = 10.0
    # a running trial silent this long is failed and queued again (its process was killed)
    grace_seconds: float = 60.0
    # test each trial's model too (false: a study ranks on validation; test the retrained best)
    test_trials: bool = False
    # start no trial after this many minutes (the running ones finish); null: no limit
    timeout_minutes: Optional[float] = None  # noqa: UP045


ConfigStore.instance().store(
    group="hydra/sweeper", name="study", node=StudySweeperConf, provider="gripdem"
)


class StudySweeper(Sweeper):
    def __init__(self, **options: Any) -> None:
        options.pop("_target_", None)
        self.options = options
        self.config: Optional[DictConfig] = None  # noqa: UP045
        self.launcher: Any = None

    def setup(
        self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig
    ) -> None:
        from hydra.core.plugins import Plugins

        from gripdem.study.sweeper import serial_context

        self.config = config
        self.launcher = Plugins.instance().instantiate_launcher(
            hydra_context=serial_context(hydra_context),
            task_function=task_function,
            config=config,
        )

    def sweep(self, arguments: list[str]) -> Any:
        from omegaconf import OmegaConf

        from gripdem.data.h5io import atomic_write_text
        from gripdem.study.report import console_lines, write_study_report
        from gripdem.study.sweeper import StudyOptions, StudyRun

        assert self.config is not None
        plain = {
            k: OmegaConf.to_container(v, resolve=True) if isinstance(v, DictConfig) else v
            for k, v in self.options.items()
        }
        run = StudyRun(StudyOptions(**plain), self.config, self.launcher, list(arguments))
        # whole or not at all: several workers of one study may share the folder
        atomic_write_text(run.sweep_dir / "multirun.yaml", OmegaConf.to_yaml(self.config), True)
        study = run.run()
        report = write_study_report(study, run.sweep_dir, run.url)
        print("\n".join(console_lines(study)))
        print(f"every trial ranked: {report}")
        return study


__all__: Any = ["StudySweeper", "StudySweeperConf"]
