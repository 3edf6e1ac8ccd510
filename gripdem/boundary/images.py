"""Wrapping and minimum images in the Lees-Edwards lattice ``(lx, 0, delta), (0, ly, 0),
(0, 0, lz)`` (a periodic box is the case delta = 0).

``offset`` arguments are LE offsets delta in length units, broadcastable to
``positions.shape[:-1]``; for two positions of the same frame use that frame's offset, for a
difference between frames the offset of the LATER frame (docs/spec/conventions.md#which-offset)."""

from __future__ import annotations

from gripdem.boundary._array import Array, _as_offset, _image_count, _stack, wrap_coordinate
from gripdem.boundary.cell import Box


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
