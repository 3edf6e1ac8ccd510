"""How each decoder mode (docs/spec/model.md#decoder-modes) feeds, advances, decodes and trains the
seq2seq GRU.

Two frames, chosen by the encoding (one source of truth):

**Exact (default, encoding ``unwrapped``)**: inputs, decoder state and outputs live in
lattice-continuous Cartesian coordinates anchored at the last observed frame
(:func:`gripdem.boundary.lattice_continuous_steps`). The network predicts what constant
velocity (CV) misses, in units of the per-step velocity change of the training data
(``Normalizer.change_std``); positions are ``last + cumsum(v0 + deviation)`` in float64 and each
predicted frame is wrapped with its own offset, so the LE shift and the velocity jump of a
crossing are applied analytically (docs/spec/model.md#exact-frame). With every learned output zero a
model IS the CV baseline (to float64 round-off), in both scenes, at every split.

=======  ==============================  ==========================  ==========================
mode     decoder input (direct; GRU)     output per step             loss (relative to CV's)
=======  ==============================  ==========================  ==========================
grip     last velocity (normalised)      velocity change             positions over the horizon
pct      last position: sin/cos per      step deviation from CV      positions over the horizon
         axis (direct); the position in
         box lengths, advanced (GRU)
vct      as pct                          step deviation from CV      per-step displacements
=======  ==============================  ==========================  ==========================

The direct decoder (:mod:`gripdem.nn.direct`, the default of every mode) reads its input beside
each particle's context vector (:func:`direct_state`); the GRU decoder carries it as a state.

The losses are ``mean|pred - true|^2 / mean|true - CV|^2`` on the batch: 1 at the start, and the
square of the RMSE ratio to CV when trained on positions. In this frame PCT and VCT differ by
their loss only: VCT's LE shift channels are replaced by the analytic LE handling.

**Paper (encodings ``sincos`` and ``vct``)**, for reproduction: the paper's wrapped sin/cos
space (docs/spec/model.md#input-channels). ``grip`` repeats the last observed velocity (CV along a
chord in feature space: not exact for LE crossers), ``pct`` / ``vct`` add the last observed delta
per step (``residual_base = constant_velocity``) or stay; the loss is the MSE of normalised
cumulative deltas (grip/pct) or of the 8-channel deltas (vct; ``vct_shift=exact`` drops the shift
channels and applies the known shift when decoding, docs/spec/model.md#exact-shift).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from gripdem.boundary import (
    Boundary,
    lattice_continuous_steps,
    remove_affine_flow,
    sincos_encode,
    step_start_x,
)
from gripdem.data.encodings import Encoding
from gripdem.data.normalizer import Normalizer
from gripdem.evaluation.ensemble_scores import fair_crps

DECODER_MODES = ("grip", "pct", "vct")
VCT_SHIFTS = ("learned", "exact")
RESIDUAL_BASES = ("constant_velocity", "stay")
#: the encoding of the exact frame; the others are the paper's wrapped-space encodings
EXACT_ENCODING = "unwrapped"


def is_exact(encoding: str) -> bool:
    return encoding == EXACT_ENCODING


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
    if is_exact(encoding):
        if residual_base != "constant_velocity":
            raise ValueError(
                "model.residual_base=stay is only read by the paper's encodings (sincos, vct); "
                "the exact frame (encoding unwrapped) always starts from constant velocity"
            )
        return
    if mode == "vct" and encoding != "vct":
        raise ValueError(
            f"model.decoder_mode=vct needs data.encoding=vct (the paper) or unwrapped (exact), "
            f"got {encoding!r}"
        )
    if mode != "vct" and encoding == "vct":
        raise ValueError(
            f"data.encoding=vct is only read by model.decoder_mode=vct (got {mode!r}); "
            "use unwrapped (exact) or sincos (the paper)"
        )


@dataclass
class ModeLayout:
    """Channel counts and the affine state update ``state += out @ fold + shift (+ drift)``."""

    state_channels: int
    out_channels: int
    fold: torch.Tensor
    shift: torch.Tensor


def layout(mode: str, encoding: Encoding, normalizer: Normalizer) -> ModeLayout:
    channels = encoding.n_channels
    std = torch.tensor(normalizer.std, dtype=torch.float32)
    mean = torch.tensor(normalizer.mean, dtype=torch.float32)
    if is_exact(encoding.name):
        change = torch.tensor(normalizer.change_std, dtype=torch.float32)
        if mode == "grip":  # normalised velocity += velocity change
            return ModeLayout(3, 3, torch.diag(change / std), torch.zeros(3))
        lengths = torch.tensor(encoding.box.lengths, dtype=torch.float32)
        return ModeLayout(3, 3, torch.diag(change / lengths), torch.zeros(3))
    if mode == "grip":
        eye = torch.eye(channels)
        return ModeLayout(channels, channels, eye, torch.zeros(channels))
    if mode == "pct":
        return ModeLayout(channels, channels, torch.diag(std), mean)
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
    if is_exact(encoding.name):
        lengths = torch.as_tensor(encoding.box.lengths, device=last_positions.device)
        return (last_positions / lengths).to(inputs.dtype)
    return encoding.position_features(last_positions).to(inputs.dtype)


#: the direct decoder's input channels beside the context vector, per mode (exact frame)
DIRECT_STATE_CHANNELS = {"grip": 3, "pct": 6, "vct": 6}


def direct_state(mode: str, box, last_positions: torch.Tensor, inputs: torch.Tensor):
    """What the direct decoder (:mod:`gripdem.nn.direct`) reads beside each particle's context
    vector, in the exact frame ``(batch, particles, DIRECT_STATE_CHANNELS[mode])``: ``grip`` the
    last observed velocity (normalised, as the GRU decoder's state), ``pct`` / ``vct`` the last
    observed position as sin/cos per axis (the paper's position input, continuous across the
    periodic faces, where a position over the box length would jump).

    inputs: normalised input steps ``(batch, particles, K, 3)``."""
    if mode == "grip":
        return inputs[:, :, -1]
    return sincos_encode(last_positions, box).to(inputs.dtype)


def state_drift(
    mode: str, encoding: Encoding, last_step: torch.Tensor | None
) -> torch.Tensor | None:
    """Per-node addition to the state each step ``(batch, particles, S)``: the CV step of the
    exact position state (``last_step`` float64 ``(B, N, 3)``), None otherwise."""
    if not is_exact(encoding.name) or mode == "grip":
        return None
    lengths = torch.as_tensor(encoding.box.lengths, device=last_step.device)
    return (last_step / lengths).float()


def residual_base(
    mode: str, base: str, encoding: Encoding, inputs: torch.Tensor, normalizer: Normalizer
) -> torch.Tensor | None:
    """Constant added to every GRU output (None: grip, and the exact frame, whose zero output
    is the constant-velocity deviation of zero)."""
    if mode == "grip" or is_exact(encoding.name):
        return None
    zero = normalizer.normalize(torch.zeros_like(inputs[:, :, -1]))
    if base == "stay":
        return zero
    last = inputs[:, :, -1].clone()
    if mode == "vct":  # the real velocity continues; the last step's LE shift does not
        last[..., 6:8] = zero[..., 6:8]
    return last


def outputs_to_deltas(mode: str, exact: bool, outputs, inputs) -> torch.Tensor:
    """``(batch, particles, f, C)`` from the GRU outputs: normalised per-step deltas (paper) or
    the per-step deviation from CV in units of the velocity change (exact)."""
    if mode == "grip":
        if exact:
            return torch.cumsum(outputs, dim=2)  # velocity changes add up to the deviation
        return inputs[:, :, -1:] + torch.cumsum(outputs, dim=2)
    return outputs


def loss_terms(mode: str, vct_shift: str, pred_norm: torch.Tensor, true_norm: torch.Tensor):
    """Paper frame: the trained quantity of each mode from normalised deltas ``(B, N, f, C)``."""
    if mode == "vct":
        if vct_shift == "exact":
            return pred_norm[..., :6], true_norm[..., :6]
        return pred_norm, true_norm
    return torch.cumsum(pred_norm, dim=2), torch.cumsum(true_norm, dim=2)


def exact_loss(mode: str, deviation: torch.Tensor, true_deviation: torch.Tensor) -> torch.Tensor:
    """Exact frame: ``mean|pred - true|^2 / mean|true|^2`` of positions over the horizon
    (grip, pct: cumulative deviations) or of per-step displacements (vct); the deviations are
    ``(B, N, f, 3)`` from CV in units of the velocity change, so the denominator is CV's loss."""
    if mode != "vct":
        deviation, true_deviation = (
            torch.cumsum(deviation, dim=2),
            torch.cumsum(true_deviation, dim=2),
        )
    cv = torch.mean(true_deviation**2).detach()
    return torch.mean((deviation - true_deviation) ** 2) / cv.clamp_min(1e-12)


def exact_cv_loss(mode: str, true_deviation: torch.Tensor) -> torch.Tensor:
    """CV's loss on the window, :func:`exact_loss`'s normaliser (a detached scalar)."""
    if mode != "vct":
        true_deviation = torch.cumsum(true_deviation, dim=2)
    return torch.mean(true_deviation**2).detach()


def exact_crps_loss(
    mode: str,
    members: torch.Tensor,
    true_deviation: torch.Tensor,
    per_step: bool = False,
    pairs: torch.Tensor | None = None,
    pair_weight: float = 1.0,
) -> torch.Tensor:
    """Exact frame, an ensemble: the fair CRPS (:func:`~gripdem.evaluation.ensemble_scores.
    fair_crps`) of the members ``(M, B, N, f, 3)`` per coordinate of the positions over the
    horizon (grip, pct: cumulative deviations; vct: per-step displacements), over CV's mean
    absolute error (the CRPS of CV, a point forecast), so an untrained model scores 1 as it does
    under :func:`exact_loss`. ``per_step``: over CV's error at each horizon step, so every step
    weighs the same (by default the late steps, whose errors are largest, dominate).

    ``pairs`` ``(2, E)`` (receiver, neighbour over the flattened ``B * N`` nodes): add
    ``pair_weight`` times the fair CRPS of the members' *relative* motion of each pair over CV's.
    The per-coordinate CRPS scores each particle's marginal only: members may then move
    neighbours independently, which breaks the contacts cohesion holds; the pair term scores
    the joint motion of neighbours."""
    if mode != "vct":
        members, true_deviation = torch.cumsum(members, dim=3), torch.cumsum(true_deviation, dim=2)
    crps = fair_crps(members, true_deviation)  # (B, N, f, 3)
    if pairs is not None:
        # the pair term: the members' relative motion of every neighbour pair over CV's
        i, j = pairs
        x = members.flatten(1, 2)  # (M, B * N, f, 3)
        y = true_deviation.flatten(0, 1)
        x_rel = x.index_select(1, j) - x.index_select(1, i)
        y_rel = y.index_select(0, j) - y.index_select(0, i)
        cv_rel = y_rel.abs().mean().detach().clamp_min(1e-12)
        pair_term = torch.mean(fair_crps(x_rel, y_rel)) / cv_rel
    if per_step:
        cv = true_deviation.abs().mean(dim=(0, 1, 3)).detach()  # (f,)
        loss = torch.mean(crps.mean(dim=(0, 1, 3)) / cv.clamp_min(1e-12))
    else:
        loss = torch.mean(crps) / torch.mean(true_deviation.abs()).detach().clamp_min(1e-12)
    return loss if pairs is None else loss + pair_weight * pair_term


# --------------------------------------------------------------------------------------------
# the exact frame from a batch (float64)
# --------------------------------------------------------------------------------------------
def derived(batch, key, compute):
    """A quantity derived from ``batch``'s tensors, computed once per batch object (the model's
    inputs, its AR prior, its loss and its decoding all read the observed steps; a batch moved
    to another device is a new object). Callers must not modify the returned tensor."""
    cache = batch.__dict__.setdefault("_derived", {})
    if key not in cache:
        cache[key] = compute()
    return cache[key]


def history_steps(batch, boundary: Boundary) -> torch.Tensor:
    """Observed steps ``(B, N, K, 3)`` float64, lattice-continuous, anchored at the last
    observed frame (the last one is the CV step ``v0``)."""

    def compute():
        positions = batch.input_positions.double()
        offsets = batch.input_offsets.double()[:, None, :] if boundary.is_lees_edwards else None
        return lattice_continuous_steps(positions, boundary.box, offsets, anchor=-1)

    return derived(batch, ("history_steps", boundary), compute)


def flow_relative_history(batch, boundary: Boundary, strain: float) -> torch.Tensor:
    """The observed steps without the LE cell's affine flow (``strain`` per frame) ``(B, N, K,
    3)`` float64, once per batch (the contact encoder's inputs and the AR prior)."""

    def compute():
        steps = history_steps(batch, boundary)
        x_start = step_start_x(steps, batch.last_positions[..., 0].double())
        return remove_affine_flow(steps, x_start, strain)

    return derived(batch, ("flow_relative", boundary, strain), compute)


def last_step(batch, boundary: Boundary) -> torch.Tensor:
    """The CV step ``v0`` ``(B, N, 3)`` float64 (anchored at the last observed frame)."""
    return history_steps(batch, boundary)[:, :, -1]


def target_steps(batch, boundary: Boundary) -> torch.Tensor:
    """True steps over the horizon ``(B, N, f, 3)`` float64, anchored at the last observed
    frame (the first from the last observed frame to the first target)."""
    positions = torch.cat(
        [batch.last_positions.double()[:, :, None], batch.target_positions.double()], dim=2
    )
    offsets = None
    if boundary.is_lees_edwards:
        offsets = torch.cat(
            [batch.input_offsets[:, -1:].double(), batch.target_offsets.double()], dim=1
        )[:, None, :]
    return lattice_continuous_steps(positions, boundary.box, offsets, anchor=0)
