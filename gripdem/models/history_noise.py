"""Random-walk noise on the observed history during training (as learned simulators do).

In a long rollout the model's history is made of its own predictions, each a little off. Trained
only on exact histories it never learns what to do with such errors, and they grow. Here, during
training, each particle's observed positions get a random walk: increments ``N(0, sigma^2 / K)``
per observed step, summed from the first observed frame, so the last observed position is off by
``N(0, sigma^2)`` per axis. Everything the model reads is recomputed from the noisy frames (the
steps, their normalisation, the pair vectors and surface gaps of the graph at the last frame),
while the targets stay the true future frames: the loss then rewards pulling a perturbed state
back onto the true trajectory. ``sigma`` is in particle diameters.

Shapes: a :class:`~gripdem.data.batch.WindowBatch` in, the same with noisy history out.
"""

from __future__ import annotations

from dataclasses import replace

import torch

from gripdem.boundary import Boundary, lattice_continuous_steps


def noisy_history(
    batch, sigma: float, diameter: float, boundary: Boundary, normalizer, generator=None
):
    """The batch with random-walk noise of final std ``sigma`` diameters on its observed frames
    (see the module doc). Only the exact frame's inputs are recomputed (encoding unwrapped)."""
    positions = batch.input_positions.double()  # (B, N, K+1, 3)
    k = positions.shape[2] - 1
    step_std = sigma * diameter / k**0.5
    increments = torch.randn(
        positions.shape[:2] + (k, 3), dtype=positions.dtype, generator=generator
    ).to(positions.device)
    walk = torch.cat(
        [torch.zeros_like(increments[:, :, :1]), torch.cumsum(step_std * increments, 2)], 2
    )
    noisy = positions + walk  # images of the wrapped frames: the steps are minimum images anyway
    offsets = batch.input_offsets.double()[:, None, :] if boundary.is_lees_edwards else None
    steps = lattice_continuous_steps(noisy, boundary.box, offsets, anchor=-1)
    inputs = normalizer.normalize(steps).float()
    # the graph at the last observed frame: pair vectors moved by the difference of the noises
    last = walk[:, :, -1].reshape(-1, 3) / diameter  # (B*N, 3) in diameters
    i, j = batch.edge_index
    vector = batch.edge_vector.double() + last.index_select(0, j) - last.index_select(0, i)
    distance = vector.norm(dim=-1)
    is_self = i == j
    return replace(
        batch,
        inputs=inputs,
        input_positions=noisy,
        edge_vector=vector.float(),
        edge_distance=distance.float(),
        edge_gap=torch.where(is_self, batch.edge_gap.double(), distance - 1.0).float(),
    )
