"""The tests whose measured values move with the CPU's vector unit (training outcomes: how far
a few hundred optimiser steps get) run once more with ATen's plain ``default`` kernels, whatever
this machine has, so that a threshold tuned to one CPU cannot land again.

``experiments/analyses/threshold_spread.py`` measures every numeric check of the suite under
ATEN_CPU_CAPABILITY = default | avx2 | avx512 and 1 | 2 threads; of the checks it finds moving,
the binding case of each threshold is marked ``numerics`` (pyproject.toml: for the overfitting
test's shared fold, the mode closest to it, ``BINDING_MODE`` in tests/models/test_module.py),
and this test runs them under the combination that differs most from the common developer
machine (AVX-512): no vector unit at all.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def files_with_numerics_tests() -> list[str]:
    """The test files that mark a test ``numerics`` (the inner run collects only these: the
    whole suite's collection imports every test module, seconds for nothing)."""
    here = Path(__file__).resolve()
    return sorted(
        str(path.relative_to(ROOT))
        for path in (ROOT / "tests").rglob("test_*.py")
        if path != here and "mark.numerics" in path.read_text()
    )


@pytest.mark.first
def test_numeric_thresholds_hold_with_plain_kernels(tmp_path, gripdem_data_root):
    env = {
        **os.environ,
        "GRIPDEM_TEST_DATA": str(gripdem_data_root),  # the tiny scenes, generated once
        "ATEN_CPU_CAPABILITY": "default",
        "GRIPDEM_TEST_THREADS": "1",
        "OMP_NUM_THREADS": "1",
    }
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-m", "numerics"]
    files = files_with_numerics_tests()
    assert files, "no test is marked numerics"
    cmd += ["--basetemp", str(tmp_path / "inner"), *files]
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert " passed" in proc.stdout.splitlines()[-1]
