"""gripdem's Python API: the stable names, re-exported at ``gripdem``.

    import gripdem
    model = gripdem.load_model("pretrained:lebc")
    data = gripdem.generate("lebc", preset="tiny", sims=1)
    run = model.rollout(data.positions[0], data.times[0], frames=100, scene=data.scene)
    print(gripdem.physics(run.trajectory()).table())

Stability: a name in ``__all__`` that changes is first kept as a deprecated alias for one minor
release: it still works, warns with a ``DeprecationWarning`` naming its replacement, and is
listed in ``DEPRECATED``; the next minor release removes it (before 1.0; from 1.0, the next
major release). ``import gripdem`` and ``import gripdem.api`` import neither torch nor the
model code; that happens when a model is loaded or a simulation runs.
"""

from __future__ import annotations

import importlib
import warnings
from typing import Any

from gripdem.api.coupling import Surrogate
from gripdem.api.dem_physics import generate, physics
from gripdem.api.loading import load_model
from gripdem.api.model import TRAINING, Model
from gripdem.api.rollout_result import RolloutError, RolloutResult
from gripdem.api.scene import Scene
from gripdem.api.trajectory import Trajectory, read_trajectory, write_trajectory
from gripdem.errors import (  # the exceptions: one base, GripdemError
    CheckpointError,
    DatasetError,
    GenerationError,
    GripdemError,
    IncompatibleError,
    RolloutDiverged,
    SplitError,
)

__all__ = [
    "Model",
    "PhysicsReport",
    "RolloutError",
    "RolloutResult",
    "Scene",
    "Surrogate",
    "TRAINING",
    "Trajectory",
    "generate",
    "load_model",
    "physics",
    "read_trajectory",
    "write_trajectory",
    "CheckpointError",
    "DatasetError",
    "GenerationError",
    "GripdemError",
    "IncompatibleError",
    "RolloutDiverged",
    "SplitError",
]

#: public names whose module imports torch: imported on first use
LAZY = {"PhysicsReport": ("gripdem.evaluation.trajectory_physics", "TrajectoryPhysics")}

#: deprecated name -> (its replacement in ``__all__``, the version that deprecated it)
DEPRECATED: dict[str, tuple[str, str]] = {}


def __getattr__(name: str) -> Any:
    if name in LAZY:
        module, attribute = LAZY[name]
        return getattr(importlib.import_module(module), attribute)
    if name in DEPRECATED:
        new, since = DEPRECATED[name]
        warnings.warn(
            f"gripdem.{name} is deprecated since gripdem {since}: use gripdem.{new}",
            DeprecationWarning,
            stacklevel=2,
        )
        return globals()[new]
    raise AttributeError(f"module 'gripdem.api' has no attribute {name!r}")
