"""``hydra/launcher=parallel``: :func:`gripdem.runner.parallel_launcher.launch_jobs` as a Hydra
launcher plugin (``n_jobs``: jobs at once; null = one per CPU, one at a time on a GPU)."""

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Optional

from hydra.core.config_store import ConfigStore
from hydra.core.utils import JobReturn
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig


@dataclass
class ParallelLauncherConf:
    _target_: str = "hydra_plugins.gripdem_launcher.parallel_launcher.ParallelLauncher"
    # jobs at once (null: one per CPU with one torch thread each; one at a time on a GPU)
    n_jobs: Optional[int] = None  # noqa: UP045 - OmegaConf reads typing.Optional only
    # (no `from __future__ import annotations` here: Hydra's plugin scan runs this module
    # before it is in sys.modules, where dataclasses cannot resolve string annotations)


ConfigStore.instance().store(
    group="hydra/launcher", name="parallel", node=ParallelLauncherConf, provider="gripdem"
)


class ParallelLauncher(Launcher):
    def __init__(self, n_jobs: Optional[int] = None) -> None:  # noqa: UP045
        self.n_jobs = n_jobs
        self.announce = True  # a study sets False: it launches its trials one by one
        self.config: Optional[DictConfig] = None  # noqa: UP045
        self.hydra_context: Optional[HydraContext] = None  # noqa: UP045

    def setup(
        self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig
    ) -> None:
        self.config, self.hydra_context = config, hydra_context

    def launch(
        self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int
    ) -> Sequence[JobReturn]:
        from gripdem.runner.parallel_launcher import launch_jobs

        assert self.config is not None and self.hydra_context is not None
        return launch_jobs(
            self.hydra_context,
            self.config,
            job_overrides,
            initial_job_idx,
            self.n_jobs,
            announce=self.announce,
        )


__all__: Any = ["ParallelLauncher", "ParallelLauncherConf"]
