"""The DataModule: batch contents against the file, training-only statistics, checkpoints."""

from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from gripdem.boundary import Box, minimum_image
from gripdem.data.datamodule import TrajectoryDataModule, WindowBatch, collate_windows
from gripdem.data.dataset_io import read_dataset, write_dataset
from gripdem.data.encodings import make_encoding, x_face_crossings
from gripdem.data.graph import build_graph
from gripdem.data.normalizer import Normalizer
from gripdem.data.schema import DatasetError
from gripdem.data.windows import SplitError

CONF = Path(__file__).resolve().parents[2] / "conf"


def _module(path, **kw):
    args = {"split": "10-5", "history_len": 6, "encoding": "vct", "batch_size": 3} | kw
    dm = TrajectoryDataModule(path, **args)
    dm.setup("fit")
    return dm


@pytest.mark.parametrize("encoding", ["sincos", "vct", "unwrapped"])
def test_batch_matches_the_file(le_path, encoding):
    dm = _module(le_path, encoding=encoding)
    data = read_dataset(le_path)
    enc = make_encoding(encoding, data.boundary)
    batch = next(iter(dm.test_dataloader()))
    assert isinstance(batch, WindowBatch) and not batch.in_sample
    b, n, k, f, c = 2, 32, 6, 5, enc.n_channels  # 2 test windows at stride f
    shapes = {
        "inputs": (b, n, k, c),
        "target_deltas": (b, n, f, c),
        "input_positions": (b, n, k + 1, 3),
        "target_positions": (b, n, f, 3),
        "times": (b, k + 1 + f),
        "offsets": (b, k + 1 + f),
        "crossing_mask": (b, n),
        "sim_index": (b,),
        "window_start": (b,),
        "edge_ptr": (b + 1,),
        "decoder_seed": (b, n, c),
        "last_positions": (b, n, 3),
        "target_offsets": (b, f),
    }
    for name, shape in shapes.items():
        assert tuple(getattr(batch, name).shape) == shape, name
    assert batch.inputs.dtype == batch.target_deltas.dtype == torch.float32
    assert batch.input_positions.dtype == batch.offsets.dtype == batch.times.dtype == torch.float64
    for s in range(b):
        w = dm.plan.test[s]
        frames = slice(w.start, w.stop)
        pos = data.positions[w.sim, frames].transpose(1, 0, 2)
        offs = data.offsets()[w.sim, frames]
        assert (batch.sim_index[s], batch.window_start[s]) == (w.sim, w.start)
        np.testing.assert_array_equal(batch.times[s], data.times[w.sim, frames])
        np.testing.assert_array_equal(batch.offsets[s], offs)
        np.testing.assert_array_equal(batch.input_positions[s], pos[:, : k + 1])
        np.testing.assert_array_equal(batch.target_positions[s], pos[:, k + 1 :])
        expected = dm.normalizer.normalize(enc.encode(pos, offs, anchor=k)).astype(np.float32)
        np.testing.assert_allclose(batch.inputs[s], expected[:, :k], rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(batch.target_deltas[s], expected[:, k:], rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(
            batch.crossing_mask[s], x_face_crossings(pos[:, k:], data.box, offs[k:])
        )
        # the denormalised targets decode back to the target positions
        deltas = dm.normalizer.denormalize(batch.target_deltas[s].double())
        decoded = enc.decode(batch.last_positions[s], deltas, batch.target_offsets[s])
        err = minimum_image(
            (decoded - batch.target_positions[s]).numpy(), data.box, offs[k + 1 :][None, :]
        )
        assert np.abs(err).max() < 1e-5 * data.diameter
        # the graph of sample s, at the last observed frame, indices offset by s*N
        e0, e1 = batch.edge_ptr[s], batch.edge_ptr[s + 1]
        graph = build_graph(
            pos[:, k], data.box, offs[k], 3 * data.diameter, length_unit=data.diameter
        )
        np.testing.assert_array_equal(batch.edge_index[:, e0:e1] - s * n, graph.edge_index)
        np.testing.assert_array_equal(batch.edge_weight[e0:e1], graph.edge_weight)
        np.testing.assert_array_equal(batch.edge_vector[e0:e1], graph.edge_vector)
    assert batch.edge_ptr[-1] == batch.edge_index.shape[1] == batch.edge_weight.shape[0]
    moved = batch.to("cpu")
    assert moved.offsets.dtype == torch.float64 and moved.in_sample is False


def test_graph_is_cached_per_last_observed_frame(le_path):
    dm = _module(le_path, train_stride=1)
    ds = dm.datasets["train"]
    first = ds[3]["graph"]
    assert ds[3]["graph"] is first and len(ds._graphs) == 1
    assert ds[4]["graph"] is not first


def _replace_sims(path, out, sims=None, frames=None, seed=9):
    """A copy of the file with the positions of ``sims`` (or of ``frames`` of every
    simulation) replaced by other wrapped positions."""
    data = read_dataset(path)
    rng = np.random.default_rng(seed)
    sel = (slice(None) if sims is None else sims, slice(None) if frames is None else frames)
    shape = data.positions[sel].shape
    data.positions[sel] = (rng.random(shape) - 0.5) * data.box.lengths
    return write_dataset(out, data)


def test_statistics_come_from_the_training_split_only_sims(le_sims_path, tmp_path):
    dm = _module(le_sims_path, protocol="sims")
    assert dm.plan.train.sims == (0, 1, 2) and dm.plan.test.sims == (4,)
    other = _replace_sims(le_sims_path, tmp_path / "other_test.h5", sims=[3, 4])
    assert _module(other, protocol="sims").normalizer == dm.normalizer
    changed = _replace_sims(le_sims_path, tmp_path / "other_train.h5", sims=[1])
    assert _module(changed, protocol="sims").normalizer != dm.normalizer


def test_statistics_come_from_the_training_split_only_time(le_path, tmp_path):
    dm = _module(le_path, protocol="time")
    b1, _ = dm.plan.notes["time_boundaries"]
    assert dm.plan.train.frames_used() == {0: [(0, b1)]}
    later = _replace_sims(le_path, tmp_path / "later.h5", frames=slice(b1, None))
    assert _module(later, protocol="time").normalizer == dm.normalizer
    earlier = _replace_sims(le_path, tmp_path / "earlier.h5", frames=slice(b1 - 1, None))
    assert _module(earlier, protocol="time").normalizer != dm.normalizer
    # the statistics are those of every step inside the training frames
    data = read_dataset(le_path)
    pos = data.positions[0, :b1].transpose(1, 0, 2)
    deltas = make_encoding("vct", data.boundary).encode(pos, data.offsets()[0, :b1])
    mean, std = deltas.reshape(-1, 8).mean(0), deltas.reshape(-1, 8).std(0)
    mean[6:8], std[6:8] = 0.0, std[4:6]  # LE shift channels are scaled like the real z ones
    np.testing.assert_allclose(dm.normalizer.mean, mean, atol=1e-15)
    np.testing.assert_allclose(dm.normalizer.std, std, rtol=1e-10)


def test_normaliser_is_restored_from_a_checkpoint_state(le_path):
    trained = _module(le_path)
    state = trained.state_dict()
    assert state["normalizer"]["mean"] == list(trained.normalizer.mean)
    before = TrajectoryDataModule(le_path, split="10-5", history_len=6, encoding="vct")
    before.load_state_dict(state)
    before.setup("test")
    assert before.normalizer == trained.normalizer
    fake = Normalizer.identity(8, "vct").to_dict()
    after = _module(le_path, batch_size=2)
    after.load_state_dict({"normalizer": fake, "encoding": "vct"})
    batch = next(iter(after.test_dataloader()))
    raw = make_encoding("vct", after.meta.boundary).encode(
        batch.input_positions[0].numpy(), batch.input_offsets[0].numpy()
    )
    np.testing.assert_allclose(batch.inputs[0], raw, rtol=1e-6, atol=1e-9)
    with pytest.raises(ValueError, match="encoding"):
        after.load_state_dict({"normalizer": fake, "encoding": "sincos"})


def test_paper_protocol_batches_are_labelled_in_sample(le_path):
    dm = _module(le_path, protocol="in_sample", split="40-5", history_len=None)
    assert dm.in_sample and dm.summary()["in_sample"] is True
    batch = next(iter(dm.train_dataloader()))
    assert batch.in_sample and batch.batch_size == 1
    test = next(iter(dm.test_dataloader()))
    assert torch.equal(test.target_positions, batch.target_positions)


def test_periodic_file_and_clear_errors(pbc_path, le_path):
    dm = _module(pbc_path, encoding="vct", protocol="sims", expect_boundary="periodic")
    batch = next(iter(dm.train_dataloader()))
    assert (batch.offsets == 0).all()
    # the walk crosses the x faces often, but no face is special in a periodic box: the LE
    # crossing mask is skipped
    assert x_face_crossings(batch.target_positions, dm.meta.box).any()
    assert not batch.crossing_mask.any()
    assert dm.normalizer.std[6:] == dm.normalizer.std[4:6] and dm.normalizer.mean[6:] == (0, 0)
    with pytest.raises(DatasetError, match="lees_edwards"):
        _module(pbc_path, expect_boundary="lees_edwards")
    with pytest.raises(SplitError, match="60 frames"):
        _module(le_path, split="100-100", history_len=None)
    with pytest.raises(ValueError, match="data.path is null"):
        TrajectoryDataModule(None)
    with pytest.raises(ValueError, match="expected one of"):
        _module(le_path, encoding="polar")


def test_from_config_composes_the_yaml_groups(le_path):
    cfg = OmegaConf.create(
        {
            "data": OmegaConf.load(f"{CONF}/data/default.yaml"),
            "split": OmegaConf.load(f"{CONF}/split/custom.yaml"),
            "model": {"encoding": "unwrapped"},
            "scene": {"boundary": "lees_edwards"},
        }
    )
    cfg.split.history, cfg.split.horizon = 12, 4
    cfg.data.history_len = 5
    for name in ("190-10", "180-20", "150-50", "100-100"):
        split = OmegaConf.load(f"{CONF}/split/{name}.yaml")
        assert f"{split.history}-{split.horizon}" == name == split.name
    dm = TrajectoryDataModule.from_config(cfg.data, cfg.split, path=le_path)
    dm.setup()
    summary = dm.summary()
    assert (summary["encoding"], summary["split"], summary["history_len"]) == (
        "unwrapped",
        "12-4",
        5,
    )
    assert summary["protocol"] == "time" and dm.expect_boundary == "lees_edwards"
    # a run's config saved before gripdem 0.1's renames: protocol paper, paper_windows
    cfg.data.protocol, cfg.data.paper_windows = "paper", 2
    del cfg.data["in_sample_windows"]
    with pytest.warns(DeprecationWarning, match="protocol 'paper'"):
        old = TrajectoryDataModule.from_config(cfg.data, cfg.split, path=le_path)
    assert old.plan_args["protocol"] == "in_sample" and old.plan_args["in_sample_windows"] == 2


class _Probe(L.LightningModule):
    """Smallest model that reads a batch on the device: a linear map of the decoder seed."""

    def __init__(self):
        super().__init__()
        self.layer = torch.nn.Linear(8, 8)
        self.seen: list[WindowBatch] = []

    def training_step(self, batch, batch_idx):
        assert isinstance(batch, WindowBatch) and batch.offsets.dtype == torch.float64
        self.seen.append(batch)
        pred = self.layer(batch.decoder_seed)[:, :, None].expand_as(batch.target_deltas)
        return torch.mean((pred - batch.target_deltas) ** 2)

    def validation_step(self, batch, batch_idx):
        self.log("val/loss", torch.mean(batch.target_deltas**2), batch_size=batch.batch_size)

    def configure_optimizers(self):
        return torch.optim.Adam(self.parameters(), lr=1e-3)


def test_lightning_fit_with_worker_processes(le_sims_path):
    dm = TrajectoryDataModule(
        le_sims_path,
        split="10-5",
        history_len=4,
        encoding="vct",
        protocol="sims",
        sims={"train": [0, 1], "val": [], "test": [2]},
        batch_size=4,
        num_workers=2,
    )
    probe = _Probe()
    trainer = L.Trainer(
        max_steps=3,
        accelerator="cpu",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
    )
    trainer.fit(probe, datamodule=dm)  # no validation simulations: validation is skipped
    assert len(probe.seen) == 3 and probe.seen[0].inputs.shape == (4, 20, 4, 8)
    assert dm.val_dataloader() == []


def test_collate_offsets_graph_indices():
    graph = build_graph(np.array([[0.0, 0, 0], [0.5, 0, 0]]), Box(4.0, 4.0, 4.0), 0.0, 1.0)
    sample = {
        "inputs": np.zeros((2, 3, 6), np.float32),
        "target_deltas": np.zeros((2, 1, 6), np.float32),
        "input_positions": np.zeros((2, 4, 3)),
        "target_positions": np.zeros((2, 1, 3)),
        "times": np.zeros(5),
        "offsets": np.zeros(5),
        "graph": graph,
        "crossing_mask": np.zeros(2, bool),
        "sim": 0,
        "start": 0,
        "in_sample": False,
    }
    batch = collate_windows([sample, sample, sample])
    assert batch.edge_index.max() == 5 and batch.edge_ptr.tolist() == [0, 4, 8, 12]
    assert batch.edge_index[:, 4:8].tolist() == (graph.edge_index + 2).tolist()


@pytest.mark.parametrize(
    "scene,encoding", [("pbc", "sincos"), ("lebc", "vct"), ("lebc", "unwrapped")]
)
def test_datamodule_on_the_tiny_dem_datasets(scene, encoding, request):
    path = request.getfixturevalue(f"tiny_{scene}_path")
    boundary = "periodic" if scene == "pbc" else "lees_edwards"
    dm = TrajectoryDataModule(
        path,
        split="20-5",
        history_len=10,
        encoding=encoding,
        batch_size=2,
        expect_boundary=boundary,
    )
    dm.setup("fit")
    summary = dm.summary()
    assert summary["protocol"] == "sims" and not summary["in_sample"]
    assert summary["n_windows_train"] > 0 and summary["n_windows_test"] > 0
    enc = make_encoding(encoding, dm.meta.boundary)
    for batch in dm.test_dataloader():
        n = dm.meta.n_particles
        assert batch.inputs.shape[1:] == (n, 10, enc.n_channels)
        assert torch.isfinite(batch.inputs).all() and torch.isfinite(batch.target_deltas).all()
        # the first step's times are absolute (after the spin-up), offsets from those times
        assert (batch.times[:, 0] > 0).all()
        np.testing.assert_array_equal(batch.offsets, dm.meta.boundary.offset(batch.times))
        deltas = dm.normalizer.denormalize(batch.target_deltas.double())
        decoded = enc.decode(batch.last_positions, deltas, batch.target_offsets)
        err = minimum_image(
            (decoded - batch.target_positions).numpy(),
            dm.meta.box,
            batch.target_offsets[:, None, :].numpy(),
        )
        assert np.abs(err).max() < 1e-5 * dm.meta.diameter
        neighbours = batch.edge_index.shape[1] / (batch.batch_size * n) - 1
        assert 20 < neighbours < n  # ~100 at phi = 0.5 and D = 3 d, fewer in a tiny box
