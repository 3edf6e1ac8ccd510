"""Slow tier: the runner as users call it, in subprocesses (multirun, Optuna, DDP, resume)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow


def run_cli(args: list[str], data_root: Path, timeout: int = 900) -> subprocess.CompletedProcess:
    env = {**os.environ, "GRIPDEM_DATA": str(data_root), "HYDRA_FULL_ERROR": "1"}
    flags = [a for a in args if a.startswith("-")]  # Hydra's flags go before the overrides
    rest = [a for a in args if not a.startswith("-")]
    proc = subprocess.run(
        [sys.executable, "-m", "gripdem.run", *flags, "experiment=smoke", "torch_threads=1", *rest],
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc


def test_multirun_of_two_jobs_writes_a_summary(tmp_path, gripdem_data_root, tiny_pbc_path):
    sweep = tmp_path / "sweep"
    run_cli(["-m", "model=grip,pct", f"hydra.sweep.dir={sweep}"], gripdem_data_root)
    for model in ("grip", "pct"):  # each job's folder is named by the swept value
        metrics = json.loads((sweep / f"model={model}" / "metrics.json").read_text())
        assert metrics["hparams"]["model"] == model
        assert list((sweep / f"model={model}").glob("events.out.tfevents*"))
    summary = (sweep / "summary.md").read_text().splitlines()
    assert summary[0].startswith("| job | model |") and len(summary) == 4
    assert summary[2].startswith("| model=grip |")  # the sweep's order
    assert (sweep / "summary.csv").exists()


def test_optuna_study_of_two_tested_trials(tmp_path, gripdem_data_root, tiny_pbc_path):
    pytest.importorskip("optuna")
    sweep = tmp_path / "optuna"
    proc = run_cli(
        [
            "hparams_search=optuna",
            "hydra.sweeper.n_trials=2",
            "hydra.sweeper.test_trials=true",  # each trial tested too, as a single run
            "hydra/sweeper/pruner=none",
            "trainer.val_check_interval=2",
            f"hydra.sweep.dir={sweep}",
        ],
        gripdem_data_root,
    )
    assert "every trial ranked" in proc.stdout
    table = (sweep / "study.md").read_text()
    assert "2 complete, 0 pruned, 0 failed" in table
    for metrics_file in sweep.glob("trial=*/metrics.json"):
        metrics = json.loads(metrics_file.read_text())
        assert metrics["test/rmse"] > 0 and metrics["val/rmse_best"] > 0
    assert len(list(sweep.glob("trial=*/metrics.json"))) == 2


def test_ddp_on_two_cpu_processes(tmp_path, gripdem_data_root, tiny_pbc_path):
    out = tmp_path / "ddp"
    proc = run_cli(["trainer=ddp", f"hydra.run.dir={out}"], gripdem_data_root)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["test/rmse"] > 0
    assert "world_size=2" in proc.stdout + proc.stderr or (out / "train_ddp_process_1.log").exists()


def test_resume_from_the_last_checkpoint(tmp_path, gripdem_data_root, tiny_pbc_path):
    out = tmp_path / "resume"
    run_cli([f"hydra.run.dir={out}", "trainer.max_epochs=1"], gripdem_data_root)
    first = json.loads((out / "metrics.json").read_text())
    proc = run_cli(
        [f"hydra.run.dir={out}", "trainer.max_epochs=3", "resume=true"], gripdem_data_root
    )
    second = json.loads((out / "metrics.json").read_text())
    assert "Restoring states from the checkpoint path" in proc.stdout + proc.stderr
    assert second["epochs"] == 3 and second["steps"] == 3 * first["steps"]
