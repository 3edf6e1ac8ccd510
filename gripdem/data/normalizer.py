"""Per-channel normalisation of the encoded deltas (training-split statistics only).

:class:`Normalizer` holds per-channel mean and std as plain floats, so it can be stored in a
checkpoint or in hyperparameters and restored, and the same statistics of the per-step change of
the deltas (the velocity change that constant velocity misses: the target scale of the exact
decoders). Statistics are merged over chunks in float64 (Chan's pairwise update).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from gripdem.boundary import Array
from gripdem.data.encodings import VCTEncoding


class _Moments:
    """Running per-channel mean and sum of squared deviations over ``(..., C)`` chunks, merged
    in float64 (Chan's pairwise update)."""

    def __init__(self) -> None:
        self.n, self.mean, self.m2 = 0, None, None

    def add(self, chunk: np.ndarray) -> None:
        x = np.asarray(chunk, dtype=np.float64).reshape(-1, chunk.shape[-1])
        if x.shape[0] == 0:
            return
        cm = x.mean(axis=0)
        cm2 = ((x - cm) ** 2).sum(axis=0)
        if self.mean is None:
            self.n, self.mean, self.m2 = x.shape[0], cm, cm2
            return
        total = self.n + x.shape[0]
        delta = cm - self.mean
        self.mean = self.mean + delta * (x.shape[0] / total)
        self.m2 = self.m2 + cm2 + delta**2 * (self.n * x.shape[0] / total)
        self.n = total

    def result(self) -> tuple[np.ndarray, np.ndarray]:
        """``(mean, std)``; a channel without spread gets std 1."""
        std = np.sqrt(self.m2 / self.n)
        return self.mean, np.where(std > 0, std, 1.0)


@dataclass(frozen=True)
class Normalizer:
    """Per-channel ``(x - mean) / std``. Plain floats: store :meth:`to_dict` in a checkpoint or
    in hyperparameters and rebuild with :meth:`from_dict`. A channel with zero spread (e.g. the
    VCT shift channels without crossings) keeps ``std = 1``.

    ``change_std``: per-channel spread of the change of the deltas from one step to the next
    (for ``unwrapped``: the velocity change per frame, what constant velocity misses), the scale
    in which the exact decoders predict; empty when it was not fitted.
    """

    mean: tuple[float, ...]
    std: tuple[float, ...]
    encoding: str = ""
    count: int = 0
    change_std: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if len(self.mean) != len(self.std):
            raise ValueError(f"mean has {len(self.mean)} channels but std {len(self.std)}")
        if self.change_std and len(self.change_std) != len(self.std):
            raise ValueError(
                f"change_std has {len(self.change_std)} channels but std {len(self.std)}"
            )
        for name in ("std", "change_std"):
            values = getattr(self, name)
            if not all(math.isfinite(s) and s > 0 for s in values):
                raise ValueError(f"{name} must be positive and finite, got {values}")
            object.__setattr__(self, name, tuple(float(s) for s in values))
        object.__setattr__(self, "mean", tuple(float(m) for m in self.mean))

    @property
    def n_channels(self) -> int:
        return len(self.mean)

    @classmethod
    def identity(cls, n_channels: int, encoding: str = "") -> Normalizer:
        return cls((0.0,) * n_channels, (1.0,) * n_channels, encoding, 0, (1.0,) * n_channels)

    @classmethod
    def fit(cls, chunks: Iterable[np.ndarray], encoding: str = "") -> Normalizer:
        """Statistics over chunks ``(..., steps, C)`` of consecutive deltas; the change
        statistics use consecutive steps within each chunk."""
        values, changes = _Moments(), _Moments()
        for chunk in chunks:
            values.add(chunk)
            if chunk.ndim >= 2 and chunk.shape[-2] >= 2:
                changes.add(np.diff(np.asarray(chunk, np.float64), axis=-2))
        if values.mean is None:
            raise ValueError("cannot fit a normaliser on no data")
        mean, std = values.result()
        change_std = changes.result()[1] if changes.mean is not None else np.ones_like(std)
        if encoding == VCTEncoding.name:
            # The LE shift channels are zero except at rare crossings: their own spread would
            # blow a crossing up to hundreds of standard deviations. Scale them like the real
            # z channels (same units), centred at zero.
            mean[6:8] = 0.0
            std[6:8] = std[4:6]
            change_std[6:8] = change_std[4:6]
        return cls(tuple(mean), tuple(std), encoding, values.n, tuple(change_std))

    def _stats(self, like: Array) -> tuple[Array, Array]:
        if isinstance(like, torch.Tensor):
            kw = {"dtype": like.dtype, "device": like.device}
            return torch.tensor(self.mean, **kw), torch.tensor(self.std, **kw)
        return np.asarray(self.mean, like.dtype), np.asarray(self.std, like.dtype)

    def normalize(self, x: Array) -> Array:
        mean, std = self._stats(x)
        return (x - mean) / std

    def denormalize(self, x: Array) -> Array:
        mean, std = self._stats(x)
        return x * std + mean

    def to_dict(self) -> dict[str, Any]:
        return {
            "encoding": self.encoding,
            "mean": list(self.mean),
            "std": list(self.std),
            "count": self.count,
            "change_std": list(self.change_std),
        }

    @classmethod
    def from_dict(cls, state: dict[str, Any]) -> Normalizer:
        return cls(
            tuple(state["mean"]),
            tuple(state["std"]),
            state.get("encoding", ""),
            int(state.get("count", 0)),
            tuple(state.get("change_std", ())),
        )
