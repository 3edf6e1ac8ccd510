"""A contact term of the training loss: the predicted frames' overlaps of neighbour pairs.

A model trained on position error alone predicts frames whose neighbour pairs overlap (the DEM's
never do by more than ~1e-4 d): its raw frames then need the contact correction, which costs
time and moves particles off their predicted paths (docs/spec/long-rollouts.md#overlaps-first).
With ``model.contact_loss = w > 0`` the exact frame's loss adds ``w`` times the mean squared
overlap of the graph's neighbour pairs in every predicted frame, beyond the correction's
tolerance, in the same units as the position loss (the per-step velocity change) and over the
same normaliser (CV's error on the window), so ``w = 1`` weighs an overlap like a position
error of the same size.

The pairs are the batch's graph at the last observed frame (the contact encoder's pairs, within
its cut-off); each pair's vector in a predicted frame is the LE-aware minimum image of the
decoded positions at that frame's offset, so the term is exact across the sheared faces and
differentiable in the predicted steps.

Shapes: positions ``(B, f, N, 3)`` float64 wrapped; ``edge_index (2, E)`` into the flattened
``B * N`` particles; ``offsets (B, f)``.
"""

from __future__ import annotations

import torch

from gripdem.boundary import Boundary, minimum_image

#: overlaps below this fraction of the diameter are the DEM's own resting contacts (the contact
#: correction's tolerance, gripdem.inference.contacts.CORRECTION_TOLERANCE)
RESTING_OVERLAP = 1e-4


def pair_overlaps(
    positions: torch.Tensor,
    edge_index: torch.Tensor,
    offsets: torch.Tensor | None,
    boundary: Boundary,
    diameter: float,
) -> torch.Tensor:
    """Overlap beyond :data:`RESTING_OVERLAP` of every non-self pair in every predicted frame
    ``(f, E)`` (metres; 0 where the pair does not overlap)."""
    b, f, n, _ = positions.shape
    keep = edge_index[0] != edge_index[1]
    i, j = edge_index[0, keep], edge_index[1, keep]
    flat = positions.transpose(0, 1).reshape(f, b * n, 3)
    vectors = flat[:, j] - flat[:, i]  # (f, E, 3)
    shift = None
    if offsets is not None and boundary.is_lees_edwards:
        shift = offsets.double()[torch.div(i, n, rounding_mode="floor")].transpose(0, 1)  # (f, E)
    distance = minimum_image(vectors, boundary.box, shift).norm(dim=-1)
    return torch.relu(diameter * (1.0 - RESTING_OVERLAP) - distance)


def contact_term(
    positions: torch.Tensor,
    edge_index: torch.Tensor,
    offsets: torch.Tensor | None,
    boundary: Boundary,
    diameter: float,
    unit: torch.Tensor,
    cv_loss: torch.Tensor,
) -> torch.Tensor:
    """The mean squared overlap of the pairs ``edge_index`` in the predicted frames (target
    ``offsets (B, f)``) in units of ``unit`` (the per-step velocity change, metres), over
    ``cv_loss`` (CV's loss on the window, the position loss's normaliser): a scalar."""
    overlaps = pair_overlaps(positions, edge_index, offsets, boundary, diameter)
    if overlaps.numel() == 0:
        return positions.new_zeros(())
    return torch.mean((overlaps / unit) ** 2) / cv_loss.clamp_min(1e-12)
