"""Trajectories held in memory, and the gripdem HDF5 format read and written from Python.

Nothing here imports torch.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gripdem.api.scene import Scene

if TYPE_CHECKING:
    from gripdem.data.schema import TrajectoryData


@dataclass
class Trajectory:
    """Trajectories of one scene held in memory.

    Attributes:
        positions: ``(sims, frames, particles, 3)`` wrapped positions, m, float64.
        times: ``(sims, frames)`` absolute frame times, s, float64.
        scene: the ``Scene``.
        velocities: optional ``(sims, frames, particles, 3)``, m/s.
        provenance: what made the data (generator and its parameters, or importer).

    Args:
        positions: ``(sims, frames, particles, 3)``, or ``(frames, particles, 3)`` for one
            simulation (a leading axis of 1 is added), m.
        times: ``(sims, frames)``, or ``(frames,)`` for one simulation, s.
        scene: the ``Scene`` the positions live in.
        velocities: optional, shaped like ``positions``, m/s.
        provenance: what made the data (written to the file's provenance).

    Raises:
        ValueError: positions that are not ``(sims, frames, particles, 3)``, or times that
            do not match them.

    Examples:
        Your own positions of one simulation, in a periodic cell (whether they form a valid
        dataset is checked when written, by ``write_trajectory``):

        >>> import numpy as np
        >>> import gripdem
        >>> scene = gripdem.Scene(box=(1e-5, 1e-5, 1e-5), diameter=1e-6, frame_interval=1e-6)
        >>> positions = np.random.default_rng(0).uniform(-5e-6, 5e-6, size=(20, 100, 3))
        >>> trajectory = gripdem.Trajectory(positions, scene.times(20), scene)
        >>> trajectory.positions.shape, trajectory.times.shape
        ((1, 20, 100, 3), (1, 20))
        >>> trajectory.n_sims, trajectory.n_frames, trajectory.n_particles
        (1, 20, 100)
        >>> gripdem.Trajectory(positions, scene.times(19), scene)
        Traceback (most recent call last):
            ...
        ValueError: Trajectory.times: expected (1, 20) (sims, frames), got (1, 19)
    """

    positions: np.ndarray
    times: np.ndarray
    scene: Scene
    velocities: np.ndarray | None = None
    provenance: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.positions = np.asarray(self.positions, dtype=np.float64)
        self.times = np.asarray(self.times, dtype=np.float64)
        if self.positions.ndim == 3:  # one simulation
            self.positions = self.positions[None]
        if self.times.ndim == 1:
            self.times = self.times[None]
        if self.positions.ndim != 4 or self.positions.shape[-1] != 3:
            raise ValueError(
                f"Trajectory.positions: expected (sims, frames, particles, 3), got "
                f"{self.positions.shape}"
            )
        if self.times.shape != self.positions.shape[:2]:
            raise ValueError(
                f"Trajectory.times: expected {self.positions.shape[:2]} (sims, frames), got "
                f"{self.times.shape}"
            )
        if self.velocities is not None:
            self.velocities = np.asarray(self.velocities, dtype=np.float64)

    @property
    def n_sims(self) -> int:
        """Simulations held.

        Returns:
            ``positions.shape[0]``."""
        return self.positions.shape[0]

    @property
    def n_frames(self) -> int:
        """Frames per simulation.

        Returns:
            ``positions.shape[1]``."""
        return self.positions.shape[1]

    @property
    def n_particles(self) -> int:
        """Particles per frame.

        Returns:
            ``positions.shape[2]``."""
        return self.positions.shape[2]

    @classmethod
    def _from_data(cls, data: TrajectoryData, scene: Scene | None = None) -> Trajectory:
        """From the in-memory form of the HDF5 format
        (``gripdem.data.schema.TrajectoryData``); ``scene`` default: its own, with the
        frame interval a file reader takes (the median step, checked equidistant)."""
        if scene is None:
            from gripdem.data.schema import validate_times

            interval = validate_times(None, data.times)
            scene = Scene.from_boundary(
                data.boundary, data.diameter, interval, data.body_force_amplitude
            )
        return cls(data.positions, data.times, scene, data.velocities, dict(data.provenance))

    def _to_data(self) -> TrajectoryData:
        """The in-memory form of the HDF5 format."""
        from gripdem.data.schema import TrajectoryData

        return TrajectoryData(
            positions=self.positions,
            times=self.times,
            boundary=self.scene.to_boundary(),
            radius=0.5 * self.scene.diameter,
            body_force_amplitude=self.scene.body_force_amplitude,
            provenance=dict(self.provenance),
            velocities=self.velocities,
        )


def check_frames(
    name: str, frames, times, scene: Scene, k1: int, particles: int | None = None
) -> tuple[np.ndarray, np.ndarray, bool]:
    """The last ``k1`` frames of one ``(frames, N, 3)`` or ``(S, frames, N, 3)`` array and their
    times, checked as every entry point checks a history (``Model.rollout``,
    ``Model.surrogate``, ``Surrogate.set_state``): ``(frames (S, k1, N, 3), times (S, k1),
    single)``. ``times`` None: ``scene.times`` (0, dt, 2 dt, ...).

    Raises:
        ValueError: naming ``name``: the wrong shape or particle count, too few frames,
            NaN/Inf, times of another shape or not one frame interval apart."""
    from gripdem.data.schema import TIME_RTOL

    positions = np.asarray(frames, dtype=np.float64)
    single = positions.ndim == 3
    if single:
        positions = positions[None]
    if positions.ndim != 4 or positions.shape[-1] != 3 or positions.shape[1] < k1:
        raise ValueError(
            f"{name}: expected (frames >= {k1}, particles, 3) or (sims, frames, particles, "
            f"3) positions (the model reads {k1} frames), got {np.shape(frames)}"
        )
    if particles is not None and positions.shape[2] != particles:
        raise ValueError(
            f"{name}: expected {particles} particles (the surrogate's), got {positions.shape[2]}"
        )
    if not np.isfinite(positions).all():
        raise ValueError(f"{name}: positions must be finite (NaN or Inf found)")
    if times is None:
        times = scene.times(positions.shape[1])
    times = np.asarray(times, dtype=np.float64)
    times = np.broadcast_to(times, positions.shape[:2]) if times.ndim == 1 else times
    if times.shape != positions.shape[:2]:
        raise ValueError(f"times: expected {positions.shape[:2]}, got {np.shape(times)}")
    times = np.ascontiguousarray(times[:, -k1:])
    steps = np.diff(times, axis=1)
    if not np.isfinite(times).all() or not np.allclose(
        steps, scene.frame_interval, rtol=TIME_RTOL, atol=0.0
    ):
        raise ValueError(
            f"times: the last {k1} frames must be {scene.frame_interval:.6g} s apart (the "
            f"scene's frame_interval), got steps {steps.min():.6g}..{steps.max():.6g} s"
        )
    return np.ascontiguousarray(positions[:, -k1:]), times, single


def read_trajectory(path: str | os.PathLike) -> Trajectory:
    """Read a gripdem HDF5 dataset into memory (checked: every bad field is a clear error).
    Its scene is ``Scene.from_file``'s, the one ``gripdem.predict`` applies a model in.

    Args:
        path: a gripdem HDF5 dataset (``.h5``): written by ``write_trajectory``,
            ``python -m gripdem.simulate`` or ``python -m gripdem.convert``.

    Returns:
        a ``Trajectory`` with the file's positions, times, velocities (if stored) and
        provenance.

    Raises:
        FileNotFoundError: no such file.
        DatasetError: a missing or bad field (named, with what was expected).

    Examples:
        Write a trajectory and read it back:

        >>> import numpy as np
        >>> import gripdem
        >>> scene = gripdem.Scene(box=(1e-5, 1e-5, 1e-5), diameter=1e-6, frame_interval=1e-6)
        >>> positions = np.random.default_rng(0).uniform(-5e-6, 5e-6, size=(20, 100, 3))
        >>> trajectory = gripdem.Trajectory(positions, scene.times(20), scene)
        >>> path = gripdem.write_trajectory("positions.h5", trajectory)
        >>> back = gripdem.read_trajectory(path)
        >>> back.positions.shape, back.scene == scene
        ((1, 20, 100, 3), True)
        >>> bool(np.array_equal(back.positions[0], positions))
        True
        >>> gripdem.read_trajectory("missing.h5")
        Traceback (most recent call last):
            ...
        FileNotFoundError: missing.h5: no such dataset file
    """
    from gripdem.data.dataset_io import read_dataset

    return Trajectory._from_data(read_dataset(path), Scene.from_file(path))


def write_trajectory(
    path: str | os.PathLike, trajectory: Trajectory, overwrite: bool = False
) -> Path:
    """Write ``trajectory`` as a gripdem HDF5 dataset, validated first and written atomically
    (an existing file is kept unless ``overwrite``); returns the path.

    Every command reads the file (``python -m gripdem.predict``, training with
    ``data.path=``); see docs/reference/hdf5-format.md.

    Args:
        path: where to write (``.h5``).
        trajectory: the ``Trajectory`` to write.
        overwrite: replace an existing file.

    Returns:
        ``path`` as a ``pathlib.Path``.

    Raises:
        FileExistsError: ``path`` exists and ``overwrite`` is False (nothing written).
        DatasetError: the arrays cannot form a valid dataset (named field; nothing written).

    Examples:
        >>> import numpy as np
        >>> import gripdem
        >>> scene = gripdem.Scene(box=(1e-5, 1e-5, 1e-5), diameter=1e-6, frame_interval=1e-6)
        >>> positions = np.random.default_rng(0).uniform(-5e-6, 5e-6, size=(20, 100, 3))
        >>> trajectory = gripdem.Trajectory(positions, scene.times(20), scene)
        >>> gripdem.write_trajectory("mine.h5", trajectory)
        PosixPath('mine.h5')
        >>> gripdem.write_trajectory("mine.h5", trajectory)
        Traceback (most recent call last):
            ...
        FileExistsError: mine.h5: exists; refusing to overwrite it (pass overwrite=True)
        >>> path = gripdem.write_trajectory("mine.h5", trajectory, overwrite=True)
        >>> gripdem.read_trajectory(path).n_frames
        20
    """
    from gripdem.data.dataset_io import write_dataset

    return write_dataset(path, trajectory._to_data(), overwrite=overwrite)
