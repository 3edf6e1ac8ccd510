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


# --------------------------------------------------------------------------------------------
# rollout training: windows of several links
# --------------------------------------------------------------------------------------------
#: ``model.rollout.links=auto``: links per training window, at most this many (the smallest
#: number of the split's links that is at least 2 and divides them; 1 where the split's horizon
#: is one link). Chosen by measurement: docs/explanation/models.md#rollout-training
AUTO_ROLLOUT_LINKS = 2


def resolve_rollout_links(links: int | str, split_horizon: int, link: int) -> int:
    """The links a training window chains (``model.rollout.links``): ``auto`` or a whole number
    ``L >= 1``. A model whose link (``model.horizon``) is shorter than the split's horizon is
    tested by chaining ``split_horizon / link`` links with the contact correction between
    them; rollout training chains ``L`` of them per training window, so a window spans
    ``K + 1 + L * link`` frames. ``L`` must divide the split's links; ``L > 1`` needs a split
    whose horizon is longer than one link. ``auto``: the smallest divisor of the split's links
    that is at least :data:`AUTO_ROLLOUT_LINKS` (1 when the split is one link).

    Raises :class:`~gripdem.errors.SplitError` naming ``model.rollout.links`` and what is
    allowed."""
    link = int(link)
    split_links, rest = divmod(int(split_horizon), link)
    if isinstance(links, str) and links.strip().lower() == "auto":
        if split_links <= 1 or rest:
            return 1
        return min(n for n in range(AUTO_ROLLOUT_LINKS, split_links + 1) if split_links % n == 0)
    if isinstance(links, bool) or not isinstance(links, int) or links < 1:
        raise SplitError(
            f"model.rollout.links must be 'auto' or a whole number >= 1, got {links!r}"
        )
    if links == 1:
        return 1
    if split_links <= 1:
        raise SplitError(
            f"model.rollout.links={links}: the split's horizon ({split_horizon} frames) is not "
            f"longer than the model's link (model.horizon={link}), so there is nothing to "
            "chain; use model.rollout.links=1 or auto, or a longer split (e.g. split=100-100)"
        )
    allowed = [n for n in range(1, split_links + 1) if split_links % n == 0 and not rest]
    if rest or split_links % links:
        raise SplitError(
            f"model.rollout.links={links} does not divide the split's {split_horizon} frames "
            f"into links of model.horizon={link}: allowed "
            + (
                ", ".join(map(str, allowed))
                if allowed
                else "1 (the horizon is not a multiple of the link)"
            )
            + " or auto"
        )
    return links
