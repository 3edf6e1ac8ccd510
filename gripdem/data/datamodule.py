"""LightningDataModule over a gripdem HDF5 file: windows, encodings, graphs, batches.

One class serves both scenes (the boundary comes from the file). The file is opened lazily:
:func:`gripdem.data.dataset_io.read_meta` at ``setup``, positions read per window, one h5py handle
per worker process. Batches are :class:`WindowBatch` dataclasses with a ``.to(device)`` method,
which Lightning's ``transfer_batch_to_device`` calls as it is (and the DataLoader's
``pin_memory`` calls ``.pin_memory()``).

Normalisation statistics come from the frames covered by the training windows only, and are
part of :meth:`TrajectoryDataModule.state_dict` (Lightning saves it in every checkpoint and
restores it with ``load_state_dict``); ``normalizer.to_dict()`` can also go into the model's
hyperparameters.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import h5py
import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader

from gripdem.data.batch import WindowBatch, collate_windows
from gripdem.data.dataset import FrameReader, WindowDataset
from gripdem.data.dataset_io import read_meta
from gripdem.data.encodings import ENCODINGS, Encoding, make_encoding
from gripdem.data.frames import FrameStore
from gripdem.data.graph import DEFAULT_ALPHA
from gripdem.data.normalizer import Normalizer
from gripdem.data.protocols import (
    PARTS,
    WindowPlan,
    current_plan_names,
    plan_arguments,
    plan_windows,
)
from gripdem.data.resumable import ResumableLoader
from gripdem.data.schema import DatasetError, DatasetMeta
from gripdem.data.windows import Split, resolve_rollout_links

__all__ = ["TrajectoryDataModule", "WindowBatch", "WindowDataset", "collate_windows"]

#: frames read at once while fitting the normaliser (bounds memory on long simulations)
_FIT_CHUNK_FRAMES = 256


# --------------------------------------------------------------------------------------------
# the dataset
# --------------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------------
# the DataModule
# --------------------------------------------------------------------------------------------
class TrajectoryDataModule(L.LightningDataModule):
    """Windows of a gripdem HDF5 file for a split ``h-f`` and a protocol (see
    :mod:`gripdem.data.windows`), encoded (:mod:`gripdem.data.encodings`) with the fixed graph
    (:mod:`gripdem.data.graph`). Arguments mirror ``conf/data/default.yaml``.

    ``graph_cutoff`` is in particle diameters (docs/spec/conventions.md#size-and-cutoff: D = 3 d).
    ``expect_boundary`` (``periodic`` | ``lees_edwards``), when given, must match the file's
    boundary.
    ``model_horizon`` (``model.horizon``): a model that predicts fewer frames than the split's
    horizon trains and validates on windows of its own horizon; the test windows keep the
    split's, and the runner chains the model over them (:mod:`gripdem.runner.chained_evaluation`).
    ``rollout_links`` (``model.rollout.links``): training and validation windows of that many of
    the model's links (rollout training, :mod:`gripdem.inference.rollout_training`; ``auto`` and
    what is allowed: :func:`gripdem.data.windows.resolve_rollout_links`); the resolved number is
    :attr:`rollout_links`.
    ``seed`` (the run's seed; None: ``torch.initial_seed()``) orders the training windows: one
    permutation per ``(seed, epoch)``, resumable mid-epoch (:mod:`gripdem.data.resumable`).
    """

    def __init__(
        self,
        path: str | os.PathLike | None,
        split: Split | str | Mapping = "190-10",
        protocol: str = "auto",
        fractions: Mapping[str, float] | None = None,
        sims: Mapping[str, Sequence[int] | None] | None = None,
        simulations: Sequence[int] | None = None,
        in_sample_windows: int = 1,
        history_len: int | None = None,
        train_stride: int = 1,
        eval_stride: int | None = None,
        encoding: str = "unwrapped",
        normalise: bool = True,
        graph_cutoff: float = 3.0,
        graph_alpha: float = DEFAULT_ALPHA,
        graph_cache_mb: float = 256.0,
        memory_mb: float = 2048.0,
        model_horizon: int | None = None,
        rollout_links: int | str = 1,
        batch_size: int = 1,
        num_workers: int = 0,
        pin_memory: bool = False,
        expect_boundary: str | None = None,
        seed: int | None = None,
    ):
        super().__init__()
        if path is None:
            raise ValueError(
                "data.path is null: give a gripdem HDF5 file (the runner resolves "
                "null to the built-in scene dataset before building the DataModule)"
            )
        self.path = Path(path)
        self.split = Split.parse(split)
        self.plan_args = plan_arguments(
            protocol=protocol,
            fractions=fractions,
            sims=sims,
            simulations=simulations,
            in_sample_windows=in_sample_windows,
            history_len=history_len,
            train_stride=train_stride,
            eval_stride=eval_stride,
        )
        self.encoding_name = encoding
        self.normalise = bool(normalise)
        if not graph_cutoff > 0:
            raise ValueError(
                f"graph_cutoff (in particle diameters) must be positive, got {graph_cutoff!r}"
            )
        self.graph_cutoff = float(graph_cutoff)
        self.graph_alpha = float(graph_alpha)
        self.graph_cache_mb = float(graph_cache_mb)
        self.memory_mb = float(memory_mb)
        if model_horizon is not None and int(model_horizon) < 1:
            raise ValueError(
                f"model.horizon must be a positive number of frames or null, got {model_horizon}"
            )
        # a model horizon beyond the split's is the split's (nothing to chain)
        self.model_horizon = (
            self.split.horizon
            if model_horizon is None
            else min(int(model_horizon), self.split.horizon)
        )
        #: links of the model per training and validation window (1: windows of one link)
        self.rollout_links = resolve_rollout_links(
            rollout_links, self.split.horizon, self.model_horizon
        )
        self.batch_size = int(batch_size)
        self.num_workers = int(num_workers)
        self.pin_memory = bool(pin_memory)
        self.expect_boundary = expect_boundary
        self.seed = seed
        self.meta: DatasetMeta | None = None
        self.plan: WindowPlan | None = None
        self.encoding: Encoding | None = None
        self.normalizer: Normalizer | None = None
        self._restored: Normalizer | None = None
        self.datasets: dict[str, WindowDataset] = {}
        self._reader: FrameReader | None = None
        self._times: np.ndarray | None = None

    @classmethod
    def from_config(cls, data: Any, split: Any, **overrides: Any) -> TrajectoryDataModule:
        """Build from the ``data`` and ``split`` config nodes (DictConfig or plain mappings;
        ``split`` may also be a string ``"h-f"``). ``overrides`` win (e.g. ``path=`` resolved
        by the runner)."""
        data, split = _plain(data), _plain(split)
        kwargs = current_plan_names({k: v for k, v in data.items() if not str(k).startswith("_")})
        kwargs.update(overrides)
        if isinstance(split, Mapping):
            split = {"history": split.get("history"), "horizon": split.get("horizon")}
        return cls(split=split, **kwargs)

    # ---- setup ---------------------------------------------------------------------------
    def setup(self, stage: str | None = None) -> None:
        if self.plan is not None:
            return
        meta = read_meta(self.path)
        if self.expect_boundary is not None and meta.boundary.kind != self.expect_boundary:
            raise DatasetError(
                self.path,
                "boundary",
                f"the scene expects "
                f"{self.expect_boundary!r} data, the file holds "
                f"{meta.boundary.kind!r}",
            )
        with h5py.File(self.path, "r") as h5:
            times = np.asarray(h5["times"][()], dtype=np.float64)
        self.meta = meta
        self.plan = plan_windows(meta.n_sims, meta.n_frames, self.split, **self.plan_args)
        if self.model_horizon < self.split.horizon:
            # train and validate on windows of the model's own horizon times the links chained
            # in training; test on the split's (chained)
            short = Split(self.split.history, self.model_horizon * self.rollout_links)
            own = plan_windows(meta.n_sims, meta.n_frames, short, **self.plan_args)
            self.plan = replace(self.plan, train=own.train, val=own.val)
        self.encoding = make_encoding(self.encoding_name, meta.boundary)
        reader = FrameReader(self.path)
        self._reader, self._times = reader, times
        if self._restored is not None:
            self.normalizer = self._restored
        elif self.normalise:
            self.normalizer = self._fit_normalizer()
        else:
            self.normalizer = Normalizer.identity(self.encoding.n_channels, self.encoding.name)
        if self.normalizer.n_channels != self.encoding.n_channels:
            raise ValueError(
                f"normaliser has {self.normalizer.n_channels} channels but "
                f"encoding {self.encoding.name!r} has {self.encoding.n_channels}"
            )
        cutoff = self.graph_cutoff * meta.diameter
        store = FrameStore(
            lambda sim: reader.read(sim, 0, meta.n_frames),
            times,
            meta.boundary,
            self.normalizer,
            cutoff,
            meta.diameter,
            self.graph_alpha,
            self.memory_mb,
            meta.n_frames * meta.n_particles * 3 * 8 / 2**20,
        )
        self.datasets = {
            part: WindowDataset(
                reader,
                meta,
                times,
                self.plan.part(part),
                self.encoding,
                self.normalizer,
                cutoff,
                self.graph_alpha,
                self.graph_cache_mb,
                self.plan.in_sample,
                store,
            )
            for part in PARTS
        }

    def training_trajectories(
        self, overlap: int = 1
    ) -> Iterator[tuple[np.ndarray, np.ndarray | None]]:
        """The frames the training windows cover, each frame range once, read in chunks of at
        most ``_FIT_CHUNK_FRAMES`` frames that share ``overlap`` frames with the previous one:
        ``(positions (N, T, 3) wrapped, offsets (T,) float64 or None for a periodic box)``.
        What the normaliser and the linear AR baseline
        (:func:`gripdem.models.autoregressive.fit_on_training_frames`) are fitted on (training
        data only)."""
        if self.plan is None:
            raise RuntimeError("call setup() first")
        offsets = self.meta.boundary.offset(self._times)
        le = self.meta.boundary.is_lees_edwards
        for sim, intervals in self.plan.train.frames_used().items():
            for a, b in intervals:
                for lo in range(a, b - overlap, _FIT_CHUNK_FRAMES):
                    hi = min(b, lo + _FIT_CHUNK_FRAMES + overlap)
                    pos = self._reader.read(sim, lo, hi).transpose(1, 0, 2)
                    yield pos, (offsets[sim, lo:hi] if le else None)

    def _fit_normalizer(self) -> Normalizer:
        """Channel statistics over every step inside the frames the training windows cover
        (each step once; the change statistics within each chunk)."""
        return Normalizer.fit(
            (self.encoding.encode(pos, off) for pos, off in self.training_trajectories()),
            self.encoding.name,
        )

    # ---- loaders -------------------------------------------------------------------------
    def _loader(self, part: str, shuffle: bool) -> DataLoader:
        if not self.datasets:
            raise RuntimeError("call setup() before asking for a dataloader")
        options = dict(
            batch_size=self.batch_size,
            num_workers=self.num_workers,
            collate_fn=collate_windows,
            pin_memory=self.pin_memory,
            persistent_workers=self.num_workers > 0,
        )
        if shuffle:  # a permutation per (seed, epoch), resumable mid-epoch
            seed = torch.initial_seed() if self.seed is None else self.seed
            return ResumableLoader(self.datasets[part], seed=int(seed), **options)
        return DataLoader(self.datasets[part], shuffle=False, **options)

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader | list:
        return self._loader("val", shuffle=False) if len(self.datasets["val"]) else []

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)

    def predict_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)

    # ---- reporting and checkpoints ---------------------------------------------------------
    @property
    def in_sample(self) -> bool:
        if self.plan is None:
            return self.plan_args["protocol"] == "in_sample"
        return self.plan.in_sample

    @property
    def n_channels(self) -> int:
        if self.encoding_name not in ENCODINGS:
            raise ValueError(
                f"unknown encoding {self.encoding_name!r}; expected one of {sorted(ENCODINGS)}"
            )
        return ENCODINGS[self.encoding_name].n_channels

    def summary(self) -> dict[str, Any]:
        """Plain values describing the data for logs and hyperparameters (after setup)."""
        if self.plan is None or self.meta is None:
            raise RuntimeError("call setup() first")
        return {
            "path": str(self.path),
            "boundary": self.meta.boundary.kind,
            "n_particles": self.meta.n_particles,
            "n_sims": self.meta.n_sims,
            "n_frames": self.meta.n_frames,
            "frame_interval": self.meta.frame_interval,
            "encoding": self.encoding.name,
            "n_channels": self.encoding.n_channels,
            "normalise": self.normalise,
            "graph_cutoff_diameters": self.graph_cutoff,
            "graph_alpha": self.graph_alpha,
            **self.plan.summary(),
        }

    def state_dict(self) -> dict[str, Any]:
        if self.normalizer is None:
            return {}
        return {"normalizer": self.normalizer.to_dict(), "encoding": self.encoding_name}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """Restore the normaliser a model was trained with (also after setup)."""
        if "normalizer" not in state_dict:
            return
        if state_dict.get("encoding", self.encoding_name) != self.encoding_name:
            raise ValueError(
                f"checkpoint was trained with encoding {state_dict['encoding']!r}, "
                f"this DataModule uses {self.encoding_name!r}"
            )
        self._restored = Normalizer.from_dict(state_dict["normalizer"])
        if self.datasets:
            self.normalizer = self._restored
            for ds in self.datasets.values():
                ds.normalizer = self._restored
                if ds.store is not None:
                    ds.store.use_normalizer(self._restored)

    def teardown(self, stage: str | None = None) -> None:
        if self.datasets:
            self.datasets["train"].reader.close()


def _plain(node: Any) -> Any:
    """A DictConfig as a resolved plain container; anything else as it is."""
    from omegaconf import DictConfig, OmegaConf

    return OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else node
