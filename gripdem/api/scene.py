"""Scenes held in memory: the periodic or Lees-Edwards unit cell of the Python API
(trajectories: ``gripdem.api.trajectory``).

Nothing here imports torch; ``gripdem.boundary`` (which does) is imported when a method
needs the boundary math.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from gripdem.boundary import Boundary
    from gripdem.data.schema import DatasetMeta

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
    """A periodic or Lees-Edwards unit cell and its particles, described in memory (SI units).

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

    Raises:
        ValueError: a number out of range or a boundary that is not one of the two (the
            field named), a Lees-Edwards scene without a shear rate, or a periodic one with.

    Examples:
        A sheared cell of 2.5 µm particles; frozen, compared by value, usable as a dict key:

        >>> import gripdem
        >>> scene = gripdem.Scene(
        ...     box=(3.2e-5, 3.2e-5, 3.2e-5), diameter=2.5e-6, frame_interval=5e-6,
        ...     boundary="lees_edwards", shear_rate=1000.0,
        ... )
        >>> scene.boundary, scene.shear_rate
        ('lees_edwards', 1000.0)
        >>> scene.times(3)
        array([0.e+00, 5.e-06, 1.e-05])

        Every number is checked when the scene is made:

        >>> gripdem.Scene(box=(3.2e-5, 3.2e-5), diameter=2.5e-6, frame_interval=5e-6)
        Traceback (most recent call last):
            ...
        ValueError: Scene.box: expected 3 positive lengths (lx, ly, lz), got (3.2e-05, 3.2e-05)
        >>> scene.with_(shear_rate=0.0)
        Traceback (most recent call last):
            ...
        ValueError: Scene.shear_rate: a lees_edwards scene needs a positive shear rate (1/s),
        got 0.0 (the flow direction is le_sign)
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

        Args:
            boundary: the cell: box and, for a sheared one, its Lees-Edwards parameters.
            diameter: particle diameter, m.
            frame_interval: seconds between two frames.
            body_force_amplitude: ``a`` in ``a_z(x) = a cos(2 pi x / lx)``, m/s² (0: none).

        Returns:
            a ``Scene``.

        Raises:
            ValueError: a number the scene refuses (named).

        Examples:
            The inverse of ``to_boundary``:

            >>> import gripdem
            >>> scene = gripdem.Scene(
            ...     box=(3.2e-5, 3.2e-5, 3.2e-5), diameter=2.5e-6, frame_interval=5e-6,
            ...     boundary="lees_edwards", shear_rate=1000.0,
            ... )
            >>> boundary = scene.to_boundary()
            >>> gripdem.Scene.from_boundary(boundary, 2.5e-6, 5e-6) == scene
            True
        """
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

        The positions are checked (streamed in blocks) but not kept in memory.

        Args:
            path: a gripdem HDF5 dataset (``.h5``).

        Returns:
            the ``Scene`` that ``read_trajectory`` and ``gripdem.predict`` apply a model in.

        Raises:
            FileNotFoundError: no such file.
            DatasetError: a missing or bad field (named).

        Examples:
            ``data`` is the small sheared scene of the ``Model`` example
            (``gripdem.generate("lebc", "tiny", sims=1, particles=300, frames=21)``):

            >>> path = gripdem.write_trajectory("sheared.h5", data)
            >>> gripdem.Scene.from_file(path).matches(data.scene)
            True
            >>> gripdem.Scene.from_file("missing.h5")
            Traceback (most recent call last):
                ...
            FileNotFoundError: missing.h5: no such dataset file
        """
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
        conventions package (minimum image, wrapping, offsets). Raises nothing of its own.

        Returns:
            a ``gripdem.boundary.Boundary`` (``gripdem.boundary`` imports torch).

        Examples:
            >>> import gripdem
            >>> scene = gripdem.Scene(
            ...     box=(3.2e-5, 3.2e-5, 3.2e-5), diameter=2.5e-6, frame_interval=5e-6,
            ...     boundary="lees_edwards", shear_rate=1000.0,
            ... )
            >>> boundary = scene.to_boundary()
            >>> boundary.kind, boundary.is_lees_edwards
            ('lees_edwards', True)
        """
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
        nothing of its own.

        Args:
            other: another ``Scene``.
            rtol: relative tolerance on each number (the boundary must be equal).

        Returns:
            True when every field agrees.

        Examples:
            A frame interval read back from a file's times differs in its last digits:

            >>> import gripdem
            >>> scene = gripdem.Scene(
            ...     box=(3.2e-5, 3.2e-5, 3.2e-5), diameter=2.5e-6, frame_interval=5e-6,
            ...     boundary="lees_edwards", shear_rate=1000.0,
            ... )
            >>> scene.matches(scene.with_(frame_interval=5e-6 * (1 + 1e-12)))
            True
            >>> scene.matches(scene.with_(shear_rate=500.0))
            False
        """
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
        the absolute times (docs/spec/conventions.md#le-offset). Raises nothing of its own.

        Args:
            times: absolute times (s), any shape.

        Returns:
            the offsets, m, float64, shaped like ``times``.

        Examples:
            The image across the +x face slides by ``shear_rate * lx`` per second:

            >>> import gripdem
            >>> scene = gripdem.Scene(
            ...     box=(3.2e-5, 3.2e-5, 3.2e-5), diameter=2.5e-6, frame_interval=5e-6,
            ...     boundary="lees_edwards", shear_rate=1000.0,
            ... )
            >>> scene.offsets(scene.times(3)) / scene.diameter
            array([0.   , 0.064, 0.128])
        """
        return self.to_boundary().offset(np.asarray(times, dtype=np.float64))

    def times(self, frames: int, start: float = 0.0) -> np.ndarray:
        """``(frames,)`` equidistant frame times from ``start`` (s), float64. Raises nothing
        of its own.

        Args:
            frames: how many times.
            start: the first time, s.

        Returns:
            ``start + frame_interval * [0, 1, ..., frames - 1]``, float64.

        Examples:
            >>> import gripdem
            >>> scene = gripdem.Scene(
            ...     box=(3.2e-5, 3.2e-5, 3.2e-5), diameter=2.5e-6, frame_interval=5e-6,
            ...     boundary="lees_edwards", shear_rate=1000.0,
            ... )
            >>> scene.times(3)
            array([0.e+00, 5.e-06, 1.e-05])
            >>> scene.times(100, start=1e-4).shape
            (100,)
        """
        return float(start) + self.frame_interval * np.arange(int(frames), dtype=np.float64)

    def with_(self, **changes: Any) -> Scene:
        """A copy with some numbers changed (checked again).

        Args:
            **changes: fields of ``Scene`` and their new values.

        Returns:
            a new ``Scene`` (this one is frozen and stays as it is).

        Raises:
            ValueError: a changed number the scene refuses (named).
            TypeError: a name that is not a field of ``Scene``.

        Examples:
            >>> import gripdem
            >>> scene = gripdem.Scene(
            ...     box=(3.2e-5, 3.2e-5, 3.2e-5), diameter=2.5e-6, frame_interval=5e-6,
            ...     boundary="lees_edwards", shear_rate=1000.0,
            ... )
            >>> scene.with_(shear_rate=500.0).shear_rate
            500.0
            >>> scene.with_(diameter=-1.0)
            Traceback (most recent call last):
                ...
            ValueError: Scene.diameter: expected a positive finite number, got -1.0
        """
        return replace(self, **changes)
