"""Input encodings (sincos | vct | unwrapped), their decoders, and per-channel normalisation.

Every encoding turns wrapped positions into per-step deltas between consecutive frames and can
decode predicted deltas back to wrapped Cartesian positions. Shapes (numpy or torch, any
leading batch axes ``...``):

- ``encode(positions (..., N, T, 3), offsets (..., T), anchor) -> deltas (..., N, T-1, C)``
- ``decode(last (..., N, 3), deltas (..., N, f, C), offsets (..., f)) -> (..., N, f, 3)``

``offsets`` are the float64 Lees-Edwards offsets of each frame (``None`` for a periodic box);
decode takes the offsets of the PREDICTED frames. A difference between frames t and t+1 uses the
offset of the later frame t+1 (docs/spec/conventions.md#which-offset).

Channels:

- ``sincos`` (6): ``[sin x, cos x, sin y, cos y, sin z, cos z]`` of frame t+1 minus frame t, each
  axis with its own length (the paper's input). About 1e-3 at the default frame interval.
- ``vct`` (8): channels 0-3 as ``sincos``; 4-5 the "real" z difference to the image of the particle
  continuous with its previous position (``boundary.displacement`` with the later offset); 6-7
  the Lees-Edwards shift ``sincos(z_{t+1}) - sincos(z~_{t+1})``, exactly zero except at steps
  that cross an x face. ``real + shift`` = the plain ``sincos`` difference. In a periodic box the
  shift channels are zero and not computed. Same layout as the authors' VCT scripts.
- ``unwrapped`` (3): Cartesian steps of the lattice-continuous trajectory in the image cell each
  particle occupies at the ``anchor`` frame (the last observed frame of a window):
  :func:`gripdem.boundary.lattice_continuous_steps`. Decoding adds them up from the anchor and
  wraps each frame with its own offset, so a constant step is exactly the constant-velocity
  rollout with the LE shift and velocity jump of every crossing
  (docs/spec/conventions.md#lattice-continuous). This is the frame of the exact (default) decoders;
  ``sincos`` and ``vct`` are the paper's wrapped-space encodings.

:class:`Normalizer` holds per-channel mean and std (from the training split only) as plain
floats, so it can be stored in a checkpoint or in hyperparameters and restored, and the same
statistics of the per-step change of the deltas (the velocity change that constant velocity
misses: the target scale of the exact decoders).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch

from gripdem.boundary import (
    Boundary,
    Box,
    apply_lattice_shift,
    lattice_continuous_steps,
    lattice_shift,
    sincos_decode,
    sincos_encode,
    wrap_coordinate,
    wrap_positions,
)

Array = Any  # np.ndarray | torch.Tensor


# --------------------------------------------------------------------------------------------
# small numpy/torch helpers
# --------------------------------------------------------------------------------------------
def _torch(x: Array) -> bool:
    return isinstance(x, torch.Tensor)


def _cat(parts: list, like: Array) -> Array:
    return torch.cat(parts, dim=-1) if _torch(like) else np.concatenate(parts, axis=-1)


def _cumsum_steps(x: Array) -> Array:
    """Cumulative sum over the step axis (-2)."""
    return torch.cumsum(x, dim=-2) if _torch(x) else np.cumsum(x, axis=-2)


def _later_offsets(offsets: Array | None) -> Array | None:
    """``(..., T)`` frame offsets -> ``(..., 1, T-1)`` offsets of the later frame of each step,
    broadcastable to per-step arrays ``(..., N, T-1)``."""
    if offsets is None:
        return None
    later = offsets[..., 1:]
    return later[..., None, :]


def step_lattice_shifts(
    positions: Array, box: Box, offsets: Array | None = None
) -> tuple[Array, Array]:
    """Per-step lattice counts and minimum-image displacements between consecutive frames.

    positions ``(..., N, T, 3)`` wrapped; offsets ``(..., T)`` float64 (None: periodic).
    Returns ``(shift (..., N, T-1, 3), displacement (..., N, T-1, 3))``; ``shift[..., 0] != 0``
    marks a step that crossed an x face (an LE face in a sheared box).
    """
    raw = positions[..., 1:, :] - positions[..., :-1, :]
    later = _later_offsets(offsets)
    shift = lattice_shift(raw, box, later)
    return shift, apply_lattice_shift(raw, shift, box, later)


def x_face_crossings(positions: Array, box: Box, offsets: Array | None = None) -> Array:
    """``(..., N, T, 3)`` -> bool ``(..., N)``: crossed an x face in any of the T-1 steps."""
    shift, _ = step_lattice_shifts(positions, box, offsets)
    crossed = shift[..., 0] != 0
    return crossed.any(dim=-1) if _torch(crossed) else crossed.any(axis=-1)


def _step_offset(offsets: Array | None, j: int, like: Array) -> Array | float:
    """Offset of predicted step j, ``(..., f)`` -> ``(..., 1)`` (broadcast over particles), of
    ``like``'s kind. The offsets are already wrapped into the box, so a cast is safe."""
    if offsets is None:
        return 0.0
    off = offsets[..., j, None]
    if _torch(like):
        return torch.as_tensor(off, dtype=like.dtype, device=like.device)
    return np.asarray(off, dtype=like.dtype)


# --------------------------------------------------------------------------------------------
# encodings
# --------------------------------------------------------------------------------------------
class Encoding:
    """Base class: per-step deltas of wrapped positions, and their inverse."""

    name: ClassVar[str]
    n_channels: ClassVar[int]
    channel_names: ClassVar[tuple[str, ...]]

    def __init__(self, boundary: Boundary):
        self.boundary = boundary

    @property
    def box(self) -> Box:
        return self.boundary.box

    def encode(self, positions: Array, offsets: Array | None = None, anchor: int = 0) -> Array:
        """``anchor``: the frame whose image cell the deltas refer to (read by ``unwrapped``;
        the wrapped-space encodings do not depend on it)."""
        raise NotImplementedError

    def decode(self, last: Array, deltas: Array, offsets: Array | None = None) -> Array:
        raise NotImplementedError

    def _check(self, deltas: Array) -> None:
        if deltas.shape[-1] != self.n_channels:
            raise ValueError(
                f"encoding {self.name!r} decodes {self.n_channels} channels, got "
                f"deltas of shape {tuple(deltas.shape)}"
            )

    def __repr__(self) -> str:
        return f"{type(self).__name__}(boundary={self.boundary.kind})"


class SinCosEncoding(Encoding):
    """The paper's 6 channels: frame-to-frame differences of per-axis sin/cos features."""

    name = "sincos"
    n_channels = 6
    channel_names = ("dsin_x", "dcos_x", "dsin_y", "dcos_y", "dsin_z", "dcos_z")

    def position_features(self, positions: Array) -> Array:
        """``(..., 3)`` -> ``(..., 6)`` sin/cos position features (the PCT position space)."""
        return sincos_encode(positions, self.box)

    def encode(self, positions: Array, offsets: Array | None = None, anchor: int = 0) -> Array:
        feats = sincos_encode(positions, self.box)
        return feats[..., 1:, :] - feats[..., :-1, :]

    def combined(self, deltas: Array) -> Array:
        """Deltas as 6 plain sin/cos differences (identity here; VCT adds real + shift)."""
        return deltas

    def accumulate(self, last: Array, deltas: Array) -> Array:
        """Sin/cos features of the predicted frames: ``sincos(last) + cumsum(deltas)``.

        last ``(..., N, 3)``, deltas ``(..., N, f, C)`` -> ``(..., N, f, 6)`` (off the unit circle
        when the deltas are imperfect; only the direction of each pair is decoded)."""
        self._check(deltas)
        start = sincos_encode(last, self.box)[..., None, :]
        return start + _cumsum_steps(self.combined(deltas))

    def decode(self, last: Array, deltas: Array, offsets: Array | None = None) -> Array:
        """Wrapped positions ``(..., N, f, 3)`` by atan2 of the accumulated features. Exact for
        true deltas in either scene (the features are those of wrapped positions); ``offsets``
        are not needed."""
        return sincos_decode(self.accumulate(last, deltas), self.box)


class VCTEncoding(SinCosEncoding):
    """8 channels: sin/cos differences with the z pair split into real + LE shift
    (docs/spec/model.md#input-channels)."""

    name = "vct"
    n_channels = 8
    channel_names = SinCosEncoding.channel_names[:4] + (
        "dsin_z_real",
        "dcos_z_real",
        "dsin_z_shift",
        "dcos_z_shift",
    )

    def encode(self, positions: Array, offsets: Array | None = None, anchor: int = 0) -> Array:
        feats = sincos_encode(positions, self.box)
        plain = feats[..., 1:, :] - feats[..., :-1, :]
        out = _cat([plain, plain[..., 4:6] * 0], plain)  # real = plain, shift = 0 ...
        if not self.boundary.is_lees_edwards:
            return out
        shift, disp = step_lattice_shifts(positions, self.box, offsets)
        crossed = shift[..., 0] != 0  # (..., N, T-1)
        if crossed.any():  # ... except at steps that crossed an x face (rare)
            # sin/cos of the image at t+1 that is continuous with the particle at t
            image = positions[..., :-1, :][crossed] + disp[crossed]
            cont = sincos_encode(image, self.box)[..., 4:6]
            out[..., 4:6][crossed] = cont - feats[..., :-1, 4:6][crossed]
            out[..., 6:8][crossed] = feats[..., 1:, 4:6][crossed] - cont
        return out

    def combined(self, deltas: Array) -> Array:
        return _cat([deltas[..., :4], deltas[..., 4:6] + deltas[..., 6:8]], deltas)

    def decode(
        self, last: Array, deltas: Array, offsets: Array | None = None, exact_shift: bool = False
    ) -> Array:
        """``exact_shift=False`` (the paper's learned VCT): positions from real + shift channels.

        ``exact_shift=True`` (docs/spec/model.md#exact-shift): ignore the shift channels, step with
        the real channels only, detect an x-face crossing in decoded space (decoded x jumps by more
        than lx/2) and apply the known shift of that frame's offset. Needs ``offsets (..., f)`` in a
        sheared box.
        """
        if not exact_shift:
            return super().decode(last, deltas, offsets)
        self._check(deltas)
        if self.boundary.is_lees_edwards and offsets is None:
            raise ValueError("vct decode with exact_shift needs the predicted frames' offsets")
        box, out, pos = self.box, [], last
        for j in range(deltas.shape[-2]):
            feats = sincos_encode(pos, box)
            # each axis wrapped on its own (no LE remap yet)
            moved = sincos_decode(feats + deltas[..., j, :6], box)
            jump = pos[..., 0] - moved[..., 0]
            n_x = (torch.round if _torch(jump) else np.round)(jump / box.lx)
            z = wrap_coordinate(moved[..., 2] - n_x * _step_offset(offsets, j, moved), box.lz)
            pos = _cat([moved[..., :2], z[..., None]], moved)
            out.append(pos)
        return torch.stack(out, dim=-2) if _torch(pos) else np.stack(out, axis=-2)


class UnwrappedEncoding(Encoding):
    """3 channels: Cartesian steps of the lattice-continuous trajectory, in each particle's image
    cell at the anchor frame (the exact frame of the default decoders,
    docs/spec/model.md#exact-frame)."""

    name = "unwrapped"
    n_channels = 3
    channel_names = ("dx", "dy", "dz")

    def _offsets(self, offsets: Array | None) -> Array | None:
        """``(..., T)`` frame offsets -> ``(..., 1, T)`` (broadcast over particles); None when
        the box is periodic (nothing LE-specific is computed)."""
        if offsets is None or not self.boundary.is_lees_edwards:
            return None
        return offsets[..., None, :]

    def encode(self, positions: Array, offsets: Array | None = None, anchor: int = 0) -> Array:
        if self.boundary.is_lees_edwards and offsets is None:
            raise ValueError("unwrapped encode needs the frames' offsets in a sheared box")
        return lattice_continuous_steps(positions, self.box, self._offsets(offsets), anchor)

    def decode(self, last: Array, deltas: Array, offsets: Array | None = None) -> Array:
        """``last + cumsum(deltas)``, each frame wrapped with its own offset: the exact inverse of
        :meth:`encode` with ``last`` at the anchor. Summed in float64 whatever the deltas' dtype
        (the offsets and positions are float64)."""
        self._check(deltas)
        if self.boundary.is_lees_edwards and offsets is None:
            raise ValueError("unwrapped decode needs the offsets of the predicted frames")
        if _torch(deltas):
            continuous = last.double()[..., None, :] + torch.cumsum(deltas.double(), dim=-2)
        else:
            continuous = np.asarray(last, np.float64)[..., None, :] + np.cumsum(
                np.asarray(deltas, np.float64), axis=-2
            )
        offs = self._offsets(offsets)
        return wrap_positions(continuous, self.box, offs)


ENCODINGS: dict[str, type[Encoding]] = {
    cls.name: cls for cls in (SinCosEncoding, VCTEncoding, UnwrappedEncoding)
}


def make_encoding(name: str, boundary: Boundary) -> Encoding:
    """The encoding called ``name`` for ``boundary`` (a clear error for an unknown name)."""
    if name not in ENCODINGS:
        raise ValueError(f"unknown encoding {name!r}; expected one of {sorted(ENCODINGS)}")
    return ENCODINGS[name](boundary)


# --------------------------------------------------------------------------------------------
# normalisation
# --------------------------------------------------------------------------------------------
