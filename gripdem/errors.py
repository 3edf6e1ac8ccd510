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
    """The base of every error gripdem raises on purpose (a bug raises something else).

    Catch it to catch them all; each subclass is also the built-in exception it has always
    been (``ValueError``, ``RuntimeError`` or ``FloatingPointError``).

    Examples:
        The shipped periodic model cannot be applied in a smaller box; the error is both a
        ``GripdemError`` and a ``ValueError``:

        >>> import gripdem
        >>> model = gripdem.load_model("pretrained:pbc")
        >>> small = model.scene.with_(box=(1.7e-5, 1.7e-5, 1.7e-5))
        >>> try:
        ...     model.check_scene(small, particles=300)
        ... except gripdem.GripdemError as error:
        ...     print(type(error).__name__, isinstance(error, ValueError))
        IncompatibleError True
    """


class DatasetError(GripdemError, ValueError):
    """Bad trajectory data: the message names the file, the field and the expectation.

    Raised by ``read_trajectory``, ``write_trajectory``, ``Scene.from_file`` and
    ``RolloutResult.save`` (nothing is written), and by the importers.

    Args:
        path: the file, or None for data in memory.
        field_name: the HDF5 field or attribute at fault (``positions``, ``times``, ...).
        message: what was found and what was expected.

    Attributes:
        path: the file as a string (None for data in memory).
        field: the field at fault.

    Examples:
        A trajectory with a NaN is refused before anything is written:

        >>> import numpy as np
        >>> import gripdem
        >>> scene = gripdem.Scene(box=(1e-5, 1e-5, 1e-5), diameter=1e-6, frame_interval=1e-6)
        >>> positions = np.random.default_rng(0).uniform(-5e-6, 5e-6, size=(20, 100, 3))
        >>> positions[3, 7, 0] = np.nan
        >>> bad = gripdem.Trajectory(positions, scene.times(20), scene)
        >>> gripdem.write_trajectory("bad.h5", bad)
        Traceback (most recent call last):
            ...
        gripdem.errors.DatasetError: bad.h5: field 'positions': expected finite values, found
        NaN/Inf: nan at simulation 0, frame 3, particle 7, axis x

        A file that is not a gripdem dataset:

        >>> from pathlib import Path
        >>> _ = Path("notes.txt").write_text("not a dataset")
        >>> try:
        ...     gripdem.read_trajectory("notes.txt")
        ... except gripdem.DatasetError as error:
        ...     print(error.path, error.field)
        notes.txt <file>
    """

    def __init__(self, path: str | os.PathLike | None, field_name: str, message: str):
        self.path = None if path is None else str(path)
        self.field = field_name
        where = "<in memory>" if path is None else str(path)
        super().__init__(f"{where}: field '{field_name}': {message}")


class SplitError(GripdemError, ValueError):
    """A split, history length or protocol that does not fit the data (message says what fits).

    Raised when a training run plans its windows (``python -m gripdem.run split=...``), which
    prints it as one ``error: ...`` line; the functions of ``gripdem.api`` do not raise it.

    Examples:
        The training command reads its ``split=`` option (``h-f``: history and horizon) with
        ``gripdem.data.windows.Split.parse``, which refuses a malformed one:

        >>> import gripdem
        >>> from gripdem.data.windows import Split
        >>> Split.parse("190-10")
        Split(history=190, horizon=10)
        >>> Split.parse("190/10")
        Traceback (most recent call last):
            ...
        gripdem.errors.SplitError: a split is written 'h-f' with whole numbers (e.g. '190-10'),
        got '190/10'
        >>> issubclass(gripdem.SplitError, ValueError)
        True
    """


class CheckpointError(GripdemError, ValueError):
    """A checkpoint or model file that cannot be loaded (safely): names file, field, finding.

    Raised by ``load_model`` (and ``python -m gripdem.predict``): a file that is not a gripdem
    model, tensors that do not fit the hyperparameters, or a pickle that would run code
    (nothing in it is run).

    Args:
        path: the model file.
        field: the part of the file at fault (``<file>``, ``state_dict``, ...).
        message: what was found and what was expected.

    Attributes:
        path: the file as a string.
        field: the part at fault.

    Examples:
        >>> from pathlib import Path
        >>> import gripdem
        >>> _ = Path("notes.txt").write_text("not a model")
        >>> gripdem.load_model("notes.txt")
        Traceback (most recent call last):
            ...
        gripdem.errors.CheckpointError: notes.txt: field '<file>': not a readable PyTorch
        checkpoint: expected a Lightning .ckpt (a zip file) or a gripdem .safetensors model
        file, found a file starting with b'not a mo'
    """

    def __init__(self, path: str | os.PathLike, field: str, message: str):
        self.path, self.field = str(path), field
        super().__init__(f"{path}: field '{field}': {message}")


class IncompatibleError(GripdemError, ValueError):
    """A model that cannot be applied to a dataset or scene: names the data, the field and the
    checkpoint (the rule: ``docs/reference/rules.md``).

    Raised by ``Model.check_scene``, ``Model.rollout`` and ``Model.surrogate`` (and
    ``python -m gripdem.predict``) before anything is predicted.

    Args:
        data: the data or scene (its file, or ``<scene in memory>``).
        checkpoint: the model file.
        field: the scene's field that differs (``box``, ``boundary``, ...).
        message: both values and why the model cannot be applied.

    Attributes:
        path: the data as a string.
        checkpoint: the model file as a string.
        field: the field that differs.

    Examples:
        The shipped periodic model depends on its box (its drive's wavelength), so a smaller
        box is refused:

        >>> import gripdem
        >>> model = gripdem.load_model("pretrained:pbc")
        >>> small = model.scene.with_(box=(1.7e-5, 1.7e-5, 1.7e-5))
        >>> model.check_scene(small, particles=300)
        Traceback (most recent call last):
            ...
        gripdem.errors.IncompatibleError: <scene in memory>: field 'box': box: data 1.7e-05 vs
        model 3.1986e-05 ...
    """

    def __init__(self, data: Any, checkpoint: Any, field: str, message: str):
        self.path, self.checkpoint, self.field = str(data), str(checkpoint), field
        super().__init__(f"{data}: field '{field}': {message} (checkpoint {checkpoint})")


class GenerationError(GripdemError, RuntimeError):
    """Data of the built-in DEM that failed a plausibility check (the message names which).

    Raised by ``generate`` (with ``validate=True``, the default) and ``python -m
    gripdem.simulate``.

    Examples:
        A periodic scene without its body force has no imposed flow profile to check:

        >>> import gripdem
        >>> gripdem.generate("pbc", "tiny", sims=1, particles=300, frames=11,
        ...                  physics={"body_force_shear_rate": 0.0})
        Traceback (most recent call last):
            ...
        gripdem.errors.GenerationError: the generated data failed the validation checks
        [...'profile_fit_r2_above_0.95'] (scene 'pbc', preset 'tiny')
    """


class RolloutDiverged(GripdemError, FloatingPointError):
    """A model predicted non-finite positions. ``partial`` holds what was predicted before
    (a ``RolloutResult`` from ``Model.rollout``, the frames array from ``Surrogate.advance``):
    nothing finite is lost.

    Args:
        message: where the model stopped and how many frames were predicted.
        partial: the finite frames predicted before it.

    Attributes:
        partial: a ``RolloutResult`` (from ``Model.rollout``) or a frames array
            (from ``Surrogate.advance``), or None.

    Examples:
        A model whose weights are NaN stands for one that diverges: the rollout raises, and
        ``partial`` keeps the frames before (here none, the first prediction is already NaN):

        >>> import gripdem
        >>> model = gripdem.load_model("pretrained:lebc")
        >>> data = gripdem.generate("lebc", "tiny", sims=1, particles=300, frames=21)
        >>> for weight in model.module(data.scene).parameters():
        ...     _ = weight.data.fill_(float("nan"))
        >>> try:
        ...     model.rollout(data.positions[0, :11], data.times[0, :11], scene=data.scene)
        ... except gripdem.RolloutDiverged as error:
        ...     print(error.partial.n_observed, error.partial.n_predicted)
        ...     print(isinstance(error, FloatingPointError))
        11 0
        True
    """

    def __init__(self, message: str, partial: Any = None):
        self.partial = partial
        super().__init__(message)
