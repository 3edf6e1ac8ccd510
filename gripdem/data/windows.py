"""Split windows: the `h-f` split, history truncation, and the three evaluation protocols.

A split ``h-f`` means up to ``h`` input velocities and ``f`` predicted frames (SPEC §4). The model
reads ``history_len = K <= h`` velocities, so one window spans ``K + 1 + f`` frames::

    frames  start ... start+K | start+K+1 ... start+K+f
            K+1 input frames  | f target frames
                     ^ last observed frame (the graph is built here)

Windows are indexed with cumulative counts over simulations (as lagrangebench's ``H5Dataset``):
a part of a protocol (train, val or test) is a list of :class:`Segment` (one simulation, a first
start frame, a stride and a count), and window ``i`` is found by bisecting the cumulative counts.

Protocols:

- ``sims``: train, val and test are different simulations (by fractions, or explicit lists).
- ``time``: each used simulation is cut in time at target-frame boundaries ``B1 < B2``: every
  training target frame is ``< B1``, every validation target frame in ``[B1, B2)``, every test
  target frame ``>= B2``. Inputs may reach back into the previous part (they are observed).
- ``paper``: in-sample, as the reference scripts: train = val = test = the same window(s).
  :attr:`WindowPlan.in_sample` is ``True``; every consumer reports it.
- ``auto``: ``sims`` when the file holds at least 3 simulations, otherwise ``time``.

Training windows slide with ``train_stride``; validation and test windows with ``eval_stride``
(default ``f``, so their targets do not overlap).
"""

from __future__ import annotations

import bisect
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

PROTOCOLS = ("sims", "time", "paper", "auto")
PARTS = ("train", "val", "test")
#: the paper's splits (h-f); a 201-frame simulation holds exactly one full-history window of each
PAPER_SPLITS = ("190-10", "180-20", "150-50", "100-100")


class SplitError(ValueError):
    """A split, history length or protocol that does not fit the data (message says what fits)."""


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
@dataclass(frozen=True)
class WindowPlan:
    """Train/val/test windows of one protocol. ``in_sample`` is True for ``paper`` only."""

    protocol: str
    split: Split
    history_len: int
    train: WindowIndex
    val: WindowIndex
    test: WindowIndex
    in_sample: bool
    notes: dict[str, Any] = field(default_factory=dict)

    def part(self, name: str) -> WindowIndex:
        if name not in PARTS:
            raise KeyError(f"unknown part {name!r}; expected one of {PARTS}")
        return getattr(self, name)

    def summary(self) -> dict[str, Any]:
        """Plain values for logs and hyperparameters."""
        return {
            "protocol": self.protocol,
            "in_sample": self.in_sample,
            "split": self.split.name,
            "history_len": self.history_len,
            "horizon": self.split.horizon,
            **{f"n_windows_{p}": len(self.part(p)) for p in PARTS},
            **{f"sims_{p}": list(self.part(p).sims) for p in PARTS},
            **self.notes,
        }


def _fractions(fractions: Mapping[str, float] | None) -> dict[str, float]:
    frac = {"train": 0.6, "val": 0.2, "test": 0.2}
    if fractions:
        unknown = set(fractions) - set(PARTS)
        if unknown:
            raise SplitError(f"unknown fraction keys {sorted(unknown)}; expected {PARTS}")
        frac.update({k: float(v) for k, v in fractions.items()})
    if any(v < 0 for v in frac.values()) or frac["train"] <= 0 or frac["test"] <= 0:
        raise SplitError(f"fractions must be >= 0 with train > 0 and test > 0, got {frac}")
    total = sum(frac.values())
    return {k: v / total for k, v in frac.items()}


def _sims_partition(
    n_sims: int, fractions: dict[str, float], explicit: Mapping[str, Sequence[int] | None] | None
) -> dict[str, list[int]]:
    if explicit and any(explicit.get(p) is not None for p in PARTS):
        parts = {p: [int(s) for s in (explicit.get(p) or [])] for p in PARTS}
        for p, sims in parts.items():
            bad = [s for s in sims if not 0 <= s < n_sims]
            if bad:
                raise SplitError(
                    f"sims.{p} = {sims} names simulations {bad} but the data has "
                    f"{n_sims} (indices 0..{n_sims - 1})"
                )
        for a, b in (("train", "val"), ("train", "test"), ("val", "test")):
            shared = set(parts[a]) & set(parts[b])
            if shared:
                raise SplitError(
                    f"protocol 'sims' needs disjoint simulations; sims.{a} and "
                    f"sims.{b} share {sorted(shared)}"
                )
        if not parts["train"] or not parts["test"]:
            raise SplitError(f"protocol 'sims' needs train and test simulations, got {parts}")
        return parts
    n_val = max(1, round(n_sims * fractions["val"])) if fractions["val"] > 0 else 0
    n_test = max(1, round(n_sims * fractions["test"]))
    n_train = n_sims - n_val - n_test
    if n_train < 1:
        raise SplitError(
            f"protocol 'sims' needs at least {n_val + n_test + 1} simulations (train, "
            f"{'val, ' if n_val else ''}test) but the data has {n_sims}; use protocol=time for "
            "one long simulation, or protocol=paper (in-sample)"
        )
    order = list(range(n_sims))
    return {
        "train": order[:n_train],
        "val": order[n_train : n_train + n_val],
        "test": order[n_train + n_val :],
    }


def plan_windows(
    n_sims: int,
    n_frames: int,
    split: Split | str | Mapping,
    protocol: str = "auto",
    history_len: int | None = None,
    train_stride: int = 1,
    eval_stride: int | None = None,
    fractions: Mapping[str, float] | None = None,
    sims: Mapping[str, Sequence[int] | None] | None = None,
    simulations: Sequence[int] | None = None,
    paper_windows: int = 1,
) -> WindowPlan:
    """Windows for every part of ``protocol``. Raises :class:`SplitError` with what fits.

    ``fractions``: of simulations (``sims``) or of frames (``time``). ``sims``: explicit
    simulation lists per part (``sims`` protocol). ``simulations``: which simulations ``time``
    (default all) and ``paper`` (default ``[0]``) use. ``paper_windows``: how many windows the
    in-sample protocol keeps (the reference used one).
    """
    try:
        return _plan(
            n_sims,
            n_frames,
            split,
            protocol,
            history_len,
            train_stride,
            eval_stride,
            fractions,
            sims,
            simulations,
            paper_windows,
        )
    except SplitError as exc:
        fits = what_fits(
            n_sims,
            n_frames,
            protocol,
            train_stride,
            eval_stride,
            fractions,
            sims,
            simulations,
            paper_windows,
        )
        raise SplitError(
            f"{exc}\nThe data holds {n_sims} simulation(s) of {n_frames} frames each. {fits}"
        ) from None


def _plan(
    n_sims,
    n_frames,
    split,
    protocol,
    history_len,
    train_stride,
    eval_stride,
    fractions,
    sims,
    simulations,
    paper_windows,
) -> WindowPlan:
    split = Split.parse(split)
    f = split.horizon
    k = split.history if history_len is None else int(history_len)
    if not 1 <= k <= split.history:
        raise SplitError(
            f"history_len must lie in 1..{split.history} for split {split.name}, got {k}"
        )
    if protocol not in PROTOCOLS:
        raise SplitError(f"unknown protocol {protocol!r}; expected one of {PROTOCOLS}")
    if protocol == "auto":
        protocol = "sims" if n_sims >= 3 else "time"
    eval_stride = f if eval_stride is None else int(eval_stride)
    span = k + 1 + f
    frac = _fractions(fractions)
    if span > n_frames:
        raise SplitError(
            f"split {split.name} with history_len {k} needs windows of {span} "
            f"frames (K+1+f) but a simulation has {n_frames}"
        )

    def index(segs: list[Segment]) -> WindowIndex:
        return WindowIndex(segs, k, f)

    notes: dict[str, Any] = {}
    if protocol == "sims":
        parts = _sims_partition(n_sims, frac, sims)
        val_optional = not parts["val"]
        last = n_frames - span
        plan = {
            p: index(
                [
                    Segment(
                        s,
                        0,
                        train_stride if p == "train" else eval_stride,
                        count_windows(0, last, train_stride if p == "train" else eval_stride),
                    )
                    for s in parts[p]
                ]
            )
            for p in PARTS
        }
        in_sample = False
    elif protocol == "time":
        used = list(range(n_sims)) if simulations is None else [int(s) for s in simulations]
        _check_sims(used, n_sims, "simulations")
        val_optional = frac["val"] == 0
        b1 = round(n_frames * frac["train"])
        b2 = round(n_frames * (frac["train"] + frac["val"]))
        notes = {"time_boundaries": [b1, b2]}
        ranges = {  # (first start, last start) so that targets lie in the part's frames
            "train": (0, b1 - span),
            "val": (max(0, b1 - k - 1), b2 - span),
            "test": (max(0, b2 - k - 1), n_frames - span),
        }
        plan = {}
        for p, (a, b) in ranges.items():
            stride = train_stride if p == "train" else eval_stride
            plan[p] = index([Segment(s, a, stride, count_windows(a, b, stride)) for s in used])
        in_sample = False
    else:  # paper
        used = [0] if simulations is None else [int(s) for s in simulations]
        _check_sims(used, n_sims, "simulations")
        if paper_windows < 1:
            raise SplitError(f"paper_windows must be >= 1, got {paper_windows}")
        segs, left = [], paper_windows
        for s in used:
            c = min(left, count_windows(0, n_frames - span, train_stride))
            segs.append(Segment(s, 0, train_stride, c))
            left -= c
        same = index(segs)
        plan = {"train": same, "val": same, "test": same}
        in_sample = True
        val_optional = False
    for p in PARTS:
        if len(plan[p]) == 0 and not (p == "val" and val_optional):
            why = ""
            if protocol == "time":
                why = (
                    f"; the {p} part of the timeline is too short (target-frame boundaries "
                    f"{notes['time_boundaries']} from fractions {frac})"
                )
            raise SplitError(
                f"protocol {protocol!r}: no {p} window fits split {split.name} "
                f"with history_len {k} (windows of {span} frames){why}"
            )
    return WindowPlan(
        protocol, split, k, plan["train"], plan["val"], plan["test"], in_sample, notes
    )


def _check_sims(used: list[int], n_sims: int, what: str) -> None:
    bad = [s for s in used if not 0 <= s < n_sims]
    if bad or not used:
        raise SplitError(f"{what} = {used}: the data has simulations 0..{n_sims - 1}")


def what_fits(
    n_sims,
    n_frames,
    protocol="auto",
    train_stride=1,
    eval_stride=None,
    fractions=None,
    sims=None,
    simulations=None,
    paper_windows=1,
) -> str:
    """One sentence: which paper splits fit this data under ``protocol``, and up to which
    ``history_len``."""
    parts = []
    for name in PAPER_SPLITS:
        split = Split.parse(name)
        best = None
        for k in range(split.history, 0, -1):
            try:
                _plan(
                    n_sims,
                    n_frames,
                    split,
                    protocol,
                    k,
                    train_stride,
                    eval_stride,
                    fractions,
                    sims,
                    simulations,
                    paper_windows,
                )
            except SplitError:
                continue
            best = k
            break
        if best is None:
            parts.append(f"{name}: does not fit at any history_len")
        elif best == split.history:
            parts.append(f"{name}: fits")
        else:
            parts.append(f"{name}: fits with history_len <= {best}")
    return f"Under protocol {protocol!r}: " + "; ".join(parts) + "."
