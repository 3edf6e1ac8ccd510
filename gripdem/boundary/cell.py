"""The unit cell: an orthorhombic :class:`Box` centred at the origin, the Lees-Edwards settings
(:class:`LeesEdwards`: offsets in float64 from absolute times) and their pair
(:class:`Boundary`), with the checks every reader, generator and model shares."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from gripdem.boundary._array import Array, _is_torch, wrap_coordinate

BOUNDARY_KINDS = ("periodic", "lees_edwards")
RANDOM_CLOSE_PACKING = 0.64


@dataclass(frozen=True)
class Box:
    """Orthorhombic box centred at the origin. Never assumed cubic."""

    lx: float
    ly: float
    lz: float

    def __post_init__(self) -> None:
        for name in ("lx", "ly", "lz"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"Box.{name} must be a positive finite length, got {value!r}")
            object.__setattr__(self, name, float(value))

    @classmethod
    def from_lengths(cls, lengths: Array) -> Box:
        values = np.asarray(lengths, dtype=np.float64).reshape(-1)
        if values.shape != (3,):
            raise ValueError(f"box lengths must have shape (3,), got {np.shape(lengths)}")
        return cls(*(float(v) for v in values))

    @property
    def lengths(self) -> np.ndarray:
        """``(3,)`` float64 array ``(lx, ly, lz)``."""
        return np.array([self.lx, self.ly, self.lz], dtype=np.float64)

    @property
    def volume(self) -> float:
        return self.lx * self.ly * self.lz

    def volume_fraction(self, n_particles: int, diameter: float) -> float:
        return n_particles * math.pi * diameter**3 / 6.0 / self.volume


@dataclass(frozen=True)
class LeesEdwards:
    """Lees-Edwards settings: gradient axis x, flow axis z.

    ``sign=+1`` is gripdem's convention (``u_z = +shear_rate * x``, +x image shifted by +delta);
    ``sign=-1`` describes data whose +x image is shifted by -delta (the authors' scripts).
    ``time_origin`` is the time at which delta = 0.
    """

    shear_rate: float
    sign: int = 1
    time_origin: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.shear_rate) and self.shear_rate >= 0):
            raise ValueError(
                f"shear_rate must be a finite non-negative rate (1/s), got {self.shear_rate!r}; "
                "give the flow direction with sign=+1/-1"
            )
        if self.sign not in (1, -1):
            raise ValueError(f"Lees-Edwards sign must be +1 or -1, got {self.sign!r}")
        if not math.isfinite(self.time_origin):
            raise ValueError(f"time_origin must be finite, got {self.time_origin!r}")
        object.__setattr__(self, "shear_rate", float(self.shear_rate))
        object.__setattr__(self, "time_origin", float(self.time_origin))

    def image_velocity(self, box: Box) -> float:
        """z velocity of the +x image cell relative to the primary cell (signed)."""
        return self.sign * self.shear_rate * box.lx

    def offset(self, box: Box, times: Array) -> np.ndarray:
        """LE offset delta(t) in float64, wrapped to ``[-lz/2, lz/2)``; same shape as ``times``.

        Computed as ``fmod`` of the float64 product, so a time of 1e6 frame intervals keeps
        the precision of the product itself (no float32 anywhere).
        """
        t = np.asarray(times.cpu() if _is_torch(times) else times, dtype=np.float64)
        raw = self.image_velocity(box) * (t - self.time_origin)
        return wrap_coordinate(np.fmod(raw, box.lz), box.lz)


@dataclass(frozen=True)
class Boundary:
    """A box plus, for a sheared cell, its Lees-Edwards settings (``None`` = fully periodic)."""

    box: Box
    lees_edwards: LeesEdwards | None = None

    @property
    def kind(self) -> str:
        return "periodic" if self.lees_edwards is None else "lees_edwards"

    @property
    def is_lees_edwards(self) -> bool:
        return self.lees_edwards is not None

    @property
    def image_velocity(self) -> float:
        """z velocity jump of a particle crossing the +x face (0 for a periodic box)."""
        return 0.0 if self.lees_edwards is None else self.lees_edwards.image_velocity(self.box)

    def offset(self, times: Array) -> np.ndarray:
        """float64 LE offsets for ``times`` (zeros for a periodic box), same shape."""
        t = np.asarray(times.cpu() if _is_torch(times) else times, dtype=np.float64)
        if self.lees_edwards is None:
            return np.zeros_like(t)
        return self.lees_edwards.offset(self.box, t)

    def to_attrs(self) -> dict[str, Any]:
        """HDF5 attributes describing this boundary (see ``gripdem.data.schema``)."""
        le = self.lees_edwards
        return {
            "box": self.box.lengths,
            "boundary": self.kind,
            "shear_rate": 0.0 if le is None else le.shear_rate,
            "le_sign": 1 if le is None else le.sign,
            "le_time_origin": 0.0 if le is None else le.time_origin,
        }

    def describe(self) -> str:
        return json.dumps(
            {
                k: (v.tolist() if isinstance(v, np.ndarray) else v)
                for k, v in self.to_attrs().items()
            }
        )


def check_volume_fraction(n_particles: int, diameter: float, box: Box, where: str) -> float:
    """Volume fraction of ``n_particles`` spheres; raise if above random close packing."""
    phi = box.volume_fraction(n_particles, diameter)
    if not phi <= RANDOM_CLOSE_PACKING:
        raise ValueError(
            f"{where}: {n_particles} spheres of diameter {diameter:g} in a box "
            f"{box.lx:g} x {box.ly:g} x {box.lz:g} give a volume fraction of {phi:.3g}, above "
            f"random close packing ({RANDOM_CLOSE_PACKING}); is the size a radius given as a "
            "diameter, or the box in other units?"
        )
    return phi


def check_finite(values: Array, what: str) -> None:
    """Raise a clear error naming ``what`` if ``values`` holds NaN or Inf."""
    if _is_torch(values):
        import torch

        bad = ~torch.isfinite(values)
        where = torch.nonzero
    else:
        bad, where = ~np.isfinite(values), np.argwhere
    if bad.any():
        count = int(bad.sum())
        first = tuple(int(i) for i in where(bad)[0])
        raise FloatingPointError(
            f"{what}: {count} non-finite value(s) (NaN or Inf), first at index {first}"
        )
