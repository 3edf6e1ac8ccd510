"""Scenes and trajectories held in memory: the data types of the Python API.

Nothing here imports torch; ``gripdem.boundary`` (which does) is imported when a method
needs the boundary math.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from gripdem.boundary import Boundary
    from gripdem.data.schema import DatasetMeta, TrajectoryData

BOUNDARIES = ("periodic", "lees_edwards")
#: where a scene's numbers may differ and still describe the same scene (relative)
SAME_SCENE_RTOL = 1e-9


def _positive(name: str, value: Any) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"Scene.{name}: expected a positive number, got {value!r}") from None
    if not (math.isfinite(number) and number > 0):
        raise ValueError(f"Scene.{name}: expected a positive finite number, got {value!r}")
    return number


@dataclass(frozen=True)
class Scene:
    """A periodic unit cell and its particles, described in memory (SI units).

    Args:
        box: ``(lx, ly, lz)`` in metres; the box is centred at the origin and positions lie in
            ``[-l/2, l/2)``.
        diameter: particle diameter, m.
        frame_interval: seconds between two frames.
        boundary: ``"periodic"`` or ``"lees_edwards"`` (gradient x, flow z).
        shear_rate: Lees-Edwards shear rate, 1/s (0 for a periodic box).
        le_sign: +1 when the +x image is shifted by +delta (``u_z = +shear_rate * x``), -1 for
            the reverse convention.
        le_time_origin: the time (s) at which the Lees-Edwards offset delta is 0.
        body_force_amplitude: ``a`` in ``a_z(x) = a cos(2 pi x / lx)``, m/s² (0: none).

    Example:
        ``Scene(box=(3.2e-5,) * 3, diameter=2.5e-6, frame_interval=5e-6,
        boundary="lees_edwards", shear_rate=1000.0)``
    """

    box: tuple[float, float, float]
    diameter: float
    frame_interval: float
    boundary: str = "periodic"
    shear_rate: float = 0.0
    le_sign: int = 1
    le_time_origin: float = 0.0
    body_force_amplitude: float = 0.0

    def __post_init__(self) -> None:
        box = np.asarray(self.box, dtype=np.float64).reshape(-1)
        if box.shape != (3,) or not (np.isfinite(box).all() and (box > 0).all()):
            raise ValueError(
                f"Scene.box: expected 3 positive lengths (lx, ly, lz), got {self.box!r}"
            )
        object.__setattr__(self, "box", tuple(float(v) for v in box))
        object.__setattr__(self, "diameter", _positive("diameter", self.diameter))
        object.__setattr__(self, "frame_interval", _positive("frame_interval", self.frame_interval))
        if self.boundary not in BOUNDARIES:
            raise ValueError(f"Scene.boundary: expected one of {BOUNDARIES}, got {self.boundary!r}")
        rate = float(self.shear_rate)
        if self.boundary == "lees_edwards" and not (math.isfinite(rate) and rate > 0):
            raise ValueError(
                f"Scene.shear_rate: a lees_edwards scene needs a positive shear rate (1/s), got "
                f"{self.shear_rate!r} (the flow direction is le_sign)"
            )
        if self.boundary == "periodic" and rate != 0:
            raise ValueError(
                f"Scene.shear_rate: a periodic scene has no shear rate, got {self.shear_rate!r} "
                "(boundary='lees_edwards' for a sheared cell)"
            )
        object.__setattr__(self, "shear_rate", rate)
        if self.le_sign not in (1, -1):
            raise ValueError(f"Scene.le_sign: expected +1 or -1, got {self.le_sign!r}")
        object.__setattr__(self, "le_sign", int(self.le_sign))
        for name in ("le_time_origin", "body_force_amplitude"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ValueError(f"Scene.{name}: expected a finite number, got {value!r}")
            object.__setattr__(self, name, value)

    # ---- conversions ----------------------------------------------------------------------
    @classmethod
    def from_boundary(
        cls,
        boundary: Boundary,
        diameter: float,
        frame_interval: float,
        body_force_amplitude: float = 0.0,
    ) -> Scene:
        """The scene of a ``gripdem.boundary.Boundary`` and the particles' numbers.

        Raises:
            ValueError: a number the scene refuses (named)."""
        attrs = boundary.to_attrs()
        return cls(
            box=tuple(float(v) for v in attrs["box"]),
            diameter=diameter,
            frame_interval=frame_interval,
            boundary=attrs["boundary"],
            shear_rate=float(attrs["shear_rate"]),
            le_sign=int(attrs["le_sign"]),
            le_time_origin=float(attrs["le_time_origin"]),
            body_force_amplitude=body_force_amplitude,
        )

    @classmethod
    def from_file(cls, path: str | os.PathLike) -> Scene:
        """The scene of a gripdem HDF5 dataset (its attributes; the frame interval from its
        times), checked as every reader checks it.

        Raises:
            FileNotFoundError: no such file.
            DatasetError: a missing or bad field (named)."""
        from gripdem.data.dataset_io import read_meta

        return cls._from_meta(read_meta(path))

    @classmethod
    def _from_meta(cls, meta: DatasetMeta) -> Scene:
        """The scene of a dataset's ``DatasetMeta``."""
        return cls.from_boundary(
            meta.boundary, meta.diameter, meta.frame_interval, meta.body_force_amplitude
        )

    @classmethod
    def _from_model_scene(cls, scene: dict[str, Any]) -> Scene:
        """The scene a model file records (its ``scene`` hyperparameter)."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in scene.items() if k in names})

    def to_boundary(self) -> Boundary:
        """The ``gripdem.boundary.Boundary`` of this scene (box and Lees-Edwards): the
        conventions package (minimum image, wrapping, offsets). Raises nothing of its own."""
        from gripdem.boundary import Boundary, Box, LeesEdwards

        box = Box(*self.box)
        if self.boundary == "periodic":
            return Boundary(box)
        return Boundary(box, LeesEdwards(self.shear_rate, self.le_sign, self.le_time_origin))

    def _to_meta(self, sims: int, frames: int, particles: int, path: str = "<in memory>"):
        """A ``DatasetMeta`` of arrays of these sizes in this scene."""
        from gripdem.data.schema import DatasetMeta

        return DatasetMeta(
            path=Path(path),
            n_sims=int(sims),
            n_frames=int(frames),
            n_particles=int(particles),
            boundary=self.to_boundary(),
            radius=0.5 * self.diameter,
            frame_interval=self.frame_interval,
            body_force_amplitude=self.body_force_amplitude,
            provenance={},
            has_velocities=False,
        )

    def matches(self, other: Scene, rtol: float = SAME_SCENE_RTOL) -> bool:
        """Whether ``other`` describes the same scene (every number within ``rtol``). Raises
        nothing of its own."""
        for f in fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if isinstance(a, str):
                if a != b:
                    return False
            elif not np.allclose(a, b, rtol=rtol, atol=0.0):
                return False
        return True

    def offsets(self, times: np.ndarray) -> np.ndarray:
        """The float64 Lees-Edwards offsets delta (m) at ``times`` (zeros if periodic), from
        the absolute times (docs/spec/conventions.md#le-offset). Raises nothing of its own."""
        return self.to_boundary().offset(np.asarray(times, dtype=np.float64))

    def times(self, frames: int, start: float = 0.0) -> np.ndarray:
        """``(frames,)`` equidistant frame times from ``start`` (s), float64. Raises nothing
        of its own."""
        return float(start) + self.frame_interval * np.arange(int(frames), dtype=np.float64)

    def with_(self, **changes: Any) -> Scene:
        """A copy with some numbers changed (checked again).

        Raises:
            ValueError: a changed number the scene refuses (named)."""
        return replace(self, **changes)


@dataclass
class Trajectory:
    """Trajectories of one scene held in memory.

    Attributes:
        positions: ``(sims, frames, particles, 3)`` wrapped positions, m, float64.
        times: ``(sims, frames)`` absolute frame times, s, float64.
        scene: the ``Scene``.
        velocities: optional ``(sims, frames, particles, 3)``, m/s.
        provenance: what made the data (generator and its parameters, or importer).
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
        """Simulations held."""
        return self.positions.shape[0]

    @property
    def n_frames(self) -> int:
        """Frames per simulation."""
        return self.positions.shape[1]

    @property
    def n_particles(self) -> int:
        """Particles per frame."""
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


#: the release that removes the deprecated aliases below
ALIASES_REMOVED_IN = "0.2.0"


def _deprecated_alias(cls: type, name: str) -> None:
    """Keep ``cls.name`` working for one release as an alias of the internal ``cls._name``
    (it takes or returns internal types), warning with a ``DeprecationWarning``."""
    internal = cls.__dict__[f"_{name}"]
    kind = type(internal)
    function = internal.__func__ if isinstance(internal, classmethod) else internal

    def alias(*args, **kwargs):
        warnings.warn(
            f"{cls.__name__}.{name} is internal (it uses gripdem's internal types) and is "
            f"deprecated: it will be removed in gripdem {ALIASES_REMOVED_IN}",
            DeprecationWarning,
            stacklevel=2,
        )
        return function(*args, **kwargs)

    alias.__name__ = name
    alias.__doc__ = f"Deprecated (removed in {ALIASES_REMOVED_IN}): internal."
    setattr(cls, name, kind(alias) if kind is classmethod else alias)


for _name in ("from_meta", "to_meta", "from_model_scene"):
    _deprecated_alias(Scene, _name)
for _name in ("from_data", "to_data"):
    _deprecated_alias(Trajectory, _name)


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

    Raises:
        FileNotFoundError: no such file.
        DatasetError: a missing or bad field (named, with what was expected)."""
    from gripdem.data.dataset_io import read_dataset

    return Trajectory._from_data(read_dataset(path), Scene.from_file(path))


def write_trajectory(
    path: str | os.PathLike, trajectory: Trajectory, overwrite: bool = False
) -> Path:
    """Write ``trajectory`` as a gripdem HDF5 dataset, validated first and written atomically
    (an existing file is kept unless ``overwrite``); returns the path.

    Raises:
        FileExistsError: ``path`` exists and ``overwrite`` is False (nothing written).
        DatasetError: the arrays cannot form a valid dataset (named field; nothing written)."""
    from gripdem.data.dataset_io import write_dataset

    return write_dataset(path, trajectory._to_data(), overwrite=overwrite)
