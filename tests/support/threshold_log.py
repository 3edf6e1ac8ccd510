"""A pytest plugin that writes down every numeric check a test makes, passed or failed, so that
the spread of the measured values across CPUs and thread counts can be set beside each threshold
(``experiments/analyses/threshold_spread.py`` runs the suite under each combination and reads
these logs).

Active only when ``GRIPDEM_ASSERT_LOG`` names a file (one JSON object a line; with
pytest-xdist each worker appends to ``<file>.<worker>``) and pytest runs with
``-o enable_assertion_pass_hook=true``. It records:

- every passing ``assert`` that compares (``<``, ``<=``, ``>``, ``>=``, ``==``, ``!=``), with
  pytest's explanation (the values on both sides);
- every failing one, from the failure report's ``E`` lines;
- every call of ``torch.testing.assert_close`` and ``numpy.testing.assert_allclose``: the
  largest difference, the tolerances, and the margin (the smallest ``(atol + rtol |b|) / |a - b|``).

Nothing is recorded, and nothing wrapped, without the variable: the default test run is as it is.
"""

from __future__ import annotations

import functools
import json
import os
import re
import sys
from pathlib import Path

import numpy as np

_COMPARISON = re.compile(r"(<=|>=|==|!=|<|>)")
_TEST = {"nodeid": None}
_TESTS_DIR = str(Path(__file__).resolve().parents[1])
_DUMPS = json.dumps  # bound now: some tests replace json.dumps to make a write fail
_DEFAULT_TOLERANCES = {"float32": (1.3e-6, 1e-5), "float64": (1e-7, 1e-7)}  # assert_close's


def _log_path() -> Path | None:
    base = os.environ.get("GRIPDEM_ASSERT_LOG")
    if not base:
        return None
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    return Path(f"{base}.{worker}" if worker else base)


def _write(record: dict) -> None:
    path = _log_path()
    if path is None:
        return
    record = {"test": _TEST["nodeid"], **record}
    with open(path, "a", encoding="utf-8") as f:
        f.write(_DUMPS(record, default=str) + "\n")


def _differences(actual, expected, rtol, atol) -> tuple[float, float]:
    """Largest |a - b|, and the margin: the smallest (atol + rtol |b|) / |a - b| over the
    entries that differ (inf when none does; NaN when nothing is numeric)."""
    try:
        dtype = str(getattr(actual, "dtype", "float64")).replace("torch.", "")
        default_rtol, default_atol = _DEFAULT_TOLERANCES.get(dtype, (1e-7, 0.0))
        rtol = default_rtol if rtol is None else float(rtol)
        atol = default_atol if atol is None else float(atol)
        a = np.asarray(getattr(actual, "detach", lambda: actual)(), dtype=float)
        b = np.asarray(getattr(expected, "detach", lambda: expected)(), dtype=float)
        diff = np.abs(a - b)
        differ = np.isfinite(diff) & (diff > 0)
        if not differ.any():
            return 0.0, float("inf")
        allowed = atol + rtol * np.abs(np.broadcast_to(b, diff.shape))
        return float(diff[differ].max()), float((allowed[differ] / diff[differ]).min())
    except (TypeError, ValueError):
        return float("nan"), float("nan")


def _assertion_file() -> str | None:
    """The file of the ``assert`` being reported: the nearest caller outside pytest/pluggy."""
    frame = sys._getframe(2)
    while frame is not None:
        name = frame.f_code.co_filename
        if not any(part in name for part in ("_pytest", "pluggy", "threshold_log")):
            return name
        frame = frame.f_back
    return None


def _wrap_closeness(module, name: str, kind: str) -> None:
    original = getattr(module, name)
    if getattr(original, "_gripdem_logged", False):
        return

    @functools.wraps(original)
    def logged(actual, expected, *args, **kwargs):
        rtol = kwargs.get("rtol", args[0] if args else (1e-7 if kind.startswith("numpy") else None))
        atol = kwargs.get(
            "atol", args[1] if len(args) > 1 else (0.0 if kind.startswith("numpy") else None)
        )
        abs_diff, margin = _differences(actual, expected, rtol, atol)
        record = {"kind": kind, "abs_diff": abs_diff, "margin": margin, "atol": atol, "rtol": rtol}
        try:
            result = original(actual, expected, *args, **kwargs)
        except AssertionError:
            _write({**record, "passed": False})
            raise
        _write({**record, "passed": True})
        return result

    logged._gripdem_logged = True
    setattr(module, name, logged)


def pytest_configure(config) -> None:
    if _log_path() is None:
        return
    import numpy.testing
    import torch.testing

    _wrap_closeness(torch.testing, "assert_close", "torch.testing.assert_close")
    _wrap_closeness(numpy.testing, "assert_allclose", "numpy.testing.assert_allclose")


def pytest_runtest_setup(item) -> None:
    _TEST["nodeid"] = item.nodeid


def pytest_assertion_pass(item, lineno, orig, expl) -> None:
    if _log_path() is None or not _COMPARISON.search(orig):
        return
    source = _assertion_file()
    if source is None or not source.startswith(_TESTS_DIR):
        return  # an assert inside a library that pytest rewrote (hypothesis' own, say)
    _write(
        {
            "kind": "assert",
            "line": lineno,
            "assert": orig,
            "values": expl.splitlines()[0] if expl else "",
            "passed": True,
        }
    )


def pytest_runtest_logreport(report) -> None:
    if _log_path() is None or not report.failed or report.when != "call":
        return
    lines = [line[1:].strip() for line in str(report.longrepr).splitlines() if line[:1] == "E"]
    compared = next((line for line in lines if line.startswith("assert ")), "")
    _write(
        {
            "test": report.nodeid,
            "kind": "assert",
            "line": None,
            "assert": compared,
            "values": compared.removeprefix("assert "),
            "passed": False,
        }
    )
