"""pytest plugin of ``test_command.py --census``: each test's wall time and CPU time (its
worker's own and that of the processes it started and waited for, which the kernel adds to the
worker's children) appended as one JSON line to ``$GRIPDEM_CENSUS_DIR/tests-<pid>.jsonl``.
A module- or session-scoped fixture is charged to the first test that needs it."""

from __future__ import annotations

import json
import os
import resource
import time

import pytest


def _cpu(who: int) -> float:
    usage = resource.getrusage(who)
    return usage.ru_utime + usage.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    folder = os.environ.get("GRIPDEM_CENSUS_DIR")
    own, children, wall = _cpu(resource.RUSAGE_SELF), _cpu(resource.RUSAGE_CHILDREN), time.time()
    yield
    if not folder:
        return
    record = {
        "test": item.nodeid,
        "wall_s": time.time() - wall,
        "cpu_s": _cpu(resource.RUSAGE_SELF) - own,
        "children_cpu_s": _cpu(resource.RUSAGE_CHILDREN) - children,
    }
    with open(os.path.join(folder, f"tests-{os.getpid()}.jsonl"), "a") as handle:
        handle.write(json.dumps(record) + "\n")
