"""Boundary math for orthorhombic periodic and Lees-Edwards unit cells.

Every other module calls this one; nothing re-implements wrapping, minimum images, LE offsets
or the sin/cos codec. All functions take numpy arrays or torch tensors with any leading batch
shape and return the same kind.

Conventions (SPEC §2):
- The box is centred at the origin; wrapped positions lie in ``[-l/2, l/2)`` per axis.
- Lees-Edwards: gradient axis x, flow axis z. With ``sign=+1`` the mean flow is
  ``u_z = +shear_rate * x`` and the image cell across the +x face is displaced along z by
  ``+delta(t)``, ``delta(t) = sign * shear_rate * lx * (t - time_origin)`` wrapped to
  ``[-lz/2, lz/2)``. The LE images form the triclinic lattice with cell vectors
  ``(lx, 0, delta), (0, ly, 0), (0, 0, lz)``.
- ``offset`` arguments are LE offsets delta in length units, broadcastable to
  ``positions.shape[:-1]`` (e.g. shape ``(frames, 1)`` for positions ``(frames, particles, 3)``).
  For two positions of the same frame use that frame's offset; for a difference between
  frames use the offset of the LATER frame (SPEC §2).
- Offsets are computed in float64 from absolute times and wrapped before any cast to the
  positions' dtype, because ``shear_rate * lx * t`` grows without bound.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

Array = Any  # np.ndarray | torch.Tensor

BOUNDARY_KINDS = ("periodic", "lees_edwards")
RANDOM_CLOSE_PACKING = 0.64


# --------------------------------------------------------------------------------------------
# numpy / torch dispatch
# --------------------------------------------------------------------------------------------
def _is_torch(x: Array) -> bool:
    return isinstance(x, torch.Tensor)


def _floor(x: Array) -> Array:
    return torch.floor(x) if _is_torch(x) else np.floor(x)


def _stack(parts: list, like: Array) -> Array:
    return torch.stack(parts, dim=-1) if _is_torch(like) else np.stack(parts, axis=-1)


def _as_offset(offset: Array | float | None, like: Array) -> Array:
    """Offset as an array of ``like``'s kind and dtype (after float64 wrapping upstream)."""
    if offset is None:
        offset = 0.0
    if _is_torch(like):
        return torch.as_tensor(offset, dtype=like.dtype, device=like.device)
    return np.asarray(offset, dtype=like.dtype)


def _image_count(x: Array, length: float) -> Array:
    """Whole number n with ``x - n*length`` in ``[-length/2, length/2)`` (same kind as x)."""
    n = _floor(x / length + 0.5)
    rem = x - n * length
    # floor(x/l + 0.5) can be off by one when x/l + 0.5 rounds onto an integer: fold back.
    up = rem >= 0.5 * length
    down = rem < -0.5 * length
    if _is_torch(x):
        return n + up.to(n.dtype) - down.to(n.dtype)
    return n + up - down.astype(n.dtype)


def wrap_coordinate(x: Array, length: float) -> Array:
    """Wrap values into ``[-length/2, length/2)``, robust to values many lengths away."""
    return x - length * _image_count(x, length)


# --------------------------------------------------------------------------------------------
# Box and Lees-Edwards settings
# --------------------------------------------------------------------------------------------
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


# --------------------------------------------------------------------------------------------
# Wrapping and minimum images
# --------------------------------------------------------------------------------------------
def lattice_shift(vectors: Array, box: Box, offset: Array | float | None = None) -> Array:
    """Integer lattice counts ``(n_x, n_y, n_z)`` with
    ``vectors - n_x*(lx, 0, delta) - n_y*(0, ly, 0) - n_z*(0, 0, lz)`` inside ``[-l/2, l/2)``.

    vectors: ``(..., 3)``; offset broadcastable to ``vectors.shape[:-1]``. Returns ``(..., 3)``
    counts in the dtype of ``vectors`` (whole numbers).
    """
    delta = _as_offset(offset, vectors)
    n_x = _image_count(vectors[..., 0], box.lx)
    n_y = _image_count(vectors[..., 1], box.ly)
    n_z = _image_count(vectors[..., 2] - n_x * delta, box.lz)
    return _stack([n_x, n_y, n_z], vectors)


def apply_lattice_shift(
    vectors: Array, shift: Array, box: Box, offset: Array | float | None = None
) -> Array:
    """``vectors - n_x*(lx,0,delta) - n_y*(0,ly,0) - n_z*(0,0,lz)`` for counts ``shift``."""
    delta = _as_offset(offset, vectors)
    x = vectors[..., 0] - shift[..., 0] * box.lx
    y = vectors[..., 1] - shift[..., 1] * box.ly
    z = vectors[..., 2] - shift[..., 0] * delta - shift[..., 2] * box.lz
    return _stack([x, y, z], vectors)


def minimum_image(vectors: Array, box: Box, offset: Array | float | None = None) -> Array:
    """LE-aware minimum image of difference vectors ``(..., 3)``: each component in
    ``[-l/2, l/2)`` after the x-face correction (z shifted by -/+ delta when x is folded).

    ``offset=None`` or 0 gives the plain periodic minimum image.
    """
    return apply_lattice_shift(vectors, lattice_shift(vectors, box, offset), box, offset)


def displacement(
    later: Array, earlier: Array, box: Box, offset: Array | float | None = None
) -> Array:
    """Minimum-image ``later - earlier``. For two frames pass the LATER frame's offset: the
    result is then the displacement of the particle's image continuous with ``earlier``."""
    return minimum_image(later - earlier, box, offset)


def wrap_positions(
    positions: Array,
    box: Box,
    offset: Array | float | None = None,
    velocities: Array | None = None,
    image_velocity: float = 0.0,
) -> Array | tuple[Array, Array]:
    """Wrap positions ``(..., 3)`` into the box with the LE remap.

    A particle that left through +x gets ``x -= lx, z -= delta`` and (if ``velocities`` are
    given) ``v_z -= image_velocity``; the reverse through -x. Returns the wrapped positions, or
    ``(positions, velocities)`` when velocities are given.
    """
    shift = lattice_shift(positions, box, offset)
    wrapped = apply_lattice_shift(positions, shift, box, offset)
    if velocities is None:
        return wrapped
    if image_velocity == 0.0:
        return wrapped, velocities
    vz = velocities[..., 2] - shift[..., 0] * image_velocity
    return wrapped, _stack([velocities[..., 0], velocities[..., 1], vz], velocities)


def wrap_into_sheared_cell(positions: Array, box: Box, offset: Array | float = 0.0) -> Array:
    """Positions ``(..., 3)`` (any image) moved into the sheared LE cell
    ``{-l/2 + v*(lx, 0, delta) + w*(0, ly, 0) + u*(0, 0, lz)}``, ``u, v, w`` in ``[0, 1)``: the
    parallelepiped a triclinic engine (LAMMPS) stores its atoms in, instead of the orthorhombic
    box gripdem wraps into. x and y are wrapped as usual; z lies in ``[-lz/2, lz/2) + v*delta``
    where ``v = (x + lx/2)/lx``. Only whole lattice vectors are added (same LE image set).
    offset broadcastable to ``positions.shape[:-1]``."""
    wrapped = wrap_positions(positions, box, offset)
    delta = _as_offset(offset, wrapped)
    lift = (wrapped[..., 0] / box.lx + 0.5) * delta
    z = lift + wrap_coordinate(wrapped[..., 2] - lift, box.lz)
    return _stack([wrapped[..., 0], wrapped[..., 1], z], wrapped)


def le_offset_increments(offsets: Array, box: Box) -> Array:
    """Unwrapped growth of the LE offset between consecutive frames, ``(..., T) -> (..., T-1)``:
    ``δ(t+1) - δ(t)`` folded into ``[-lz/2, lz/2)`` is the image cell's z advance per step
    (``image_velocity * dt``), valid while it is shorter than half the box (0.064 d per frame
    at the default parameters, box 12.8 d)."""
    return wrap_coordinate(offsets[..., 1:] - offsets[..., :-1], box.lz)


def lattice_continuous_steps(
    positions: Array,
    box: Box,
    offsets: Array | None = None,
    anchor: int = 0,
    increments: Array | None = None,
) -> Array:
    """Frame-to-frame steps of the lattice-continuous trajectory, in the image cell that each
    particle occupies at frame ``anchor``.

    positions: ``(..., T, 3)`` wrapped (time on axis -2); offsets: float64 LE offsets of the
    frames, broadcastable to ``positions.shape[:-1]`` (``None``: periodic box); increments:
    unwrapped offset growth per step, broadcastable to ``(..., T-1)`` (default: from
    ``offsets``, :func:`le_offset_increments`); anchor: a frame index (negative counts from the
    end). Returns ``(..., T-1, 3)`` in the dtype of ``positions``.

    Each step is the minimum-image difference with the LATER frame's offset (the displacement of
    the image continuous with the earlier frame) plus the z drift of the image cell the particle
    sits in relative to the anchor: a particle ``m`` cells away along x moves with ``m`` times
    the image velocity on top of its own motion. With these steps a particle's velocity is smooth
    across LE faces (the affine flow ``u_z = k x`` extends continuously through the lattice), and
    ``p_anchor + cumsum(steps)`` wrapped with each frame's own offset gives the stored frames
    back: a constant step extrapolated from the anchor is the constant-velocity rollout,
    including the LE shift and the velocity jump of every crossing.
    """
    raw = positions[..., 1:, :] - positions[..., :-1, :]
    if offsets is None:
        return minimum_image(raw, box)
    later = _as_offset(offsets, raw[..., 0])[..., 1:]
    shift = lattice_shift(raw, box, later)
    steps = apply_lattice_shift(raw, shift, box, later)
    if increments is None:
        increments = le_offset_increments(_as_offset(offsets, raw[..., 0]), box)
    inc = _as_offset(increments, raw[..., 0])
    crossings = -shift[..., 0]  # +1 for a step out through +x (into image cell +1)
    cells = torch.cumsum(crossings, -1) if _is_torch(crossings) else np.cumsum(crossings, -1)
    frame = anchor % (raw.shape[-2] + 1)
    at_anchor = cells[..., frame - 1 : frame] if frame else cells[..., :1] * 0
    drift = (cells - crossings - at_anchor) * inc  # cell at the start of each step, from anchor
    return _stack([steps[..., 0], steps[..., 1], steps[..., 2] + drift], steps)


def affine_flow_strain(boundary: Boundary, frame_interval: float) -> float:
    """Strain of the LE cell's affine flow per frame, signed: ``u_z = strain * x`` per frame
    (``sign * shear_rate * dt``; 0 for a periodic box)."""
    if boundary.lees_edwards is None:
        return 0.0
    return boundary.image_velocity * float(frame_interval) / boundary.box.lx


def step_start_x(steps: Array, x_end: Array) -> Array:
    """Continuous x at the start of each step from the x at the end of the last one:
    steps ``(..., S, 3)``, x_end ``(...)`` -> ``(..., S)``."""
    dx = steps[..., 0]
    if _is_torch(dx):
        after = torch.flip(torch.cumsum(torch.flip(dx, [-1]), -1), [-1])
    else:
        after = np.flip(np.cumsum(np.flip(dx, -1), -1), -1)
    return x_end[..., None] - after


def remove_affine_flow(steps: Array, x_start: Array, strain: float) -> Array:
    """Flow-relative (non-affine) steps: z minus the affine flow ``strain * x_mid`` of each
    step, ``x_mid = x_start + dx / 2`` (continuous x). steps ``(..., S, 3)``, x_start
    ``(..., S)``. The result does not depend on which LE image a particle is followed in (the
    image's z velocity and its x differ by one image velocity and one box length), so a model
    or baseline in these coordinates is LE-consistent by construction."""
    if strain == 0.0:
        return steps
    z = steps[..., 2] - strain * (x_start + 0.5 * steps[..., 0])
    return _stack([steps[..., 0], steps[..., 1], z], steps)


def add_affine_flow(relative: Array, x_start: Array, strain: float) -> Array:
    """Inverse of :func:`remove_affine_flow`."""
    if strain == 0.0:
        return relative
    z = relative[..., 2] + strain * (x_start + 0.5 * relative[..., 0])
    return _stack([relative[..., 0], relative[..., 1], z], relative)


def unwrap_trajectory(
    positions: Array, box: Box, offsets: Array | None = None, offset_increments: Array | None = None
) -> Array:
    """Lattice-continuous trajectory from wrapped positions, frames first.

    positions: ``(frames, ..., 3)`` wrapped. offsets: ``(frames,)`` float64 LE offsets of each
    frame (``None`` for periodic). offset_increments: ``(frames-1,)`` unwrapped increments
    ``delta(t+1) - delta(t)`` (= image_velocity * dt; default: from the offsets).

    Frame 0 is the anchor (continuous = wrapped there); see :func:`lattice_continuous_steps`.
    The result satisfies ``wrap_positions(unwrapped[t], box, offsets[t]) == positions[t]`` (to
    rounding). Assumes every true frame-to-frame displacement is shorter than half the box.
    """
    xp_torch = _is_torch(positions)
    moved = torch.movedim(positions, 0, -2) if xp_torch else np.moveaxis(positions, 0, -2)
    steps = lattice_continuous_steps(moved, box, offsets, 0, offset_increments)
    if xp_torch:
        steps = torch.movedim(steps, -2, 0)
        return torch.cat([positions[:1], positions[:1] + torch.cumsum(steps, 0)], 0)
    steps = np.moveaxis(steps, -2, 0)
    return np.concatenate([positions[:1], positions[:1] + np.cumsum(steps, 0)], 0)


def rewrap_trajectory(continuous: Array, box: Box, offsets: Array | None = None) -> Array:
    """Inverse of :func:`unwrap_trajectory`: wrap frame t with its own offset."""
    if offsets is None:
        return wrap_positions(continuous, box)
    extra = continuous.ndim - 2
    off = offsets.reshape((continuous.shape[0],) + (1,) * extra)
    return wrap_positions(continuous, box, off)


# --------------------------------------------------------------------------------------------
# sin/cos codec
# --------------------------------------------------------------------------------------------
def sincos_encode(positions: Array, box: Box) -> Array:
    """``(..., 3)`` positions -> ``(..., 6)`` features
    ``[sin θx, cos θx, sin θy, cos θy, sin θz, cos θz]`` with ``θ = 2π·p/l`` per axis."""
    lengths = box.lengths
    if _is_torch(positions):
        lengths_t = torch.as_tensor(lengths, dtype=positions.dtype, device=positions.device)
        angle = 2 * math.pi * positions / lengths_t
        out = torch.stack([torch.sin(angle), torch.cos(angle)], dim=-1)
    else:
        angle = 2 * np.pi * positions / lengths
        out = np.stack([np.sin(angle), np.cos(angle)], axis=-1)
    return out.reshape(*positions.shape[:-1], 6)


def sincos_decode(features: Array, box: Box) -> Array:
    """``(..., 6)`` features -> ``(..., 3)`` positions in ``[-l/2, l/2)``.

    Uses atan2 on each (sin, cos) pair: correct in all four quadrants and for pairs off the
    unit circle (only the direction counts). A pair at the origin decodes to 0.
    """
    pairs = features.reshape(*features.shape[:-1], 3, 2)
    lengths = box.lengths
    if _is_torch(features):
        angle = torch.atan2(pairs[..., 0], pairs[..., 1])
        lengths_t = torch.as_tensor(lengths, dtype=features.dtype, device=features.device)
        pos = angle * lengths_t / (2 * math.pi)
    else:
        angle = np.arctan2(pairs[..., 0], pairs[..., 1])
        pos = angle * lengths / (2 * np.pi)
    return _stack([wrap_coordinate(pos[..., i], float(lengths[i])) for i in range(3)], pos)


# --------------------------------------------------------------------------------------------
# Checks shared by readers, generators and models
# --------------------------------------------------------------------------------------------
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
    bad = ~torch.isfinite(values) if _is_torch(values) else ~np.isfinite(values)
    if bad.any():
        count = int(bad.sum())
        first = tuple(
            int(i) for i in (torch.nonzero(bad)[0] if _is_torch(values) else np.argwhere(bad)[0])
        )
        raise FloatingPointError(
            f"{what}: {count} non-finite value(s) (NaN or Inf), first at index {first}"
        )
