"""Sparse graph-conv encoder and seq2seq decoder: exactness, equivariance, initial state."""

import pytest
import torch

from gripdem.nn.graph_conv import EdgeGraph, GraphConvEncoder, GraphOperation, sparse_aggregate
from gripdem.nn.seq2seq import TrajectoryDecoder


def random_graph(batch, particles, edges_per_sample, seed=0):
    gen = torch.Generator().manual_seed(seed)
    index = []
    for b in range(batch):
        pairs = torch.randint(0, particles, (2, edges_per_sample), generator=gen) + b * particles
        self_pairs = torch.arange(particles).repeat(2, 1) + b * particles
        index.append(torch.cat([pairs, self_pairs], 1))
    edge_index = torch.cat(index, 1)
    e = edge_index.shape[1]
    return EdgeGraph(
        edge_index,
        torch.rand(e, generator=gen),
        torch.randn(e, 4, generator=gen),
        batch * particles,
    )


def test_sparse_aggregate_equals_dense_product_with_duplicates():
    graph = random_graph(1, 30, 200)
    x = torch.randn(30, 7, dtype=torch.float64)
    w = graph.fixed_weight.double()
    dense = torch.zeros(30, 30, dtype=torch.float64)
    dense.index_put_((graph.edge_index[0], graph.edge_index[1]), w, accumulate=True)
    torch.testing.assert_close(sparse_aggregate(x, graph.edge_index, w, 30), dense @ x)


def test_sparse_aggregate_gradients_match_dense():
    graph = random_graph(1, 12, 40)
    x = torch.randn(12, 5, dtype=torch.float64, requires_grad=True)
    w = graph.fixed_weight.double().requires_grad_()
    torch.autograd.gradcheck(lambda x, w: sparse_aggregate(x, graph.edge_index, w, 12), (x, w))


@pytest.mark.parametrize("mode", ["edge", "none"])
def test_encoder_is_permutation_equivariant(mode):
    torch.manual_seed(0)
    b, n, t, c = 2, 25, 6, 6
    graph = random_graph(b, n, 120)
    x = torch.randn(b, n, t, c)
    encoder = GraphConvEncoder(c, 8, trainable_graph=mode).eval()
    if mode == "edge":  # move the learned weights off their zero start
        for block in encoder.blocks:
            torch.nn.init.normal_(block.graph_op.edge_net.net[-1].weight)
    perm = torch.randperm(n)
    inverse = torch.argsort(perm)
    # relabel particle p -> inverse[p] within each sample
    node_map = (inverse.repeat(b) + torch.arange(b).repeat_interleave(n) * n).long()
    permuted = EdgeGraph(
        node_map[graph.edge_index], graph.fixed_weight, graph.edge_features, graph.n_nodes
    )
    out = encoder(x, graph)
    out_perm = encoder(x[:, perm], permuted)
    torch.testing.assert_close(out_perm, out[:, perm], atol=1e-5, rtol=1e-5)


def test_learned_edge_weights_start_at_zero():
    graph = random_graph(1, 20, 60)
    op_edge = GraphOperation("edge", 4)
    op_none = GraphOperation("none", 4)
    x = torch.randn(1, 20, 3, 5)
    torch.testing.assert_close(op_edge(x, graph), op_none(x, graph))


def test_dense_mode_refuses_another_particle_count():
    op = GraphOperation("dense", 4, n_particles=20)
    graph = random_graph(1, 10, 30)
    with pytest.raises(ValueError, match="built for 20 particles and cannot run on 10"):
        op(torch.randn(1, 10, 3, 5), graph)
    with pytest.raises(ValueError, match="needs the particle count"):
        GraphOperation("dense", 4)
    with pytest.raises(ValueError, match="must be one of"):
        GraphOperation("full", 4)


def test_untrained_decoder_reproduces_its_base():
    torch.manual_seed(0)
    decoder = TrajectoryDecoder(8, 6, 6, hidden=16, n_heads=2)
    features = torch.randn(2, 5, 4, 8)
    state = torch.randn(2, 5, 6)
    # grip: emitted velocity = last velocity at every step (state advances by it)
    out = decoder(features, state, None, horizon=3)
    torch.testing.assert_close(out, torch.zeros_like(out))
    base = torch.randn(2, 5, 6)
    out = decoder(features, state, base, horizon=3)
    torch.testing.assert_close(out, base.unsqueeze(2).expand(-1, -1, 3, -1))


def test_vct_fold_adds_shift_channels_to_z():
    fold = torch.zeros(8, 6)
    fold[:6, :6] = torch.eye(6)
    fold[6, 4] = fold[7, 5] = 1.0
    decoder = TrajectoryDecoder(8, 6, 8, hidden=16, n_heads=1, fold=fold)
    head = decoder.heads[0].head
    torch.nn.init.zeros_(head.weight)
    with torch.no_grad():
        head.bias.copy_(torch.tensor([0, 0, 0, 0, 1.0, 2.0, 10.0, 20.0]))
    captured = []
    decoder.heads[0].decoder.register_forward_hook(lambda m, i, o: captured.append(i[0].clone()))
    # the cell-by-cell loop shows each step's input (the batched loop equals it:
    # tests/nn/test_seq2seq.py)
    decoder.reference_forward(torch.randn(1, 1, 3, 8), torch.zeros(1, 1, 6), None, horizon=2)
    # second decoder input = first state + real + shift on the z channels
    torch.testing.assert_close(captured[1].reshape(6), torch.tensor([0, 0, 0, 0, 11.0, 22.0]))


def test_state_update_is_affine_with_shift():
    shift = torch.tensor([0.5, 0, 0, 0, 0, -1.0])
    decoder = TrajectoryDecoder(4, 6, 6, hidden=8, n_heads=1, fold=2 * torch.eye(6), shift=shift)
    with torch.no_grad():
        decoder.heads[0].head.bias.fill_(1.0)
    captured = []
    decoder.heads[0].decoder.register_forward_hook(lambda m, i, o: captured.append(i[0].clone()))
    decoder.reference_forward(torch.randn(1, 1, 3, 4), torch.zeros(1, 1, 6), None, horizon=3)
    # state_k = state_{k-1} + 2 * 1 + shift
    torch.testing.assert_close(captured[2].reshape(6), 2 * (2.0 + shift))
    with pytest.raises(ValueError, match="shift must be"):
        TrajectoryDecoder(4, 6, 6, shift=torch.zeros(5))
