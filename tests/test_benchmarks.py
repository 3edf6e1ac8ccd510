"""The benchmark scripts of ``experiments/`` in their ``--quick`` mode (slow tier): each runs on
the session's tiny datasets, prints the machine line (CPU, threads, torch version) beside its
table, and its figures are consistent. Timings themselves are never asserted."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow


@pytest.fixture
def run_script(run_experiment_quick, tiny_pbc_path, tiny_lebc_path):
    """``run_script(name, *args) -> stdout`` of ``python experiments/<name>.py --quick``
    (name: e.g. ``benchmarks/model_cost/scaling``)."""

    def run(name: str, *args: str) -> str:
        proc = run_experiment_quick(name, *args)
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
        assert "machine:" in proc.stdout and "torch 2" in proc.stdout and "thread" in proc.stdout
        return proc.stdout

    return run


def test_time_vs_error_quick(run_script, tmp_path):
    out = run_script("benchmarks/end_to_end/time_vs_error", "--out-dir", str(tmp_path))
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
    out = run_script("benchmarks/surrogate/surrogate_speed", "--json", str(tmp_path / "s.json"))
    report = json.loads((tmp_path / "s.json").read_text())
    # several runs side by side: the median of each group, every run in brackets
    speed = tmp_path / "speed"
    proc = subprocess.run(
        [sys.executable, str(Path(__file__).parents[1] / "experiments/analyses/speed_runs.py"),
         "--group", "a", str(tmp_path / "s.json"), str(tmp_path / "s.json"),
         "--group", "b", str(tmp_path / "s.json"), "--out", str(speed)],
        capture_output=True, text=True,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    runs = json.loads(speed.with_suffix(".json").read_text())["rows"]
    assert {(r["scene"], r["particles"]) for r in runs} == {
        (r["scene"], r["particles"]) for r in report["rows"]
    }
    for row in runs:
        assert len(row["a/over_dem"]) == 2 and row["a/over_dem"][0] == row["b/over_dem"][0] > 0
    assert {(r["scene"], r["particles"]) for r in report["rows"]} == {
        (s, n) for s in ("pbc", "lebc") for n in (400, 1600)
    }
    assert "steps per frame" in out and "÷ LAMMPS" in out
    for row in report["rows"]:  # the model's time broken into the stepper's parts
        parts = row["model"]["parts_s_per_frame"]
        assert 0 < sum(parts.values()) <= row["model"]["s_per_frame"] * 1.001
        assert row["model"]["precision"] in ("fp32", "bf16")


def test_encoder_speed_quick(run_script, tmp_path):
    """Every lever's row; the chunked rounds give the unchunked output, bf16 stays within its
    stated tolerance of fp32 (the same weights and inputs)."""
    run_script("benchmarks/model_cost/encoder_speed", "--json", str(tmp_path / "e.json"))
    rows = json.loads((tmp_path / "e.json").read_text())["rows"]
    assert {r["particles"] for r in rows} == {400, 1600}
    for row in rows:
        assert row["ms"] > 0
        if "chunked" in row["variant"] and "bf16" not in row["variant"]:
            assert row["relative_deviation"] < 1e-5, row
        if "bf16" in row["variant"]:
            assert row["relative_deviation"] < 0.03, row


def test_scaling_quick(run_script, tmp_path):
    run_script("benchmarks/model_cost/scaling", "--json", str(tmp_path / "s.json"))
    rows = json.loads((tmp_path / "s.json").read_text())["rows"]
    forms = {r["op"] for r in rows if "seconds" in r}
    assert forms == {"sparse", "dense", "contact"}
    assert {r["mode"] for r in rows} == {"inference", "train step"}


def test_scene_cost_quick(run_script, tmp_path):
    run_script("benchmarks/model_cost/scene_cost", "--json", str(tmp_path / "s.json"))
    report = json.loads((tmp_path / "s.json").read_text())
    assert report["le_path_difference"] < 1e-12  # the LE path predicts the same positions
    assert [row[0] for row in report["dem"]][:3] == ["pbc", "lebc", "pbc via the LE path"]


def test_surrogate_rollout_quick(run_script, tmp_path):
    """Smoke ensembles of 3 members beside the smoke point models (the references)."""
    out = run_script(
        "benchmarks/surrogate/surrogate_rollout", "--out-dir", str(tmp_path), "--members", "3"
    )
    report = json.loads((tmp_path / "surrogate_rollout.json").read_text())
    for scene in ("pbc", "lebc"):
        ensemble, reference = report["scenes"][scene], report["scenes"][f"{scene} (reference)"]
        assert ensemble["members"] == 3 and reference["members"] == 1
        assert len(ensemble["member_blocks"]) == 2 and len(ensemble["spread_over_d"]) == 2
        assert len(ensemble["spread_skill"]) == 40 and len(ensemble["rank_histogram"]) == 4
        assert min(ensemble["spread_over_d"]) > 0
        assert set(ensemble["crps_over_d"]) == set(reference["crps_over_d"])
    for scene in ("pbc", "lebc", "pbc (reference)", "lebc (reference)"):
        data = report["scenes"][scene]
        assert data["frames"] == 40 and data["dem_ms_per_frame"] > 0
        assert set(data["rmse_over_d"]) == {"model", "constant_velocity", "linear_ar"}
        assert len(data["blocks"]["blocks"]) == 2 and data["noise_floor"]["blocks"]
        stem = scene.replace(" (reference)", "_reference")
        assert data["handback"] and (tmp_path / f"surrogate_rollout_{stem}.png").exists()
        # the stable setting: contact correction, nothing closer than 0.98 d in a kept frame
        assert data["settings"]["contact_correction"] is True
        assert max(data["blocks"]["overlap_per_frame"]["model"]) == 0.0
    assert "| target | measured (worst) | verdict |" in out
    assert "| spread/skill 0.8-1.2 at every frame 1-40 |" in out
    # the ensemble's microstructure figure, ablation rows and model-card section, from the report
    report_path = tmp_path / "surrogate_rollout.json"
    root = Path(__file__).resolve().parents[1] / "experiments" / "analyses"

    def analysis(name: str, *args: str) -> str:
        proc = subprocess.run(
            [sys.executable, str(root / f"{name}.py"), *args], capture_output=True, text=True
        )
        assert proc.returncode == 0, proc.stderr[-3000:]
        return proc.stdout

    analysis("microstructure_figure", str(report_path), "pbc", str(tmp_path / "m.png"))
    assert (tmp_path / "m.png").stat().st_size > 10_000
    metrics = tmp_path / "metrics.json"
    metrics.write_text(
        json.dumps({"test/rmse_ratio_constant_velocity": 0.9, "test/crps_over_d": 1})
    )
    rows = [
        f"pbc|{label}|{metrics}|{report_path}|{entry}"
        for label, entry in (("ensemble", "pbc"), ("deterministic", "pbc (reference)"))
    ]
    table = analysis(
        "ensemble_ablation", "--row", rows[0], "--row", rows[1], "--out", str(tmp_path / "ablation")
    )
    assert "worst 20-frame block" in table and table.count("| pbc |") == 2
    # several seeds side by side: the same report twice is one value with no spread
    out = analysis(
        "surrogate_seeds", "--group", "twice", str(report_path), str(report_path),
        "--group", "once", str(report_path), "--out", str(tmp_path / "seeds"),
    )  # fmt: skip
    seeds = json.loads((tmp_path / "seeds.json").read_text())
    for scene in ("pbc", "lebc", "pbc (reference)", "lebc (reference)"):
        twice, once = seeds[scene]["twice"], seeds[scene]["once"]
        assert twice["gr_l1"] == 2 * once["gr_l1"] and len(once["msd_1"]) == 1
        assert once["gr_l1"][0] == max(
            b["gr_l1"]
            for b in report["scenes"][scene]["blocks"]["blocks"]
            + [b for m in report["scenes"][scene].get("member_blocks", []) for b in m]
        )
    assert "| pbc | g(r) L1 | 0.02 |" in out and " ± 0 (" in out
    # chosen entries, relabelled, in the order given
    analysis(
        "surrogate_seeds", "--group", "one", str(report_path),
        "--entry", "pbc (reference)=pbc, deterministic", "--entry", "pbc=pbc, ensemble",
        "--out", str(tmp_path / "entries"),
    )  # fmt: skip
    entries = json.loads((tmp_path / "entries.json").read_text())
    assert [k for k in entries if k != "header"] == ["pbc, deterministic", "pbc, ensemble"]
    assert entries["pbc, ensemble"]["one"] == seeds["pbc"]["once"]


def test_model_front_quick(run_script, tmp_path):
    run_script("benchmarks/surrogate/model_front", "--out-dir", str(tmp_path), "--links", "5", "1")
    rows = json.loads((tmp_path / "model_front.json").read_text())
    assert len(rows) == 2 and all(r["weights"] > 0 for r in rows)
    assert all(set(r["timing"]) == {"1t/link5", "1t/link1"} for r in rows)
    assert (tmp_path / "model_front.png").stat().st_size > 0


def test_model_ab_speed_quick(run_script, tmp_path):
    """Two model files side by side: a row each, every part timed."""
    out = run_script(
        "benchmarks/surrogate/model_ab_speed",
        *("--model", "a=pretrained:pbc", "--model", "b=pretrained:pbc"),
        *("--out", str(tmp_path / "ab")),
    )
    report = json.loads((tmp_path / "ab.json").read_text())
    assert set(report["walls_s"]) == {"a", "b"} and "| a | 10 | 10 |" in out
    for name, walls in report["walls_s"].items():
        assert len(walls) == 2 and min(walls) > 0
        assert 0 < sum(report["parts_s"][name].values()) <= min(walls) * 1.001


def test_dem_cost_quick(run_script, tmp_path):
    """Both engines from one state; a coarser DEM step costs fewer steps per frame."""
    run_script(
        "benchmarks/surrogate/dem_cost", "--steps-per-contact", "30", "20",
        "--out", str(tmp_path / "c"),
    )  # fmt: skip
    report = json.loads((tmp_path / "c.json").read_text())
    cells = {(c["scene"], c["steps_per_contact"]): c["rounds"][0] for c in report["cells"]}
    assert set(cells) == {(s, k) for s in ("pbc", "lebc") for k in (30.0, 20.0)}
    for scene in ("pbc", "lebc"):
        fine, coarse = cells[(scene, 30.0)], cells[(scene, 20.0)]
        assert coarse["dem"]["steps_per_frame"] < fine["dem"]["steps_per_frame"]
        assert coarse["dem"]["dt"] > fine["dem"]["dt"]
        assert fine["dem_us_per_particle_step"] > 0
        if report["lammps"] is None:  # LAMMPS present: timed from the same state
            assert fine["lammps_us_per_particle_step"] > 0
    assert "µs per particle-step" in (tmp_path / "c.md").read_text()


def test_dem_kernel_options_quick(run_script, tmp_path):
    """Every variant compiles and runs from the same state; the shipped one is the reference
    (no change), the kernels without fastmath differ (the flags are in use) and the option
    without division checks changes nothing beyond rounding."""
    run_script("benchmarks/surrogate/dem_kernel_options", "--out", str(tmp_path / "k"))
    report = json.loads((tmp_path / "k.json").read_text())
    change = {v["variant"]: v["state_change_max"] for v in report["variants"]}
    assert change["shipped (fastmath, NaN/Inf kept)"] == 0.0
    # without the division checks the compiler may order the fast-math arithmetic otherwise:
    # rounding level (1e-20 m measured), far below a physical change
    assert change["shipped + error_model numpy"] < 1e-9 * 2.5e-6
    assert change["no fastmath (generator version 1)"] > 0.0  # the kernels' flags are in use
    assert len(change) == 5 and all(np.isfinite(c) for c in change.values())
