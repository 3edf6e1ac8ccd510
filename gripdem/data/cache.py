"""Dataset cache (SPEC §3): generated scenes live in one documented place, keyed by a hash.

Location: ``$GRIPDEM_DATA`` if set, else the user cache directory
(``platformdirs.user_cache_dir("gripdem")``, e.g. ``~/.cache/gripdem`` on Linux).
File name: ``<scene>-<preset>-<key>.h5`` where ``key`` hashes the full generator
configuration (scene physics, preset sizes, sims, seed, backend) and the generator version,
so a changed parameter or a new generator version never reuses a stale file. A file lock
(``<file>.lock``) makes parallel sweep jobs wait for one generation instead of racing; the
dataset is written atomically, so a crash or Ctrl-C leaves nothing half-written. The
validation report (``.validation.json`` + ``.profile.png``) is written next to it.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from filelock import FileLock

from gripdem.dem.params import GENERATOR_VERSION, GeneratorConfig

log = logging.getLogger(__name__)

ENV_VAR = "GRIPDEM_DATA"


def data_root(root: str | os.PathLike | None = None) -> Path:
    """``root``, else ``$GRIPDEM_DATA``, else the user cache directory."""
    if root is not None:
        return Path(root)
    if os.environ.get(ENV_VAR):
        return Path(os.environ[ENV_VAR])
    from platformdirs import user_cache_dir

    return Path(user_cache_dir("gripdem"))


def config_key(config: GeneratorConfig) -> str:
    """16 hex digits of SHA-256 over the configuration and the generator version."""
    payload = json.dumps(
        {"config": config.to_dict(), "generator_version": GENERATOR_VERSION},
        sort_keys=True,
        default=str,
    )
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


def dataset_path(config: GeneratorConfig, root: str | os.PathLike | None = None) -> Path:
    return data_root(root) / f"{config.scene.name}-{config.preset.name}-{config_key(config)}.h5"


def ensure_scene_dataset(
    scene: Mapping[str, Any],
    preset: Mapping[str, Any],
    *,
    sims: int | None = None,
    seed: int = 0,
    backend: str = "numba",
    root: str | os.PathLike | None = None,
    progress: bool = True,
    workers: int | None = None,
    device: str = "cpu",
) -> Path:
    """Path of the cached dataset for this configuration, generating it first if needed.

    ``scene``/``preset``: the config nodes (``conf/scene/*.yaml``, ``conf/preset/*.yaml``) as
    dicts or DictConfigs; ``sims`` overrides the preset's number of simulations.
    """
    from gripdem.dem.output import generate_dataset

    config = GeneratorConfig.from_mappings(scene, preset, sims=sims, seed=seed, backend=backend)
    path = dataset_path(config, root)
    if path.exists():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(str(path) + ".lock"):
        if path.exists():  # another job generated it while we waited
            return path
        message = (
            f"gripdem: generating dataset {path.name} ({config.sims} x "
            f"{config.preset.frames} frames x {config.preset.particles} particles, "
            f"scene {config.scene.name}) into {path.parent}"
        )
        if log.hasHandlers():  # Hydra / Lightning configured logging
            log.info(message)
        else:
            print(message, flush=True)
        generate_dataset(config, path, progress=progress, workers=workers, device=device)
    return path
