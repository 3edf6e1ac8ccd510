"""Lattice-continuous trajectories: frame-to-frame steps that stay smooth across the
Lees-Edwards faces, the affine flow of the sheared cell, unwrapping and rewrapping.

A particle that crosses an LE face keeps its lattice-continuous motion
(docs/spec/conventions.md#lattice-continuous): in these coordinates a constant step extrapolated
from an anchor frame is the constant-velocity rollout, including the LE shift and the velocity jump
of every crossing."""

from __future__ import annotations

import numpy as np

from gripdem.boundary._array import (
    Array,
    _as_offset,
    _cumsum_last,
    _is_torch,
    _stack,
    wrap_coordinate,
)
from gripdem.boundary.cell import Boundary, Box
from gripdem.boundary.images import (
    apply_lattice_shift,
    lattice_shift,
    minimum_image,
    wrap_positions,
)


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
    cells = _cumsum_last(crossings)
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
        import torch

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
    if _is_torch(positions):
        import torch

        moved = torch.movedim(positions, 0, -2)
        steps = lattice_continuous_steps(moved, box, offsets, 0, offset_increments)
        steps = torch.movedim(steps, -2, 0)
        return torch.cat([positions[:1], positions[:1] + torch.cumsum(steps, 0)], 0)
    moved = np.moveaxis(positions, 0, -2)
    steps = lattice_continuous_steps(moved, box, offsets, 0, offset_increments)
    steps = np.moveaxis(steps, -2, 0)
    return np.concatenate([positions[:1], positions[:1] + np.cumsum(steps, 0)], 0)


def rewrap_trajectory(continuous: Array, box: Box, offsets: Array | None = None) -> Array:
    """Inverse of :func:`unwrap_trajectory`: wrap frame t with its own offset."""
    if offsets is None:
        return wrap_positions(continuous, box)
    extra = continuous.ndim - 2
    off = offsets.reshape((continuous.shape[0],) + (1,) * extra)
    return wrap_positions(continuous, box, off)
