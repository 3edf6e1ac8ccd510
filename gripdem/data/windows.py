"""Split windows: the `h-f` split, history truncation and the window index.

A split ``h-f`` means up to ``h`` input velocities and ``f`` predicted frames
(docs/spec/protocols.md#splits). The model reads ``history_len = K <= h`` velocities, so one window
spans ``K + 1 + f`` frames::

    frames  start ... start+K | start+K+1 ... start+K+f
            K+1 input frames  | f target frames
                     ^ last observed frame (the graph is built here)

Windows are indexed with cumulative counts over simulations (as lagrangebench's ``H5Dataset``):
a part of a protocol (train, val or test) is a list of :class:`Segment` (one simulation, a first
start frame, a stride and a count), and window ``i`` is found by bisecting the cumulative counts.

The protocols that choose the windows of each part: :mod:`gripdem.data.protocols`.
"""

from __future__ import annotations

import bisect
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from gripdem.errors import SplitError

#: the paper's splits (h-f); a 201-frame simulation holds exactly one full-history window of each
PAPER_SPLITS = ("190-10", "180-20", "150-50", "100-100")


# --------------------------------------------------------------------------------------------
# the split h-f
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Split:
    """``history`` = h (maximum input velocities), ``horizon`` = f (predicted frames)."""

    history: int
    horizon: int

    def __post_init__(self) -> None:
        for name in ("history", "horizon"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise SplitError(f"split {name} must be a positive integer, got {value!r}")

    @property
    def name(self) -> str:
        return f"{self.history}-{self.horizon}"

    @classmethod
    def parse(cls, value: Any) -> Split:
        """From ``"h-f"``, a ``Split``, or a mapping with ``history`` and ``horizon``."""
        if isinstance(value, Split):
            return value
        if isinstance(value, Mapping):
            missing = [k for k in ("history", "horizon") if value.get(k) is None]
            if missing:
                raise SplitError(
                    f"split config needs {missing} (e.g. split=custom "
                    "split.history=50 split.horizon=5), got {dict(value)!r}"
                )
            return cls(int(value["history"]), int(value["horizon"]))
        match = re.fullmatch(r"\s*(\d+)\s*-\s*(\d+)\s*", str(value))
        if match is None:
            raise SplitError(
                f"a split is written 'h-f' with whole numbers (e.g. '190-10'), got {value!r}"
            )
        return cls(int(match.group(1)), int(match.group(2)))


# --------------------------------------------------------------------------------------------
# window arithmetic
# --------------------------------------------------------------------------------------------
def count_windows(first: int, last: int, stride: int) -> int:
    """Number of start frames ``first, first+stride, ... <= last`` (0 if ``last < first``)."""
    if stride < 1:
        raise SplitError(f"window stride must be >= 1, got {stride}")
    return 0 if last < first else (last - first) // stride + 1


@dataclass(frozen=True)
class Segment:
    """Windows of one simulation: starts ``first + k*stride`` for ``k < count``."""

    sim: int
    first: int
    stride: int
    count: int


@dataclass(frozen=True)
class Window:
    """One window: simulation index and first frame; frames ``start .. start+K+f``."""

    sim: int
    start: int
    history_len: int
    horizon: int

    @property
    def span(self) -> int:
        return self.history_len + 1 + self.horizon

    @property
    def stop(self) -> int:
        """One past the last frame."""
        return self.start + self.span

    @property
    def last_observed(self) -> int:
        return self.start + self.history_len

    @property
    def target_frames(self) -> range:
        return range(self.last_observed + 1, self.stop)


class WindowIndex(Sequence):
    """The windows of one protocol part, indexed through cumulative counts over segments."""

    def __init__(self, segments: Sequence[Segment], history_len: int, horizon: int):
        self.segments = tuple(s for s in segments if s.count > 0)
        self.history_len = history_len
        self.horizon = horizon
        self._cumulative: list[int] = []
        total = 0
        for seg in self.segments:
            total += seg.count
            self._cumulative.append(total)

    def __len__(self) -> int:
        return self._cumulative[-1] if self._cumulative else 0

    def __getitem__(self, index: int) -> Window:  # type: ignore[override]
        n = len(self)
        if index < 0:
            index += n
        if not 0 <= index < n:
            raise IndexError(f"window {index} out of range ({n} windows)")
        k = bisect.bisect_right(self._cumulative, index)
        before = self._cumulative[k - 1] if k else 0
        seg = self.segments[k]
        return Window(
            seg.sim, seg.first + (index - before) * seg.stride, self.history_len, self.horizon
        )

    @property
    def sims(self) -> tuple[int, ...]:
        return tuple(sorted({s.sim for s in self.segments}))

    def frames_used(self) -> dict[int, list[tuple[int, int]]]:
        """Per simulation, merged half-open frame intervals ``[a, b)`` covered by windows."""
        span = self.history_len + 1 + self.horizon
        raw: dict[int, list[tuple[int, int]]] = {}
        for seg in self.segments:
            ivals = raw.setdefault(seg.sim, [])
            if seg.stride <= span:  # consecutive windows overlap or touch: one interval
                ivals.append((seg.first, seg.first + (seg.count - 1) * seg.stride + span))
            else:
                ivals.extend(
                    (seg.first + j * seg.stride, seg.first + j * seg.stride + span)
                    for j in range(seg.count)
                )
        out: dict[int, list[tuple[int, int]]] = {}
        for sim, ivals in raw.items():
            merged: list[tuple[int, int]] = []
            for a, b in sorted(ivals):
                if merged and a <= merged[-1][1]:
                    merged[-1] = (merged[-1][0], max(merged[-1][1], b))
                else:
                    merged.append((a, b))
            out[sim] = merged
        return out

    def target_frames(self) -> dict[int, set[int]]:
        """Per simulation, the set of target frame indices (for protocol checks and tests)."""
        out: dict[int, set[int]] = {}
        for w in self:
            out.setdefault(w.sim, set()).update(w.target_frames)
        return out


# --------------------------------------------------------------------------------------------
# protocols
# --------------------------------------------------------------------------------------------
