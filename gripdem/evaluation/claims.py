"""``python -m gripdem.claims SWEEP_DIR [SWEEP_DIR ...]``: the paper's claims
(docs/spec/evaluation.md#claims) as hypotheses, tested on a sweep's out-of-sample results over
seeds.

The claims (models by their config names, ``--grip/--pct/--vct`` to test other variants):

1. ``pbc``: PCT beats GRIP++ at every split; the gap grows with the horizon.
2. ``lebc``: PCT and VCT beat GRIP++; VCT is best at the short splits (190-10, 180-20) and for
   the particles that cross the LE faces; PCT is best at the long splits (150-50, 100-100).
3. All models predict some overlapping particles.

Each comparison "A beats B" on a metric (test RMSE, or the crossers' RMSE) uses the mean over
seeds of each model and the standard error of the difference,
``se = sqrt(s_A²/n_A + s_B²/n_B)``: **held** when B's mean exceeds A's by more than
``MARGIN`` standard errors, **not held** when A's exceeds B's by as much, **undecided**
otherwise or with fewer than two seeds of either model. "The gap grows" compares the relative
gap ``(GRIP - PCT) / GRIP`` at the longest split with that at the shortest, the same way. A
claim holds when every comparison in it holds, fails when any fails, and is undecided
otherwise. "Some overlapping particles": every run of every model has a non-zero overlap
fraction at the last predicted step (the truth's beside it), no statistics needed.

Writes ``claims.md`` (and prints it) into the first sweep folder or ``--out``.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass

#: standard errors of the difference that decide a comparison
MARGIN = 2.0
SHORT_SPLITS = ("190-10", "180-20")
LONG_SPLITS = ("150-50", "100-100")
HELD, NOT_HELD, UNDECIDED = "held", "not held", "undecided"
#: overlap fraction of the model at the last step (older runs: the flat key)
OVERLAP_KEYS = ("test/physics/model/overlap_fraction", "test/physics/overlap_fraction")
TRUTH_OVERLAP_KEYS = ("test/physics/truth/overlap_fraction", "test/physics/overlap_fraction_true")

Groups = dict[tuple[str, str, str], list[dict]]


@dataclass
class Comparison:
    """One tested statement and its evidence."""

    statement: str
    verdict: str
    evidence: str


def _horizon(split: str) -> int:
    return int(split.split("-")[1])


def _values(groups: Groups, scene: str, split: str, model: str, key: str) -> list[float]:
    out = []
    for metrics in groups.get((scene, split, model), []):
        value = metrics.get(key)
        if isinstance(value, (int, float)) and math.isfinite(value):
            out.append(float(value))
    return out


def _mean_var(values: list[float]) -> tuple[float, float, int]:
    """Mean, variance of the mean (squared standard error; NaN below two values), count."""
    n = len(values)
    if n == 0:
        return math.nan, math.nan, 0
    var = statistics.variance(values) / n if n > 1 else math.nan
    return statistics.fmean(values), var, n


def decide(difference: float, variance: float, n_min: int) -> tuple[str, float]:
    """Verdict of "difference > 0" and its margin in standard errors, ``variance`` being the
    squared standard error of the difference."""
    if n_min < 2 or not math.isfinite(variance) or not math.isfinite(difference):
        return UNDECIDED, math.nan
    if variance == 0.0:
        margin = math.inf if difference > 0 else (-math.inf if difference < 0 else 0.0)
    else:
        margin = difference / math.sqrt(variance)
    if margin > MARGIN:
        return HELD, margin
    if margin < -MARGIN:
        return NOT_HELD, margin
    return UNDECIDED, margin


def beats(groups: Groups, scene: str, split: str, a: str, b: str, key: str, what: str):
    """``a`` has the lower mean of ``key`` than ``b`` beyond the seed spread."""
    mean_a, var_a, n_a = _mean_var(_values(groups, scene, split, a, key))
    mean_b, var_b, n_b = _mean_var(_values(groups, scene, split, b, key))
    verdict, margin = decide(mean_b - mean_a, var_a + var_b, min(n_a, n_b))
    evidence = (
        f"{a} {mean_a:.4g} (n={n_a}) vs {b} {mean_b:.4g} (n={n_b}); "
        f"{b} - {a} = {mean_b - mean_a:+.3g} = {_in_se(margin)}"
    )
    return Comparison(f"{scene} {split}: {a} beats {b} ({what})", verdict, evidence)


def _in_se(margin: float) -> str:
    """A margin in standard errors, or why there is none."""
    return "no seed spread (fewer than 2 seeds)" if math.isnan(margin) else f"{margin:+.1f} se"


def gap_grows(groups: Groups, scene: str, splits: list[str], grip: str, pct: str) -> Comparison:
    """The relative gap ``(grip - pct) / grip`` of test RMSE is larger at the longest split."""
    ends = []
    for split in (splits[0], splits[-1]):
        g = _mean_var(_values(groups, scene, split, grip, "test/rmse"))
        p = _mean_var(_values(groups, scene, split, pct, "test/rmse"))
        gap = (g[0] - p[0]) / g[0] if g[2] else math.nan
        # delta method: var of (g - p)/g ~ (p/g²)² var_g + (1/g)² var_p
        var = (p[0] / g[0] ** 2) ** 2 * g[1] + p[1] / g[0] ** 2 if g[2] else math.nan
        ends.append((gap, var, min(g[2], p[2])))
    (short, var_s, n_s), (long, var_l, n_l) = ends
    verdict, margin = decide(long - short, var_s + var_l, min(n_s, n_l))
    evidence = (
        f"gap (GRIP - PCT) / GRIP: {short:+.3%} at {splits[0]}, {long:+.3%} at {splits[-1]}; "
        f"growth {long - short:+.3%} = {_in_se(margin)}"
    )
    return Comparison(f"{scene}: the PCT-GRIP gap grows with the horizon", verdict, evidence)


def combine(parts: list[Comparison]) -> str:
    verdicts = {p.verdict for p in parts}
    if not parts or verdicts == {UNDECIDED}:
        return UNDECIDED
    if NOT_HELD in verdicts:
        return NOT_HELD
    return HELD if verdicts == {HELD} else UNDECIDED


def _splits(groups: Groups, scene: str, models: Sequence[str]) -> list[str]:
    found = {k[1] for k in groups if k[0] == scene and k[2] in models}
    return sorted(found, key=_horizon)


def evaluate(groups: Groups, grip="grip", pct="pct", vct="vct") -> list[tuple[str, list]]:
    """``[(claim, [Comparison, ...]), ...]`` for the three claims (see the module doc)."""
    claims = []
    rmse = "test/rmse"
    splits = _splits(groups, "pbc", (grip, pct))
    parts = [beats(groups, "pbc", s, pct, grip, rmse, "test RMSE") for s in splits]
    if len(splits) > 1:
        parts.append(gap_grows(groups, "pbc", splits, grip, pct))
    claims.append(("PBC: PCT beats GRIP++ at every split; the gap grows with the horizon", parts))

    splits = _splits(groups, "lebc", (grip, pct, vct))
    parts = []
    for s in splits:
        parts += [
            beats(groups, "lebc", s, pct, grip, rmse, "test RMSE"),
            beats(groups, "lebc", s, vct, grip, rmse, "test RMSE"),
        ]
        if s in SHORT_SPLITS:
            parts.append(beats(groups, "lebc", s, vct, pct, rmse, "test RMSE"))
        if s in LONG_SPLITS:
            parts.append(beats(groups, "lebc", s, pct, vct, rmse, "test RMSE"))
        for other in (grip, pct):
            parts.append(
                beats(groups, "lebc", s, vct, other, "test/rmse_crossers", "RMSE of LE crossers")
            )
    claims.append(
        (
            "LEBC: PCT and VCT beat GRIP++; VCT best at short splits and for LE crossers; "
            "PCT best at long splits",
            parts,
        )
    )

    parts = []
    for (scene, split, model), runs in sorted(groups.items()):
        if model not in (grip, pct, vct):
            continue
        fractions = [_first(m, OVERLAP_KEYS) for m in runs]
        truth = [_first(m, TRUTH_OVERLAP_KEYS) for m in runs]
        known = [f for f in fractions if math.isfinite(f)]
        verdict = UNDECIDED if not known else (HELD if min(known) > 0 else NOT_HELD)
        evidence = (
            f"overlap fraction at the last step: model {_range(fractions)}, truth {_range(truth)}"
        )
        parts.append(Comparison(f"{scene} {split} {model}: some overlap", verdict, evidence))
    claims.append(("All models predict some overlapping particles", parts))
    return claims


def _first(metrics: dict, keys: Sequence[str]) -> float:
    for key in keys:
        value = metrics.get(key)
        if isinstance(value, (int, float)):
            return float(value)
    return math.nan


def _range(values: list[float]) -> str:
    known = [v for v in values if math.isfinite(v)]
    if not known:
        return "–"
    lo, hi = min(known), max(known)
    return f"{lo:.3%}" if lo == hi else f"{lo:.3%}..{hi:.3%}"


def to_markdown(claims: list[tuple[str, list]]) -> str:
    lines = [
        "# The paper's claims (docs/spec/evaluation.md#claims), out of sample",
        "",
        f"Comparisons: means over seeds, decided at {MARGIN:g} standard errors of the difference.",
        "",
    ]
    for claim, parts in claims:
        lines += [f"## {claim}: **{combine(parts)}**", "", "| statement | verdict | evidence |"]
        lines.append("|---|---|---|")
        lines += [f"| {p.statement} | {p.verdict} | {p.evidence} |" for p in parts]
        if not parts:
            lines.append("| (no runs of these models in the sweep) | undecided | |")
        lines.append("")
    return "\n".join(lines)
