"""The test command's census (``experiments/benchmarks/end_to_end/test_command.py --census``):
a real pytest run (one xdist worker) with the census plugin and ``sitecustomize`` on a two-test
file, one test of which starts a Python process; the census finds both tests and that one
process, and counts neither pytest nor its worker as started by a test."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

END_TO_END = Path(__file__).resolve().parents[1] / "experiments" / "benchmarks" / "end_to_end"
sys.path.insert(0, str(END_TO_END))
from test_command import CENSUS, read_census  # noqa: E402

INNER = """
import subprocess, sys

def test_starts_a_process():
    subprocess.run([sys.executable, "-c", "import json"], check=True)

def test_starts_none():
    pass
"""


def test_the_census_counts_the_tests_and_the_processes_they_start(tmp_path):
    folder = tmp_path / "census"
    folder.mkdir()
    (tmp_path / "test_inner.py").write_text(textwrap.dedent(INNER))
    env = {
        **{k: v for k, v in os.environ.items() if k != "PYTEST_XDIST_WORKER"},  # a run of its own
        "GRIPDEM_CENSUS_DIR": str(folder),
        "PYTHONPATH": os.pathsep.join(filter(None, [str(CENSUS), os.environ.get("PYTHONPATH")])),
    }
    proc = subprocess.Popen(
        [sys.executable, "-m", "pytest", "-q", "-p", "census_plugin", "-p", "no:cacheprovider",
         "-n", "1", "test_inner.py"],  # one xdist worker, as the test command runs them
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, out[-2000:] + err[-2000:]
    census = read_census(folder, proc.pid)
    assert census["tests"] == 2 and census["groups"]["test_inner.py"]["tests"] == 2
    by_name = {t["test"].split("::")[1]: t for t in census["costliest"]}
    assert set(by_name) == {"test_starts_a_process", "test_starts_none"}
    assert by_name["test_starts_none"]["children_cpu_s"] == 0.0
    assert census["processes_started"] == 1 and census["processes_killed"] == 0
    assert census["processes_torch"] == 0 and census["processes_lightning"] == 0
