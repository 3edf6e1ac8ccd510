"""Time one window's features and graph: gripdem's pipeline vs a straightforward O(n²) one.

    python experiments/benchmarks/model_cost/feature_cost.py \
        [--particles 2000] [--frames 200] [--repeats 5]

A sheared (Lees-Edwards) trajectory at the paper's scale (2000 particles of d = 2.5e-6 m in a
3.2e-5 m box, φ ≈ 0.5, frames every 5e-6 s at shear rate 1000 1/s, absolute times from 1.1 ms)
is written to a temporary gripdem HDF5 file. Timed, best of ``--repeats``:

- features: encode all ``frames`` of the window (sincos, vct, unwrapped);
- graph (gripdem): vesin on the LE triclinic lattice + G_fixed normalisation, O(n);
- graph (O(n²)): every pair's minimum image at once in numpy, dense A and G_fixed (the
  vectorised form of the reference scripts' double loop);
- the reference scripts' Python double loop itself on ``--loop-particles`` particles,
  extrapolated by (n / loop-particles)² to n;
- one whole DataModule sample (HDF5 read + vct encoding + normalisation + graph, uncached).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from gripdem.boundary import Boundary, Box, LeesEdwards, minimum_image, wrap_positions
from gripdem.data.datamodule import TrajectoryDataModule
from gripdem.data.dataset_io import write_dataset
from gripdem.data.encodings import ENCODINGS, make_encoding
from gripdem.data.graph import DEFAULT_ALPHA, build_graph
from gripdem.data.schema import TrajectoryData

DIAMETER = 2.5e-6


def trajectory(n: int, frames: int, seed: int = 0) -> TrajectoryData:
    """Affine shear plus a random walk of 0.02 d per frame, wrapped at each frame's offset."""
    side = (n * np.pi / 6 * DIAMETER**3 / 0.5) ** (1 / 3)
    boundary = Boundary(Box(side, side, side), LeesEdwards(1000.0))
    times = 1.1e-3 + 5e-6 * np.arange(frames)[None, :]
    offsets = boundary.offset(times)[0]
    rng = np.random.default_rng(seed)
    cont = (rng.random((n, 3)) - 0.5) * side
    pos = np.empty((1, frames, n, 3))
    for t in range(frames):
        if t:
            cont = cont + rng.normal(0, 0.02 * DIAMETER, cont.shape)
            cont[:, 2] += 1000.0 * cont[:, 0] * 5e-6
        pos[0, t] = wrap_positions(cont, boundary.box, offsets[t])
    return TrajectoryData(pos, times, boundary, DIAMETER / 2, provenance={"generator": "bench"})


def dense_graph(positions, box, offset, cutoff, alpha=DEFAULT_ALPHA) -> np.ndarray:
    """The straightforward O(n²) graph: all minimum images, dense A (with i = j), G_fixed."""
    vec = minimum_image(positions[None, :, :] - positions[:, None, :], box, offset)
    adjacency = (np.einsum("ijc,ijc->ij", vec, vec) < cutoff**2).astype(np.float64)
    lam = adjacency.sum(axis=1) + alpha
    inv = 1.0 / np.sqrt(lam)
    return np.eye(len(positions)) / (1 + alpha) + adjacency * inv[:, None] * inv[None, :]


def python_loop_graph(positions, box, offset, cutoff) -> np.ndarray:
    """The reference scripts' shape: a Python double loop over pairs, one minimum image each."""
    n = len(positions)
    adjacency = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            r = minimum_image(positions[i] - positions[j], box, offset)
            adjacency[i, j] = float(np.sqrt(np.sum(r**2)) < cutoff)
    return adjacency


def best(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, default=2000)
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--cutoff", type=float, default=3.0, help="in diameters")
    parser.add_argument("--loop-particles", type=int, default=150)
    args = parser.parse_args()

    data = trajectory(args.particles, args.frames)
    box, cutoff = data.box, args.cutoff * DIAMETER
    pos = data.positions[0].transpose(1, 0, 2)  # (N, T, 3)
    offs = data.offsets()[0]
    last, last_off = np.ascontiguousarray(pos[:, -1]), float(offs[-1])
    print(
        f"{args.particles} particles, {args.frames} frames, box {box.lx:.3g} m, cut-off "
        f"{args.cutoff:g} d, best of {args.repeats}"
    )

    feats = {}
    for name in ENCODINGS:
        enc = make_encoding(name, data.boundary)
        feats[name] = best(lambda enc=enc: enc.encode(pos, offs), args.repeats)
        print(f"  features {name:<10} {feats[name] * 1e3:8.1f} ms")

    graph = build_graph(last, box, last_off, cutoff, length_unit=DIAMETER)
    dense = dense_graph(last, box, last_off, cutoff)
    assert np.allclose(graph.dense(), dense, rtol=1e-6), "vesin graph differs from O(n²) graph"
    t_fast = best(
        lambda: build_graph(last, box, last_off, cutoff, length_unit=DIAMETER), args.repeats
    )
    t_dense = best(lambda: dense_graph(last, box, last_off, cutoff), args.repeats)
    print(
        f"  graph gripdem (vesin)     {t_fast * 1e3:8.1f} ms  "
        f"({graph.n_edges / args.particles - 1:.1f} neighbours per particle)"
    )
    print(f"  graph O(n²) numpy         {t_dense * 1e3:8.1f} ms  ratio {t_dense / t_fast:6.1f}x")
    m = min(args.loop_particles, args.particles)
    t_loop = best(lambda: python_loop_graph(last[:m], box, last_off, cutoff), 1)
    t_loop *= (args.particles / m) ** 2
    print(
        f"  graph O(n²) Python loop   {t_loop:8.1f} s   ratio {t_loop / t_fast:6.0f}x  "
        f"(timed on {m} particles, x(n/{m})²)"
    )

    ours = feats["vct"] + t_fast
    straight = feats["vct"] + t_dense
    print(
        f"  window (vct + graph): gripdem {ours * 1e3:.1f} ms vs O(n²) {straight * 1e3:.1f} ms, "
        f"ratio {straight / ours:.1f}x"
    )

    with tempfile.TemporaryDirectory() as tmp:
        path = write_dataset(Path(tmp) / "bench.h5", data)
        dm = TrajectoryDataModule(
            path,
            split=f"{args.frames - 11}-10",
            protocol="in_sample",
            encoding="vct",
            graph_cache_mb=0,
        )
        dm.setup("fit")
        ds = dm.datasets["train"]
        t_sample = best(lambda: ds[0], args.repeats)
        print(
            f"  one DataModule sample (read + vct + normalise + graph, uncached) "
            f"{t_sample * 1e3:.1f} ms"
        )
        ds.reader.close()


if __name__ == "__main__":
    main()
