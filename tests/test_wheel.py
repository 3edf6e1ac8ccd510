"""gripdem installed as a wheel (not editable): the wheel holds its configs, launcher plugin and
shipped models, and its commands and API run from a folder outside the source tree."""

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
         "-w", str(out), str(ROOT)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    (path,) = out.glob("gripdem-*.whl")
    return path


def test_the_wheel_holds_every_config_and_shipped_model(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    needed = [f"gripdem/conf/{p.relative_to(ROOT / 'conf').as_posix()}"
              for p in (ROOT / "conf").rglob("*.yaml")]  # fmt: skip
    pretrained = ROOT / "gripdem" / "inference" / "pretrained"
    needed += [f"gripdem/inference/pretrained/{p.name}" for p in pretrained.iterdir()
               if p.suffix in (".safetensors", ".md")]  # fmt: skip
    needed.append("hydra_plugins/gripdem_launcher/parallel_launcher.py")
    for name in needed:
        assert name in names, f"{wheel.name} lacks {name}"


@pytest.mark.first  # about 45 s: started before the short tests
def test_the_installed_wheel_runs_from_another_folder(
    wheel, tmp_path, gripdem_data_root, tiny_pbc_path, tiny_lebc_path
):
    """``pip install`` of the wheel (into its own folder, first on the path), then from an
    empty folder: the main command as a multirun with gripdem's launcher, ``predict`` with a
    shipped model and the API's ``generate`` (its scenes), each reading the installed files."""
    target = tmp_path / "site"
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target),
         str(wheel)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {**os.environ, "PYTHONPATH": str(target), "GRIPDEM_DATA": str(gripdem_data_root)}
    env.pop("GRIPDEM_TRACEBACK", None)

    def run(*args: str) -> str:
        done = subprocess.run(
            [sys.executable, *args], cwd=elsewhere, env=env, capture_output=True, text=True,
            timeout=600,
        )  # fmt: skip
        assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-3000:]
        return done.stdout

    # where gripdem is imported from, and the API finds its scenes among the installed configs
    # (an unknown one is refused, naming them); not a simulation: the DEM kernels would compile
    # again for the installed copy's path (numba's cache is keyed by it), 7 s of the suite for
    # code that is the same
    code = (
        "import gripdem, gripdem.run as r\nprint(r.__file__, r.CONFIG_DIR)\n"
        "try:\n gripdem.generate('walls')\nexcept ValueError as e:\n print(e)"
    )
    where, refused = run("-c", code).splitlines()
    assert where.split()[0].startswith(str(target)) and str(ROOT) not in where
    assert "expected one of ['lebc', 'pbc']" in refused
    # the main command, in a multirun: each job is `python -m gripdem.run` of the wheel
    out = run("-m", "gripdem.run", "-m", "model=vct", "experiment=smoke", "hydra.sweep.dir=sw",
              "outputs.figures=false")  # fmt: skip
    job = elsewhere / "sw" / "scene=pbc,split=10-5,model=vct"  # one job: named by what it runs
    assert "launching 1 job(s)" in out and (job / "metrics.json").exists(), out[-2000:]
    run("-m", "gripdem.predict", "pretrained:lebc", str(tiny_lebc_path), "--out", "p.h5",
        "--sims", "0", "--frames", "5", "--no-overlap")  # fmt: skip
    assert (elsewhere / "p.h5").exists()
