"""The console of ``python -m gripdem.run`` reads cleanly: each log line once, no third-party
advertising, no known dependency deprecation warnings, the result table and the output folder
at the end. A real subprocess (Hydra configures logging per process)."""

import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_smoke_run_console_is_clean(tmp_path, gripdem_data_root, tiny_pbc_path):
    env = {**os.environ, "GRIPDEM_DATA": str(gripdem_data_root), "PYTHONWARNINGS": "default"}
    out = tmp_path / "run"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "gripdem.run",
            "experiment=smoke",
            "torch_threads=1",
            "outputs.figures=false",
            "outputs.export_xyz=false",
            f"hydra.run.dir={out}",
        ],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    text = proc.stdout + proc.stderr
    assert proc.returncode == 0, text[-3000:]
    lines = [line.split("] - ", 1)[-1] for line in text.splitlines() if line.strip()]
    logged = Counter(line for line in lines if "Seed set" in line or "available" in line)
    assert logged and max(logged.values()) == 1, logged
    assert "Tip:" not in text and "litlogger" not in text
    assert "LeafSpec" not in text
    tail = text.strip().splitlines()[-9:]
    assert tail[0].startswith("== gripdem result: pbc / 10-5 / contact (seed 0) ==")
    assert tail[1].startswith("| test (out of sample) |")
    assert tail[-1] == f"outputs: {out}"
