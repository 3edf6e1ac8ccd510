"""How much of what constant velocity misses is predictable, and by what kind of model?

    python experiments/analyses/predictability.py [--scene pbc|lebc] [--horizon 10] [--quick]

On the default dataset of a scene (generated on first use), out of sample (fit on simulations
0-3, score on simulation 5, as protocol ``sims``), this fits linear least-squares models of

1. the one-step velocity change ``Δv = d_{t+1} - d_t`` (what CV misses at the first step), and
2. the CV residual of positions over the horizon (one linear model per step),

on three feature sets: *AR* (the last 10 flow-relative steps and sin/cos of x: the linear
autoregressive baseline's information), *pairs* (hand-made sums over neighbours within 1.6 d:
unit vectors weighted by gap bins, by the overlap, and by the pair's normal approach speed; the
relative motion of neighbours), and both. It prints R² of Δv, the RMSE over the horizon as a
ratio to CV's, and the statistics that explain why CV is hard to beat (the velocity
autocorrelation and how concentrated Δv is in a few large events), and an oracle: constant
velocity from the DEM's own instantaneous velocity at the last observed frame (stored by the
generator; no model reads it), which shows how little of CV's error is the velocity at the
last frame and how much is the change over the horizon. A learned interaction
model should beat the *pairs* line: the hand-made features are linear in the pair terms.
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import time

import h5py
import numpy as np
import torch

from gripdem.boundary import (
    affine_flow_strain,
    lattice_continuous_steps,
    neighbour_pairs,
    remove_affine_flow,
    step_start_x,
)
from gripdem.data.dataset_io import read_meta
from gripdem.dem.output import ensure_scene_dataset

GAP_BINS = (
    (-1.0, 0.0),
    (0.0, 0.005),
    (0.005, 0.02),
    (0.02, 0.05),
    (0.05, 0.1),
    (0.1, 0.3),
    (0.3, 0.6),
)
LAGS = 10


def scene_dataset(scene: str):
    from hydra import compose, initialize_config_dir

    from gripdem.run import CONFIG_DIR

    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose("simulate", overrides=[f"scene={scene}"])
    return ensure_scene_dataset(cfg.scene, cfg.preset, sims=cfg.sims, seed=cfg.seed)


class Simulation:
    """One simulation: wrapped positions, offsets, continuous and flow-relative steps."""

    def __init__(self, path, sim: int):
        meta = read_meta(path)
        self.meta, self.box, self.boundary = meta, meta.box, meta.boundary
        with h5py.File(path) as h5:
            self.positions = np.asarray(h5["positions"][sim], np.float64)  # (T, N, 3)
            times = np.asarray(h5["times"][sim], np.float64)
            stored = h5["velocities"][sim] if "velocities" in h5 else None
        self.offsets = self.boundary.offset(times)
        le = self.boundary.is_lees_edwards
        pos = self.positions.transpose(1, 0, 2)  # (N, T, 3)
        self.steps = lattice_continuous_steps(
            pos, self.box, self.offsets[None] if le else None, anchor=0
        )  # (N, T-1, 3), image cell of frame 0
        self.strain = affine_flow_strain(self.boundary, meta.frame_interval)
        x_start = step_start_x(self.steps, pos[:, 0, 0] + self.steps[..., 0].sum(-1))
        self.relative = remove_affine_flow(self.steps, x_start, self.strain)
        self.x_start = x_start
        self.velocity = None  # (N, T, 3) the DEM's own velocities, in diameters per frame
        if stored is not None:
            v = np.asarray(stored, np.float64).transpose(1, 0, 2) * meta.frame_interval
            # lattice-continuous like the steps: a particle m cells away moves with m times
            # the image velocity
            x_cont = pos[:, :1, 0] + np.concatenate(
                [np.zeros_like(pos[:, :1, 0]), np.cumsum(self.steps[..., 0], 1)], 1
            )
            cells = np.round((x_cont - pos[..., 0]) / self.box.lx)
            v[..., 2] += cells * self.boundary.image_velocity * meta.frame_interval
            self.velocity = v / meta.diameter

    def rows(self, t: int, horizon: int) -> dict[str, np.ndarray]:
        """Targets and features of every particle with last observed frame t."""
        d = self.meta.diameter
        v = self.relative / d
        dv = v[:, t] - v[:, t - 1]
        cont = np.concatenate([np.zeros_like(self.steps[:, :1]), np.cumsum(self.steps, 1)], 1) / d
        future = cont[:, t + 1 : t + 1 + horizon] - cont[:, t, None]
        cv_residual = future - np.arange(1, horizon + 1)[None, :, None] * (
            self.steps[:, t - 1, None] / d
        )
        i, j, vec = neighbour_pairs(
            self.positions[t], self.box, float(self.offsets[t]), 1.6 * d, both_directions=True
        )
        vec = vec / d
        r = np.linalg.norm(vec, axis=1)
        n = vec / r[:, None]
        gap = r - 1.0
        rel = v[j, t - 1] - v[i, t - 1]  # flow-relative: no image correction needed
        approach = np.einsum("ec,ec->e", rel, n)
        count = len(self.positions[t])

        def pair_sum(weights, vectors):
            return np.stack([np.bincount(i, weights * vectors[:, c], count) for c in range(3)], 1)

        pairs = []
        for lo, hi in GAP_BINS:
            inside = ((gap >= lo) & (gap < hi)).astype(float)
            pairs += [pair_sum(inside, n), pair_sum(inside * approach, n), pair_sum(inside, rel)]
        pairs.append(pair_sum(np.clip(-gap, 0, None) * 1e4, n))
        theta = 2 * math.pi * self.x_start[:, t] / self.box.lx
        steps_ahead = np.arange(1, horizon + 1)[None, :, None]
        oracle = None if self.velocity is None else future - steps_ahead * self.velocity[:, t, None]
        return {
            "dv": dv,
            "cv_residual": cv_residual,
            "oracle_residual": oracle,
            "lags": [v[:, t - k] for k in range(1, LAGS + 1)],
            "trig": np.stack([np.sin(theta), np.cos(theta)], 1),
            "pairs": pairs,
        }


def sample(path, sim: int, frames: int, horizon: int, rng) -> tuple[Simulation, list[dict]]:
    """``frames`` random last observed frames of one simulation, as rows."""
    s = Simulation(path, sim)
    chosen = rng.choice(np.arange(LAGS + 1, s.steps.shape[1] - horizon), frames, replace=False)
    return s, [s.rows(int(t), horizon) for t in chosen]


def design(rows: list[dict], use_ar: bool, use_pairs: bool) -> np.ndarray:
    """Per-component design matrix, components stacked as samples: ``(rows * N * 3, F)``."""
    blocks = []
    for row in rows:
        per_component = []
        for c in range(3):
            cols = [np.full(len(row["dv"]), float(c == k)) for k in range(3)]
            if use_ar:
                cols += [lag[:, c] for lag in row["lags"]]
                cols += [lag[:, 0] * (c == 2) for lag in row["lags"]]  # shear couples x into z
                cols += [row["trig"][:, 0] * (c == 2), row["trig"][:, 1] * (c == 2)]
            if use_pairs:
                cols += [p[:, c] for p in row["pairs"]]
            per_component.append(np.stack(cols, 1))
        blocks.append(np.concatenate(per_component))
    return np.concatenate(blocks)


def targets(rows: list[dict], key: str) -> np.ndarray:
    return np.concatenate([np.concatenate([r[key][..., c] for c in range(3)]) for r in rows])


def ridge(x: np.ndarray, y: np.ndarray, penalty: float = 1e-3) -> np.ndarray:
    mean, std = x.mean(0), x.std(0) + 1e-12
    mean[:3], std[:3] = 0.0, 1.0
    a = (x - mean) / std
    w = np.linalg.solve(a.T @ a + penalty * np.eye(a.shape[1]), a.T @ y)
    return lambda z: ((z - mean) / std) @ w


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", choices=("pbc", "lebc"), action="append")
    parser.add_argument("--horizon", type=int, default=10)
    parser.add_argument("--quick", action="store_true", help="fewer frames (slow test tier)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    print(f"machine: {platform.processor() or platform.machine()}, numpy {np.__version__}")
    for scene in args.scene or ["pbc", "lebc"]:
        started = time.perf_counter()
        path = scene_dataset(scene)
        per_sim = 3 if args.quick else 12
        rng = np.random.default_rng(0)

        train = [
            row for sim in range(4) for row in sample(path, sim, per_sim, args.horizon, rng)[1]
        ]
        test_sim, test = sample(path, 5, per_sim, args.horizon, rng)
        print(f"\n## {scene}: fit on 4 simulations x {per_sim} frames, scored on simulation 5")
        v = test_sim.relative / test_sim.meta.diameter
        dv = np.diff(v, axis=1)
        norm = np.sqrt((dv**2).sum(-1)).ravel()
        top = np.sort(norm**2)[-len(norm) // 100 :].sum() / (norm**2).sum()
        fluct = v - v.mean(0, keepdims=True)
        acf = [
            float((fluct[:, :-k] * fluct[:, k:]).sum(-1).mean() / (fluct**2).sum(-1).mean())
            for k in (1, 5, 10, 50)
        ]
        print(
            f"rms velocity change per frame: {np.sqrt((dv**2).mean()):.3g} d; the largest 1% of "
            f"changes carry {100 * top:.0f}% of their variance; velocity autocorrelation at lags "
            f"1, 5, 10, 50 frames: " + ", ".join(f"{a:.2f}" for a in acf)
        )
        print("| features | R² of Δv (one step) | RMSE / CV's over the horizon |")
        print("|---|---|---|")
        cv = targets(test, "cv_residual")
        cv_rmse = math.sqrt((cv**2).mean() * 3)
        for name, ar, pairs in (
            ("AR (lags, sin/cos x)", True, False),
            ("pairs", False, True),
            ("AR + pairs", True, True),
        ):
            xtr, xte = design(train, ar, pairs), design(test, ar, pairs)
            fit = ridge(xtr, targets(train, "dv"))
            y = targets(test, "dv")
            r2 = 1 - ((y - fit(xte)) ** 2).mean() / ((y - y.mean()) ** 2).mean()
            fit_h = ridge(xtr, targets(train, "cv_residual"))
            rmse = math.sqrt(((cv - fit_h(xte)) ** 2).mean() * 3)
            print(f"| {name} | {r2:.3f} | {rmse / cv_rmse:.3f} |")
        if test[0]["oracle_residual"] is not None:
            oracle = math.sqrt((targets(test, "oracle_residual") ** 2).mean() * 3) / cv_rmse
            print(
                "| oracle: CV from the DEM's instantaneous velocity at the last frame (stored by "
                f"the generator, no model's input) | – | {oracle:.3f} |"
            )
        print(f"CV RMSE over the horizon: {cv_rmse:.4g} d ({time.perf_counter() - started:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
