"""gripdem: graph-based trajectory forecasts (GRIP++, PCT, VCT) for DEM unit cells.

The Python API (:mod:`gripdem.api`) is re-exported here and imported on first use, so
``import gripdem`` stays fast and imports no torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from gripdem._version import __version__

if TYPE_CHECKING:  # the names below, for type checkers and IDEs
    from gripdem.api import *  # noqa: F403

#: the names of :mod:`gripdem.api` available as ``gripdem.<name>``
API_NAMES = (
    "CheckpointError",
    "DatasetError",
    "GenerationError",
    "GripdemError",
    "IncompatibleError",
    "Model",
    "PhysicsReport",
    "RolloutDiverged",
    "RolloutError",
    "RolloutResult",
    "Scene",
    "SplitError",
    "Surrogate",
    "TRAINING",
    "Trajectory",
    "generate",
    "load_model",
    "physics",
    "read_trajectory",
    "write_trajectory",
)

__all__ = ["__version__", *API_NAMES]


def __getattr__(name: str) -> Any:
    if name in API_NAMES:
        from gripdem import api

        return getattr(api, name)
    if name != "api":
        from gripdem import api

        if name in api.DEPRECATED:
            return getattr(api, name)
    raise AttributeError(f"module 'gripdem' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(API_NAMES))
