"""The contact-aware encoder: permutation equivariance, invariance to an LE-consistent shift
of the whole configuration, any particle count, contact-scale gap features."""

import numpy as np
import pytest
import torch

from gripdem.boundary import affine_flow_strain, rewrap_trajectory, unwrap_trajectory
from gripdem.data.datamodule import TrajectoryDataModule
from gripdem.data.dataset_io import read_dataset, write_dataset
from gripdem.data.schema import TrajectoryData
from gripdem.models.module import TrajectoryModule
from gripdem.nn.contact import ContactEncoder, ContactGraph, gap_features


def random_contacts(batch, particles, pairs, seed=0):
    gen = torch.Generator().manual_seed(seed)
    index = []
    for b in range(batch):
        i = torch.randint(0, particles, (pairs,), generator=gen)
        j = (i + torch.randint(1, particles, (pairs,), generator=gen)) % particles
        index.append(torch.stack([i, j]) + b * particles)
    edge_index = torch.cat(index, 1)
    e = edge_index.shape[1]
    vector = torch.randn(e, 3, generator=gen)
    gap = torch.rand(e, generator=gen) * 0.5 - 0.01
    return ContactGraph(edge_index, vector, gap, 1.5, batch * particles)


def test_encoder_is_permutation_equivariant_for_any_particle_count():
    torch.manual_seed(0)
    encoder = ContactEncoder(history_len=5, static_features=2, channels=16, rounds=3)
    for n in (7, 40):
        b = 2
        graph = random_contacts(b, n, 6 * n)
        history, static = torch.randn(b, n, 5, 3), torch.randn(b, n, 2)
        out = encoder(history, static, graph)
        assert out.shape == (b, n, 1, 16) and torch.isfinite(out).all()
        perm = torch.randperm(n)
        inverse = torch.argsort(perm)
        node_map = (inverse.repeat(b) + torch.arange(b).repeat_interleave(n) * n).long()
        permuted = ContactGraph(
            node_map[graph.edge_index], graph.vector, graph.gap, graph.cutoff, graph.n_nodes
        )
        out_perm = encoder(history[:, perm], static[:, perm], permuted)
        torch.testing.assert_close(out_perm, out[:, perm], atol=1e-5, rtol=1e-4)


def test_gap_features_are_order_one_at_contact_scale():
    gaps = torch.tensor([-1e-4, -1e-5, 0.0, 1e-5, 1e-3, 0.01, 0.05, 0.1, 0.5])
    feats = gap_features(gaps)
    assert feats.shape == (9, 3)
    assert feats.abs().max() <= 5.0
    # every transform is monotonic in the gap
    assert (feats.diff(dim=0) >= 0).all()
    # the signed log resolves contact overlaps that a linear scale would not
    assert feats[1, 2] - feats[2, 2] < -0.05 and feats[0, 2] < feats[1, 2]
    # the contact-scale tanh separates touching from near (0.01 d) from far (0.1 d)
    assert feats[2, 0] == 0 and feats[5, 0] > 0.9 * feats[7, 0] - 0.1


def shifted_copy(tmp_path, path, shift, boost: bool):
    """The same trajectories moved by ``shift`` (in box lengths) as a whole; in a sheared cell
    with the boost that keeps them LE trajectories (z also gains strain * dx per frame)."""
    data = read_dataset(path)
    box, boundary = data.box, data.boundary
    offsets = data.offsets()
    positions = np.empty_like(data.positions)
    strain = affine_flow_strain(boundary, data.frame_interval) if boost else 0.0
    for s in range(data.positions.shape[0]):
        cont = unwrap_trajectory(data.positions[s], box, offsets[s])
        move = np.asarray(shift) * box.lengths
        frames = np.arange(cont.shape[0])[:, None, None]
        drift = np.zeros_like(cont)
        drift[..., 2] = strain * move[0] * frames[..., 0]
        positions[s] = rewrap_trajectory(cont + move + drift, box, offsets[s])
    moved = TrajectoryData(positions, data.times, boundary, radius=data.radius)
    return write_dataset(tmp_path / "shifted.h5", moved)


def _features(path, model_kw):
    dm = TrajectoryDataModule(path, split="20-5", history_len=5, graph_cutoff=1.5)
    dm.setup("fit")
    meta = dm.meta
    scene = {
        k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in meta.boundary.to_attrs().items()
    }
    scene.update(diameter=meta.diameter, frame_interval=meta.frame_interval)
    torch.manual_seed(0)
    model = TrajectoryModule(
        scene=scene,
        normalizer=dm.normalizer.to_dict(),
        encoding="unwrapped",
        horizon=5,
        history_len=5,
        encoder={"name": "contact", "channels": 16, "rounds": 2, **model_kw},
        hidden=8,
        graph_cutoff=1.5,
    ).eval()
    batch = next(iter(dm.test_dataloader()))
    with torch.no_grad():
        return model._encode(batch), model.normalizer


@pytest.mark.parametrize(
    ("scene", "shift", "options"),
    [
        ("lebc", (0.37, 0.21, 0.5), {}),  # the sheared cell: any shift (with the boost)
        ("pbc", (0.0, 0.21, 0.5), {}),  # the periodic drive depends on x: y and z shifts
        ("pbc", (0.37, 0.21, 0.5), {"position_features": "false"}),
    ],
)
def test_encoder_is_invariant_to_an_le_consistent_shift(request, tmp_path, scene, shift, options):
    path = request.getfixturevalue(f"tiny_{scene}_path")
    moved = shifted_copy(tmp_path, path, shift, boost=scene == "lebc")
    features, _ = _features(path, options)
    features_moved, _ = _features(moved, options)
    scale = features.abs().max()
    torch.testing.assert_close(features_moved, features, atol=2e-5 * float(scale), rtol=1e-4)


def test_position_features_see_the_periodic_drive(request, tmp_path):
    """With the x-position features on (the periodic default), an x shift changes the output:
    the drive a cos(2 pi x / lx) is not shift-invariant, and the model must know where it is."""
    path = request.getfixturevalue("tiny_pbc_path")
    moved = shifted_copy(tmp_path, path, (0.37, 0.0, 0.0), boost=False)
    features, _ = _features(path, {})
    features_moved, _ = _features(moved, {})
    assert (features_moved - features).abs().max() > 1e-3 * features.abs().max()


@pytest.mark.parametrize("edge_updates", [True, False])
def test_chunked_rounds_equal_the_unchunked(edge_updates):
    """Edges in blocks (no gradients: the inference path) give the same output as all edges at
    once, for blocks that do and do not divide the edge count, with and without edge updates."""
    torch.manual_seed(0)
    encoder = ContactEncoder(
        history_len=5, channels=16, rounds=3, edge_updates=edge_updates, pair_channels=8
    ).eval()
    graph = random_contacts(2, 50, 300)  # 600 edges
    history = torch.randn(2, 50, 5, 3)
    encoder.edge_chunk = 0
    with torch.no_grad():
        reference = encoder(history, None, graph)
        for chunk in (1, 7, 128, 600, 5000):
            encoder.edge_chunk = chunk
            torch.testing.assert_close(
                encoder(history, None, graph), reference, atol=1e-6, rtol=1e-5
            )
    # with gradients the rounds are never chunked (the same graph as training)
    encoder.edge_chunk = 7
    torch.testing.assert_close(
        encoder(history, None, graph).detach(), reference, atol=1e-6, rtol=1e-5
    )


def per_edge_messages(encoder, history, graph):
    """The encoder without edge updates written out per edge (every message through both
    layers of its MLP, summed with index_add): the reference of the folded rounds."""
    b, n, k, _ = history.shape
    flat = history.reshape(b * n, k, 3)
    h = encoder.node_in(flat.reshape(b * n, 3 * k))
    e = encoder.edge_in(encoder.edge_inputs(flat, graph))
    for message, node_update in zip(encoder.message, encoder.node_update, strict=True):
        msg = message(h, e, graph.edge_index)
        incoming = h.new_zeros(h.shape[0], msg.shape[1]).index_add_(0, graph.edge_index[0], msg)
        h = h + node_update(torch.cat([h, incoming], dim=-1))
    return h.reshape(b, n, 1, -1)


@pytest.mark.parametrize("grad", [True, False])
def test_folded_rounds_are_the_per_edge_messages(grad):
    """Without edge updates the rounds fold the linear layers around each edge (the edge
    MLP's output into the message's edge term, the message's output past the sum): in float64
    the same function as every message computed per edge and summed, to round-off, with and
    without gradients (blocks of edges), for nodes with no edge too."""
    torch.manual_seed(0)
    encoder = ContactEncoder(
        history_len=5, channels=16, rounds=3, edge_updates=False, pair_channels=8
    ).double()
    for layer in (encoder.edge_in[-1], *(m.out for m in encoder.message)):  # nonzero biases
        torch.nn.init.normal_(layer.bias)
    encoder.edge_chunk = 7
    graph = random_contacts(2, 60, 50)  # 100 edges over 120 nodes: some receive none
    graph.vector, graph.gap = graph.vector.double(), graph.gap.double()
    history = torch.randn(2, 60, 5, 3, dtype=torch.float64)
    assert torch.bincount(graph.edge_index[0], minlength=120).eq(0).any()
    with torch.set_grad_enabled(grad):
        folded = encoder(history, None, graph)
        reference = per_edge_messages(encoder, history, graph)
    torch.testing.assert_close(folded, reference, atol=1e-12, rtol=1e-12)
    assert (folded - reference).abs().max() < 1e-12 * reference.abs().max()


def test_narrow_pair_channels_keep_the_node_latents():
    encoder = ContactEncoder(history_len=4, channels=32, rounds=2, pair_channels=8)
    out = encoder(torch.randn(1, 20, 4, 3), None, random_contacts(1, 20, 80))
    assert out.shape == (1, 20, 1, 32) and encoder.out_channels == 32
    assert encoder.message[0].out.out_features == 8 and encoder.edge_in[-1].out_features == 8
    with pytest.raises(ValueError, match="pair_channels"):
        ContactEncoder(history_len=4, pair_channels=0)


#: bf16 keeps 8 significant bits: one rounding is 2^-9 = 0.2 % relative; through 4 rounds of
#: residual MLPs the largest output deviation measured 0.8-0.9 % of the largest output (random
#: weights, experiments/benchmarks/model_cost/encoder_speed.py); 3 % bounds it with margin
BF16_TOLERANCE = 0.03


def test_bf16_encoder_stays_within_its_stated_tolerance_of_fp32():
    """The same weights and inputs in bf16 (computed natively or emulated: the tolerance is a
    property of the format) against fp32: the output is fp32 again and within BF16_TOLERANCE of
    the fp32 output's scale."""
    torch.manual_seed(0)
    encoder = ContactEncoder(
        history_len=5, channels=32, rounds=4, edge_updates=False, pair_channels=16
    ).eval()
    graph = random_contacts(1, 200, 1800)
    history = torch.randn(1, 200, 5, 3)
    with torch.no_grad():
        reference = encoder(history, None, graph)
        encoder.to(torch.bfloat16)
        half = encoder(history, None, graph)
    assert half.dtype == torch.float32
    deviation = (half - reference).abs().max() / reference.abs().max()
    assert 0 < deviation < BF16_TOLERANCE
