"""Issue 24 (slow tier): every command killed at a random moment, by SIGKILL, SIGTERM or
Ctrl-C, leaves no process running and no half-written file, and the same command then works
(``experiments/benchmarks/robustness/kill_commands.py --quick``: 3 kills of each command)."""

from __future__ import annotations

import json

import pytest

pytestmark = pytest.mark.slow


def test_killed_commands_leave_nothing_behind(run_experiment_quick, tmp_path):
    proc = run_experiment_quick("benchmarks/robustness/kill_commands", "--out-dir", str(tmp_path))
    report = json.loads((tmp_path / "kill_commands.json").read_text())
    rows = report["rows"]
    assert {r["command"] for r in rows} == {
        "simulate",
        "run",
        "multirun",
        "predict",
        "handback",
        "convert",
    }
    assert {r["signal"] for r in rows} == {"SIGKILL", "SIGTERM", "SIGINT"}
    strays = [(r["command"], r["index"], s) for r in rows for s in r["strays"] + r["next_strays"]]
    assert strays == [], strays
    bad = [(r["command"], r["index"], b) for r in rows for b in r["bad_files"]]
    assert bad == [], bad
    assert not any(r["hung"] for r in rows)
    assert all(r["next_rc"] == 0 for r in rows), [(r["command"], r["next_rc"]) for r in rows]
    assert all(r["cache_temporary"] == [] for r in rows)
    # SIGTERM / Ctrl-C: one "interrupted:" line and status 143 / 130, but for a signal that
    # lands while Python itself starts (timing-dependent: reported in the table, not asserted)
    assert any(r["exit"] == "clean" for r in rows)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "| simulate |" in proc.stdout and "machine:" in proc.stdout
