"""Every command answers a user error with one line ``error: ...`` and a non-zero status,
Ctrl-C with one line ``interrupted: ...``; tracebacks only for bugs, or on request
(GRIPDEM_TRACEBACK=1). Real commands: the Hydra ones in a subprocess (Hydra configures a
process), the argparse ones in this one."""

from __future__ import annotations

import contextlib
import importlib
import io
import os
import signal
import subprocess
import sys
import time
import weakref
from pathlib import Path

import h5py
import numpy as np
import pytest

from gripdem.data.dataset_io import write_dataset
from gripdem.data.schema import DatasetError
from gripdem.runner.console import (
    INTERRUPTED_STATUS,
    TERMINATED_STATUS,
    one_line,
    run_command,
)

ROOT = Path(__file__).resolve().parents[2]


def _stderr_of(call) -> tuple[object, str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        result = call()
    return result, err.getvalue()


# --------------------------------------------------------------------------------------------
# run_command
# --------------------------------------------------------------------------------------------
def test_user_errors_are_one_line_and_bugs_raise(monkeypatch):
    monkeypatch.delenv("GRIPDEM_TRACEBACK", raising=False)

    def bad_input():
        raise DatasetError("data.h5", "times", "expected 2 frames,\n  got 1")

    status, err = _stderr_of(lambda: run_command("gripdem.x", bad_input))
    assert status == 1 and err == "error: data.h5: field 'times': expected 2 frames, got 1\n"
    with pytest.raises(ZeroDivisionError):  # a bug keeps its traceback
        run_command("gripdem.x", lambda: 1 / 0)
    monkeypatch.setenv("GRIPDEM_TRACEBACK", "1")
    status, err = _stderr_of(lambda: run_command("gripdem.x", bad_input))
    assert status == 1 and err.startswith("Traceback") and err.endswith("got 1\n")


def test_library_errors_get_a_hint_and_ctrl_c_one_line(monkeypatch):
    monkeypatch.delenv("GRIPDEM_TRACEBACK", raising=False)
    status, err = _stderr_of(lambda: run_command("gripdem.x", lambda: int("x")))
    assert status == 1 and "(ValueError; GRIPDEM_TRACEBACK=1 shows where)" in err

    def interrupted():
        raise KeyboardInterrupt

    status, err = _stderr_of(lambda: run_command("gripdem.x", interrupted, "nothing written"))
    assert status == INTERRUPTED_STATUS
    assert err == "interrupted: gripdem.x stopped by Ctrl-C; nothing written\n"


def test_a_signal_python_cannot_raise_where_it_lands_still_stops_the_command(monkeypatch):
    """A weakref callback (importlib's module locks have them) swallows the handler's
    exception ("Exception ignored in ..."): it is delivered again, the command stops there."""
    monkeypatch.delenv("GRIPDEM_TRACEBACK", raising=False)
    done = []

    def body():
        class Thing:
            pass

        thing = Thing()
        ref = weakref.ref(thing, lambda r: (os.kill(os.getpid(), signal.SIGTERM), time.sleep(1)))
        del thing  # the callback runs, the signal lands inside it
        for _ in range(100):
            time.sleep(0.01)
        done.append(ref)

    status, err = _stderr_of(lambda: run_command("gripdem.x", body, "nothing written"))
    assert status == TERMINATED_STATUS and done == []
    assert err == "interrupted: gripdem.x stopped by SIGTERM; nothing written\n"


def test_sigterm_is_answered_as_ctrl_c(monkeypatch):
    """SIGTERM raises where the command is (a KeyboardInterrupt: every Ctrl-C cleanup runs),
    ends in the same one line and status 143; the handlers are given back afterwards."""
    monkeypatch.delenv("GRIPDEM_TRACEBACK", raising=False)
    cleaned = []

    def terminated():
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)
        except KeyboardInterrupt:
            cleaned.append(True)
            raise

    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    status, err = _stderr_of(lambda: run_command("gripdem.x", terminated, "nothing written"))
    assert status == TERMINATED_STATUS and cleaned == [True]
    assert err == "interrupted: gripdem.x stopped by SIGTERM; nothing written\n"
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before


def test_one_line_keeps_a_key_error_readable():
    assert one_line(KeyError("optimized_metric 'x' is unknown")) == (
        "optimized_metric 'x' is unknown"
    )


# --------------------------------------------------------------------------------------------
# the argparse commands, in this process
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("command", "args", "status", "expected"),
    [
        ("convert", ["fordatis", "{tmp}/nope.tar.gz", "{tmp}/o.h5"], 1, "nope.tar.gz: no such"),
        ("convert", ["lammps", "{junk}", "{tmp}/o.h5", "--diameter", "1", "--timestep", "1"], 1,
         "expected 'ITEM: TIMESTEP'"),
        ("predict", ["{junk}", "{nan}", "--out", "{tmp}/p.h5"], 1, "simulation 2, frame 50"),
        ("predict", ["{junk}", "{tmp}/nope.h5", "--out", "{tmp}/p.h5"], 1, "no such dataset"),
        ("handback", ["{nan}", "--xyz", "{tmp}/s.xyz"], 1, "particle 7, axis x"),
        ("claims", ["{tmp}/none"], 2, "no such sweep folder"),
        ("physics_report", ["{nan}"], 1, "field 'format': expected 'gripdem-predictions'"),
        ("summary", ["{tmp}/none"], 2, "no such sweep folder"),
    ],
)  # fmt: skip
def test_each_command_answers_bad_input_in_one_line(
    tmp_path, trajectories, command, args, status, expected
):
    nan = write_dataset(tmp_path / "nan.h5", trajectories(n_sims=3, n_frames=60, n_particles=10))
    with h5py.File(nan, "r+") as h5:
        h5["positions"][2, 50, 7, 0] = np.nan
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"\xff\xfe not a file gripdem reads \x00")
    argv = [a.format(tmp=tmp_path, nan=nan, junk=junk) for a in args]
    main = importlib.import_module(f"gripdem.{command}").main
    got, err = _stderr_of(lambda: main(argv))
    assert got == status
    assert err.count("\n") == 1 and err.startswith("error: ") and expected in err, err
    assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["junk.bin", "nan.h5"]  # nothing new


# --------------------------------------------------------------------------------------------
# the Hydra commands, each in its own process
# --------------------------------------------------------------------------------------------
def _run(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", *args],
        cwd=ROOT,
        env={**os.environ, **(env or {})},
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.fixture(scope="module")
def frames201(tmp_path_factory, trajectories) -> Path:
    data = trajectories(n_sims=3, n_frames=201, n_particles=10, lees_edwards=False)
    return write_dataset(tmp_path_factory.mktemp("cli") / "d201.h5", data)


def test_run_refuses_a_split_longer_than_the_data_in_one_line(tmp_path, frames201):
    """Before Lightning is imported: the window plan is made from the file's shape first."""
    proc = _run(
        "gripdem.run",
        f"data.path={frames201}",
        "split=custom",
        "split.history=300",
        "split.horizon=10",
        "torch_threads=1",
        f"hydra.run.dir={tmp_path / 'run'}",
        env={"PYTHONPROFILEIMPORTTIME": "1"},
    )
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert "lightning" not in _imported(proc.stderr)
    stderr = "".join(line for line in proc.stderr.splitlines(True) if "import time:" not in line)
    assert stderr.count("error:") == 1 and stderr.endswith("\n")
    last = stderr.strip().splitlines()[-1]
    assert last.startswith("error: split 300-10 needs 311 frames") and "has 201." in last
    assert "Traceback" not in stderr and "HYDRA_FULL_ERROR" not in stderr
    assert "Error executing job" not in stderr


def _imported(importtime_stderr: str) -> set[str]:
    """Module names a ``PYTHONPROFILEIMPORTTIME=1`` process imported (from its stderr)."""
    return {
        line.rsplit("|", 1)[1].strip()
        for line in importtime_stderr.splitlines()
        if line.startswith("import time:") and "|" in line
    }


def test_a_missing_data_file_is_refused_before_lightning_is_imported(tmp_path):
    """The seconds of Lightning's import are not paid to say that data.path is wrong."""
    proc = _run(
        "gripdem.run",
        "data.path=/nonexistent/data.h5",
        f"hydra.run.dir={tmp_path / 'run'}",
        env={"PYTHONPROFILEIMPORTTIME": "1"},
    )
    assert proc.returncode == 1
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert errors == ["error: data.path=/nonexistent/data.h5: no such file"]
    imported = _imported(proc.stderr)
    assert "gripdem.runner.console" in imported and "lightning" not in imported


def test_run_refuses_a_config_typo_in_one_line():
    proc = _run("gripdem.run", "data.protocl=sims")
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()]
    assert proc.stderr.startswith("error: Could not override 'data.protocl'")


@pytest.mark.slow
def test_ctrl_c_during_generation_is_one_line_and_leaves_nothing(tmp_path):
    """SIGINT to the whole process group (a terminal's Ctrl-C) during a parallel generation."""
    out = tmp_path / "scene.h5"
    proc = subprocess.Popen(
        [sys.executable, "-m", "gripdem.simulate", "scene=pbc", "preset=tiny", f"out={out}"]
        + ["workers=2", "preset.frames=600", "progress=false", f"hydra.run.dir={tmp_path / 'h'}"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    time.sleep(12)  # imports done, workers simulating (for about 30 s more)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == INTERRUPTED_STATUS, err
    assert err.strip().splitlines()[-1].startswith("interrupted: gripdem.simulate stopped by")
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    assert not out.exists() and not list(tmp_path.glob(".scene.h5*"))
    time.sleep(1)
    group = subprocess.run(["ps", "-o", "pid=,stat=", "-g", str(proc.pid)], capture_output=True)
    alive = [line for line in group.stdout.decode().splitlines() if "Z" not in line.split()[1]]
    assert alive == [], alive  # (exited workers not yet reaped by init show as zombies)
