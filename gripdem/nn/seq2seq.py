"""Trajectory block of GRIP++: ``n_heads`` seq2seq GRU networks whose outputs are averaged.

Each network encodes the graph features of every particle over the observed time with a
fused multi-layer GRU, then decodes ``horizon`` steps autoregressively. The decoder carries a
*state* (what it is fed: a velocity for ``grip``, a position for ``pct``/``vct``) and emits
an *output* per step; the state advances by a fixed linear map of the output::

    output_k = head(GRU(state_{k-1}, h)) + base        (base: None, or a constant per node)
    state_k  = state_{k-1} + output_k @ fold + shift + drift
                                    (an affine map: de-normalise, fold; drift: None or per node)

``grip``: state = (normalised) velocity, output = the change of velocity (residual on the
input velocity), fold = identity.
``pct``: state = position features, output = the normalised per-step position delta; fold and
shift de-normalise it.
``vct``: state = position features (6 sin/cos channels), output = the normalised 8 channel
delta (real + shift); fold de-normalises and adds the two shift channels onto the z channels.
In the exact frame (:mod:`gripdem.models.decoder_modes`) the position state advances by the
constant-velocity step (drift) plus the predicted deviation.
The output head starts at zero, so an untrained decoder reproduces its base: the last
velocity for ``grip`` (constant velocity along a chord in feature space), and for ``pct`` /
``vct`` a zero delta (stay) or the last observed delta (constant velocity) by config.
All work is batched over particles and heads: no Python loop per particle, one loop over the
horizon with one set of matrix products per step for every head (:mod:`gripdem.nn.stacked_gru`).
"""

from __future__ import annotations

import torch
from torch import nn

from gripdem.nn.stacked_gru import decode_heads, stacked_gru_weights

CONTEXTS = ("sequence", "vector")


class Seq2SeqGRU(nn.Module):
    """One encoder-decoder GRU network.

    ``context="sequence"``: a GRU encodes the features over time (the graph-conv encoder's
    ``(nodes, K, C)``). ``context="vector"``: the features are one vector per node (the
    contact encoder's ``(nodes, 1, C)``) and a linear map with tanh gives the decoder's
    initial hidden state of every layer (a GRU over one step from a zero state would leave its
    hidden-to-hidden weights unused).

    forward(features, state, base, horizon, fold, shift, drift=None):
      features ``(nodes, time, channels)``, state ``(nodes, state_channels)``,
      base ``(nodes, out_channels)`` or None, fold ``(out_channels, state_channels)``,
      shift ``(state_channels,)``, drift ``(nodes, state_channels)`` or None
      -> outputs ``(nodes, horizon, out_channels)``.
    """

    def __init__(
        self,
        in_channels: int,
        state_channels: int,
        out_channels: int,
        hidden: int = 350,
        layers: int = 2,
        dropout: float = 0.0,
        context: str = "sequence",
    ):
        super().__init__()
        if context not in CONTEXTS:
            raise ValueError(f"context must be one of {CONTEXTS}, got {context!r}")
        self.layers, self.hidden = layers, hidden
        if context == "sequence":
            self.encoder = nn.GRU(in_channels, hidden, layers, batch_first=True, dropout=dropout)
        else:
            self.encoder = nn.Linear(in_channels, layers * hidden)
        self.context = context
        self.decoder = nn.GRU(state_channels, hidden, layers, batch_first=True, dropout=dropout)
        self.head = nn.Linear(hidden, out_channels)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def initial_hidden(self, features: torch.Tensor) -> torch.Tensor:
        """The decoder's initial hidden state ``(layers, nodes, hidden)`` from the features."""
        if self.context == "sequence":
            return self.encoder(features)[1]
        init = torch.tanh(self.encoder(features[:, -1]))
        return init.reshape(-1, self.layers, self.hidden).transpose(0, 1).contiguous()

    def forward(
        self,
        features: torch.Tensor,
        state: torch.Tensor,
        base: torch.Tensor | None,
        horizon: int,
        fold: torch.Tensor,
        shift: torch.Tensor,
        drift: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """The reference loop: one ``nn.GRU`` call per step (:class:`TrajectoryDecoder` runs
        every head at once with :func:`~gripdem.nn.stacked_gru.decode_heads`)."""
        hidden = self.initial_hidden(features)
        if drift is not None:
            shift = shift + drift
        outputs = []
        for _ in range(horizon):
            step, hidden = self.decoder(state.unsqueeze(1), hidden)
            out = self.head(step.squeeze(1))
            if base is not None:
                out = out + base
            outputs.append(out)
            state = state + out @ fold + shift
        return torch.stack(outputs, dim=1)


class TrajectoryDecoder(nn.Module):
    """``n_heads`` seq2seq networks, outputs averaged (docs/spec/model.md#decoder-modes).

    forward(features ``(batch, particles, time, channels)``, state ``(batch, particles, S)``,
    base ``(batch, particles, O)`` or None, horizon, drift ``(batch, particles, S)`` or None)
    -> ``(batch, particles, horizon, O)``.
    """

    def __init__(
        self,
        in_channels: int,
        state_channels: int,
        out_channels: int,
        hidden: int = 350,
        layers: int = 2,
        n_heads: int = 2,
        dropout: float = 0.0,
        fold: torch.Tensor | None = None,
        shift: torch.Tensor | None = None,
        context: str = "sequence",
    ):
        super().__init__()
        if fold is None:
            if state_channels != out_channels:
                raise ValueError("a fold matrix is needed when state and output channels differ")
            fold = torch.eye(out_channels)
        if tuple(fold.shape) != (out_channels, state_channels):
            raise ValueError(
                f"fold must be ({out_channels}, {state_channels}), got {tuple(fold.shape)}"
            )
        if shift is None:
            shift = torch.zeros(state_channels)
        if tuple(shift.shape) != (state_channels,):
            raise ValueError(f"shift must be ({state_channels},), got {tuple(shift.shape)}")
        self.register_buffer("fold", fold.float())
        self.register_buffer("shift", shift.float())
        self.heads = nn.ModuleList(
            Seq2SeqGRU(in_channels, state_channels, out_channels, hidden, layers, dropout, context)
            for _ in range(n_heads)
        )

    def _flat(self, features, state, base, drift):
        """The inputs with batch and particles on one nodes axis, in the features' dtype, and
        the state update's fold and shift in that dtype."""
        b, n, t, c = features.shape

        def nodes(x: torch.Tensor | None) -> torch.Tensor | None:
            return None if x is None else x.reshape(b * n, -1).to(features.dtype)

        fold, shift = self.fold.to(features.dtype), self.shift.to(features.dtype)
        return features.reshape(b * n, t, c), nodes(state), nodes(base), nodes(drift), fold, shift

    def forward(
        self,
        features: torch.Tensor,
        state: torch.Tensor,
        base: torch.Tensor | None,
        horizon: int,
        drift: torch.Tensor | None = None,
    ) -> torch.Tensor:
        b, n = features.shape[:2]
        flat, flat_state, flat_base, flat_drift, fold, shift = self._flat(
            features, state, base, drift
        )
        if flat_drift is not None:
            shift = shift + flat_drift
        first = self.heads[0]
        hidden = torch.stack([head.initial_hidden(flat) for head in self.heads], dim=1)
        outputs = decode_heads(
            hidden,
            flat_state,
            flat_base,
            horizon,
            stacked_gru_weights([head.decoder for head in self.heads], first.layers),
            torch.stack([head.head.weight.t() for head in self.heads]),
            torch.stack([head.head.bias[None] for head in self.heads]),
            fold,
            shift,
            first.decoder.dropout if self.training else 0.0,
        )
        return outputs.mean(0).reshape(b, n, horizon, -1)

    def reference_forward(
        self,
        features: torch.Tensor,
        state: torch.Tensor,
        base: torch.Tensor | None,
        horizon: int,
        drift: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """:meth:`forward` through each head's own cell-by-cell loop (the reference the
        batched loop is tested and benchmarked against; same arguments and result)."""
        b, n = features.shape[:2]
        flat, flat_state, flat_base, flat_drift, fold, shift = self._flat(
            features, state, base, drift
        )
        outputs = [
            head(flat, flat_state, flat_base, horizon, fold, shift, flat_drift)
            for head in self.heads
        ]
        return torch.stack(outputs, 0).mean(0).reshape(b, n, horizon, -1)
