"""Hand-back and DEM timing for ``surrogate_rollout.py`` (a sibling module of the script).

A state (the frame and the one before it) is handed to the built-in DEM as ``gripdem.handback``
would hand it to an engine: positions of the frame, velocities from the lattice-continuous step
over the last frame interval. The DEM runs ``steps`` steps; what is measured is the kinetic
energy at the end, of the velocities relative to the state's own mean-flow profile (the
fluctuations, which a state with compressed contacts inflates), and of the whole velocities.
The same restart from the true state of the same frame is the reference.
"""

from __future__ import annotations

import json
import time

import h5py
import numpy as np

from gripdem.dem.config import GeneratorConfig
from gripdem.dem.engine import Simulation
from gripdem.evaluation.rollout_stats import profile_basis
from gripdem.inference.relaxation import frame_velocities


def generator_config(data_path) -> GeneratorConfig:
    """The built-in DEM's configuration of a generated dataset (its provenance)."""
    with h5py.File(data_path, "r") as h5:
        params = json.loads(h5.attrs["provenance"])["parameters"]
    return GeneratorConfig.from_mappings(params["scene"], params["preset"], sims=1)


restart_velocities = frame_velocities  # the velocities a hand-back gives the DEM


def kinetic_energies(config: GeneratorConfig, positions, velocities) -> dict:
    """Total and fluctuating kinetic energy (J): ``0.5 m v^2`` summed, the fluctuation relative
    to the least-squares profile of the z velocities (cosine or linear in x, plus a constant)."""
    mass = config.mass
    basis = profile_basis(positions[:, 0], config.boundary)
    coeffs = np.linalg.lstsq(basis, velocities[:, 2], rcond=None)[0]
    relative = velocities.copy()
    relative[:, 2] -= basis @ coeffs
    return {
        "total": float(0.5 * mass * np.sum(velocities**2)),
        "fluctuation": float(0.5 * mass * np.sum(relative**2)),
    }


def restart(config: GeneratorConfig, pair: np.ndarray, times: np.ndarray, steps: int) -> dict:
    """Run the DEM ``steps`` steps from a state (see the module doc); its energies at the end,
    or the DEM's refusal (a compressed contact it cannot integrate) as an error."""
    velocities = restart_velocities(pair, times, config.boundary)
    try:
        sim = Simulation(config, pair[1], velocities, step=round(float(times[1]) / config.dt))
        sim.run(steps)
    except (FloatingPointError, RuntimeError, ValueError) as exc:
        return {"error": str(exc).splitlines()[0]}
    positions, velocities, _ = sim.snapshot()
    return {**kinetic_energies(config, positions, velocities), "max_overlap_d": sim.max_overlap}


def handback_ratios(config, predicted, truth, times, frames, steps: int) -> list[dict]:
    """Per frame of ``frames`` (1-based predicted frame numbers; index 0 of the arrays is the
    last observed frame): the DEM restarted from the predicted and from the true state."""
    rows = []
    for frame in frames:
        if frame >= len(truth):
            continue
        window = slice(frame - 1, frame + 1)
        model = restart(config, predicted[window], times[window], steps)
        true = restart(config, truth[window], times[window], steps)
        row = {"frame": frame, "model": model, "truth": true}
        if "error" not in model and "error" not in true:
            row["fluctuation_ratio"] = model["fluctuation"] / true["fluctuation"]
            row["total_ratio"] = model["total"] / true["total"]
        rows.append(row)
    return rows


def dem_seconds_per_frame(config, truth, times, frames: int = 3) -> float:
    """Wall seconds per frame of the built-in DEM restarted from the true state (one untimed
    step first: numba's cached kernels load on first use); fastest frame of ``frames``."""
    velocities = restart_velocities(truth[:2], times[:2], config.boundary)
    sim = Simulation(config, truth[1], velocities, step=round(float(times[1]) / config.dt))
    sim.run(1)
    best = np.inf
    for _ in range(frames):
        start = time.perf_counter()
        sim.run(config.steps_per_frame)
        best = min(best, time.perf_counter() - start)
    return float(best)
