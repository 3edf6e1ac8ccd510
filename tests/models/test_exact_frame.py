"""The exact frame's invariant (docs/spec/model.md#exact-frame): with every learned output zero a
model IS constant velocity, to float64 round-off, in both scenes, at every split, for every decoder
mode and both encoders, on windows where many particles cross the LE faces in the history and the
horizon. The paper's wrapped-space decoding is not exact for crossers (shown beside it)."""

import numpy as np
import pytest
import torch

from gripdem.boundary import minimum_image
from gripdem.data.datamodule import TrajectoryDataModule
from gripdem.data.dataset_io import write_dataset
from gripdem.data.encodings import step_lattice_shifts
from gripdem.models.autoregressive import fit_on_training_frames
from gripdem.models.baselines import constant_velocity
from gripdem.models.module import TrajectoryModule

SPLITS = [("6-4", 4), ("20-12", 3), ("3-1", 3)]  # (split h-f, history_len)
EXACT_MODES = [
    ("grip", "graph_conv"),
    ("pct", "graph_conv"),
    ("vct", "graph_conv"),
    ("grip", "contact"),
    ("pct", "contact"),
    ("vct", "contact"),
]


def module(
    dm: TrajectoryDataModule, mode: str, encoder: str, encoding: str = "unwrapped", **options
):
    meta = dm.meta
    scene = {
        k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in meta.boundary.to_attrs().items()
    }
    scene.update(diameter=meta.diameter, frame_interval=meta.frame_interval)
    encoders = {
        "graph_conv": {"name": "graph_conv", "channels": 8, "n_blocks": 1},
        "contact": {"name": "contact", "channels": 8, "rounds": 2},
    }
    torch.manual_seed(0)
    model = TrajectoryModule(
        scene=scene,
        normalizer=dm.normalizer.to_dict(),
        encoding=encoding,
        horizon=dm.split.horizon,
        history_len=dm.plan.history_len,
        decoder_mode=mode,
        encoder=encoders[encoder],
        hidden=8,
        n_particles=meta.n_particles,
        graph_cutoff=dm.graph_cutoff,
        **options,
    )
    return model.eval()


@pytest.fixture(scope="module")
def crossing_paths(tmp_path_factory, trajectories):
    """Random walks under strong affine shear (LE, offsets sweeping the box) and in a periodic
    box: every face is crossed many times."""
    root = tmp_path_factory.mktemp("exact")
    le = trajectories(n_sims=3, n_frames=40, n_particles=24, lees_edwards=True, seed=11)
    pbc = trajectories(n_sims=3, n_frames=40, n_particles=24, lees_edwards=False, seed=12)
    return {
        "lebc": write_dataset(root / "le.h5", le),
        "pbc": write_dataset(root / "pbc.h5", pbc),
    }


def _datamodule(path, split, history_len, encoding="unwrapped", cutoff=3.0):
    dm = TrajectoryDataModule(
        path,
        split=split,
        history_len=history_len,
        encoding=encoding,
        protocol="sims",
        batch_size=4,
        graph_cutoff=cutoff,
        eval_stride=1,
    )
    dm.setup("fit")
    return dm


def _max_difference(pred, reference, box, offsets) -> float:
    """Largest LE minimum-image difference of two (W, f, N, 3) predictions, in box lengths."""
    diff = minimum_image(pred - reference, box, offsets[..., None])
    return float(diff.abs().max()) / min(box.lx, box.ly, box.lz)


def _cv(batch, box):
    """The constant-velocity baseline's wrapped positions ``(B, f, N, 3)`` on a batch."""
    return constant_velocity(
        batch.input_positions.transpose(1, 2), batch.input_offsets, batch.target_offsets, box
    )


def _crossings(batch, box) -> tuple[int, int]:
    """x-face crossings in the history and in the horizon of a batch."""
    pos = torch.cat([batch.input_positions, batch.target_positions], dim=2)
    shift, _ = step_lattice_shifts(pos, box, batch.offsets)
    crossed = shift[..., 0] != 0
    k = batch.history_len
    return int(crossed[..., :k].sum()), int(crossed[..., k:].sum())


@pytest.mark.parametrize("scene", ["lebc", "pbc"])
@pytest.mark.parametrize(("split", "history_len"), SPLITS)
@pytest.mark.parametrize(("mode", "encoder"), EXACT_MODES)
def test_untrained_model_is_constant_velocity(
    crossing_paths, scene, split, history_len, mode, encoder
):
    dm = _datamodule(crossing_paths[scene], split, history_len)
    model = module(dm, mode, encoder)
    box = dm.meta.box
    history_crossings = horizon_crossings = 0
    for batch in dm.test_dataloader():
        with torch.no_grad():
            pred = model.decode(model(batch), batch)
        cv = _cv(batch, box)
        assert pred.dtype == torch.float64
        assert _max_difference(pred, cv, box, batch.target_offsets) < 1e-13
        h, f = _crossings(batch, box)
        history_crossings, horizon_crossings = history_crossings + h, horizon_crossings + f
    assert history_crossings >= 10 and horizon_crossings >= 10


@pytest.mark.parametrize("scene", ["lebc", "pbc"])
@pytest.mark.parametrize(("mode", "encoder"), EXACT_MODES)
def test_untrained_model_is_constant_velocity_on_the_dem_scene(request, scene, mode, encoder):
    """The same on the built-in DEM's tiny scenes (real contacts, real LE crossers)."""
    path = request.getfixturevalue(f"tiny_{scene}_path")
    dm = _datamodule(path, "50-10", 10, cutoff=1.5 if encoder == "contact" else 3.0)
    model = module(dm, mode, encoder)
    for batch in dm.test_dataloader():
        with torch.no_grad():
            pred = model.decode(model(batch), batch)
        cv = _cv(batch, dm.meta.box)
        assert _max_difference(pred, cv, dm.meta.box, batch.target_offsets) < 1e-13


def test_paper_frame_is_not_exact_for_le_crossers(crossing_paths):
    """The paper's grip (sin/cos chord) misses the LE shift and jump of crossers: the
    difference to constant velocity is of the order of the box, not of round-off."""
    dm = _datamodule(crossing_paths["lebc"], "6-4", 4, encoding="sincos")
    model = module(dm, "grip", "graph_conv", encoding="sincos")
    worst = 0.0
    for batch in dm.test_dataloader():
        with torch.no_grad():
            pred = model.decode(model(batch), batch)
        cv = _cv(batch, dm.meta.box)
        worst = max(worst, _max_difference(pred, cv, dm.meta.box, batch.target_offsets))
    assert worst > 1e-2


def test_true_deviation_decodes_to_the_truth(crossing_paths):
    """Decoding the true deviation from CV returns the stored target frames (crossings in the
    horizon included): the exact frame loses nothing (float64), and the float32 training
    targets only their rounding."""
    dm = _datamodule(crossing_paths["lebc"], "6-4", 4)
    model = module(dm, "grip", "graph_conv")
    for batch in dm.test_dataloader():
        truth = batch.target_positions.transpose(1, 2)
        exact = model.decode(model.true_deviation(batch, torch.float64), batch)
        assert _max_difference(exact, truth, dm.meta.box, batch.target_offsets) < 1e-13
        rounded = model.decode(model.true_deviation(batch).double(), batch)
        assert _max_difference(rounded, truth, dm.meta.box, batch.target_offsets) < 1e-6


def test_exact_loss_is_one_at_the_start(crossing_paths):
    """The exact losses are relative to constant velocity's: an untrained model scores 1."""
    dm = _datamodule(crossing_paths["pbc"], "6-4", 4)
    for mode in ("grip", "pct", "vct"):
        model = module(dm, mode, "graph_conv")
        batch = next(iter(dm.train_dataloader()))
        with torch.no_grad():
            loss = model._loss(model(batch), batch)
        np.testing.assert_allclose(float(loss), 1.0, rtol=1e-6)


@pytest.mark.parametrize("scene", ["lebc", "pbc"])
@pytest.mark.parametrize("mode", ["grip", "pct", "vct"])
def test_ar_prior_starts_at_cv_and_its_open_gate_is_the_ar_baseline(crossing_paths, scene, mode):
    """``ar_prior``: the gate starts at zero (the model is CV); with the gate open and the GRU
    heads at zero the model is the linear AR baseline, crossers included (random walks under
    strong shear: AR and CV differ by much more than the tolerance)."""
    dm = _datamodule(crossing_paths[scene], "6-4", 4)
    ar = fit_on_training_frames(dm, 2)
    model = module(dm, mode, "contact", ar_prior=True, linear_ar=ar.to_dict())
    box = dm.meta.box
    for batch in dm.test_dataloader():
        with torch.no_grad():
            closed = model.decode(model(batch), batch)
            model.ar_gate.fill_(1.0)
            opened = model.decode(model(batch), batch)
            model.ar_gate.zero_()
        baselines = model.predict_baselines(batch)
        offsets = batch.target_offsets
        assert _max_difference(closed, baselines["constant_velocity"], box, offsets) < 1e-13
        # the prior enters the float32 output: AR up to float32 rounding of the deviation
        assert _max_difference(opened, baselines["linear_ar"], box, offsets) < 1e-7
        assert _max_difference(opened, closed, box, offsets) > 1e-4


def test_ar_prior_needs_the_exact_frame_and_the_filter(crossing_paths):
    dm = _datamodule(crossing_paths["pbc"], "6-4", 4)
    with pytest.raises(ValueError, match="ar_prior"):
        module(dm, "grip", "graph_conv", ar_prior=True)


@pytest.mark.parametrize("scene", ["lebc", "pbc"])
@pytest.mark.parametrize(("mode", "encoder"), EXACT_MODES)
def test_direct_decoder_and_zero_mean_start_at_cv(crossing_paths, scene, mode, encoder):
    """The direct multi-step head starts at zero (the model is CV, crossers included) in every
    decoder mode on both encoders, with the AR prior and the zero-mean constraint: the
    default form of grip, pct and vct."""
    dm = _datamodule(crossing_paths[scene], "6-4", 4)
    ar = fit_on_training_frames(dm, 2)
    model = module(
        dm,
        mode,
        encoder,
        decoder="direct",
        zero_mean=True,
        ar_prior=True,
        linear_ar=ar.to_dict(),
    )
    for batch in dm.test_dataloader():
        with torch.no_grad():
            pred = model.decode(model(batch), batch)
        assert (
            _max_difference(pred, _cv(batch, dm.meta.box), dm.meta.box, batch.target_offsets)
            < 1e-13
        )


def test_direct_decoder_inputs_differ_by_mode(crossing_paths):
    """What the direct decoder reads beside the context: grip the last velocity (3 channels),
    pct and vct the last position as sin/cos per axis (6), continuous across the faces."""
    dm = _datamodule(crossing_paths["lebc"], "6-4", 4)
    batch = next(iter(dm.test_dataloader()))
    sizes = {}
    for mode in ("grip", "pct", "vct"):
        model = module(dm, mode, "contact", decoder="direct")
        sizes[mode] = model.decoder.net[0].in_features - model.encoder.out_channels
    assert sizes == {"grip": 3, "pct": 6, "vct": 6}
    from gripdem.models.decoder_modes import direct_state

    box = dm.meta.box
    edge = torch.tensor([[[box.lx / 2 - 1e-12, 0.0, 0.0], [-box.lx / 2, 0.0, 0.0]]])
    state = direct_state("pct", box, edge, batch.inputs[:1, :2])
    assert torch.allclose(state[0, 0], state[0, 1], atol=1e-6)  # float32 features


@pytest.mark.parametrize("decoder", ["gru", "direct"])
def test_zero_mean_removes_any_net_deviation(crossing_paths, decoder):
    """A perturbed model's deviation from CV averages to zero over the particles at every step
    (the truth's does, to round-off), so its centre of mass moves exactly as CV's."""
    dm = _datamodule(crossing_paths["lebc"], "6-4", 4)
    model = module(dm, "grip", "contact", decoder=decoder, zero_mean=True)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.1 * torch.randn_like(p))
        batch = next(iter(dm.test_dataloader()))
        deviation = model(batch)
    assert deviation.abs().max() > 1e-2
    assert deviation.mean(dim=1).abs().max() < 1e-6


def test_direct_decoder_needs_the_exact_frame(crossing_paths):
    dm = _datamodule(crossing_paths["pbc"], "6-4", 4)
    paper = _datamodule(crossing_paths["pbc"], "6-4", 4, encoding="sincos")
    with pytest.raises(ValueError, match="model.decoder=direct"):
        module(paper, "pct", "graph_conv", encoding="sincos", decoder="direct")
    with pytest.raises(ValueError, match="model.decoder must be one of"):
        module(dm, "grip", "contact", decoder="lstm")
