"""Forward/backward time of the GRIP++ model: sparse graph operation vs a dense n x n one.

The sparse encoder multiplies node features by G_fixed + G_train on the edge list (cost
O(edges x channels x time)); the reference scripts multiply by dense n x n matrices
(O(n^2 x channels x time)). Both run side by side in one process on the same configuration.

    python experiments/benchmarks/model_cost/encoder_forms.py          # paper preset, n = 2000, CPU
    python experiments/benchmarks/model_cost/encoder_forms.py --particles 500 --history 20 \
        --hidden 64 --channels 32

Prints a table: encoder forward+backward (sparse vs dense, ratio), and one full training step
(encoder + 2 seq2seq GRU heads + loss + backward) with each graph operation. Memory is
estimated first; a case that cannot fit is skipped, not attempted.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
import torch
from torch import nn

from gripdem.boundary import Box
from gripdem.data.graph import build_graph
from gripdem.nn.graph_conv import EdgeGraph, GraphConvEncoder
from gripdem.nn.seq2seq import TrajectoryDecoder


class DenseGraphOperation(nn.Module):
    """The reference scripts' operation: ``(G_fixed + G_train) @ f`` with dense n x n matrices."""

    def __init__(self, fixed: torch.Tensor):
        super().__init__()
        self.register_buffer("fixed", fixed)
        self.train_matrix = nn.Parameter(torch.zeros_like(fixed))

    def forward(self, x: torch.Tensor, graph: EdgeGraph) -> torch.Tensor:
        return torch.einsum("ij,bjtc->bitc", self.fixed + self.train_matrix, x)


def random_configuration(n: int, diameter: float, phi: float, seed: int = 0):
    length = (n * math.pi * diameter**3 / 6 / phi) ** (1 / 3)
    box = Box(length, length, length)
    rng = np.random.default_rng(seed)
    return box, (rng.random((n, 3)) - 0.5) * box.lengths


def build(args, dense: bool, graph: EdgeGraph, fixed_dense: torch.Tensor | None):
    encoder = GraphConvEncoder(6, args.channels, trainable_graph="edge")
    if dense:
        for block in encoder.blocks:
            block.graph_op = DenseGraphOperation(fixed_dense)
    decoder = TrajectoryDecoder(args.channels, 6, 6, hidden=args.hidden, n_heads=args.heads)
    return encoder, decoder


def timed(fn, repeats: int) -> float:
    fn()  # warm-up (allocations, kernel selection)
    start = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - start) / repeats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, default=2000)
    parser.add_argument("--history", type=int, default=190)
    parser.add_argument("--horizon", type=int, default=10)
    parser.add_argument("--channels", type=int, default=64)
    parser.add_argument("--hidden", type=int, default=350)
    parser.add_argument("--heads", type=int, default=2)
    parser.add_argument("--cutoff", type=float, default=3.0, help="graph cut-off in diameters")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--encoder-only", action="store_true")
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--memory-limit-gb", type=float, default=16.0)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    n, k, f, c = args.particles, args.history, args.horizon, args.channels
    d = 2.5e-6
    box, pos = random_configuration(n, d, 0.5)
    g = build_graph(pos, box, 0.0, args.cutoff * d, length_unit=d)
    features = torch.cat(
        [torch.from_numpy(g.edge_vector), torch.from_numpy(g.edge_distance)[:, None]], 1
    )
    graph = EdgeGraph(
        torch.from_numpy(g.edge_index),
        torch.from_numpy(g.edge_weight),
        features / args.cutoff,
        n,
    )
    fixed_dense = torch.zeros(n, n)
    fixed_dense.index_put_(
        (graph.edge_index[0], graph.edge_index[1]), graph.fixed_weight, accumulate=True
    )
    x = torch.randn(1, n, k, 6)
    target = torch.randn(1, n, f, 6)
    # activations: ~ (blocks * 6 + 2) feature maps of n*k*c floats, plus GRU states
    act_gb = 4 * n * k * (c * 20 + args.hidden * args.heads * 2 * 4) / 1e9
    print(
        f"n={n} history={k} horizon={f} channels={c} hidden={args.hidden} heads={args.heads} "
        f"edges={graph.edge_index.shape[1]} ({graph.edge_index.shape[1] / n:.0f}/particle) "
        f"threads={torch.get_num_threads()} est. activations {act_gb:.1f} GB"
    )
    rows = []
    for label, dense in (("sparse (edge list)", False), ("dense n x n", True)):
        encoder, decoder = build(args, dense, graph, fixed_dense)

        def encoder_step(encoder=encoder):
            encoder.zero_grad()
            encoder(x, graph).square().mean().backward()

        row = {"op": label, "encoder": timed(encoder_step, args.repeats)}
        if not args.encoder_only and act_gb < args.memory_limit_gb:

            def full_step(encoder=encoder, decoder=decoder):
                encoder.zero_grad()
                decoder.zero_grad()
                feats = encoder(x, graph)
                out = decoder(feats, x[:, :, -1], None, f)
                ((out - target) ** 2).mean().backward()

            row["full"] = timed(full_step, args.repeats)
        rows.append(row)
        del encoder, decoder
    print("\n| graph operation | encoder fwd+bwd (s) | full step fwd+bwd (s) |")
    print("|---|---|---|")
    for row in rows:
        full = f"{row['full']:.3f}" if "full" in row else "skipped"
        print(f"| {row['op']} | {row['encoder']:.3f} | {full} |")
    ratio_enc = rows[1]["encoder"] / rows[0]["encoder"]
    line = f"dense / sparse: encoder {ratio_enc:.1f}x"
    if "full" in rows[0] and "full" in rows[1]:
        line += f", full step {rows[1]['full'] / rows[0]['full']:.2f}x"
    print(line)
    dense_bytes = n * n * 4 * 2 * 3  # fixed + trainable per block, float32
    print(
        f"dense graph matrices: {dense_bytes / 1e6:.0f} MB at n={n}; "
        f"at n=64000 they would need {64000**2 * 4 * 2 * 3 / 1e9:.0f} GB"
    )


if __name__ == "__main__":
    main()
