"""Names of the jobs of a sweep: what differs between them, as the command line said it.

A multirun's job folder, and so its TensorBoard run, is named by the values of the swept keys
(``split=190-10``, ``model=vct,seed=1``), not by its job number; with TensorBoard pointed at
the folder above the sweep, a run reads ``<sweep>/split=190-10``, and runs of several sweeps in
one log folder stay apart. ``conf/config.yaml`` sets ``hydra.sweep.subdir:
${gripdem.run_name:}``; the resolver reads the job's own overrides and the sweep's:

- the basic sweeper: the command line's sweep overrides (``split=190-10,100-100``, ranges,
  globs) and ``hydra.sweeper.params``, from the ``multirun.yaml`` it writes before the jobs
  start; jobs that would share a name (the same overrides twice) get their job number too
  (``seed=0,job=3``), so event files are never merged;
- other sweepers (Optuna): the keys of ``hydra.sweeper.params``, with the trial's number first
  (``trial=7,model.lr=0.00123``): trials are chosen as the sweep goes and may repeat;
- a sweep of one job (no key swept): its scene, split and model.

Values are written as given (floats with 4 significant digits, a path by its file name); a
``/`` in a key becomes ``.`` so that a name is one folder.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from gripdem.evaluation.sweep_console import shown_value

#: the resolver's name in configs: ``${gripdem.run_name:}``
RESOLVER = "gripdem.run_name"
#: longest name kept whole (longer ones are cut and get the job number)
MAX_NAME = 120
#: what names a job when no key is swept
DEFAULT_KEYS = ("scene", "split", "model")


def _parser():
    from hydra.core.override_parser.overrides_parser import OverridesParser

    return OverridesParser.create()


def _parse(overrides: list[str]) -> list:
    return _parser().parse_overrides(list(overrides))


def swept_keys(task_overrides: list[str], sweeper_params: dict[str, Any] | None) -> list[str]:
    """Keys that take several values in a sweep, in command-line order: sweep overrides
    (``a=1,2``, ``range``, ``glob``, ``choice``) and every ``hydra.sweeper.params`` key."""
    keys = [o.get_key_element() for o in _parse(task_overrides) if o.is_sweep_override()]
    for key in sweeper_params or {}:
        if key not in keys:
            keys.append(str(key))
    return keys


def override_keys(overrides: list[str]) -> list[str]:
    """The keys that overrides set, as written (``model.lr``, ``model/encoder``; ``+``
    dropped), deletions (``~key``) left out."""
    parsed = _parse(overrides)
    return [o.get_key_element().lstrip("+") for o in parsed if not o.is_delete()]


def name_of(job_overrides: list[str], keys: list[str]) -> str:
    """``key=value`` of the swept ``keys`` among one job's overrides, joined by ``,``."""
    values = {}
    for override in _parse(job_overrides):
        values[override.get_key_element()] = override.get_value_element_as_str()
    parts = [
        f"{key.lstrip('+~').replace('/', '.')}={shown_value(values[key])}"
        for key in keys
        if key in values
    ]
    return ",".join(parts)


def _default_name(config: DictConfig) -> str:
    choices = config.hydra.runtime.get("choices") or {}
    parts = []
    for key in DEFAULT_KEYS:
        value = choices.get(key) or OmegaConf.select(config, f"{key}.name", default=None)
        if value is not None:
            parts.append(f"{key}={value}")
    return ",".join(parts) or "run"


def job_name(config: DictConfig) -> str:
    """The folder name of the job whose config (with its ``hydra`` node) is ``config``."""
    hydra = config.hydra
    number = int(hydra.job.get("num") or 0)
    own = list(OmegaConf.to_container(hydra.overrides.task, resolve=False))
    target = str(hydra.sweeper.get("_target_", ""))
    params_node = hydra.sweeper.get("params")
    params = {} if params_node is None else OmegaConf.to_container(params_node, resolve=False)
    if not target.endswith("BasicSweeper"):  # trials chosen as the sweep goes
        keys = [str(k) for k in params or {}]
        name = name_of(own, keys)
        return f"trial={number}" + (f",{name}" if name else "")
    sweep_file = Path(str(hydra.sweep.dir)) / "multirun.yaml"
    sweep_overrides = own
    if sweep_file.exists():
        sweep = OmegaConf.load(sweep_file)
        sweep_overrides = list(OmegaConf.to_container(sweep.hydra.overrides.task, resolve=False))
    keys = swept_keys(sweep_overrides, params)
    name = name_of(own, keys) or _default_name(config)
    if len(name) > MAX_NAME or _repeated(own, sweep_overrides, params):
        name = f"{name[:MAX_NAME]},job={number}"
    return name


def _repeated(own: list[str], sweep_overrides: list[str], params) -> bool:
    """Whether another job of the basic sweep gets the same name: the jobs are the product of
    the swept keys' values, so two share every swept value exactly when one of this job's
    values is listed twice for its key (``seed=0,0``)."""
    values = {o.get_key_element(): o.get_value_element_as_str() for o in _parse(own)}
    arguments = [f"{k}={v}" for k, v in (params or {}).items()] + list(sweep_overrides)
    for override in _parse(arguments):
        key = override.get_key_element()
        if not override.is_sweep_override() or key not in values:
            continue
        try:
            listed = list(override.sweep_string_iterator())
        except Exception:  # noqa: BLE001 - a glob needs Hydra's config loader: distinct values
            continue
        if listed.count(values[key]) > 1:
            return True
    return False


def _resolve(*, _root_: DictConfig) -> str:
    return job_name(_root_)


def register_resolver() -> None:
    """Make ``${gripdem.run_name:}`` known to OmegaConf (idempotent)."""
    if not OmegaConf.has_resolver(RESOLVER):
        OmegaConf.register_new_resolver(RESOLVER, _resolve)


def hydra_choices(cfg: DictConfig) -> dict[str, str]:
    """Hydra's chosen config files (``{"preset": "tiny", "experiment": "smoke", ...}``): from
    the config's own ``hydra`` node, else from the running job (empty outside Hydra)."""
    node = OmegaConf.select(cfg, "hydra.runtime.choices", default=None)
    if node is None:
        from hydra.core.hydra_config import HydraConfig

        if not HydraConfig.initialized():
            return {}
        node = HydraConfig.get().runtime.choices
    return {str(k): str(v) for k, v in (node or {}).items() if v is not None}
