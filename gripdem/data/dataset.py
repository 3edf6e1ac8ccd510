"""The windows of one protocol part as samples: positions read lazily from the HDF5 file (one
handle per process, workers fork), encoded and normalised, with the graph at the last observed
frame (cached per simulation and frame in a bounded LRU) and the LE crossing mask of the
targets. :func:`gripdem.data.batch.collate_windows` stacks the samples into a batch.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from torch.utils.data import Dataset

from gripdem.data.encodings import Encoding, x_face_crossings
from gripdem.data.frames import FrameStore, SimulationFrames
from gripdem.data.graph import DEFAULT_ALPHA, Graph, build_graph
from gripdem.data.normalizer import Normalizer
from gripdem.data.schema import DatasetMeta
from gripdem.data.windows import WindowIndex


class FrameReader:
    """Positions of a gripdem file, read lazily; one h5py handle per process (workers fork)."""

    def __init__(self, path: Path):
        self.path = path
        self._h5: h5py.File | None = None
        self._pid = -1

    def read(self, sim: int, start: int, stop: int) -> np.ndarray:
        """``(stop-start, N, 3)`` float64 wrapped positions."""
        if self._h5 is None or self._pid != os.getpid():
            self._h5 = h5py.File(self.path, "r")
            self._pid = os.getpid()
        return np.asarray(self._h5["positions"][sim, start:stop], dtype=np.float64)

    def close(self) -> None:
        if self._h5 is not None and self._pid == os.getpid():
            self._h5.close()
        self._h5 = None

    def __getstate__(self) -> dict:
        return {"path": self.path, "_h5": None, "_pid": -1}


class WindowDataset(Dataset):
    """Windows of one protocol part, as sample dicts for :func:`collate_windows`.

    The graph depends only on the last observed frame: it is cached per (simulation, frame)
    in an LRU bounded by ``graph_cache_mb`` (per worker process; 0 = no cache).
    """

    def __init__(
        self,
        reader: FrameReader,
        meta: DatasetMeta,
        times: np.ndarray,
        windows: WindowIndex,
        encoding: Encoding,
        normalizer: Normalizer,
        graph_cutoff: float,
        graph_alpha: float = DEFAULT_ALPHA,
        graph_cache_mb: float = 256.0,
        in_sample: bool = False,
        store: FrameStore | None = None,
    ):
        self.reader = reader
        self.meta = meta
        self.times = times
        self.offsets = meta.boundary.offset(times)
        self.windows = windows
        self.encoding = encoding
        self.normalizer = normalizer
        self.graph_cutoff = graph_cutoff
        self.graph_alpha = graph_alpha
        self.graph_cache_bytes = graph_cache_mb * 2**20
        self.in_sample = in_sample
        self._graphs: OrderedDict[tuple[int, int], Graph] = OrderedDict()
        self._graph_bytes = 0
        # the in-memory fast path: exact-frame windows of simulations that fit the budget
        self.store = store if encoding.name == "unwrapped" else None

    def __len__(self) -> int:
        return len(self.windows)

    def graph(self, sim: int, frame: int, positions: np.ndarray) -> Graph:
        """The graph of a frame searched afresh (the file path), through the cache."""

        def search(frame: int) -> Graph:
            return build_graph(
                positions,
                self.meta.box,
                float(self.offsets[sim, frame]),
                self.graph_cutoff,
                self.graph_alpha,
                length_unit=self.meta.diameter,
            )

        return self.cached_graph(sim, frame, search)

    def cached_graph(self, sim: int, frame: int, make) -> Graph:
        """``make(frame)`` through the per-process LRU of graphs (``graph_cache_mb``)."""
        key = (sim, frame)
        if key in self._graphs:
            self._graphs.move_to_end(key)
            return self._graphs[key]
        g = make(frame)
        self._graphs[key] = g
        self._graph_bytes += g.nbytes
        while self._graph_bytes > self.graph_cache_bytes and self._graphs:
            _, old = self._graphs.popitem(last=False)
            self._graph_bytes -= old.nbytes
        return g

    def crossing_mask(self, positions: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """``(N,)`` particles that cross an LE face in the target steps of ``positions``
        ``(N, f+1, 3)``; all False in a periodic box, where no face is special and the mask is
        never read (skipped: it cost ~8 % of a window's preparation, measured on the tiny scene)."""
        if not self.meta.boundary.is_lees_edwards:
            return np.zeros(positions.shape[0], dtype=bool)
        return x_face_crossings(positions, self.meta.box, offsets)

    def __getitem__(self, index: int) -> dict[str, Any]:
        w = self.windows[index]
        frames = None if self.store is None else self.store.frames(w.sim)
        if frames is not None:
            return self._prepared(w, frames)
        k = w.history_len
        pos = self.reader.read(w.sim, w.start, w.stop).transpose(1, 0, 2)  # (N, T, 3)
        offs = self.offsets[w.sim, w.start : w.stop]
        deltas = self.encoding.encode(pos, offs, anchor=k)  # unwrapped: image cell at frame k
        deltas = self.normalizer.normalize(deltas).astype(np.float32)
        return {
            "inputs": np.ascontiguousarray(deltas[:, :k]),
            "target_deltas": np.ascontiguousarray(deltas[:, k:]),
            "input_positions": np.ascontiguousarray(pos[:, : k + 1]),
            "target_positions": np.ascontiguousarray(pos[:, k + 1 :]),
            "times": self.times[w.sim, w.start : w.stop].copy(),
            "offsets": offs.copy(),
            "graph": self.graph(w.sim, w.last_observed, np.ascontiguousarray(pos[:, k])),
            "crossing_mask": self.crossing_mask(pos[:, k:], offs[k:]),
            "sim": w.sim,
            "start": w.start,
            "in_sample": self.in_sample,
        }

    def _prepared(self, w, frames: SimulationFrames) -> dict[str, Any]:
        """The same sample from a simulation prepared in memory (:mod:`gripdem.data.frames`)."""
        k = w.history_len
        pos = frames.by_particle[:, w.start : w.stop]
        _, deltas = frames.window_steps(w.start, w.stop, w.last_observed)
        le = self.meta.boundary.is_lees_edwards
        n = pos.shape[0]
        return {
            "inputs": np.ascontiguousarray(deltas[:, :k]),
            "target_deltas": np.ascontiguousarray(deltas[:, k:]),
            "input_positions": np.ascontiguousarray(pos[:, : k + 1]),
            "target_positions": np.ascontiguousarray(pos[:, k + 1 :]),
            "times": self.times[w.sim, w.start : w.stop].copy(),
            "offsets": self.offsets[w.sim, w.start : w.stop].copy(),
            "graph": self.cached_graph(w.sim, w.last_observed, frames.graph),
            "crossing_mask": (
                frames.crossers(w.last_observed, w.stop) if le else np.zeros(n, dtype=bool)
            ),
            "sim": w.sim,
            "start": w.start,
            "in_sample": self.in_sample,
        }
