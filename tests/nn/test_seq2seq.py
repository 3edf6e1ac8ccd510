"""The seq2seq GRU block: every head in one batched loop (gripdem.nn.stacked_gru) equals each
head's own cell-by-cell ``nn.GRU`` loop, outputs and gradients, for every state update the
decoder modes use; untrained heads give the base; model files keep their keys."""

import pytest
import torch

from gripdem.nn.seq2seq import TrajectoryDecoder


def decoder(context, state, out, heads, layers, hidden=16):
    torch.manual_seed(0)
    fold = 0.1 * torch.randn(out, state)
    dec = TrajectoryDecoder(
        12,
        state,
        out,
        hidden,
        layers,
        heads,
        fold=fold,
        shift=0.01 * torch.randn(state),
        context=context,
    )
    for p in dec.parameters():  # trained-looking weights (the output heads start at zero)
        torch.nn.init.normal_(p, std=0.4)
    return dec


def relative_gap(a, b) -> float:
    return float((a - b).abs().max() / b.abs().max().clamp_min(1e-30))


@pytest.mark.parametrize(
    ("context", "state", "out"),
    [("sequence", 6, 6), ("sequence", 6, 8), ("vector", 3, 3)],  # pct, vct (paper), exact
)
@pytest.mark.parametrize(("heads", "layers"), [(2, 2), (1, 1), (3, 2)])
@pytest.mark.parametrize("extras", [False, True])
def test_batched_loop_equals_the_cell_by_cell_loop(context, state, out, heads, layers, extras):
    dec = decoder(context, state, out, heads, layers)
    torch.manual_seed(1)
    time = 4 if context == "sequence" else 1
    features = torch.randn(2, 30, time, 12, requires_grad=True)
    start = torch.randn(2, 30, state)
    base = 0.1 * torch.randn(2, 30, out) if extras else None
    drift = 0.01 * torch.randn(2, 30, state) if extras else None
    batched = dec(features, start, base, 9, drift)
    reference = dec.reference_forward(features, start, base, 9, drift)
    assert batched.shape == (2, 30, 9, out)
    assert relative_gap(batched, reference) < 1e-5
    params = [features, *dec.parameters()]
    grads = torch.autograd.grad(batched.square().mean(), params)
    expected = torch.autograd.grad(reference.square().mean(), params)
    for got, want in zip(grads, expected, strict=True):
        assert relative_gap(got, want) < 1e-4


def test_untrained_heads_output_their_base():
    dec = TrajectoryDecoder(12, 6, 6, 16, 2, 2)  # output heads start at zero
    base = torch.randn(1, 5, 6)
    out = dec(torch.randn(1, 5, 3, 12), torch.randn(1, 5, 6), base, 4)
    assert torch.equal(out, base[:, :, None].expand(1, 5, 4, 6))


def test_state_dict_keys_are_each_heads_own():
    """Model files written before the batched loop load unchanged: the weights stay in each
    head's nn.GRU / nn.Linear."""
    keys = set(TrajectoryDecoder(12, 6, 6, 16, 2, 2).state_dict())
    assert {"heads.0.decoder.weight_ih_l0", "heads.1.decoder.weight_hh_l1"} <= keys
    assert "heads.1.head.bias" in keys and "fold" in keys
