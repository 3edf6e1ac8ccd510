"""The examples of the documentation's tutorials (examples/*.py) run as users run them, on the
tiny scene, and print what their tutorial says they print.

Each example runs as ``python examples/<name>.py ARGS`` would run it, as ``__main__`` with that
``sys.argv``, but in the test's own process: the process boundary is not what these tests
check (the CLIs' and the launcher's are tested in tests/runner), and a new process would import
torch and gripdem again (4 to 5 s of the suite per example, measured). The commands an example
starts itself (``python -m gripdem.run``) still run in their own processes."""

from __future__ import annotations

import contextlib
import io
import re
import runpy
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


@contextlib.contextmanager
def as_a_user(data_root: Path, cwd: Path, argv: list[str]):
    """The environment a user's shell gives the example: the dataset cache, one OpenMP
    thread for the commands it starts, its working folder and command line; what it prints
    is collected (the commands it starts print to the test's captured output)."""
    printed = io.StringIO()
    with pytest.MonkeyPatch.context() as patch, contextlib.redirect_stdout(printed):
        patch.setenv("GRIPDEM_DATA", str(data_root))
        patch.setenv("OMP_NUM_THREADS", "1")
        patch.chdir(cwd)
        patch.setattr(sys, "argv", argv)
        yield printed


def run_example(name: str, data_root: Path, *args: str) -> str:
    """What ``python examples/<name>.py ARGS`` prints, run from the repository root."""
    path = EXAMPLES / f"{name}.py"
    with as_a_user(data_root, ROOT, [str(path), *args]) as printed:
        runpy.run_path(str(path), run_name="__main__")
    return printed.getvalue()


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
    with as_a_user(gripdem_data_root, tmp_path, ["-c"]) as printed:
        exec(compile(code, "README.md", "exec"), {"__name__": "__main__"})
    assert "| coordination (< 1.01 d) |" in printed.getvalue()
