"""The examples of the documentation's tutorials (examples/*.py) run as users run them, on the
tiny scene, and print what their tutorial says they print."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


def run_example(name: str, data_root: Path, *args: str) -> str:
    proc = subprocess.run(
        [sys.executable, str(EXAMPLES / f"{name}.py"), *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
        env={**os.environ, "GRIPDEM_DATA": str(data_root), "OMP_NUM_THREADS": "1"},
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc.stdout


def test_every_example_is_tested_and_in_the_docs():
    tested = set(re.findall(r'run_example\(\s*"(\w+)"', Path(__file__).read_text()))
    assert {p.stem for p in EXAMPLES.glob("*.py")} == tested
    docs = "\n".join(p.read_text() for p in (ROOT / "docs").rglob("*.md"))
    for name in tested:
        assert f"examples/{name}.py" in docs, f"examples/{name}.py is in no docs page"


def test_python_api_example(gripdem_data_root):
    out = run_example("python_api", gripdem_data_root, "--frames", "20")
    rows = re.findall(r"^\s*(\d+)\s+([\d.e-]+)\s+([\d.e-]+)$", out, re.M)
    assert [r[0] for r in rows] == ["1", "10", "20"]
    assert all(float(model) < float(cv) for _, model, cv in rows)  # out of sample, beats CV
    assert re.search(r"^DEM  : coordination .*\n^model: coordination", out, re.M)


def test_coupling_example(gripdem_data_root):
    out = run_example("coupling", gripdem_data_root, "--frames", "20", "--every", "10")
    rows = re.findall(r"^\s*(\d+)\s+([\d.e-]+)\s+([\d.e-]+)$", out, re.M)
    assert [r[0] for r in rows] == ["10", "20"]
    free, coupled = float(rows[-1][1]), float(rows[-1][2])
    assert coupled < free  # handed the DEM's state at frame 10, it tracks the DEM closer
    assert "ms per frame (neighbour_list" in out and "state: (11, 400, 3)" in out


@pytest.mark.first
def test_own_data_finetune_example(tmp_path, gripdem_data_root):
    out = run_example(
        "own_data_finetune", gripdem_data_root, "--out", str(tmp_path), "--steps", "20"
    )
    assert re.search(r"test RMSE / d: before [\d.e-]+, after [\d.e-]+, constant velocity", out)
    assert "trained on mine.h5" in out and "rolled out 20 frames" in out


@pytest.mark.first
def test_first_run_example(tmp_path, gripdem_data_root, tiny_pbc_path):
    out = run_example("first_run", gripdem_data_root, "--out", str(tmp_path / "run"))
    assert "checkpoints/best.safetensors" in out and "metrics.json" in out
    assert re.search(r"events\.out\.tfevents", out)
    assert re.search(r"of constant velocity's \((beats|loses to) it\), in sample: False", out)


@pytest.mark.first
def test_sweep_tensorboard_example(tmp_path, gripdem_data_root, tiny_pbc_path):
    out = run_example("sweep_tensorboard", gripdem_data_root, "--out", str(tmp_path / "sweep"))
    assert re.search(r"run sweep/model=grip \(model grip\): test RMSE / CV's [\d.]+", out)
    assert re.search(r"run sweep/model=vct \(model vct\): test RMSE / CV's [\d.]+", out)


def test_the_readme_python_snippet_runs(tmp_path, gripdem_data_root):
    """The README's "From Python" block, run as it is printed."""
    readme = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", readme, re.S)
    assert len(blocks) == 1
    code = "\n".join(line[2:] if line.startswith("  ") else line for line in blocks[0].splitlines())
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=600,
        env={**os.environ, "GRIPDEM_DATA": str(gripdem_data_root), "OMP_NUM_THREADS": "1"},
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "| coordination (< 1.01 d) |" in proc.stdout
