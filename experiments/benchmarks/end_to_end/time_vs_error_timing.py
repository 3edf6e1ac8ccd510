"""Timings of ``time_vs_error.py`` (a sibling module of the script): the model, the baselines
and the reads over a run's test windows, the DEM restarted from a test state, and the DEM time
of the training data. Each returns wall seconds measured in this process."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import torch

from gripdem.data.batch import collate_windows
from gripdem.data.datamodule import TrajectoryDataModule
from gripdem.dem.config import GeneratorConfig
from gripdem.dem.engine import Simulation
from gripdem.evaluation.metrics import position_residuals, rmse
from gripdem.models.module import TrajectoryModule


@dataclass
class Run:
    """One trained run: its folder, composed config, metrics and a label."""

    path: Path
    cfg: object
    metrics: dict
    preset: str

    @property
    def scene(self) -> str:
        return str(self.cfg.scene.name)

    @property
    def split(self) -> str:
        return str(self.cfg.split.name)

    @property
    def label(self) -> str:
        return f"{self.metrics['hparams']['model']} ({self.preset}, seed {self.cfg.seed})"

    @property
    def checkpoint(self) -> Path:
        return self.path / "checkpoints" / "best.ckpt"

    @property
    def data_path(self) -> Path:
        return Path(self.metrics["data"]["path"])


def test_windows(run: Run, model: TrajectoryModule):
    """The run's test windows (rebuilt from its config, its own normaliser; graphs never
    cached, so every window pays for its graph)."""
    dm = TrajectoryDataModule.from_config(
        run.cfg.data, run.cfg.split, path=str(run.data_path), graph_cache_mb=0.0
    )
    dm.load_state_dict({"normalizer": model.normalizer.to_dict(), "encoding": dm.encoding_name})
    dm.setup("fit")
    return dm


@torch.no_grad()
def time_model(model: TrajectoryModule, dataset, n: int) -> tuple[float, float, list, list]:
    """(prep s, predict s, batches, predicted positions) over the first ``n`` windows."""
    warm = collate_windows([dataset[0]])
    model.decode(model(warm), warm)  # first call: lazy initialisation, not timed
    prep = predict = 0.0
    batches, preds = [], []
    for i in range(n):
        start = time.perf_counter()
        batch = collate_windows([dataset[i]])
        mid = time.perf_counter()
        positions = model.decode(model(batch), batch)
        predict += time.perf_counter() - mid
        prep += mid - start
        batches.append(batch)
        preds.append(positions)
    return prep, predict, batches, preds


def time_baseline(model: TrajectoryModule, name: str, batches: list) -> tuple[float, list]:
    """(s, predictions) of one baseline on the already read windows."""
    from gripdem.models.baselines import predict_baseline

    box, out = model.boundary.box, []
    start = time.perf_counter()
    for b in batches:
        observed = b.input_positions.double().transpose(1, 2)
        out.append(
            predict_baseline(
                name,
                observed,
                b.input_offsets.double(),
                b.target_offsets.double(),
                box,
                model.profile,
                model.linear_ar,
                model.boundary,
            )
        )
    return time.perf_counter() - start, out


def read_seconds(dataset, n: int) -> float:
    """HDF5 read of the first ``n`` windows' frames (what a baseline needs as input)."""
    start = time.perf_counter()
    for i in range(n):
        w = dataset.windows[i]
        dataset.reader.read(w.sim, w.start, w.stop)
    return time.perf_counter() - start


def rmse_over_d(preds: list, batches: list, model: TrajectoryModule) -> float:
    pred = torch.cat(preds)
    true = torch.cat([b.target_positions.double().transpose(1, 2) for b in batches])
    offsets = torch.cat([b.target_offsets.double() for b in batches])
    offsets = offsets if model.boundary.is_lees_edwards else None
    return rmse(position_residuals(pred, true, model.boundary.box, offsets)) / model.diameter


def dem_seconds_per_frame(data_path: Path, sim: int, frame: int, frames: int) -> dict:
    """The built-in DEM restarted from a stored frame of ``data_path``, timed over ``frames``
    frames (after one untimed step: numba's cached kernels load on first use)."""
    with h5py.File(data_path, "r") as h5:
        params = json.loads(h5.attrs["provenance"])["parameters"]
        positions = np.asarray(h5["positions"][sim, frame], np.float64)
        velocities = np.asarray(h5["velocities"][sim, frame], np.float64)
        t = float(h5["times"][sim, frame])
    config = GeneratorConfig.from_mappings(params["scene"], params["preset"], sims=1)
    sim_ = Simulation(config, positions, velocities, step=round(t / config.dt))
    sim_.run(1)
    start = time.perf_counter()
    for _ in range(frames):
        sim_.run(config.steps_per_frame)
    wall = time.perf_counter() - start
    return {
        "s_per_frame": wall / frames,
        "frames_timed": frames,
        "dt": config.dt,
        "steps_per_frame": config.steps_per_frame,
        "max_overlap_d": sim_.max_overlap,
    }


def data_seconds(run: Run, parts: tuple[str, ...]) -> float | None:
    """DEM wall time (dataset provenance) that generated the run's simulations of ``parts``
    (``sims_train``, ``sims_val``); None when not recorded or not split by simulation."""
    with h5py.File(run.data_path, "r") as h5:
        walls = json.loads(h5.attrs["provenance"]).get("wall_time_s")
    summary = run.metrics["data"]
    if not walls or any(part not in summary for part in parts):
        return None
    return float(sum(walls[s] for part in parts for s in summary[part]))
