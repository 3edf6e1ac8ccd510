"""Sparse graph-convolution encoder of GRIP++ (docs/spec/model.md#graph-conv).

The graph operation multiplies node features by ``G_fixed + G_train`` with a sparse matrix,
so its cost is O(edges x channels x time) and no n x n tensor is ever built (except in the
``dense`` reproduction mode, which is the paper's learned n x n matrix).

Shapes: node features are ``(batch, particles, time, channels)``; a batch of graphs is one
block-diagonal graph over ``batch * particles`` nodes given as an edge list.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch
from torch import nn

TRAINABLE_GRAPH_MODES = ("edge", "dense", "none")


@dataclass
class EdgeGraph:
    """A batch of graphs as one block-diagonal sparse matrix over ``n_nodes`` nodes.

    edge_index: ``(2, E)`` long, rows ``(target i, source j)`` in flattened node numbering
    (sample b, particle p -> ``b * particles + p``), self pairs included.
    fixed_weight: ``(E,)`` normalised fixed-graph weights G_fixed[i, j]
    (docs/spec/model.md#fixed-graph).
    edge_features: ``(E, F)`` features for learned edge weights (e.g. displacement / cut-off
    and distance / cut-off).
    """

    edge_index: torch.Tensor
    fixed_weight: torch.Tensor
    edge_features: torch.Tensor
    n_nodes: int


def _spmm(edge_index: torch.Tensor, weight: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    matrix = torch.sparse_coo_tensor(
        edge_index, weight, (x.shape[0], x.shape[0]), check_invariants=False
    )
    return torch.sparse.mm(matrix, x)


def _edge_products(
    edge_index: torch.Tensor, grad_out: torch.Tensor, x: torch.Tensor
) -> torch.Tensor:
    """``<grad_out[target_e], x[source_e]>`` for every edge ``(E,)``: a sampled dense-dense
    product (SDDMM) on the graph's CSR pattern, never an ``E x features`` gather."""
    n = x.shape[0]
    target, source = edge_index
    order = torch.argsort(target * n + source)
    crow = torch._convert_indices_from_coo_to_csr(target[order], n)
    zeros = torch.zeros(order.shape[0], dtype=x.dtype, device=x.device)
    with warnings.catch_warnings():  # "sparse CSR support is in beta": tested here
        warnings.simplefilter("ignore", UserWarning)
        pattern = torch.sparse_csr_tensor(
            crow, source[order], zeros, (n, n), check_invariants=False
        )
    sampled = torch.sparse.sampled_addmm(pattern, grad_out, x.t().contiguous(), beta=0.0)
    products = torch.empty_like(sampled.values())
    products[order] = sampled.values()
    return products


class _SparseAggregate(torch.autograd.Function):
    """``W @ x`` with W given by an edge list. torch's own backward for the sparse values
    forms ``grad @ x^T`` densely (O(n^2 x features)); here it is an SDDMM, O(E x features)."""

    @staticmethod
    def forward(ctx, x, edge_index, weight):
        ctx.save_for_backward(x, edge_index, weight)
        return _spmm(edge_index, weight, x)

    @staticmethod
    def backward(ctx, grad_out):
        x, edge_index, weight = ctx.saved_tensors
        grad_x = grad_w = None
        if ctx.needs_input_grad[0]:
            grad_x = _spmm(edge_index.flip(0), weight, grad_out)
        if ctx.needs_input_grad[2]:
            grad_w = _edge_products(edge_index, grad_out.contiguous(), x)
        return grad_x, None, grad_w


def sparse_aggregate(
    x: torch.Tensor, edge_index: torch.Tensor, weight: torch.Tensor, n_nodes: int
) -> torch.Tensor:
    """``out[i] = sum_j W[i, j] x[j]`` for ``x`` of shape ``(n_nodes, features)``, W given by
    ``edge_index (2, E)`` (target, source) and ``weight (E,)``; duplicate edges add up.

    Differentiable in ``x`` and ``weight``; time and memory O(E x features + n x features).
    """
    if x.shape[0] != n_nodes:
        raise ValueError(f"x has {x.shape[0]} rows, the graph {n_nodes} nodes")
    return _SparseAggregate.apply(x, edge_index, weight)


class EdgeWeightNet(nn.Module):
    """Learned edge weight from edge features; the last layer starts at zero so that the
    trainable graph contributes nothing at initialisation (docs/spec/model.md#trainable-graph)."""

    def __init__(self, in_features: int, hidden: int = 16):
        super().__init__()
        # SiLU: 3x cheaper than tanh on CPU, and this MLP runs on ~1e5 edges per sample
        self.net = nn.Sequential(nn.Linear(in_features, hidden), nn.SiLU(), nn.Linear(hidden, 1))
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, edge_features: torch.Tensor) -> torch.Tensor:
        """``(E, F)`` -> ``(E,)`` weights."""
        return self.net(edge_features).squeeze(-1)


class GraphOperation(nn.Module):
    """``(G_fixed + G_train) @ f`` on node features ``(batch, particles, time, channels)``.

    mode ``edge``: G_train[i, j] = MLP(edge features of (i, j)) on the fixed graph's edges
    (transfers across particle counts). ``dense``: a learned ``(particles, particles)`` matrix
    (the paper; refuses another particle count). ``none``: G_fixed only.
    """

    def __init__(
        self,
        mode: str,
        edge_feature_dim: int,
        n_particles: int | None = None,
        dense_init: str = "zeros",
    ):
        super().__init__()
        if mode not in TRAINABLE_GRAPH_MODES:
            raise ValueError(
                f"trainable graph mode must be one of {TRAINABLE_GRAPH_MODES}, got {mode!r}"
            )
        self.mode = mode
        self.edge_net = EdgeWeightNet(edge_feature_dim) if mode == "edge" else None
        self.dense = None
        if mode == "dense":
            if not n_particles:
                raise ValueError(
                    "trainable graph mode 'dense' needs the particle count n_particles"
                )
            if dense_init not in ("zeros", "randn"):
                raise ValueError(f"dense_init must be 'zeros' or 'randn', got {dense_init!r}")
            init = torch.zeros if dense_init == "zeros" else torch.randn
            self.dense = nn.Parameter(init(n_particles, n_particles))

    def forward(self, x: torch.Tensor, graph: EdgeGraph) -> torch.Tensor:
        """x: ``(batch, particles, time, channels)`` -> same shape."""
        b, n, t, c = x.shape
        if graph.n_nodes != b * n:
            raise ValueError(f"graph has {graph.n_nodes} nodes, features have {b}x{n}")
        weight = graph.fixed_weight.to(x.dtype)
        if self.edge_net is not None:
            weight = weight + self.edge_net(graph.edge_features.to(x.dtype))
        flat = x.reshape(b * n, t * c)
        out = sparse_aggregate(flat, graph.edge_index, weight, b * n).reshape(b, n, t, c)
        if self.dense is not None:
            if self.dense.shape[0] != n:
                raise ValueError(
                    f"trainable graph mode 'dense' was built for {self.dense.shape[0]} particles "
                    f"and cannot run on {n}; use model.encoder.trainable_graph=edge"
                )
            out = out + torch.einsum("ij,bjtc->bitc", self.dense, x)
        return out


def _batch_norm(bn: nn.BatchNorm1d, x: torch.Tensor) -> torch.Tensor:
    """BatchNorm over the channel axis of ``(..., channels)``."""
    shape = x.shape
    return bn(x.reshape(-1, shape[-1])).reshape(shape)


class GraphConvBlock(nn.Module):
    """graph op -> BN -> ReLU -> temporal conv (kernel 3, length kept) -> BN -> dropout,
    + residual, ReLU. ``(batch, particles, time, channels)`` in and out."""

    def __init__(
        self, channels: int, graph_op: GraphOperation, kernel: int = 3, dropout: float = 0.0
    ):
        super().__init__()
        if kernel % 2 != 1:
            raise ValueError(f"temporal kernel must be odd to keep the length, got {kernel}")
        self.graph_op = graph_op
        self.bn_graph = nn.BatchNorm1d(channels)
        self.temporal = nn.Conv1d(channels, channels, kernel, padding=kernel // 2)
        self.bn_temporal = nn.BatchNorm1d(channels)
        self.dropout = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor, graph: EdgeGraph) -> torch.Tensor:
        b, n, t, c = x.shape
        y = torch.relu(_batch_norm(self.bn_graph, self.graph_op(x, graph)))
        y = self.temporal(y.reshape(b * n, t, c).transpose(1, 2)).transpose(1, 2)
        y = self.dropout(_batch_norm(self.bn_temporal, y.reshape(b, n, t, c)))
        return torch.relu(y + x)


class GraphConvEncoder(nn.Module):
    """1x1 conv (in_channels -> channels) with BN, then ``n_blocks`` graph-conv blocks."""

    def __init__(
        self,
        in_channels: int,
        channels: int = 64,
        n_blocks: int = 3,
        trainable_graph: str = "edge",
        edge_feature_dim: int = 4,
        n_particles: int | None = None,
        temporal_kernel: int = 3,
        dropout: float = 0.0,
        dense_init: str = "zeros",
    ):
        super().__init__()
        self.lift = nn.Linear(in_channels, channels)
        self.bn_lift = nn.BatchNorm1d(channels)
        self.blocks = nn.ModuleList(
            GraphConvBlock(
                channels,
                GraphOperation(trainable_graph, edge_feature_dim, n_particles, dense_init),
                temporal_kernel,
                dropout,
            )
            for _ in range(n_blocks)
        )

    @property
    def out_channels(self) -> int:
        return self.lift.out_features

    #: the seq2seq block reads the features over time (see gripdem.nn.seq2seq)
    context = "sequence"

    def forward(self, x: torch.Tensor, graph: EdgeGraph) -> torch.Tensor:
        """x: ``(batch, particles, time, in_channels)`` -> ``(..., channels)``."""
        y = _batch_norm(self.bn_lift, self.lift(x))
        for block in self.blocks:
            y = block(y, graph)
        return y
