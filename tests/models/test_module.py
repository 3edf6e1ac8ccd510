"""The LightningModule: shapes, gradients, learning, equivariance, the paper's exact LE shift.

The exact frame's defining invariant (untrained = constant velocity) is in test_exact_frame.py.
"""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from gripdem.boundary import Boundary, Box, LeesEdwards, wrap_positions
from gripdem.data.datamodule import TrajectoryDataModule
from gripdem.data.dataset_io import write_dataset
from gripdem.data.schema import TrajectoryData
from gripdem.models.module import TrajectoryModule

MODES = [  # (decoder mode, encoding, vct shift, encoder)
    ("grip", "unwrapped", "learned", "graph_conv"),
    ("pct", "unwrapped", "learned", "graph_conv"),
    ("vct", "unwrapped", "learned", "graph_conv"),
    ("grip", "unwrapped", "learned", "contact"),
    ("grip", "sincos", "learned", "graph_conv"),
    ("pct", "sincos", "learned", "graph_conv"),
    ("vct", "vct", "learned", "graph_conv"),
    ("vct", "vct", "exact", "graph_conv"),
]
ENCODERS = {
    "graph_conv": {"name": "graph_conv", "channels": 8, "n_blocks": 2},
    "contact": {"name": "contact", "channels": 8, "rounds": 2},
}


def make_module(
    dm: TrajectoryDataModule, mode: str, encoding: str, shift: str, encoder="graph_conv", **kw
):
    meta = dm.meta
    scene = {
        k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in meta.boundary.to_attrs().items()
    }
    scene["diameter"] = meta.diameter
    scene["frame_interval"] = meta.frame_interval
    args = dict(
        scene=scene,
        normalizer=dm.normalizer.to_dict(),
        encoding=encoding,
        horizon=dm.split.horizon,
        history_len=dm.plan.history_len,
        decoder_mode=mode,
        vct_shift=shift,
        encoder=ENCODERS[encoder] if isinstance(encoder, str) else encoder,
        hidden=16,
        n_heads=2,
        lr=3e-3,
        n_particles=meta.n_particles,
        graph_cutoff=dm.graph_cutoff,
    )
    args.update(kw)
    return TrajectoryModule(**args)


def kick(model: TrajectoryModule) -> TrajectoryModule:
    """Move the zero-initialised output heads and edge weights off zero."""
    for p in model.parameters():
        if p.dim() > 0 and torch.all(p == 0):
            torch.nn.init.normal_(p, std=0.1)
    return model


def datamodule(path, encoding, split="6-4", history_len=4, batch_size=1, **kw):
    dm = TrajectoryDataModule(
        path, split=split, encoding=encoding, history_len=history_len, batch_size=batch_size, **kw
    )
    dm.setup("fit")
    return dm


@pytest.mark.parametrize("scene", ["pbc", "lebc"])
@pytest.mark.parametrize(("mode", "encoding", "shift", "encoder"), MODES)
def test_shapes_and_decoded_positions_inside_the_box(
    request, scene, mode, encoding, shift, encoder
):
    path = request.getfixturevalue(f"tiny_{scene}_path")
    dm = datamodule(path, encoding, graph_cutoff=1.5 if encoder == "contact" else 3.0)
    model = kick(make_module(dm, mode, encoding, shift, encoder)).eval()
    batch = next(iter(dm.val_dataloader()))
    with torch.no_grad():
        pred = model(batch)
        positions = model.decode(pred, batch)
    b, n = batch.inputs.shape[:2]
    assert pred.shape == (b, n, 4, dm.encoding.n_channels)
    assert torch.isfinite(positions).all()
    assert positions.shape == (b, 4, n, 3) and positions.dtype == torch.float64
    half = torch.tensor(dm.meta.box.lengths) / 2
    assert torch.all(positions >= -half) and torch.all(positions < half)


def test_untrained_paper_grip_is_constant_velocity_along_a_chord(tiny_pbc_path):
    dm = datamodule(tiny_pbc_path, "sincos")
    model = make_module(dm, "grip", "sincos", "learned").eval()
    batch = next(iter(dm.val_dataloader()))
    with torch.no_grad():
        pred = model(batch)
    torch.testing.assert_close(pred, batch.inputs[:, :, -1:].expand_as(pred))


@pytest.mark.parametrize(("mode", "encoding", "shift", "encoder"), MODES)
def test_gradients_reach_every_parameter(tiny_lebc_path, mode, encoding, shift, encoder):
    dm = datamodule(tiny_lebc_path, encoding, graph_cutoff=1.5 if encoder == "contact" else 3.0)
    model = kick(make_module(dm, mode, encoding, shift, encoder))
    batch = next(iter(dm.train_dataloader()))
    loss = model._loss(model(batch), batch)
    loss.backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None or not p.grad.any()]
    assert missing == []


#: Adam steps and the fold asked of them. Measured folds (lowest of the 20 losses before the
#: step), over every mode, ATEN_CPU_CAPABILITY=default|avx2|avx512 and 1|2 threads
#: (experiments/analyses/overfit_folds.py, experiments/results/test_suite/overfit_folds.md):
#: after 120
#: steps 4.14-4.45 (vct, exact frame), 9.2-31.5 (every other mode); 2 leaves more than twice
#: the smallest. (200 steps and a fold of 5 had the same margin at 1.7x the time.)
OVERFIT_STEPS = 120
OVERFIT_FOLD = 2.0


def overfit_losses(path, mode, encoding, shift, encoder, steps: int) -> list[float]:
    """The loss of each of ``steps`` Adam steps (lr 1e-2) on one fixed window of ``path``, a
    small model of the mode (also run by experiments/analyses/overfit_folds.py)."""
    torch.manual_seed(0)
    dm = datamodule(path, encoding, graph_cutoff=1.5)
    options = {"graph_conv": {"channels": 16, "n_blocks": 1}, "contact": {"channels": 16}}
    model = make_module(dm, mode, encoding, shift, {"name": encoder, **options[encoder]}, hidden=32)
    batch = next(iter(dm.val_dataloader()))  # one fixed window, whatever the shuffling
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    losses = []
    for _ in range(steps):
        opt.zero_grad()
        loss = model._loss(model(batch), batch)
        loss.backward()
        opt.step()
        losses.append(loss.item())
    return losses


#: The mode whose fold lies closest to OVERFIT_FOLD on every CPU path measured (the smallest in
#: overfit_folds.md): the one case of the shared threshold that runs again with plain kernels
#: (marked ``numerics``; test_portable_numerics.py). A threshold tuned to one CPU fails there
#: first; the other modes' folds are at least twice as far from it.
BINDING_MODE = ("vct", "unwrapped", "learned", "graph_conv")
OVERFIT_CASES = [
    pytest.param(*mode, marks=pytest.mark.numerics) if mode == BINDING_MODE else mode
    for mode in MODES
]
OVERFIT_FOLDS = (
    Path(__file__).resolve().parents[2] / "experiments/results/test_suite/overfit_folds.json"
)


def test_the_plain_kernel_rerun_takes_the_binding_mode():
    """BINDING_MODE is the mode with the smallest fold at OVERFIT_STEPS in the measured
    spread, under every CPU path and thread count; and every overfitting mode was measured."""
    runs = json.loads(OVERFIT_FOLDS.read_text())["runs"]
    for path, folds in runs.items():
        assert set(folds) == {"/".join(mode) for mode in MODES}, path
        smallest = min(folds, key=lambda mode: folds[mode][str(OVERFIT_STEPS)])
        assert smallest == "/".join(BINDING_MODE), (path, smallest)


@pytest.mark.parametrize(("mode", "encoding", "shift", "encoder"), OVERFIT_CASES)
def test_overfits_one_window(tiny_lebc_path, mode, encoding, shift, encoder):
    """Learning works: 120 Adam steps on one fixed window cut the loss several-fold.

    The fold reached moves with the CPU's vector unit and the thread count (Adam at lr 1e-2
    oscillates near its floor), so the test reads the lowest loss of the last 20 steps and asks
    for a fold well inside the spread measured over ATEN_CPU_CAPABILITY=default|avx2|avx512 and
    1|2 threads (experiments/results/test_suite/overfit_folds.md): the smallest fold measured
    there is
    at least twice the one asked for here.
    """
    losses = overfit_losses(tiny_lebc_path, mode, encoding, shift, encoder, OVERFIT_STEPS)
    fold_reached = losses[0] / min(losses[-20:])
    assert fold_reached > OVERFIT_FOLD, (losses[0], min(losses[-20:]))


@pytest.mark.parametrize(
    ("encoding", "encoder"),
    [("sincos", "edge"), ("sincos", "none"), ("unwrapped", "edge"), ("unwrapped", "contact")],
)
def test_permuting_particles_permutes_predictions(tiny_lebc_path, encoding, encoder):
    cutoff = 1.5 if encoder == "contact" else 3.0
    dm = datamodule(tiny_lebc_path, encoding, graph_cutoff=cutoff)
    config = (
        ENCODERS["contact"]
        if encoder == "contact"
        else {"name": "graph_conv", "channels": 8, "trainable_graph": encoder}
    )
    model = kick(make_module(dm, "grip", encoding, "learned", config))
    model.eval()
    batch = next(iter(dm.val_dataloader()))
    b, n = batch.inputs.shape[:2]
    perm = torch.randperm(n, generator=torch.Generator().manual_seed(1))
    new_label = torch.argsort(perm)  # old particle p is new particle new_label[p]
    node_map = (new_label.repeat(b) + torch.arange(b).repeat_interleave(n) * n).long()
    permuted = type(batch)(
        **{
            **batch.__dict__,
            "inputs": batch.inputs[:, perm],
            "input_positions": batch.input_positions[:, perm],
            "target_positions": batch.target_positions[:, perm],
            "edge_index": node_map[batch.edge_index],
        }
    )
    with torch.no_grad():
        out = model(batch)
        out_perm = model(permuted)
    torch.testing.assert_close(out_perm, out[:, perm], atol=1e-5, rtol=1e-4)


def shear_with_crossings(tmp_path) -> str:
    """Ballistic x motion under affine shear: many particles cross the LE faces."""
    rng = np.random.default_rng(0)
    box = Box(1e-5, 1.2e-5, 0.9e-5)
    le = LeesEdwards(2000.0, sign=1, time_origin=0.0)
    n, frames, dt = 40, 30, 5e-5
    times = 3e-3 + dt * np.arange(frames)
    x0 = (rng.random(n) - 0.5) * box.lx
    vx = rng.normal(0, 0.15, n) * box.lx / (frames * dt) * 4
    cont = np.zeros((frames, n, 3))
    cont[:, :, 1] = (rng.random(n) - 0.5) * box.ly
    z = (rng.random(n) - 0.5) * box.lz
    for t in range(frames):
        cont[t, :, 0] = x0 + vx * dt * t
        cont[t, :, 2] = z
        z = z + le.shear_rate * (x0 + vx * dt * (t + 0.5)) * dt
    offsets = le.offset(box, times)
    wrapped = np.stack([wrap_positions(cont[t], box, offsets[t]) for t in range(frames)])
    data = TrajectoryData(wrapped[None], times[None], Boundary(box, le), radius=2e-7)
    return str(write_dataset(tmp_path / "shear.h5", data))


def test_paper_vct_exact_shift_reproduces_the_le_jumps_of_affine_shear(tmp_path):
    dm = datamodule(
        shear_with_crossings(tmp_path), "vct", split="20-8", history_len=3, protocol="in_sample"
    )
    # the paper's 8 channels, docs/spec/model.md#exact-shift
    exact = make_module(dm, "vct", "vct", "exact")
    learned = make_module(dm, "vct", "vct", "learned")
    crossers, worst_learned = 0, 0.0
    for batch in dm.test_dataloader():
        crossers += int(batch.crossing_mask.sum())
        truth = batch.target_positions.transpose(1, 2)
        deltas = batch.target_deltas.double().clone()
        # the real channels are what the model predicts; the shift channels are left at zero
        deltas[..., 6:8] = torch.as_tensor(dm.normalizer.normalize(np.zeros(8)))[6:8]
        torch.testing.assert_close(exact.decode(deltas, batch), truth, atol=1e-12, rtol=0)
        worst_learned = max(
            worst_learned, float((learned.decode(deltas, batch) - truth).abs().max())
        )
    assert crossers > 0
    assert worst_learned > 1e-7  # without the shift, the learned decoder misses the jumps
