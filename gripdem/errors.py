"""gripdem's exception hierarchy: one base, one class per kind of failure.

Every error gripdem raises on purpose is a :class:`GripdemError` and also a subclass of the
built-in exception it has always been (``ValueError`` for bad input, ``RuntimeError`` for a
generation that failed its checks, ``FloatingPointError`` for a diverged rollout), so
``except ValueError`` keeps working. Each message names the file, field or option, what was
found and what was expected. The commands print it as one ``error: ...`` line; the Python API
raises it (``docs/reference/errors.md`` lists them). Exported at ``gripdem``::

    GripdemError
    ├── DatasetError        (ValueError)          bad trajectory data or file
    │   ├── DumpError                             a LAMMPS / LIGGGHTS dump
    │   └── FordatisError                         the authors' Fordatis files
    ├── SplitError          (ValueError)          a split or protocol that does not fit the data
    ├── CheckpointError     (ValueError)          a model file that cannot be loaded safely
    ├── IncompatibleError   (ValueError)          a model applied to a scene it cannot serve
    ├── GenerationError     (RuntimeError)        built-in DEM data that failed its checks
    └── RolloutDiverged     (FloatingPointError)  a model that predicted non-finite positions

This is a ground module: it imports nothing from gripdem.
"""

from __future__ import annotations

import os
from typing import Any

__all__ = [
    "CheckpointError",
    "DatasetError",
    "GenerationError",
    "GripdemError",
    "IncompatibleError",
    "RolloutDiverged",
    "SplitError",
]


class GripdemError(Exception):
    """The base of every error gripdem raises on purpose (a bug raises something else)."""


class DatasetError(GripdemError, ValueError):
    """Bad trajectory data: the message names the file, the field and the expectation."""

    def __init__(self, path: str | os.PathLike | None, field_name: str, message: str):
        self.path = None if path is None else str(path)
        self.field = field_name
        where = "<in memory>" if path is None else str(path)
        super().__init__(f"{where}: field '{field_name}': {message}")


class SplitError(GripdemError, ValueError):
    """A split, history length or protocol that does not fit the data (message says what fits)."""


class CheckpointError(GripdemError, ValueError):
    """A checkpoint or model file that cannot be loaded (safely): names file, field, finding."""

    def __init__(self, path: str | os.PathLike, field: str, message: str):
        self.path, self.field = str(path), field
        super().__init__(f"{path}: field '{field}': {message}")


class IncompatibleError(GripdemError, ValueError):
    """A model that cannot be applied to a dataset or scene: names the data, the field and the
    checkpoint (the rule: ``docs/reference/rules.md``)."""

    def __init__(self, data: Any, checkpoint: Any, field: str, message: str):
        self.path, self.checkpoint, self.field = str(data), str(checkpoint), field
        super().__init__(f"{data}: field '{field}': {message} (checkpoint {checkpoint})")


class GenerationError(GripdemError, RuntimeError):
    """Data of the built-in DEM that failed a plausibility check (the message names which)."""


class RolloutDiverged(GripdemError, FloatingPointError):
    """A model predicted non-finite positions. ``partial`` holds what was predicted before
    (a ``RolloutResult`` from ``Model.rollout``, the frames array from ``Surrogate.advance``):
    nothing finite is lost."""

    def __init__(self, message: str, partial: Any = None):
        self.partial = partial
        super().__init__(message)
