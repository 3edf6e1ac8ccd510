"""Helpers of the fuzz suite (tests/fuzz): one harness that runs a reader on a corrupted input
and checks the four promises of issue 21, and the settings every fuzz test shares.

:func:`refuses_or_accepts` calls the reader and asserts: it either returns (the caller then
checks what it returned is valid) or raises one of the documented error types with a message
that names the input; nothing else escapes (any other exception fails the test: a bug); it ends
within ``seconds``; its peak resident memory grows by less than ``megabytes`` (the kernel's
high-water mark ``VmHWM``, reset before each call through ``/proc/self/clear_refs``: it sees
numpy, HDF5 and torch allocations alike); and it leaves no new file in ``watch``.

``COUNTS`` counts the examples each fuzz target ran; ``tests/fuzz/conftest.py`` prints them at
the end of the session.
"""

from __future__ import annotations

import os
import time
from collections import Counter
from collections.abc import Callable
from datetime import timedelta
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, settings

#: examples per fuzz target run (hypothesis), counted in COUNTS; of them refused (a documented
#: error) in REFUSED, the rest were read as valid data
COUNTS: Counter[str] = Counter()
REFUSED: Counter[str] = Counter()

#: the settings of every fuzz test: fixed example counts, reproducible (derandomize), a
#: generous deadline (the machine may be loaded) on top of the harness's own time bound
FUZZ = settings(
    derandomize=True,
    deadline=timedelta(seconds=10),
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    database=None,
)


def _status_kb(key: str) -> int | None:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(key + ":"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def _reset_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def refuses_or_accepts(
    target: str,
    call: Callable[[], Any],
    errors: tuple[type[BaseException], ...],
    names: str | os.PathLike | None = None,
    watch: Path | None = None,
    seconds: float = 10.0,
    megabytes: float = 256.0,
    count: bool = True,
) -> tuple[Any, BaseException | None]:
    """Run ``call``; returns ``(result, None)`` or ``(None, error)`` for a documented error.
    Asserts the bounds above; ``names``: text the error message must contain (the file).
    ``count``: count this call as one example of ``target``."""
    COUNTS[target] += int(count)
    before = sorted(os.listdir(watch)) if watch is not None else None
    measured = _reset_peak()
    start_rss = _status_kb("VmRSS") or 0
    started = time.perf_counter()
    result, error = None, None
    try:
        result = call()
    except errors as exc:
        error = exc
    elapsed = time.perf_counter() - started
    assert elapsed < seconds, f"{target}: took {elapsed:.1f} s (bound {seconds} s)"
    if measured:
        peak = (_status_kb("VmHWM") or 0) - start_rss
        assert peak < megabytes * 1024, f"{target}: peak memory grew by {peak / 1024:.0f} MB"
    if error is not None:
        REFUSED[target] += int(count)
        message = str(error)
        assert message.strip(), f"{target}: {type(error).__name__} without a message"
        if names is not None:
            assert str(names) in message, f"{target}: message does not name {names}: {message}"
    if before is not None:
        after = sorted(os.listdir(watch))
        assert after == before, f"{target}: left {sorted(set(after) - set(before))} behind"
    return result, error
