"""Worker processes die with their parent (gripdem.dem.workers): a parent killed by SIGKILL
leaves no worker running, by the Linux parent-death signal and by the portable watchdog alone;
and a DEM generation killed by SIGKILL leaves no process and no file behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gripdem.dem.workers import ORPHAN_STATUS

ROOT = Path(__file__).resolve().parents[2]

#: a parent that starts a spawn pool of 2 workers (initializer: ``init``) that sleep for a
#: minute, and waits
PARENT = """
import os, sys, time
sys.path.insert(0, {folder!r})
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pool_helpers import init, nap
if __name__ == "__main__":
    ctx = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(2, mp_context=ctx, initializer=init, initargs=(os.getpid(),))
    futures = [pool.submit(nap) for _ in range(2)]
    time.sleep(120)
"""

#: each worker writes ``started-<pid>`` once it is set up (``NO_PDEATHSIG``: the watchdog
#: alone, as on macOS)
HELPERS = """
import os, time
from pathlib import Path
import gripdem.dem.workers as workers

def init(parent_pid):
    if os.environ.get("NO_PDEATHSIG"):
        workers._parent_death_signal = lambda sig: False
    workers.die_with_parent(parent_pid)
    Path(__file__).with_name(f"started-{os.getpid()}").touch()

def nap():
    time.sleep(60)
"""


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[-1].split()[0] not in ("Z", "X")


def _wait_gone(pids: list[int], seconds: float) -> list[int]:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.05)
    return [p for p in pids if _alive(p)]


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc")
@pytest.mark.parametrize("pdeathsig", [True, False], ids=["prctl", "watchdog"])
def test_workers_die_with_a_killed_parent(tmp_path, pdeathsig):
    (tmp_path / "pool_helpers.py").write_text(HELPERS)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    if not pdeathsig:
        env["NO_PDEATHSIG"] = "1"
    proc = subprocess.Popen(
        [sys.executable, "-c", PARENT.format(folder=str(tmp_path))],
        env=env,
        start_new_session=True,
    )
    deadline = time.monotonic() + 60
    while len(list(tmp_path.glob("started-*"))) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    workers = [int(p.name.split("-")[1]) for p in tmp_path.glob("started-*")]
    try:
        assert len(workers) == 2 and all(_alive(p) for p in workers)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        # the kernel's signal is immediate; the watchdog polls every 0.5 s
        assert _wait_gone(workers, 3.0) == []
    finally:
        for pid in [proc.pid, *workers]:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
        proc.wait(timeout=10)


def test_a_worker_whose_parent_is_already_gone_exits():
    # this process is the child's parent: any other pid stands for a parent already gone
    code = f"import gripdem.dem.workers as w; w.die_with_parent({os.getpid()} + 1); print('on')"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == ORPHAN_STATUS and "on" not in out.stdout


def test_a_worker_with_its_parent_runs_on():
    code = "import os, gripdem.dem.workers as w; w.die_with_parent(os.getppid()); print('on')"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout == "on\n"


@pytest.mark.slow
def test_sigkilled_generation_leaves_no_process_and_no_file(tmp_path):
    """The defect of issue 24: SIGKILL during a parallel generation into the cache left both
    workers, the Manager process and the resource tracker running."""
    trial = f"{os.getpid()}-{time.time_ns()}"
    env = {**os.environ, "GRIPDEM_DATA": str(tmp_path / "data"), "GRIPDEM_TEST_TRIAL": trial}
    argv = ["scene=pbc", "preset=tiny", "sims=2", "workers=2", "preset.frames=3000"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "gripdem.simulate", *argv, "progress=false"]
        + [f"hydra.run.dir={tmp_path / 'h'}"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    time.sleep(15)  # imports done, workers simulating
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=10)
    time.sleep(3)
    left = []
    for entry in filter(str.isdigit, os.listdir("/proc")):
        try:
            environ = Path(f"/proc/{entry}/environ").read_bytes().split(b"\0")
        except OSError:
            continue
        if f"GRIPDEM_TEST_TRIAL={trial}".encode() in environ and _alive(int(entry)):
            left.append(int(entry))
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    assert left == []
    assert [p.name for p in (tmp_path / "data").iterdir() if not p.name.endswith(".lock")] == []
