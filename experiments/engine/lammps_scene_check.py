"""Checks and statistics of a converted LAMMPS scene (``lammps_scene.py``) beside the built-in
DEM's cached dataset of the same scene: what a model trained on one meets in the other.

Per dataset: frames, particles, x-face crossings, the largest frame-to-frame step (LE-aware,
the later frame's offset), the RMS step across the flow (x and y: the contact model's
velocity unit), the mean-flow profile (Lees-Edwards: slope over the shear rate; periodic: the
cosine amplitude over the drag-only amplitude ``A tau_p``), the mean coordination within
1.01 d, the fraction of particles overlapping a neighbour by more than 2 % of d, and the height
and place of the first peak of g(r).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from gripdem.boundary import lattice_continuous_steps, wrap_coordinate
from gripdem.data.dataset_io import read_dataset
from gripdem.dem.config import GeneratorConfig
from gripdem.dem.output import dataset_path
from gripdem.evaluation.physics import (
    coordination_number,
    fit_profile,
    overlap_fraction,
    radial_distribution,
)

#: frames used for the structural statistics (every 20th)
STRIDE = 20


def statistics(path: Path, relaxation_time: float, sim: int = 0) -> dict[str, float]:
    data = read_dataset(path)  # gripdem's load checks (shapes, NaN, box, times, phi)
    box, d = data.box, data.diameter
    pos = data.positions[sim]
    offsets = data.offsets()[sim]
    le = data.boundary.is_lees_edwards
    steps = lattice_continuous_steps(
        pos.transpose(1, 0, 2), box, offsets[None] if le else None, anchor=0
    )  # (particles, frames - 1, 3)
    moves = pos[1:] - pos[:-1]
    x_mid = wrap_coordinate(pos[:-1, :, 0] + 0.5 * steps.transpose(1, 0, 2)[..., 0], box.lx)
    vz = steps.transpose(1, 0, 2)[..., 2] / data.frame_interval
    kind = "linear" if le else "cosine"
    slope = fit_profile(x_mid.ravel(), vz.ravel(), box, kind)[0]
    scale = (
        data.boundary.lees_edwards.shear_rate if le else data.body_force_amplitude * relaxation_time
    )
    frames = slice(None, None, STRIDE)
    r, g = radial_distribution(pos[frames], box, 2.0 * d, 80, offsets[frames])
    peak = int(np.argmax(g))
    return {
        "sims": data.n_sims,
        "frames": data.n_frames,
        "particles": data.n_particles,
        "interval": data.frame_interval,
        "body_force": data.body_force_amplitude,
        "crossings": int((np.abs(moves[..., 0]) > 0.5 * box.lx).sum()),
        "max_step_d": float(np.sqrt((steps**2).sum(-1)).max() / d),
        "rms_xy_step_d": float(np.sqrt(np.mean(steps[..., :2] ** 2)) / d),
        "profile": slope / scale if scale else float("nan"),
        "coordination": coordination_number(pos[frames], box, 1.01 * d, offsets[frames]),
        "overlap": overlap_fraction(pos[frames], box, d, offsets[frames]),
        "g_peak": float(g[peak]),
        "r_peak_d": float(r[peak] / d),
    }


ROWS = (
    ("crossings", "x-face crossings (sim 0)", "{:d}"),
    ("max_step_d", "largest frame-to-frame step / d", "{:.4f}"),
    ("rms_xy_step_d", "RMS x, y step per frame / d", "{:.5f}"),
    ("profile", "mean-flow profile / imposed (slope / k; cos amplitude / A tau_p)", "{:.3f}"),
    ("coordination", "neighbours within 1.01 d", "{:.3f}"),
    ("overlap", "particles overlapping > 0.02 d", "{:.4f}"),
    ("g_peak", "g(r) first peak", "{:.2f}"),
    ("r_peak_d", "at r / d", "{:.3f}"),
)


def check_dataset(path: Path, config: GeneratorConfig, scene: str, preset: str) -> list[str]:
    """Lines: the converted dataset's checks and statistics beside the built-in DEM's."""
    tau = config.relaxation_time
    ours = statistics(path, tau)
    builtin = dataset_path(dataclasses.replace(config, sims=config.preset.sims, seed=0))
    theirs = statistics(builtin, tau) if builtin.exists() else None
    lines = [
        f"read back {path}: {ours['sims']} simulation, {ours['frames']} frames, "
        f"{ours['particles']} particles, frame interval {ours['interval']:.6g} s, "
        f"body_force_amplitude {ours['body_force']:.6g}",
        f"{'':66s} {'LAMMPS':>10s} {'built-in' if theirs else '':>10s}",
    ]
    for key, label, fmt in ROWS:
        other = fmt.format(theirs[key]) if theirs else ""
        lines.append(f"{label:66s} {fmt.format(ours[key]):>10s} {other:>10s}")
    if theirs:
        lines.append(f"built-in: {builtin} (simulation 0 of {theirs['sims']})")
    return lines
