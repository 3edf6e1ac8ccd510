"""The batch of windows the DataModule yields: one documented dataclass and its collate.

:class:`WindowBatch` has a ``.to(device)`` method, which Lightning's
``transfer_batch_to_device`` calls as it is, and ``.pin_memory()`` for the DataLoader.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
import torch

from gripdem.data.graph import Graph


@dataclass
class WindowBatch:
    """A batch of windows. ``B`` windows, ``N`` particles, ``K`` history_len, ``f`` horizon,
    ``C`` channels of the encoding, ``T = K + 1 + f`` frames, ``E`` edges of all graphs.

    Encoded arrays are normalised (:class:`~gripdem.data.encodings.Normalizer` of the
    DataModule) float32; positions, times and LE offsets are float64 (positions are wrapped
    into the box; offsets are the float64 δ of each frame, zeros in a periodic box).

    - ``inputs (B, N, K, C)``: encoded deltas of the K input steps.
    - ``target_deltas (B, N, f, C)``: encoded deltas of the f target steps (the first one from the
      last observed frame to the first target frame).
    - ``input_positions (B, N, K+1, 3)``, ``target_positions (B, N, f, 3)``: wrapped Cartesian.
    - ``times (B, T)``, ``offsets (B, T)``: absolute frame times and LE offsets of all frames.
    - Graph at the last observed frame, batched: ``edge_index (2, E)`` into the flattened
      ``B*N`` particles (sample b's particles are ``b*N .. b*N+N-1``; row 0 receives, row 1 is
      the neighbour; self pairs included), ``edge_weight (E,)`` = G_fixed, ``edge_vector (E, 3)``
      minimum-image ``r_j - r_i`` and ``edge_distance (E,)`` in particle diameters,
      ``edge_gap (E,)`` surface gap ``distance - 1`` in diameters (from float64; -1 on self
      pairs), ``edge_ptr (B+1,)`` first edge of each sample.
    - ``crossing_mask (B, N)`` bool: crossed an LE face (an x face of a sheared box) in one of
      the f target steps; all False in a periodic box.
    - ``sim_index (B,)``, ``window_start (B,)``: simulation index and first frame of each window.
    - ``in_sample``: True under the ``paper`` protocol (train = test); report it.

    An inference batch (:func:`inference_batch`) has no targets: ``target_deltas``,
    ``target_positions`` and ``crossing_mask`` are None; what a model reads to predict is there.
    """

    inputs: torch.Tensor
    target_deltas: torch.Tensor | None
    input_positions: torch.Tensor
    target_positions: torch.Tensor | None
    times: torch.Tensor
    offsets: torch.Tensor
    edge_index: torch.Tensor
    edge_weight: torch.Tensor
    edge_vector: torch.Tensor
    edge_distance: torch.Tensor
    edge_gap: torch.Tensor
    edge_ptr: torch.Tensor
    crossing_mask: torch.Tensor | None
    sim_index: torch.Tensor
    window_start: torch.Tensor
    in_sample: bool = False

    @property
    def batch_size(self) -> int:
        return int(self.inputs.shape[0])

    @property
    def n_particles(self) -> int:
        return int(self.inputs.shape[1])

    @property
    def history_len(self) -> int:
        return int(self.inputs.shape[2])

    @property
    def horizon(self) -> int:
        """f: the frames after the last observed one (their times and offsets are known even
        when their positions are not, as in an inference batch)."""
        return int(self.times.shape[1]) - self.history_len - 1

    @property
    def last_positions(self) -> torch.Tensor:
        """``(B, N, 3)`` float64 wrapped positions at the last observed frame."""
        return self.input_positions[:, :, -1]

    @property
    def decoder_seed(self) -> torch.Tensor:
        """``(B, N, C)`` the encoded input of the last step (GRIP decoder input)."""
        return self.inputs[:, :, -1]

    @property
    def input_times(self) -> torch.Tensor:
        """``(B, K+1)`` absolute times of the input frames."""
        return self.times[:, : self.history_len + 1]

    @property
    def input_offsets(self) -> torch.Tensor:
        """``(B, K+1)`` float64 LE offsets of the input frames."""
        return self.offsets[:, : self.history_len + 1]

    @property
    def target_times(self) -> torch.Tensor:
        """``(B, f)`` absolute times of the target frames."""
        return self.times[:, -self.horizon :]

    @property
    def target_offsets(self) -> torch.Tensor:
        """``(B, f)`` float64 LE offsets of the target frames (what decoders need)."""
        return self.offsets[:, -self.horizon :]

    def _map(self, fn) -> WindowBatch:
        return replace(
            self,
            **{
                f.name: fn(getattr(self, f.name))
                for f in fields(self)
                if isinstance(getattr(self, f.name), torch.Tensor)
            },
        )

    def to(self, device: torch.device | str, non_blocking: bool = False) -> WindowBatch:
        """Move every tensor, keeping dtypes (float64 stays float64)."""
        return self._map(lambda t: t.to(device, non_blocking=non_blocking))

    def pin_memory(self) -> WindowBatch:
        return self._map(lambda t: t.pin_memory())


def collate_windows(samples: Sequence[dict[str, Any]]) -> WindowBatch:
    """Stack samples from :class:`WindowDataset` into a :class:`WindowBatch`."""

    def stack(key: str) -> torch.Tensor:
        return torch.from_numpy(np.stack([s[key] for s in samples]))

    n = samples[0]["inputs"].shape[0]
    graphs: list[Graph] = [s["graph"] for s in samples]
    counts = [g.n_edges for g in graphs]
    edge_index = np.concatenate([g.edge_index + b * n for b, g in enumerate(graphs)], axis=1)
    return WindowBatch(
        inputs=stack("inputs"),
        target_deltas=stack("target_deltas"),
        input_positions=stack("input_positions"),
        target_positions=stack("target_positions"),
        times=stack("times"),
        offsets=stack("offsets"),
        edge_index=torch.from_numpy(edge_index),
        edge_weight=torch.from_numpy(np.concatenate([g.edge_weight for g in graphs])),
        edge_vector=torch.from_numpy(np.concatenate([g.edge_vector for g in graphs])),
        edge_distance=torch.from_numpy(np.concatenate([g.edge_distance for g in graphs])),
        edge_gap=torch.from_numpy(np.concatenate([g.edge_gap for g in graphs])),
        edge_ptr=torch.from_numpy(np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)),
        crossing_mask=stack("crossing_mask"),
        sim_index=torch.tensor([s["sim"] for s in samples], dtype=torch.int64),
        window_start=torch.tensor([s["start"] for s in samples], dtype=torch.int64),
        in_sample=bool(samples[0]["in_sample"]),
    )


def inference_batch(
    inputs: np.ndarray,
    input_positions: np.ndarray,
    times: np.ndarray,
    offsets: np.ndarray,
    graphs: Sequence[Graph],
) -> WindowBatch:
    """A batch to predict from, without targets: ``inputs (B, N, K, C)`` normalised float32,
    ``input_positions (B, N, K+1, 3)``, ``times`` and ``offsets`` ``(B, K+1+f)`` of the observed
    and the predicted frames, one graph per window (at its last observed frame)."""
    n = input_positions.shape[1]
    counts = [g.n_edges for g in graphs]
    edge_index = np.concatenate([g.edge_index + b * n for b, g in enumerate(graphs)], axis=1)
    b = input_positions.shape[0]
    return WindowBatch(
        inputs=torch.from_numpy(np.ascontiguousarray(inputs, dtype=np.float32)),
        target_deltas=None,
        input_positions=torch.from_numpy(np.ascontiguousarray(input_positions)),
        target_positions=None,
        times=torch.from_numpy(np.ascontiguousarray(times, dtype=np.float64)),
        offsets=torch.from_numpy(np.ascontiguousarray(offsets, dtype=np.float64)),
        edge_index=torch.from_numpy(edge_index),
        edge_weight=torch.from_numpy(np.concatenate([g.edge_weight for g in graphs])),
        edge_vector=torch.from_numpy(np.concatenate([g.edge_vector for g in graphs])),
        edge_distance=torch.from_numpy(np.concatenate([g.edge_distance for g in graphs])),
        edge_gap=torch.from_numpy(np.concatenate([g.edge_gap for g in graphs])),
        edge_ptr=torch.from_numpy(np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)),
        crossing_mask=None,
        sim_index=torch.arange(b, dtype=torch.int64),
        window_start=torch.zeros(b, dtype=torch.int64),
    )
