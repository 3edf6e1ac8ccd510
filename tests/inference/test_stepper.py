"""The in-memory stepper predicts what the dataset path predicts, to round-off: a perturbed
model (every weight moved, so every layer matters) on the built-in DEM's tiny scenes, one link
and chained links, across LE crossings and neighbour-list rebuilds. The contact correction
removes overlaps without moving the centre of mass."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from stress_models import perturb, smoke_model

from gripdem.boundary import NeighbourList, minimum_image
from gripdem.data.batch import collate_windows
from gripdem.data.dataset import WindowDataset
from gripdem.data.windows import Segment, WindowIndex
from gripdem.inference.contacts import push_apart
from gripdem.inference.stepper import Stepper, StepperSettings

# a thin skin: the lists are rebuilt several times within the links compared
RAW = StepperSettings(contact_correction=False, skin=0.05)


class BufferReader:
    """Frames from memory with the file reader's interface."""

    def __init__(self, positions):
        self.positions = positions

    def read(self, sim, start, stop):
        return self.positions[sim, start:stop]

    def close(self):
        pass


def dataset_prediction(model, dm, positions, times, start):
    """The dataset path's prediction of the window starting at ``start`` of ``positions``
    ``(S, T, N, 3)`` (each simulation one window): a fresh graph search, the file encoding."""
    k, f = int(model.hparams.history_len), int(model.hparams.horizon)
    windows = WindowIndex([Segment(s, start, 1, 1) for s in range(len(positions))], k, f)
    ds = WindowDataset(
        BufferReader(positions),
        dm.meta,
        times,
        windows,
        model.encoding,
        model.normalizer,
        dm.graph_cutoff * dm.meta.diameter,
        graph_cache_mb=0.0,
    )
    batch = collate_windows([ds[i] for i in range(len(ds))])
    with torch.no_grad():
        return model.decode(model(batch), batch).numpy()


@pytest.mark.parametrize("scene", ["pbc", "lebc"])
def test_stepper_links_equal_the_dataset_path(request, scene):
    path = request.getfixturevalue(f"tiny_{scene}_path")
    model, dm = smoke_model(path, f"scene={scene}")
    perturb(model, scale=0.02)
    k, f = int(model.hparams.history_len), int(model.hparams.horizon)
    reader = dm.datasets["test"].reader
    sims = list(dm.plan.test.sims)
    times = dm._times[sims]
    frames = np.stack([reader.read(s, 0, dm.meta.n_frames) for s in sims])
    stepper = Stepper(model, frames[:, : k + 1], times[:, : k + 1], RAW)
    links = 4
    predicted = stepper.advance(links * f)
    # the reference: each link's window rebuilt from the frames predicted before it
    buffer = np.concatenate([frames[:, : k + 1], predicted], axis=1)
    ext_times = times[:, :1] + dm.meta.frame_interval * np.arange(buffer.shape[1])[None]
    box = dm.meta.box
    offsets = dm.meta.boundary.offset(ext_times)
    for link in range(links):
        want = dataset_prediction(model, dm, buffer, ext_times, link * f)
        got = predicted[:, link * f : (link + 1) * f]
        diff = minimum_image(
            got - want, box, offsets[:, k + 1 + link * f : k + 1 + (link + 1) * f, None]
        )
        assert np.abs(diff).max() < 1e-9 * dm.meta.diameter, link
    assert np.abs(predicted[:, -1] - frames[:, k + links * f]).max() > 0.01 * dm.meta.diameter
    assert sum(nl.builds for nl in stepper.lists) > len(sims)  # lists were rebuilt on the way
    if scene == "lebc":
        moves = np.abs(np.diff(buffer[..., 0], axis=1))
        assert (moves > 0.5 * box.lx).sum() > 0  # particles crossed the LE faces


def test_contact_correction_pushes_overlapping_pairs_apart():
    """A jittered simple-cubic lattice of spacing 1 in a box of 1.05 per particle (many
    neighbours overlap; a solution exists): after the correction
    no pair is closer than the contact distance (to the tolerance) and the centre of mass has not
    moved."""
    from gripdem.boundary import Box, brute_force_pairs

    rng = np.random.default_rng(3)
    box = Box(8.4, 7.35, 9.45)
    grid = np.stack(np.meshgrid(*(np.arange(k) for k in (8, 7, 9)), indexing="ij"), -1)
    q = (grid.reshape(-1, 3) + 0.5) * 1.05 - 0.5 * box.lengths
    q = q + rng.normal(0.0, 0.04, q.shape)
    nl = NeighbourList(box, 1.0, 0.3, image_velocity=0.0)
    nl.build(q, 0.0, 0.0)
    before = nl.q.copy()
    corr = push_apart(nl, 0.0, 1.0, sweeps=200, tolerance=1e-6)
    assert corr.overlapping_before > 50 and corr.overlapping_after == 0
    _, _, vec = brute_force_pairs(nl.q, box, 0.0, 1.0)
    assert np.linalg.norm(vec, axis=1).min() > 1.0 - 1e-5
    np.testing.assert_allclose(nl.q.mean(axis=0), before.mean(axis=0), atol=1e-12)
    assert 0 < corr.rms_push < 0.1


def test_the_candidate_margin_changes_the_correction_only_where_pushes_exceed_it(monkeypatch):
    """The candidate margin is a speed setting: where no particle is pushed more than half of
    it within a sweep (the model's frames: pushes of ~1e-4 d), a pair outside it cannot touch
    before it is chosen, so the corrected positions are the same bit for bit at any margin;
    where pushes exceed it, candidates are chosen again between sweeps and the result is
    another correction to the same tolerance."""
    from gripdem.boundary import Box, brute_force_pairs
    from gripdem.inference import contacts

    grid = np.stack(np.meshgrid(*(np.arange(k) for k in (8, 7, 9)), indexing="ij"), -1)

    def corrected(spacing, jitter, margin):
        box = Box(8 * spacing, 7 * spacing, 9 * spacing)
        q = (grid.reshape(-1, 3) + 0.5) * spacing - 0.5 * box.lengths
        q = q + np.random.default_rng(5).normal(0.0, jitter, q.shape)
        monkeypatch.setattr(contacts, "CANDIDATE_MARGIN", margin)
        nl = NeighbourList(box, 1.0, 0.3, image_velocity=0.0)
        nl.build(q, 0.0, 0.0)
        corr = push_apart(nl, 0.0, 1.0, sweeps=500, tolerance=1e-6)
        assert corr.overlapping_before > 50 and corr.overlapping_after == 0
        _, _, vec = brute_force_pairs(nl.q, box, 0.0, 1.0)
        assert np.linalg.norm(vec, axis=1).min() >= 1.0 - 1e-6 * (1 + 1e-9)
        return nl.q, np.abs(corr.moves).max()

    small = {m: corrected(1.0005, 0.0005, m) for m in (1.01, 1.05, 1.2)}
    assert max(move for _, move in small.values()) < 0.5 * 0.01
    for margin, (positions, _) in small.items():
        np.testing.assert_array_equal(positions, small[1.05][0], err_msg=f"margin {margin}")
    large = {m: corrected(1.05, 0.05, m) for m in (1.001, 1.05)}  # both corrected (asserted)
    assert not np.array_equal(large[1.001][0], large[1.05][0])


@pytest.mark.parametrize("tolerance", [1e-4, 1e-3])
def test_a_looser_correction_tolerance_leaves_only_overlaps_below_it(tolerance):
    """The same jittered lattice: no pair closer than the contact distance by more than the
    tolerance, the centre of mass in place, and a looser tolerance never takes more sweeps."""
    from gripdem.boundary import Box, brute_force_pairs

    rng = np.random.default_rng(3)
    box = Box(8.4, 7.35, 9.45)
    grid = np.stack(np.meshgrid(*(np.arange(k) for k in (8, 7, 9)), indexing="ij"), -1)
    q = (grid.reshape(-1, 3) + 0.5) * 1.05 - 0.5 * box.lengths + rng.normal(0.0, 0.04, (504, 3))
    sweeps = {}
    for tol in (tolerance, 1e-6):
        nl = NeighbourList(box, 1.0, 0.3, image_velocity=0.0)
        nl.build(q, 0.0, 0.0)
        corr = push_apart(nl, 0.0, 1.0, sweeps=200, tolerance=tol)
        assert corr.overlapping_after == 0 and corr.worst_after <= tol
        _, _, vec = brute_force_pairs(nl.q, box, 0.0, 1.0)
        assert np.linalg.norm(vec, axis=1).min() >= 1.0 - tol * (1 + 1e-9)
        np.testing.assert_allclose(nl.q.mean(axis=0), q.mean(axis=0), atol=1e-12)
        sweeps[tol] = corr.sweeps
    assert sweeps[tolerance] <= sweeps[1e-6]


def test_the_stepper_corrects_to_its_tolerance(tiny_pbc_path):
    """A perturbed model's frames overlap: the default tolerance (1e-4 contact distances)
    counts and pushes those pairs, a tolerance of half a diameter counts none of them."""
    assert StepperSettings().correction_tolerance == 1e-4
    model, dm = smoke_model(tiny_pbc_path, "scene=pbc")
    perturb(model, scale=0.05)
    k = int(model.hparams.history_len)
    sims = list(dm.plan.test.sims)
    frames = np.stack([dm.datasets["test"].reader.read(s, 0, k + 1) for s in sims])
    times = dm._times[sims][:, : k + 1]
    counted = {}
    for tolerance in (1e-4, 0.5):
        stepper = Stepper(model, frames, times, StepperSettings(correction_tolerance=tolerance))
        stepper.advance(5)
        assert stepper.settings.to_dict()["correction_tolerance"] == tolerance
        counted[tolerance] = sum(stepper.report.overlapping_before)
    assert counted[1e-4] > 0 and counted[0.5] == 0, counted


def test_bf16_stepper_runs_a_copy_close_to_fp32(tiny_pbc_path):
    """precision bf16 (native or emulated) predicts within a stated tolerance of fp32 on the
    same state, and leaves the caller's model in fp32; auto follows the CPU's bf16 units."""
    import warnings

    from gripdem.inference.precision import bf16_supported, resolve_precision

    model, dm = smoke_model(tiny_pbc_path, "scene=pbc")
    perturb(model, scale=0.02)
    k = int(model.hparams.history_len)
    sims = list(dm.plan.test.sims)
    reader = dm.datasets["test"].reader
    frames = np.stack([reader.read(s, 0, k + 1) for s in sims])
    times = dm._times[sims][:, : k + 1]
    reference = Stepper(model, frames, times, RAW).advance(5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # emulated bf16 where the CPU has no bf16 units
        stepper = Stepper(
            model, frames, times, StepperSettings(**{**RAW.__dict__, "precision": "bf16"})
        )
    half = stepper.advance(5)
    assert stepper.precision == "bf16"
    assert next(model.encoder.parameters()).dtype == torch.float32
    assert next(stepper.model.encoder.parameters()).dtype == torch.bfloat16
    box = dm.meta.box
    moved = np.abs(minimum_image(reference - frames[:, -1:], box)).max()
    deviation = np.abs(minimum_image(half - reference, box)).max()
    # bf16 rounds the encoder's latents to 2^-9 relative; the AR prior and decoding stay fp64
    # (measured 7e-6 of the motion under every ATEN_CPU_CAPABILITY, 1 and 2 threads)
    assert 0 < deviation < 1e-3 * moved
    assert resolve_precision("auto") == ("bf16" if bf16_supported() else "fp32")
    with pytest.raises(ValueError, match="precision must be one of"):
        Stepper(model, frames, times, StepperSettings(precision="fp16"))
