"""The tests' tiny DEM scenes: made once per test run in a shared dataset cache, and, for a
whole-suite run under pytest-xdist, ahead of the tests.

``tiny_dataset(scene, root)`` is what the ``tiny_pbc_path`` / ``tiny_lebc_path`` fixtures
return: the dataset of ``python -m gripdem.simulate scene=<scene> preset=tiny``, through the
dataset cache (:func:`gripdem.dem.output.ensure_scene_dataset`), whose file lock makes a second
process that needs it wait for the first one's generation instead of making it again.

``python tests/support/tiny_scenes.py ROOT`` makes both scenes in ``ROOT``. The suite's
controlling process starts it before its workers (tests/conftest.py): the workers spend their
first seconds importing and collecting the tests, and the scenes (and, in a fresh clone, the
compilation of the DEM's kernels into numba's cache, about 8 s) are made meanwhile, once,
instead of by a worker while the other waits for it.
"""

from __future__ import annotations

import sys
from pathlib import Path

from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

CONF_DIR = Path(__file__).resolve().parents[2] / "conf"
SCENES = ("pbc", "lebc")


def compose_simulate(overrides: list[str]) -> DictConfig:
    """The config ``python -m gripdem.simulate <overrides>`` would run with."""
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return compose(config_name="simulate", overrides=overrides)


def tiny_dataset(scene: str, root: Path) -> Path:
    """The tiny dataset of ``scene`` in the cache ``root`` (made if it is not there yet)."""
    from gripdem.dem.output import ensure_scene_dataset

    cfg = compose_simulate([f"scene={scene}", "preset=tiny"])
    return ensure_scene_dataset(
        cfg.scene, cfg.preset, sims=cfg.sims, seed=cfg.seed, root=root, progress=False
    )


if __name__ == "__main__":
    for name in SCENES:
        print(tiny_dataset(name, Path(sys.argv[1])), flush=True)
