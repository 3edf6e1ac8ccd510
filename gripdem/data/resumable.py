"""A training DataLoader whose order is reproducible and which resumes mid-epoch.

The order of an epoch is a permutation drawn from ``(seed, epoch)`` alone
(:class:`EpochPermutation`), not from the global random stream, so it does not depend on what
else drew random numbers before. :class:`ResumableLoader` counts the batches it has handed
out in the current epoch; its ``state_dict``/``load_state_dict`` (plain ints) is what Lightning
saves for a stateful training loader in every checkpoint (``loops.fit_loop.state_dict.
combined_loader``) and gives back before the first ``iter()`` of a resumed fit. The resumed
epoch then skips the batches already trained on (as lists of indices: nothing is read) and
continues at the next one.

The skip is applied to the batch sampler, so it also holds when Lightning wraps the sampler for
DDP (its ``DistributedSamplerWrapper`` shuffles by ``(seed, epoch)`` too). The loader draws its
worker base seed from a generator of its own, never from the global one.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader, Sampler

__all__ = ["EpochPermutation", "ResumableLoader", "epoch_seed"]


def epoch_seed(seed: int, epoch: int) -> int:
    """A 64-bit seed for ``(seed, epoch)`` (numpy's SeedSequence: neighbouring pairs give
    unrelated streams, unlike ``seed + epoch``)."""
    return int(np.random.SeedSequence([int(seed), int(epoch)]).generate_state(1, np.uint64)[0])


class EpochPermutation(Sampler[int]):
    """A random permutation of ``range(n)`` per epoch, drawn from ``(seed, epoch)``; Lightning
    calls :meth:`set_epoch` at the start of every epoch."""

    def __init__(self, n: int, seed: int = 0):
        self.n = int(n)
        self.seed = int(seed)
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return self.n

    def __iter__(self) -> Iterator[int]:
        generator = torch.Generator().manual_seed(epoch_seed(self.seed, self.epoch))
        return iter(torch.randperm(self.n, generator=generator).tolist())


class _SkipBatches:
    """The loader's batch sampler with a resumed epoch's first batches left out (decided when
    the epoch's first batch is drawn, after Lightning has set the sampler's epoch)."""

    def __init__(self, batch_sampler, loader: ResumableLoader):
        self.batch_sampler = batch_sampler
        self.loader = loader

    def __len__(self) -> int:
        return len(self.batch_sampler)

    def __iter__(self) -> Iterator[list[int]]:
        loader = self.loader
        epoch = loader.sampler_epoch()
        skip = 0
        if loader._pending is not None:
            pending_epoch, pending_batches = loader._pending
            loader._pending = None
            if pending_epoch == epoch:
                skip = pending_batches
        loader._epoch, loader._consumed = epoch, skip
        for index, batch in enumerate(self.batch_sampler):
            if index >= skip:
                yield batch


class _Counting:
    """The DataLoader's iterator, counting the batches it hands out."""

    def __init__(self, iterator, loader: ResumableLoader):
        self.iterator = iterator
        self.loader = loader

    def __iter__(self) -> _Counting:
        return self

    def __next__(self):
        batch = next(self.iterator)
        self.loader._consumed += 1
        return batch

    def __len__(self) -> int:
        return len(self.iterator)


class ResumableLoader(DataLoader):
    """A shuffling training DataLoader that resumes mid-epoch (see the module doc). ``seed``
    drives the permutations (:class:`EpochPermutation`) unless a ``sampler`` is given (Lightning
    passes its distributed wrapper when it rebuilds the loader for DDP)."""

    def __init__(self, dataset, *args: Any, seed: int = 0, sampler=None, **kwargs: Any):
        if sampler is None:
            sampler = EpochPermutation(len(dataset), seed)
        kwargs.pop("shuffle", None)
        kwargs.setdefault("generator", torch.Generator().manual_seed(int(seed)))
        super().__init__(dataset, *args, sampler=sampler, **kwargs)
        self.seed = int(seed)
        self._epoch: int | None = None  # the epoch being iterated (the sampler's)
        self._consumed = 0  # its batches handed out
        self._pending: tuple[int, int] | None = None  # restored (epoch, batches), not yet used

    def sampler_epoch(self) -> int:
        return int(getattr(self.sampler, "epoch", 0))

    @property
    def _index_sampler(self):
        return _SkipBatches(super()._index_sampler, self)

    def __iter__(self):
        return _Counting(super().__iter__(), self)

    def state_dict(self) -> dict[str, int]:
        """``{"epoch", "batches"}``: batches of that epoch handed out (plain ints)."""
        if self._pending is not None:  # restored and not iterated yet: pass it on unchanged
            return {"epoch": self._pending[0], "batches": self._pending[1]}
        epoch = self.sampler_epoch() if self._epoch is None else self._epoch
        return {"epoch": int(epoch), "batches": int(self._consumed)}

    def load_state_dict(self, state_dict: dict[str, int]) -> None:
        epoch, batches = int(state_dict["epoch"]), int(state_dict["batches"])
        if batches >= len(self):  # that epoch was complete: the next one starts from its start
            epoch, batches = epoch + 1, 0
        set_epoch = getattr(self.sampler, "set_epoch", None)
        if callable(set_epoch):  # workers draw the first indices at iter(), before Lightning
            set_epoch(epoch)  # sets the epoch: they must see the resumed one
        self._pending = (epoch, batches)
