"""The ground layer: boundary math for orthorhombic periodic and Lees-Edwards unit cells.

Every other layer calls this one; nothing re-implements wrapping, minimum images, LE offsets,
the sin/cos codec or the LE neighbour search. Modules: ``cell`` (Box, LeesEdwards, Boundary,
checks), ``images`` (wrap, minimum image), ``continuous`` (lattice-continuous steps, affine
flow, unwrap), ``codec`` (sin/cos), ``neighbours`` (the O(n) LE pair search) and ``neighbour_list``
(the same with a skin, followed over frames). All functions
take numpy arrays or torch tensors with any leading batch shape and return the same kind.

Conventions (docs/spec/conventions.md):
- The box is centred at the origin; wrapped positions lie in ``[-l/2, l/2)`` per axis.
- Lees-Edwards: gradient axis x, flow axis z. With ``sign=+1`` the mean flow is
  ``u_z = +shear_rate * x`` and the image cell across the +x face is displaced along z by
  ``+delta(t)``, ``delta(t) = sign * shear_rate * lx * (t - time_origin)`` wrapped to
  ``[-lz/2, lz/2)``. The LE images form the triclinic lattice with cell vectors
  ``(lx, 0, delta), (0, ly, 0), (0, 0, lz)``.
- ``offset`` arguments are LE offsets delta in length units, broadcastable to
  ``positions.shape[:-1]`` (e.g. shape ``(frames, 1)`` for positions ``(frames, particles, 3)``).
  For two positions of the same frame use that frame's offset; for a difference between
  frames use the offset of the LATER frame (docs/spec/conventions.md#which-offset).
- Offsets are computed in float64 from absolute times and wrapped before any cast to the
  positions' dtype, because ``shear_rate * lx * t`` grows without bound.
"""

from gripdem.boundary._array import Array, wrap_coordinate
from gripdem.boundary.cell import (
    BOUNDARY_KINDS,
    RANDOM_CLOSE_PACKING,
    Boundary,
    Box,
    LeesEdwards,
    check_finite,
    check_volume_fraction,
)
from gripdem.boundary.codec import sincos_decode, sincos_encode
from gripdem.boundary.continuous import (
    add_affine_flow,
    affine_flow_strain,
    lattice_continuous_steps,
    le_offset_increments,
    remove_affine_flow,
    rewrap_trajectory,
    step_start_x,
    unwrap_trajectory,
)
from gripdem.boundary.images import (
    apply_lattice_shift,
    displacement,
    lattice_shift,
    minimum_image,
    wrap_into_sheared_cell,
    wrap_positions,
)
from gripdem.boundary.neighbour_list import NeighbourList
from gripdem.boundary.neighbours import (
    brute_force_pairs,
    le_cell,
    neighbour_pairs,
    neighbour_pairs_with_shifts,
)

__all__ = [
    "Array",
    "BOUNDARY_KINDS",
    "RANDOM_CLOSE_PACKING",
    "Boundary",
    "Box",
    "LeesEdwards",
    "add_affine_flow",
    "affine_flow_strain",
    "apply_lattice_shift",
    "brute_force_pairs",
    "check_finite",
    "check_volume_fraction",
    "displacement",
    "lattice_continuous_steps",
    "lattice_shift",
    "le_cell",
    "le_offset_increments",
    "minimum_image",
    "NeighbourList",
    "neighbour_pairs",
    "neighbour_pairs_with_shifts",
    "remove_affine_flow",
    "rewrap_trajectory",
    "sincos_decode",
    "sincos_encode",
    "step_start_x",
    "unwrap_trajectory",
    "wrap_coordinate",
    "wrap_into_sheared_cell",
    "wrap_positions",
]
