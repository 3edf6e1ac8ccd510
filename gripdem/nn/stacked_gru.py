"""The seq2seq decoder loop of all heads at once: one set of matrix products per step.

:class:`gripdem.nn.seq2seq.Seq2SeqGRU` holds each head's weights in ``nn.GRU`` / ``nn.Linear``
modules (so model files keep their keys); its own ``forward`` is the reference, one
``nn.GRU`` call per head and per step (``horizon x n_heads`` calls, as many again in the
backward pass). :func:`decode_heads` runs the same recurrence for every head in one batched
product per gate block (``torch.baddbmm`` over a leading heads axis), with

- the layer-0 input projection out of the loop: the decoder's input (its state) advances by
  an affine map of the previous output, ``state_k = state_{k-1} + out_k @ fold + shift``, so
  its projection does too: ``gi_k = gi_{k-1} + out_k @ (fold @ W_ih) + shift @ W_ih``, with
  ``fold @ W_ih`` and ``shift @ W_ih`` formed once per sequence;
- the reset and update gates in one add + sigmoid;
- nothing per step in Python but the loop itself.

Measured (``decoder_loop.py``, 2-core machine, one thread): 1.0-1.1x the reference loop,
forward and backward, at hidden 32 and 350, horizons 10 and 100. The loop is bound by its
matrix products and the memory traffic of its gate arithmetic, which batching does not reduce;
what made the decoder modes fast is the direct decoder (no loop, :mod:`gripdem.nn.direct`).

Equal to the reference to float round-off (tested, and side by side in
``experiments/benchmarks/model_cost/decoder_loop.py``); dropout between layers draws other random
numbers.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def stacked_gru_weights(grus: list[nn.GRU], layers: int):
    """Per layer ``(W_ih (heads, in, 3H), W_hh (heads, H, 3H), b_ih (heads, 1, 3H),
    b_hh (heads, 1, 3H))`` stacked from the heads' ``nn.GRU`` modules (differentiable: the
    gradients reach each head's own parameters)."""

    def stack(name: str, layer: int, transpose: bool) -> torch.Tensor:
        tensors = [getattr(g, f"{name}_l{layer}") for g in grus]
        return torch.stack([t.t() if transpose else t[None] for t in tensors])

    return [
        (
            stack("weight_ih", layer, True),
            stack("weight_hh", layer, True),
            stack("bias_ih", layer, False),
            stack("bias_hh", layer, False),
        )
        for layer in range(layers)
    ]


def _gru_cell(gi: torch.Tensor, h: torch.Tensor, w_hh: torch.Tensor, b_hh: torch.Tensor):
    """One GRU cell of every head ``(heads, M, H)``, its input projection ``gi`` ``(heads, M,
    3H)`` given: ``nn.GRU``'s gate algebra (r, z, n in that order;
    ``n = tanh(gi_n + r * (h W_hn + b_hn))``; ``h' = n + z (h - n)``). A hand-written backward
    of this cell measured no faster than autograd's (``decoder_loop.py``)."""
    gh = torch.baddbmm(b_hh, h, w_hh)
    hidden = h.shape[-1]
    rz = torch.sigmoid(gi[..., : 2 * hidden] + gh[..., : 2 * hidden])
    r, z = rz[..., :hidden], rz[..., hidden:]
    n = torch.tanh(torch.addcmul(gi[..., 2 * hidden :], r, gh[..., 2 * hidden :]))
    return torch.addcmul(n, z, h - n)


def decode_heads(
    hidden: torch.Tensor,
    state: torch.Tensor,
    base: torch.Tensor | None,
    horizon: int,
    weights: list,
    head_weight: torch.Tensor,
    head_bias: torch.Tensor,
    fold: torch.Tensor,
    shift: torch.Tensor,
    dropout: float = 0.0,
) -> torch.Tensor:
    """The autoregressive decoder of every head.

    Args:
        hidden: initial hidden state ``(layers, heads, M, H)`` (M nodes).
        state: the decoder's first input ``(M, S)``, the same for every head.
        base: constant added to every output ``(M, O)`` or None.
        weights: :func:`stacked_gru_weights` of the heads' decoder GRUs.
        head_weight, head_bias: the output heads ``(heads, H, O)``, ``(heads, 1, O)``.
        fold, shift: the state update ``state += out @ fold + shift`` with ``fold (O, S)`` and
            ``shift`` ``(S,)`` or per node ``(M, S)`` (the exact frame's drift included).
        dropout: between GRU layers, in training (as ``nn.GRU``'s).

    Returns:
        ``(heads, M, horizon, O)``: every head's outputs (the caller averages them).
    """
    w_ih0, w_hh0, b_ih0, b_hh0 = weights[0]
    n_heads = w_ih0.shape[0]
    gi0 = torch.baddbmm(b_ih0, state.expand(n_heads, *state.shape), w_ih0)
    fold_ih = torch.matmul(fold, w_ih0)  # (heads, O, 3H): the output's share of gi0
    shift_ih = torch.matmul(shift.reshape(-1, shift.shape[-1]), w_ih0)  # (heads, 1 or M, 3H)
    if base is not None:  # the base is part of every output: fold it into the constant too
        shift_ih = shift_ih + torch.matmul(base @ fold, w_ih0)
        base = base.expand(n_heads, *base.shape)
    h = list(hidden.unbind(0))
    outputs = []
    for _ in range(horizon):
        x = h[0] = _gru_cell(gi0, h[0], w_hh0, b_hh0)
        for layer in range(1, len(weights)):
            if dropout > 0:
                x = F.dropout(x, dropout, training=True)
            w_ih, w_hh, b_ih, b_hh = weights[layer]
            x = h[layer] = _gru_cell(torch.baddbmm(b_ih, x, w_ih), h[layer], w_hh, b_hh)
        head_out = torch.baddbmm(head_bias, x, head_weight)  # without the base
        outputs.append(head_out if base is None else head_out + base)
        gi0 = gi0 + torch.baddbmm(shift_ih, head_out, fold_ih)
    return torch.stack(outputs, dim=2)
