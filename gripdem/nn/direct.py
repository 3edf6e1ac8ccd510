"""A direct multi-step head: every horizon step at once from each particle's context vector.

The seq2seq GRU (:mod:`gripdem.nn.seq2seq`) unrolls the horizon one step after another, a
sequential loop over ``f`` steps that costs as much as a message-passing round on a CPU. When the
encoder already carries the interactions (:mod:`gripdem.nn.contact`), the decoder only has to
spread one context vector over the horizon: an MLP does that in one pass. Its last layer starts
at zero, so an untrained head outputs zeros (the exact frame's constant velocity).

forward(features ``(B, N, 1, C)``, state ``(B, N, S)``) -> ``(B, N, horizon, O)``.
"""

from __future__ import annotations

import torch
from torch import nn


class DirectDecoder(nn.Module):
    """``MLP([context, state]) -> (horizon, out_channels)`` per particle (see module doc)."""

    def __init__(
        self,
        in_channels: int,
        state_channels: int,
        out_channels: int,
        horizon: int,
        hidden: int = 64,
    ):
        super().__init__()
        self.horizon, self.out_channels = int(horizon), int(out_channels)
        self.net = nn.Sequential(
            nn.Linear(in_channels + state_channels, hidden),
            nn.SiLU(),
            nn.Linear(hidden, hidden),
            nn.SiLU(),
            nn.Linear(hidden, self.horizon * self.out_channels),
        )
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, features: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        b, n = features.shape[:2]
        x = torch.cat([features[:, :, -1], state.to(features.dtype)], dim=-1)
        return self.net(x).reshape(b, n, self.horizon, self.out_channels)
