"""Generate, validate and write one scene dataset (``gripdem.simulate``), and find or generate
the built-in scene datasets in the dataset cache (:mod:`gripdem.data.cache`): the file
``<scene>-<preset>-<key>.h5``, ``key`` hashing the full generator configuration (scene physics,
preset sizes, sims, seed, backend) and the generator version.

The DEM and its validation (:mod:`gripdem.dem.scenes`, :mod:`gripdem.dem.validation`, numba
kernels both) are imported where a dataset is generated: a run whose dataset is cached, and a
sweep's controlling process, which names its jobs' datasets, do not import them."""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import h5py

from gripdem.data.cache import cached_file, content_key, data_root
from gripdem.data.dataset_io import read_str_attr, write_dataset
from gripdem.dem.config import GeneratorConfig
from gripdem.dem.params import GENERATOR_VERSION
from gripdem.errors import GenerationError

log = logging.getLogger(__name__)


class ValidationFailed(GenerationError):
    """The generated data failed a plausibility check; the report says which."""

    def __init__(self, report: dict[str, Any], report_path: Path):
        failed = [k for k, ok in report.get("checks", {}).items() if not ok]
        super().__init__(
            f"generated data failed validation checks {failed}; nothing written "
            f"but the report {report_path}"
        )
        self.report = report


def generate_dataset(
    config: GeneratorConfig,
    path: str | os.PathLike,
    *,
    overwrite: bool = False,
    progress: bool = True,
    workers: int | None = None,
    device: str = "cpu",
    strict: bool = True,
) -> tuple[Path, dict[str, Any]]:
    """Generate ``config`` in memory, validate it, write the HDF5 atomically and the report
    (``<stem>.validation.json``, ``<stem>.profile.png``) next to it.

    With ``strict`` a failed check raises :class:`ValidationFailed` and no dataset is written.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path}: exists; refusing to overwrite it (pass overwrite=true)")
    # the DEM and its validation (numba kernels both): imported by a generation only
    from gripdem.dem.scenes import generate
    from gripdem.dem.validation import validate_trajectories, write_report

    start = time.perf_counter()
    data, results = generate(config, progress=progress, workers=workers, device=device)
    generation_time = time.perf_counter() - start
    report = validate_trajectories(
        data,
        extra={
            "scene": config.scene.name,
            "preset": config.preset.name,
            "max_overlap_all_steps_d": max(r.max_overlap for r in results),
            "generation_wall_time_s": generation_time,
            "simulation_wall_time_s": [r.wall_time for r in results],
            "dem_steps_per_sim": results[0].steps,
            "dt": config.dt,
            "neighbour_rebuilds_per_sim": [r.rebuilds for r in results],
        },
    )
    title = (
        f"{config.scene.name} / {config.preset.name}: {config.sims} x {config.preset.frames} frames"
    )
    if strict and not report["passed"]:
        json_path, _ = write_report(report, path, title)
        raise ValidationFailed(report, json_path)
    write_dataset(path, data, overwrite=overwrite)
    write_report(report, path, title)
    log.info("wrote %s (%.1f s)", path, generation_time)
    return path, report


def config_key(config: GeneratorConfig) -> str:
    """16 hex digits of SHA-256 over the configuration and the generator version."""
    return content_key({"config": config.to_dict(), "generator_version": GENERATOR_VERSION})


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
    config = GeneratorConfig.from_mappings(scene, preset, sims=sims, seed=seed, backend=backend)
    path = dataset_path(config, root)
    message = (
        f"gripdem: generating dataset {path.name} ({config.sims} x "
        f"{config.preset.frames} frames x {config.preset.particles} particles, "
        f"scene {config.scene.name}) into {path.parent}"
    )

    def generate(target: Path) -> None:
        generate_dataset(config, target, progress=progress, workers=workers, device=device)

    return cached_file(path, generate, message, lambda: not_reused_note(config, path))


def not_reused_note(config: GeneratorConfig, path: Path) -> str | None:
    """One line saying why a cached dataset of the same scene and preset (another key in
    ``path``'s folder) is not reused for ``config``: what its provenance records differently
    (generator version, spin-up, sizes, physics), the closest such file named; ``None`` when
    the folder holds none."""
    recorded = {"version": GENERATOR_VERSION, "parameters": config.to_dict()}
    wanted = _flat(json.loads(json.dumps(recorded, default=str)))  # as the provenance stores it
    closest: tuple[int, float, str, list[str]] | None = None
    for other in path.parent.glob(f"{config.scene.name}-{config.preset.name}-*.h5"):
        if other == path:
            continue
        try:
            with h5py.File(other, "r") as f:
                made = json.loads(read_str_attr(other, f, "provenance", "{}"))
            modified = other.stat().st_mtime
        except (OSError, ValueError) as exc:  # not ours, being written, or just removed
            log.debug("cache sibling %s has no readable provenance: %s", other, exc)
            continue
        parameters = made.get("parameters") if isinstance(made, dict) else None
        if not isinstance(parameters, Mapping):
            continue
        have = _flat({"version": made.get("version"), "parameters": parameters})
        differ = sorted(k for k in wanted.keys() | have.keys() if wanted.get(k) != have.get(k))
        said = [f"{_label(k)} {have.get(k, '-')} -> {wanted.get(k, '-')}" for k in differ]
        rank = (len(said), -modified, other.name, said)
        if said and (closest is None or rank < closest):
            closest = rank
    if closest is None:
        return None
    _, _, name, said = closest
    more = f" and {len(said) - 3} more" if len(said) > 3 else ""
    return f"gripdem: not reusing the cached {name} ({', '.join(said[:3])}{more}): generating anew"


def _flat(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, Mapping):
            flat.update(_flat(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def _label(key: str) -> str:
    """``parameters.preset.spinup_time`` -> ``preset.spinup_time``; ``version`` -> its name."""
    if key == "version":
        return "generator version"
    return key.removeprefix("parameters.")
