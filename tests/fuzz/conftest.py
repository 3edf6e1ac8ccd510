"""The fuzz suite's report: how many examples each target ran (printed at the end)."""

from __future__ import annotations

from fuzzing import COUNTS, REFUSED


def pytest_terminal_summary(terminalreporter):
    if COUNTS:
        parts = ", ".join(
            f"{name} {count} ({REFUSED[name]} refused)" for name, count in sorted(COUNTS.items())
        )
        terminalreporter.write_line(f"fuzz examples run: {sum(COUNTS.values())} ({parts})")
