"""Dataset cache (hash key, location, lock) and ``python -m gripdem.simulate``."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import gripdem.dem.output as output
import gripdem.dem.scenes as scenes
from gripdem.data import cache
from gripdem.data.dataset_io import read_dataset
from gripdem.dem.validation import report_paths
from gripdem.simulate import run

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def tiny_nodes(make_config):
    """Plain scene/preset dicts of the tiny LE scene."""
    cfg = make_config("lebc")
    d = cfg.to_dict()
    return d["scene"], d["preset"]


def test_data_root_order(monkeypatch, tmp_path):
    monkeypatch.setenv("GRIPDEM_DATA", str(tmp_path / "env"))
    assert cache.data_root() == tmp_path / "env"
    assert cache.data_root(tmp_path / "arg") == tmp_path / "arg"
    monkeypatch.delenv("GRIPDEM_DATA")
    assert "gripdem" in str(cache.data_root())  # the user cache directory


def test_key_changes_with_everything_that_changes_the_data(make_config, monkeypatch):
    base = output.config_key(make_config("lebc"))
    assert output.config_key(make_config("lebc")) == base
    others = [
        make_config("lebc", friction=0.2),
        make_config("lebc", frames=42),
        make_config("pbc"),
        make_config("lebc", sims=2),
    ]
    assert len({output.config_key(c) for c in others} | {base}) == 5
    monkeypatch.setattr(output, "GENERATOR_VERSION", "999")
    assert output.config_key(make_config("lebc")) != base


def _fake_generator(calls):
    def fake(config, path, **kwargs):
        calls.append(path)
        time.sleep(0.3)  # long enough for a second job to arrive and wait on the lock
        Path(path).write_bytes(b"data")
        return Path(path), {}

    return fake


def test_generates_once_and_parallel_jobs_wait(tiny_nodes, tmp_path, monkeypatch):
    calls: list = []
    monkeypatch.setattr(output, "generate_dataset", _fake_generator(calls))
    scene, preset = tiny_nodes
    results = []

    def job():
        results.append(output.ensure_scene_dataset(scene, preset, root=tmp_path, progress=False))

    threads = [threading.Thread(target=job) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(calls) == 1 and len(set(results)) == 1
    assert results[0].name.startswith("lebc-tiny-") and results[0].read_bytes() == b"data"
    output.ensure_scene_dataset(scene, preset, root=tmp_path, progress=False)
    assert len(calls) == 1  # cached
    output.ensure_scene_dataset(scene, preset, root=tmp_path, seed=1, progress=False)
    assert len(calls) == 2  # another seed is another dataset


def test_a_dataset_of_other_settings_is_not_reused_and_the_run_says_why(
    tiny_pbc_path, tmp_path, monkeypatch, make_config, capsys, caplog
):
    """A cached file of the same scene and preset made with another spin-up (or another
    generator version) is never picked up: its key differs, and the generation says in one
    line which file it does not reuse and what differs."""
    import shutil

    made = make_config("pbc", sims=3)  # the fixture's settings
    shutil.copy(tiny_pbc_path, tmp_path / tiny_pbc_path.name)
    assert output.dataset_path(made, tmp_path).exists()
    assert output.not_reused_note(made, output.dataset_path(made, tmp_path)) is None  # itself
    longer = make_config("pbc", sims=3, spinup_time=2 * made.preset.spinup_time)
    note = output.not_reused_note(longer, output.dataset_path(longer, tmp_path))
    assert note is not None and "\n" not in note
    assert tiny_pbc_path.name in note and "preset.spinup_time" in note and "anew" in note
    assert f"{made.preset.spinup_time:g} -> {longer.preset.spinup_time:g}" in note

    version = output.GENERATOR_VERSION  # the one that wrote the cached file
    monkeypatch.setattr(output, "GENERATOR_VERSION", "999")
    note = output.not_reused_note(made, output.dataset_path(made, tmp_path))
    assert note is not None and f"generator version {version} -> 999" in note
    assert "preset.spinup_time" not in note  # only what differs

    calls: list = []
    monkeypatch.setattr(output, "generate_dataset", _fake_generator(calls))
    caplog.set_level("INFO", logger=cache.__name__)
    d = made.to_dict()
    path = output.ensure_scene_dataset(
        d["scene"], d["preset"], sims=3, root=tmp_path, progress=False
    )
    assert calls == [path] and path.name != tiny_pbc_path.name  # generated anew, not reused
    said = capsys.readouterr().out.splitlines() + "\n".join(caplog.messages).splitlines()
    assert sum("not reusing" in line for line in said) == 1  # one line, before the generation
    assert said[0].startswith(f"gripdem: not reusing the cached {tiny_pbc_path.name}")
    assert said[1].startswith("gripdem: generating dataset")


def test_fixture_datasets_live_in_the_cache(tiny_pbc_path, tiny_lebc_path):
    assert tiny_pbc_path.name.startswith("pbc-tiny-") and tiny_pbc_path.suffix == ".h5"
    assert tiny_lebc_path.parent == tiny_pbc_path.parent


def test_run_writes_validated_file_and_refuses_to_overwrite(tmp_path, compose_simulate_config):
    out = tmp_path / "pbc.h5"
    cfg = compose_simulate_config(
        ["scene=pbc", "preset=tiny", "sims=1", f"out={out}", "progress=false"]
    )
    assert run(cfg) == out
    data = read_dataset(out)
    assert data.n_sims == 1 and data.boundary.kind == "periodic"
    assert data.body_force_amplitude > 0
    np.testing.assert_allclose(np.diff(data.times[0]), 5e-6, rtol=1e-9)
    with pytest.raises(FileExistsError, match="overwrite"):
        run(cfg)
    cfg.overwrite = True
    assert run(cfg) == out


def test_interrupt_leaves_nothing_behind(tmp_path, monkeypatch, make_config):
    real = scenes.simulate_one
    count = {"n": 0}

    def interrupted(*args, **kwargs):
        count["n"] += 1
        if count["n"] == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(scenes, "simulate_one", interrupted)
    cfg = make_config("pbc", sims=2)
    with pytest.raises(KeyboardInterrupt):
        output.generate_dataset(cfg, tmp_path / "x.h5", progress=False, workers=1)
    assert list(tmp_path.iterdir()) == []


def test_cli_writes_dataset_and_report(tmp_path):
    """The CLI writes the dataset and its validation report; the numba generator (the default
    backend) runs without importing torch (about 1.2 s of each DEM process)."""
    out = tmp_path / "lebc.h5"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "gripdem.simulate",
            "scene=lebc",
            "preset=tiny",
            "sims=1",
            f"out={out}",
            f"hydra.run.dir={tmp_path / 'hydra'}",
            "progress=false",
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPROFILEIMPORTTIME": "1"},
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "validation PASSED" in proc.stdout
    imported = {line.rsplit("|", 1)[-1].strip() for line in proc.stderr.splitlines() if "|" in line}
    assert "gripdem.dem.forces_numba" in imported and "torch" not in imported
    data = read_dataset(out)
    assert data.positions.shape == (1, 61, 400, 3) and data.boundary.is_lees_edwards
    assert all(p.exists() for p in report_paths(out))
