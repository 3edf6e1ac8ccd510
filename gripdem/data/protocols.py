"""The three evaluation protocols (docs/spec/protocols.md#protocols): which windows train, validate
and test.

- ``sims``: train, val and test are different simulations (by fractions, or explicit lists).
- ``time``: each used simulation is cut in time at target-frame boundaries ``B1 < B2``: every
  training target frame is ``< B1``, every validation target frame in ``[B1, B2)``, every test
  target frame ``>= B2``. Inputs may reach back into the previous part (they are observed).
- ``in_sample``: as the reference scripts: train = val = test = the same window(s).
  :attr:`WindowPlan.in_sample` is ``True``; every consumer reports it.
- ``auto``: ``sims`` when the file holds at least 3 simulations, otherwise ``time``.

Training windows slide with ``train_stride``; validation and test windows with ``eval_stride``
(default ``f``, so their targets do not overlap). A split that does not fit raises
:class:`~gripdem.data.windows.SplitError` saying how long the data is and what fits.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from gripdem.data.windows import (
    PAPER_SPLITS,
    Segment,
    Split,
    SplitError,
    WindowIndex,
    count_windows,
)

PROTOCOLS = ("sims", "time", "in_sample", "auto")
#: former protocol names (``paper`` before gripdem 0.1.0: the word also names the paper's models,
#: preset and claims): old -> new. The option name was removed in 0.2.0 (the command line
#: refuses it); a config or file saved before the rename is still read, with a warning
RENAMED_PROTOCOLS = {"paper": "in_sample"}
#: former option names of the window plan: old -> new (a config saved before the rename)
RENAMED_PLAN_OPTIONS = {"paper_windows": "in_sample_windows"}


PARTS = ("train", "val", "test")


@dataclass(frozen=True)
class WindowPlan:
    """Train/val/test windows of one protocol. ``in_sample`` is True for the ``in_sample``
    protocol only."""

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
            "one long simulation, or protocol=in_sample"
        )
    order = list(range(n_sims))
    return {
        "train": order[:n_train],
        "val": order[n_train : n_train + n_val],
        "test": order[n_train + n_val :],
    }


def current_protocol(protocol: str, warn: bool = True) -> str:
    """The protocol's name today: a former name (``RENAMED_PROTOCOLS``) is mapped to it, with a
    ``DeprecationWarning`` unless ``warn`` is False (a file written before the rename)."""
    new = RENAMED_PROTOCOLS.get(protocol)
    if new is None:
        return protocol
    if warn:
        import warnings

        warnings.warn(
            f"protocol {protocol!r} was renamed {new!r} in gripdem 0.1.0: read as {new!r} (a "
            "config saved before the rename)",
            DeprecationWarning,
            stacklevel=3,
        )
    return new


def plan_arguments(
    protocol: str = "auto",
    fractions: Mapping[str, float] | None = None,
    sims: Mapping[str, Sequence[int] | None] | None = None,
    simulations: Sequence[int] | None = None,
    in_sample_windows: int = 1,
    history_len: int | None = None,
    train_stride: int = 1,
    eval_stride: int | None = None,
) -> dict[str, Any]:
    """:func:`plan_windows`' keyword arguments from the data options of the same names: one
    place for the DataModule and the runner's check of a user's file before Lightning
    (:func:`gripdem.runner.config_checks.check_windows_fit_the_file`)."""
    return dict(
        protocol=current_protocol(protocol),
        history_len=history_len,
        train_stride=int(train_stride),
        eval_stride=eval_stride,
        fractions=None if fractions is None else dict(fractions),
        sims=None if sims is None else dict(sims),
        simulations=None if simulations is None else list(simulations),
        in_sample_windows=int(in_sample_windows),
    )


def current_plan_names(options: Mapping[str, Any]) -> dict[str, Any]:
    """``options`` with the plan's former names (:data:`RENAMED_PLAN_OPTIONS`) renamed."""
    options = dict(options)
    for old, new in RENAMED_PLAN_OPTIONS.items():
        value = options.pop(old, None)
        if value is not None:
            options[new] = value
    return options


#: the data options that :func:`plan_arguments` reads
PLAN_OPTIONS = (
    "protocol", "fractions", "sims", "simulations", "in_sample_windows", "history_len",
    "train_stride", "eval_stride",
)  # fmt: skip


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
    in_sample_windows: int = 1,
) -> WindowPlan:
    """Windows for every part of ``protocol``. Raises :class:`SplitError` with what fits.

    ``fractions``: of simulations (``sims``) or of frames (``time``). ``sims``: explicit
    simulation lists per part (``sims`` protocol). ``simulations``: which simulations ``time``
    (default all) and ``in_sample`` (default ``[0]``) use. ``in_sample_windows``: how many
    windows the in-sample protocol keeps (the reference used one). A former protocol name
    (``paper``) is read as today's with a ``DeprecationWarning``.
    """
    protocol = current_protocol(protocol)
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
            in_sample_windows,
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
            in_sample_windows,
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
    in_sample_windows,
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
    if split.history + 1 + f > n_frames:  # the split's name promises h input velocities
        raise SplitError(
            f"split {split.name} needs {split.history + 1 + f} frames for one window at its full "
            f"history (h+1+f; history_len={k} only shortens what the model reads, the split's "
            f"h is still its label) but a simulation has {n_frames}."
        )
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
    else:  # in_sample
        used = [0] if simulations is None else [int(s) for s in simulations]
        _check_sims(used, n_sims, "simulations")
        if in_sample_windows < 1:
            raise SplitError(f"in_sample_windows must be >= 1, got {in_sample_windows}")
        segs, left = [], in_sample_windows
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
    in_sample_windows=1,
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
                    in_sample_windows,
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
