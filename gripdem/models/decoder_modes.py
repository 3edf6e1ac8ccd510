"""How each decoder mode (SPEC §5) feeds, advances and decodes the seq2seq GRU.

One class per concern would scatter three short recipes; this module keeps them side by side:

=======  ====================  ========================  ===============================
mode     decoder state         GRU output per step       loss
=======  ====================  ========================  ===============================
grip     last velocity (norm)  change of velocity        cumulative deltas (positions
                                                         relative to the last frame)
pct      position features     normalised delta          same as grip
vct      sin/cos position (6)  normalised 8-ch delta     normalised 8-ch deltas (the
                                                         shift channels are not used by
                                                         ``exact``, so not in its loss)
=======  ====================  ========================  ===============================

Positions "relative to the last frame" are compared in normalised units
(``cumsum(deltas) / std``): for ``sincos`` this is the paper's sin/cos position loss scaled to
order one per channel.

Initial state (zero-initialised output heads): ``grip`` repeats the last observed velocity
(constant velocity along a chord in feature space: exact for small steps, not for LE crossers
or long horizons); ``pct`` and ``vct`` add the last observed delta each step when
``residual_base = constant_velocity`` (the default; the same chord), or stay in place when
``residual_base = stay``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from gripdem.data.features import Encoding, Normalizer

DECODER_MODES = ("grip", "pct", "vct")
VCT_SHIFTS = ("learned", "exact")
RESIDUAL_BASES = ("constant_velocity", "stay")


def check_mode(mode: str, encoding: str, vct_shift: str, residual_base: str) -> None:
    """Refuse combinations that have no meaning, naming the option."""
    if mode not in DECODER_MODES:
        raise ValueError(f"model.decoder_mode must be one of {DECODER_MODES}, got {mode!r}")
    if vct_shift not in VCT_SHIFTS:
        raise ValueError(f"model.vct_shift must be one of {VCT_SHIFTS}, got {vct_shift!r}")
    if residual_base not in RESIDUAL_BASES:
        raise ValueError(
            f"model.residual_base must be one of {RESIDUAL_BASES}, got {residual_base!r}"
        )
    if mode == "vct" and encoding != "vct":
        raise ValueError(f"model.decoder_mode=vct needs data.encoding=vct, got {encoding!r}")
    if mode != "vct" and encoding == "vct":
        raise ValueError(
            f"data.encoding=vct is only read by model.decoder_mode=vct (got {mode!r}); "
            "use sincos or unwrapped"
        )


@dataclass
class ModeLayout:
    """Channel counts and the affine state update ``state += out @ fold + shift``."""

    state_channels: int
    out_channels: int
    fold: torch.Tensor
    shift: torch.Tensor


def position_state_scale(encoding: Encoding) -> torch.Tensor:
    """Per-channel factor from deltas to position-state units: 1 for sin/cos features, 1/l
    for Cartesian (``unwrapped``) positions, which are fed in box lengths."""
    if encoding.name == "unwrapped":
        return torch.tensor(1.0 / encoding.box.lengths, dtype=torch.float32)
    return torch.ones(6)


def layout(mode: str, encoding: Encoding, normalizer: Normalizer) -> ModeLayout:
    channels = encoding.n_channels
    std = torch.tensor(normalizer.std, dtype=torch.float32)
    mean = torch.tensor(normalizer.mean, dtype=torch.float32)
    if mode == "grip":
        eye = torch.eye(channels)
        return ModeLayout(channels, channels, eye, torch.zeros(channels))
    if mode == "pct":
        scale = position_state_scale(encoding)
        return ModeLayout(channels, channels, torch.diag(std * scale), mean * scale)
    # vct: 8 output channels folded onto 6 sin/cos position channels (real + shift on z)
    combine = torch.zeros(8, 6)
    combine[:6, :6] = torch.eye(6)
    combine[6, 4] = combine[7, 5] = 1.0
    return ModeLayout(6, 8, torch.diag(std) @ combine, mean @ combine)


def initial_state(mode: str, encoding: Encoding, last_positions: torch.Tensor, inputs):
    """Decoder state at the last observed frame ``(batch, particles, state_channels)``.

    inputs: normalised input deltas ``(batch, particles, K, C)``."""
    if mode == "grip":
        return inputs[:, :, -1]
    if encoding.name == "unwrapped":
        lengths = torch.as_tensor(encoding.box.lengths, device=last_positions.device)
        return (last_positions / lengths).to(inputs.dtype)
    return encoding.position_features(last_positions).to(inputs.dtype)


def residual_base(
    mode: str, base: str, inputs: torch.Tensor, normalizer: Normalizer
) -> torch.Tensor | None:
    """Constant added to every GRU output (``None`` for ``grip``, whose state carries it)."""
    if mode == "grip":
        return None
    zero = normalizer.normalize(torch.zeros_like(inputs[:, :, -1]))
    if base == "stay":
        return zero
    last = inputs[:, :, -1].clone()
    if mode == "vct":  # the real velocity continues; the last step's LE shift does not
        last[..., 6:8] = zero[..., 6:8]
    return last


def outputs_to_deltas(mode: str, outputs, inputs, normalizer: Normalizer) -> torch.Tensor:
    """Normalised per-step deltas ``(batch, particles, f, C)`` from the GRU outputs."""
    if mode == "grip":
        return inputs[:, :, -1:] + torch.cumsum(outputs, dim=2)
    return outputs


def loss_terms(mode: str, vct_shift: str, pred_norm: torch.Tensor, true_norm: torch.Tensor):
    """The trained quantity of each mode from normalised deltas ``(batch, particles, f, C)``."""
    if mode == "vct":
        if vct_shift == "exact":
            return pred_norm[..., :6], true_norm[..., :6]
        return pred_norm, true_norm
    return torch.cumsum(pred_norm, dim=2), torch.cumsum(true_norm, dim=2)
