"""The ensemble model (model=ensemble): latent noise in the message passing, one member per
forward pass, trained on the fair CRPS. Its invariants: an untrained member is constant
velocity; a member whose noise is zero is the deterministic network with the same weights; the
seed fixes the members; the CRPS loss is one at the start and trains the spread."""

import numpy as np
import pytest
import torch

from gripdem.boundary import minimum_image
from gripdem.data.datamodule import TrajectoryDataModule
from gripdem.data.dataset_io import read_meta
from gripdem.inference.rollout import rollout
from gripdem.models.autoregressive import fit_on_training_frames
from gripdem.models.baselines import constant_velocity
from gripdem.models.module import TrajectoryModule

ENCODER = {"name": "contact", "channels": 8, "rounds": 2}


def datamodule(path) -> TrajectoryDataModule:
    dm = TrajectoryDataModule(
        path, split="6-4", encoding="unwrapped", history_len=4, batch_size=2, graph_cutoff=1.5
    )
    dm.setup("fit")
    return dm


def module(dm, noise_channels: int = 4, seed: int = 0, **options) -> TrajectoryModule:
    """The default model's form (direct decoder, AR prior, zero mean), small."""
    meta = dm.meta
    scene = {
        k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in meta.boundary.to_attrs().items()
    }
    scene.update(diameter=meta.diameter, frame_interval=meta.frame_interval)
    torch.manual_seed(seed)
    args = dict(
        scene=scene,
        normalizer=dm.normalizer.to_dict(),
        encoding="unwrapped",
        horizon=dm.split.horizon,
        history_len=dm.plan.history_len,
        encoder={**ENCODER, "noise_channels": noise_channels},
        hidden=8,
        decoder="direct",
        zero_mean=True,
        ar_prior=True,
        linear_ar=fit_on_training_frames(dm, 2).to_dict(),
        n_particles=meta.n_particles,
        graph_cutoff=dm.graph_cutoff,
        loss="crps" if noise_channels else "mse",
    )
    args.update(options)
    return TrajectoryModule(**args)


def perturb(model: TrajectoryModule, seed: int = 1) -> TrajectoryModule:
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.1 * torch.randn(p.shape, generator=gen))
    return model


@pytest.mark.parametrize("scene", ["pbc", "lebc"])
def test_untrained_members_are_constant_velocity(request, scene):
    dm = datamodule(request.getfixturevalue(f"tiny_{scene}_path"))
    model = module(dm).eval()
    assert model.is_ensemble
    for batch in dm.test_dataloader():
        with torch.no_grad():
            members = model.forward_members(batch, 3)
            positions = torch.stack([model.decode(m, batch) for m in members])
        observed = batch.input_positions.double().transpose(1, 2)
        cv = constant_velocity(
            observed, batch.input_offsets.double(), batch.target_offsets.double(), dm.meta.box
        )
        off = batch.target_offsets.double()[None, :, :, None]
        diff = minimum_image(
            positions - cv, dm.meta.box, off if dm.meta.boundary.is_lees_edwards else None
        )
        assert float(diff.abs().max()) < 1e-13 * float(dm.meta.box.lengths.max())


@pytest.mark.parametrize("scene", ["pbc", "lebc"])
def test_a_member_with_zero_noise_is_the_deterministic_network(request, scene):
    """The same weights without the noise path give the same output to round-off."""
    dm = datamodule(request.getfixturevalue(f"tiny_{scene}_path"))
    ensemble = perturb(module(dm)).eval()
    deterministic = module(dm, noise_channels=0).eval()
    missing, unexpected = deterministic.load_state_dict(ensemble.state_dict(), strict=False)
    assert missing == [] and all(k.startswith("encoder.noise_embedding") for k in unexpected)
    batch = next(iter(dm.test_dataloader()))
    b, n = batch.inputs.shape[:2]
    with torch.no_grad():
        quiet = ensemble(batch, noise=torch.zeros(b, n, 4))
        reference = deterministic(batch)
        noisy = ensemble(batch)
    assert reference.abs().max() > 1e-3  # the network is not trivially zero
    torch.testing.assert_close(quiet, reference, rtol=0, atol=1e-6 * float(reference.abs().max()))
    assert (noisy - reference).abs().max() > 1e-3  # the noise moves the member


def test_members_differ_and_the_seed_fixes_them(tiny_lebc_path):
    """Rolled out with members: each member differs from the others; one seed gives the same
    members again, another seed others."""
    dm = datamodule(tiny_lebc_path)
    model = perturb(module(dm)).eval()
    meta = read_meta(tiny_lebc_path)
    import h5py

    with h5py.File(tiny_lebc_path, "r") as h5:
        observed = np.asarray(h5["positions"][:1, :5], np.float64)
        times = np.asarray(h5["times"][:1, :5], np.float64)

    def members(seed):
        run = rollout(model, meta, observed, times, 6, members=3, seed=seed, check_overlap=False)
        assert run.members == 3 and run.predicted.shape[0] == 3
        return run.by_member(run.predicted)[0]

    first, again, other = members(7), members(7), members(8)
    np.testing.assert_array_equal(first, again)
    assert np.abs(first - other).max() > 1e-6 * meta.diameter  # round-off: ~1e-16 of the box
    assert np.abs(first[0] - first[1]).max() > 1e-6 * meta.diameter


def test_a_deterministic_model_has_no_ensemble(tiny_pbc_path):
    dm = datamodule(tiny_pbc_path)
    model = module(dm, noise_channels=0).eval()
    meta = read_meta(tiny_pbc_path)
    observed = np.zeros((1, 5, meta.n_particles, 3))
    with pytest.raises(ValueError, match="deterministic .* no ensemble"):
        rollout(model, meta, observed, np.zeros((1, 5)), 2, members=2)
    with pytest.raises(ValueError, match="takes no noise"):
        batch = next(iter(dm.test_dataloader()))
        model(batch, noise=torch.zeros(1))


def test_crps_loss_starts_at_one_and_needs_two_members(tiny_pbc_path):
    dm = datamodule(tiny_pbc_path)
    model = module(dm).train()
    batch = next(iter(dm.train_dataloader()))
    loss = model._loss(model.forward_members(batch, 2), batch)
    assert float(loss.detach()) == pytest.approx(1.0, abs=1e-6)  # untrained: every member is CV
    stepwise = module(dm, loss_weighting="step").train()
    loss = stepwise._loss(stepwise.forward_members(batch, 2), batch)
    assert float(loss.detach()) == pytest.approx(1.0, abs=1e-6)  # each step's CV error is 1
    paired = module(dm, pair_crps=0.5).train()
    loss = paired._loss(paired.forward_members(batch, 2), batch)
    assert float(loss.detach()) == pytest.approx(1.5, abs=1e-6)  # 1 + 0.5 x the pairs' 1
    with pytest.raises(ValueError, match="loss_weighting=step weighs the CRPS"):
        module(dm, noise_channels=0, loss_weighting="step")
    with pytest.raises(ValueError, match="at least 2 members"):
        module(dm, members=1)
    with pytest.raises(ValueError, match="model.loss must be one of"):
        module(dm, loss="energy")


@pytest.mark.numerics
def test_crps_training_learns_a_spread(tiny_lebc_path):
    """On one fixed window, CRPS training lowers the loss and opens the members' spread from
    the start's zero (a deterministic fit would keep it at zero)."""
    dm = datamodule(tiny_lebc_path)
    model = module(dm)
    batch = next(iter(dm.val_dataloader()))
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    losses = []
    for _ in range(150):
        opt.zero_grad()
        loss = model._loss(model.forward_members(batch, 2), batch)
        loss.backward()
        opt.step()
        losses.append(float(loss))
    with torch.no_grad():
        spread = model.forward_members(batch, 4).std(dim=0).mean()
    assert min(losses[-20:]) < 0.8 * losses[0]
    assert float(spread) > 1e-3


def test_the_scores_figure_of_an_ensemble_and_of_a_point_forecast(tmp_path, tiny_pbc_path):
    """Every run's scores figure: CRPS per step; an ensemble adds spread/skill and the rank
    histogram."""
    from gripdem.plots.common import save_figure
    from gripdem.plots.scores import plot_scores

    dm = datamodule(tiny_pbc_path)
    for noise, panels in ((4, 3), (0, 1)):
        model = perturb(module(dm, noise_channels=noise)).eval()
        for batch in dm.test_dataloader():
            with torch.no_grad():
                model._evaluate(batch, "test")
        data = model.results("test")
        scores = data["scores"]
        assert set(scores["crps_over_d"]) == {"model", *model.baselines}
        assert ("spread_skill" in scores) == (panels == 3)
        fig = plot_scores(scores, "title")
        assert len(fig.axes) == panels
        save_figure(fig, tmp_path / f"scores_{noise}.png")
        if noise:
            assert data["metrics"]["test/members"] == 8
            assert len(scores["rank_histogram"]) == 9
            assert sum(scores["rank_histogram"]) == pytest.approx(1.0)


@pytest.mark.parametrize("where", ["rounds", "input", "head"])
def test_the_noise_enters_where_asked(tiny_pbc_path, where):
    """One embedding per place; zero noise is the deterministic network wherever it enters."""
    dm = datamodule(tiny_pbc_path)
    encoder = {**ENCODER, "noise_into": where}
    model = perturb(module(dm, encoder=encoder | {"noise_channels": 4})).eval()
    assert len(model.encoder.noise_embedding) == {"rounds": 3, "input": 1, "head": 1}[where]
    batch = next(iter(dm.test_dataloader()))
    b, n = batch.inputs.shape[:2]
    with torch.no_grad():
        a, c = model(batch), model(batch)
        quiet = model(batch, noise=torch.zeros(b, n, 4))
    assert (a - c).abs().max() > 1e-4 and (a - quiet).abs().max() > 1e-4


def test_neighbour_shared_noise_keeps_the_zero_noise_network(tiny_lebc_path):
    """noise_neighbours: each particle's noise mixed with its neighbours' (unit variance); zero
    noise is still the deterministic network, and the members still differ."""
    dm = datamodule(tiny_lebc_path)
    encoder = {**ENCODER, "noise_channels": 4, "noise_neighbours": True}
    model = perturb(module(dm, encoder=encoder)).eval()
    batch = next(iter(dm.test_dataloader()))
    b, n = batch.inputs.shape[:2]
    with torch.no_grad():
        quiet = model(batch, noise=torch.zeros(b, n, 4))
        deterministic = module(dm, noise_channels=0).eval()
        deterministic.load_state_dict(model.state_dict(), strict=False)
        reference = deterministic(batch)
        a, c = model(batch), model(batch)
    torch.testing.assert_close(quiet, reference, rtol=0, atol=1e-6 * float(reference.abs().max()))
    assert (a - c).abs().max() > 1e-4
