"""A study's search space: ``hydra.sweeper.params`` in Hydra's sweep grammar, as Optuna
distributions, and a trial's sampled values as the overrides of its run.

The grammar (as the Hydra Optuna sweeper read it, so existing configs keep working):

- ``choice(32, 64)``: categorical;
- ``range(1, 5)``: the integers 1-4 as a categorical (``range(0, 1, 0.25)``: its values);
- ``interval(a, b)``: uniform float in [a, b]; ``int(interval(a, b))``: uniform integer;
- ``tag(log, interval(a, b))``: log-uniform (float or integer);
- a plain value (``model.hidden=32``): fixed in every trial.

:func:`space_record` is the space as plain JSON: the study stores it when it is created and a
study resumed or joined with another space is refused (:mod:`gripdem.study.storage`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from optuna.distributions import (
    BaseDistribution,
    CategoricalDistribution,
    FloatDistribution,
    IntDistribution,
    distribution_to_json,
)

#: Optuna's categorical choices: plain values only (what an override can say)
_CHOICE_TYPES = (type(None), bool, int, float, str)


def _choices(values: list[Any], key: str) -> tuple:
    for value in values:
        if not isinstance(value, _CHOICE_TYPES):
            raise ValueError(
                f"hydra.sweeper.params.{key}: a choice must be a number, a string, a boolean "
                f"or null, got {value!r}"
            )
    return tuple(values)


def _distribution(key: str, value: Any) -> BaseDistribution | Any:
    from hydra.core.override_parser.types import ChoiceSweep, IntervalSweep, RangeSweep

    if isinstance(value, ChoiceSweep):
        return CategoricalDistribution(_choices(list(value.list), key))
    if isinstance(value, RangeSweep):
        start, stop, step = value.start, value.stop, value.step
        values = []
        x = start
        while (step > 0 and x < stop) or (step < 0 and x > stop):
            values.append(x)
            x = x + step
        if not values:
            raise ValueError(f"hydra.sweeper.params.{key}: range({start}, {stop}, {step}) is empty")
        return CategoricalDistribution(tuple(values))
    if isinstance(value, IntervalSweep):
        log = "log" in value.tags
        unknown = set(value.tags) - {"log"}
        if unknown:
            raise ValueError(
                f"hydra.sweeper.params.{key}: unknown tag(s) {sorted(unknown)} (allowed: log)"
            )
        if value.start >= value.end:
            raise ValueError(
                f"hydra.sweeper.params.{key}: interval({value.start}, {value.end}) must have "
                "its lower bound first"
            )
        if log and value.start <= 0:
            raise ValueError(
                f"hydra.sweeper.params.{key}: a log interval needs a positive lower bound, got "
                f"{value.start}"
            )
        if isinstance(value.start, int) and isinstance(value.end, int):
            return IntDistribution(value.start, value.end, log=log)
        return FloatDistribution(float(value.start), float(value.end), log=log)
    return value  # fixed in every trial


def parse_space(params: Mapping[str, Any] | None) -> tuple[dict[str, BaseDistribution], dict]:
    """``(distributions, fixed)``: the swept keys' Optuna distributions and the keys given one
    value, from ``hydra.sweeper.params`` (values as strings of Hydra's grammar). Raises
    ``ValueError`` naming the key on what cannot be searched."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parser = OverridesParser.create()
    distributions: dict[str, BaseDistribution] = {}
    fixed: dict[str, Any] = {}
    for key, text in (params or {}).items():
        try:
            override = parser.parse_overrides([f"{key}={text}"])[0]
        except Exception as exc:  # noqa: BLE001 - Hydra's grammar errors: one line of ours
            raise ValueError(
                f"hydra.sweeper.params.{key}={text!r} is not Hydra's sweep grammar (choice(..), "
                f"range(..), interval(..), tag(log, interval(..))): {exc}"
            ) from None
        result = _distribution(str(key), override.value())
        if isinstance(result, BaseDistribution):
            distributions[str(key)] = result
        else:
            fixed[str(key)] = override.get_value_element_as_str()
    if not distributions:
        raise ValueError(
            "hydra.sweeper.params holds no searched key: give at least one choice(..), "
            "range(..) or interval(..)"
        )
    return distributions, fixed


def space_record(distributions: Mapping[str, BaseDistribution], fixed: Mapping[str, Any]) -> str:
    """The space as one JSON string (keys sorted): what a study stores and compares."""
    record = {
        "searched": {k: json.loads(distribution_to_json(d)) for k, d in distributions.items()},
        "fixed": {k: str(v) for k, v in fixed.items()},
    }
    return json.dumps(record, sort_keys=True)


def describe_difference(stored: str, given: str) -> str:
    """What differs between two :func:`space_record` strings, in a few words."""
    old, new = json.loads(stored), json.loads(given)
    parts = []
    for part in ("searched", "fixed"):
        a, b = old.get(part, {}), new.get(part, {})
        for key in sorted(set(a) | set(b)):
            if a.get(key) != b.get(key):
                was = json.dumps(a[key]) if key in a else "absent"
                now = json.dumps(b[key]) if key in b else "absent"
                parts.append(f"{key}: stored {was}, given {now}")
    return "; ".join(parts) or "the same keys"


def trial_overrides(params: Mapping[str, Any], fixed: Mapping[str, Any]) -> list[str]:
    """A trial's overrides: its sampled values, then the fixed keys, in the space's order."""
    from gripdem.runner.parallel_launcher import quoted

    overrides = []
    for key, value in params.items():
        if isinstance(value, str):
            value = quoted(value)
        elif value is None:
            value = "null"
        elif isinstance(value, bool):
            value = str(value).lower()
        elif isinstance(value, float):
            value = repr(value)
        overrides.append(f"{key}={value}")
    overrides += [f"{key}={value}" for key, value in fixed.items()]
    return overrides
