"""Before anything runs: every job's options are checked (one line, no folder written) and a
multirun says how many jobs it has and what they will cost (gripdem.runner.sweep_plan)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from gripdem.run import CONFIG_DIR
from gripdem.runner.sweep_plan import job_seconds


def gripdem_run(
    args: list[str], cwd: Path, data_root: Path, **extra_env: str
) -> subprocess.CompletedProcess:
    env = {**os.environ, "GRIPDEM_DATA": str(data_root), **extra_env}
    env.pop("GRIPDEM_TRACEBACK", None)
    return subprocess.run(
        [sys.executable, "-m", "gripdem.run", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def compose_run(overrides: list[str]):
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        return compose("config", overrides=overrides)


def test_a_decoder_a_mode_cannot_take_is_refused_before_the_run_folder(tmp_path):
    run_dir = tmp_path / "run"
    proc = gripdem_run(
        ["model=vct_paper", "model.decoder=direct", f"hydra.run.dir={run_dir}"],
        tmp_path,
        tmp_path / "data",
    )
    assert proc.returncode == 1, proc.stderr[-2000:]
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: model.decoder=direct"), lines
    assert "model.decoder=gru" in lines[0]  # the allowed value named
    assert not run_dir.exists()
    assert not (tmp_path / "data").exists()  # no dataset generated either


def test_a_bad_job_of_a_sweep_is_named_before_any_job_runs(tmp_path):
    sweep = tmp_path / "sweep"
    proc = gripdem_run(
        ["-m", "model=vct,vct_paper", "model.decoder=direct", f"hydra.sweep.dir={sweep}"],
        tmp_path,
        tmp_path / "data",
    )
    assert proc.returncode == 1, proc.stderr[-2000:]
    error = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(error) == 1 and "job model=vct_paper model.decoder=direct" in error[0], error
    assert not sweep.exists()


def test_a_removed_name_ends_the_command_before_anything_is_written(tmp_path):
    """``python -m gripdem.run`` with removed names: one line naming each one's replacement,
    status 1, no run folder, no dataset generated; Hydra's own message never shown."""
    from gripdem.runner.renamed_options import removed_line

    run_dir, data = tmp_path / "run", tmp_path / "data"
    names = [
        "experiment=fast",
        "model.fast_steps",
        "model/encoder=interaction",
        "model.encoder.name=interaction",
        "data.protocol=paper",
        "data.paper_windows",
    ]
    proc = gripdem_run(
        [
            *("experiment=fast", "+model.fast_steps=100", "model/encoder=interaction"),
            *("model.encoder.name=interaction", "data.protocol=paper", "data.paper_windows=3"),
            f"hydra.run.dir={run_dir}",
        ],
        tmp_path,
        data,
    )
    assert proc.returncode == 1, proc.stderr[-2000:]
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert lines == ["error: " + "; ".join(removed_line(name) for name in names)], lines
    assert not run_dir.exists() and not data.exists()
    # a sweep that chooses a removed config file among others: refused before any job
    sweep = tmp_path / "sweep"
    proc = gripdem_run(
        ["-m", "model=contact,interaction", f"hydra.sweep.dir={sweep}"], tmp_path, data
    )
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert proc.stderr.splitlines() == [f"error: {removed_line('model=interaction')}"]
    assert not sweep.exists() and not data.exists()


def test_decoder_modes_differ_only_in_the_mode():
    """model=grip,pct,vct is a fair sweep: same encoder, decoder, budget and data; the default
    model (contact) is grip under its own name."""
    from gripdem.runner.config_schema import plain

    models = {m: plain(compose_run([f"model={m}"]).model) for m in ("grip", "pct", "vct")}
    default = plain(compose_run([]).model)
    for m, cfg in models.items():
        assert cfg.pop("name") == m and cfg.pop("decoder_mode") == m
    assert models["grip"] == models["pct"] == models["vct"]
    assert default.pop("name") == "contact" and default.pop("decoder_mode") == "grip"
    assert default == models["grip"]
    assert models["grip"]["encoder"]["name"] == "contact"
    assert models["grip"]["decoder"] == "direct" and models["grip"]["horizon"] == 10
    budgets = {compose_run([f"model={m}"]).trainer.max_steps for m in ("grip", "pct", "vct")}
    assert budgets == {2400}
    # the paper's encoder is one option like any other, on the same decoder and budget
    paper_encoder = plain(compose_run(["model=vct", "model/encoder=graph_conv"]).model)
    assert paper_encoder["encoder"]["name"] == "graph_conv"
    assert paper_encoder["decoder"] == "direct"


@pytest.mark.parametrize(
    ("overrides", "low", "high"),
    [
        # measured on the 2-core machine (experiments/results/split_sweep/split_sweep.md)
        (["split=190-10", "model=vct"], 120, 300),
        (["split=100-100", "model=vct"], 150, 400),
        (["split=190-10", "model=vct_paper"], 600, 1500),
        (["experiment=smoke"], 1, 120),
    ],
)
def test_the_estimate_is_of_the_measured_order(overrides, low, high):
    assert low < job_seconds(compose_run(overrides)) < high


def test_a_sweep_says_its_jobs_and_their_cost_first(tmp_path):
    """A sweep that stops at its first job still printed its plan: 2 jobs, an estimate."""
    sweep = tmp_path / "sweep"
    proc = gripdem_run(
        [
            "-m",
            "split=190-10,100-100",
            "model=vct",
            "data.path=/nonexistent/data.h5",
            f"hydra.sweep.dir={sweep}",
        ],
        tmp_path,
        tmp_path / "data",
        PYTHONPROFILEIMPORTTIME="1",
    )
    plan = [line for line in proc.stdout.splitlines() if line.startswith("sweep:")]
    assert plan and plan[0].startswith("sweep: 2 jobs, about "), proc.stdout[-2000:]
    # the sweep's own process plans, launches and summarises without importing Lightning
    # (its jobs are processes of their own, their output in their console.log)
    imported = {
        line.rsplit("|", 1)[1].strip()
        for line in proc.stderr.splitlines()
        if line.startswith("import time:")
    }
    assert "gripdem.runner.parallel_launcher" in imported and "lightning" not in imported
    assert "on a 2-core CPU like the one it was measured on" in plan[0]
    assert "dataset" not in plan[0]  # data.path given: nothing to generate
    # every job failed on its data: each is named with its error, and the command says so
    assert proc.returncode == 1
    assert "2 job(s) of the sweep failed" in proc.stderr
    summary = (sweep / "summary.md").read_text()
    assert summary.count("failed: ") == 2 and "/nonexistent/data.h5" in summary
