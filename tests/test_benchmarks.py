"""The benchmark scripts of ``experiments/`` in their ``--quick`` mode (slow tier): each runs on
the session's tiny datasets, prints the machine line (CPU, threads, torch version) beside its
table, and its figures are consistent. Timings themselves are never asserted."""

from __future__ import annotations

import json

import pytest

pytestmark = pytest.mark.slow


@pytest.fixture
def run_script(run_experiment_quick, tiny_pbc_path, tiny_lebc_path):
    """``run_script(name, *args) -> stdout`` of ``python experiments/<name>.py --quick``
    (name: e.g. ``benchmarks/scaling``)."""

    def run(name: str, *args: str) -> str:
        proc = run_experiment_quick(name, *args)
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
        assert "machine:" in proc.stdout and "torch 2" in proc.stdout and "thread" in proc.stdout
        return proc.stdout

    return run


def test_time_vs_error_quick(run_script, tmp_path):
    out = run_script("benchmarks/time_vs_error", "--out-dir", str(tmp_path))
    assert "| DEM solver" in out and "| constant_velocity |" in out
    assert (tmp_path / "pareto_time_vs_error.png").stat().st_size > 0
    report = json.loads((tmp_path / "time_vs_error.json").read_text())
    assert {(g["scene"], g["split"]) for g in report["groups"]} == {
        ("pbc", "10-5"),
        ("lebc", "10-5"),
    }
    for group in report["groups"]:
        kinds = [row["kind"] for row in group["rows"]]
        assert kinds.count("dem") == 1 and "model" in kinds and kinds.count("baseline") == 4
        assert all(row["rmse_over_d"] >= 0 for row in group["rows"])


def test_surrogate_quick(run_script, tmp_path):
    out = run_script("benchmarks/surrogate_speed", "--json", str(tmp_path / "s.json"))
    report = json.loads((tmp_path / "s.json").read_text())
    assert {(r["scene"], r["particles"]) for r in report["rows"]} == {
        (s, n) for s in ("pbc", "lebc") for n in (400, 1600)
    }
    assert "steps per frame" in out


def test_scaling_quick(run_script, tmp_path):
    run_script("benchmarks/scaling", "--json", str(tmp_path / "s.json"))
    rows = json.loads((tmp_path / "s.json").read_text())["rows"]
    forms = {r["op"] for r in rows if "seconds" in r}
    assert forms == {"sparse", "dense", "interaction"}
    assert {r["mode"] for r in rows} == {"inference", "train step"}


def test_scene_cost_quick(run_script, tmp_path):
    run_script("benchmarks/scene_cost", "--json", str(tmp_path / "s.json"))
    report = json.loads((tmp_path / "s.json").read_text())
    assert report["le_path_difference"] < 1e-12  # the LE path predicts the same positions
    assert [row[0] for row in report["dem"]][:3] == ["pbc", "lebc", "pbc via the LE path"]
