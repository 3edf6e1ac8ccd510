"""Contact capture (``contact_capture``): the contact correction pulls pairs closer than a small
gap into contact, pairwise, never leaving an overlap and never moving the centre of mass; moved
pairs end at the data's resting overlap; the stepper takes the model's own value unless told;
an ensemble's noise is inflated outside training only; bad values are refused in one line."""

from __future__ import annotations

import json
import shutil

import h5py
import numpy as np
import pytest
import torch
from stress_models import perturb, smoke_model

from gripdem.boundary import Box, NeighbourList, brute_force_pairs
from gripdem.inference.contacts import push_apart, resting_overlap
from gripdem.inference.stepper import Stepper, StepperSettings
from gripdem.predict import main

CAPTURE = 0.002


def corrected_lattice(seed: int = 3) -> tuple[Box, np.ndarray]:
    """A jittered simple-cubic lattice (spacing 1.05, jitter 0.04) after a full correction: many
    pairs touch at exactly the contact distance 1."""
    rng = np.random.default_rng(seed)
    box = Box(8.4, 7.35, 9.45)
    grid = np.stack(np.meshgrid(*(np.arange(k) for k in (8, 7, 9)), indexing="ij"), -1)
    q = (grid.reshape(-1, 3) + 0.5) * 1.05 - 0.5 * box.lengths + rng.normal(0.0, 0.04, (504, 3))
    nl = NeighbourList(box, 1.0, 0.3)
    nl.build(q, 0.0, 0.0)
    push_apart(nl, 0.0, 1.0, sweeps=500, tolerance=1e-9)
    return box, nl.q.copy()


def touching(box: Box, q: np.ndarray, gap: float = 1e-3) -> int:
    """Pairs closer than ``1 + gap`` (brute force lists each pair both ways)."""
    _, _, vec = brute_force_pairs(q, box, 0.0, 1.0 + gap)
    return len(vec) // 2


def corrected(box, q, **options):
    nl = NeighbourList(box, 1.0, 0.3)
    nl.build(q, 0.0, 0.0)
    corr = push_apart(nl, 0.0, 1.0, sweeps=200, tolerance=1e-6, **options)
    return corr, nl.q.copy()


def test_captured_pairs_close_without_overlap_and_the_centre_of_mass_stays():
    """A touching configuration moved by 0.001 per axis: with capture, more pairs touch after
    the correction than without, none overlaps beyond the tolerance, and every move is pairwise
    (the centre of mass to round-off)."""
    box, previous = corrected_lattice()
    q = previous + np.random.default_rng(4).normal(0.0, 0.001, previous.shape)
    plain, plain_q = corrected(box, q)
    held, held_q = corrected(box, q, capture=CAPTURE)
    assert plain.pulled == 0 and held.pulled > 100
    assert held.overlapping_after == 0 and held.worst_after <= 1e-6
    assert held.worst_after <= held.worst_before
    _, _, vec = brute_force_pairs(held_q, box, 0.0, 1.0)
    assert np.linalg.norm(vec, axis=1).min() >= 1.0 - 1e-6 * (1 + 1e-9)
    np.testing.assert_allclose(held_q.mean(axis=0), q.mean(axis=0), atol=1e-12)
    assert touching(box, held_q) > 1.1 * touching(box, plain_q), (
        touching(box, held_q),
        touching(box, plain_q),
    )


def test_a_pair_beyond_the_capture_gap_stays_open_and_moved_pairs_end_at_the_overlap():
    """Three pairs far apart at gaps 0.0015, 0.005 and -0.01 (overlapping): the first is
    captured and the third pushed, both to 3e-5 inside contact; the second keeps its gap."""
    box = Box(12.0, 12.0, 12.0)
    q = []
    for row, gap in enumerate([0.0015, 0.005, -0.01]):
        centre = np.array([-4.0 + 4.0 * row, 0.0, 0.0])
        q += [centre, centre + [0.0, 0.0, 1.0 + gap]]
    q = np.array(q)
    nl = NeighbourList(box, 1.0, 0.3)
    nl.build(q, 0.0, 0.0)
    corr = push_apart(nl, 0.0, 1.0, tolerance=1e-4, capture=CAPTURE, overlap=3e-5)
    after = np.linalg.norm(nl.q[1::2] - nl.q[0::2], axis=1) - 1.0
    np.testing.assert_allclose(after, [-3e-5, 0.005, -3e-5], atol=1e-12)
    assert corr.pulled == 1 and corr.overlapping_before == 1 and corr.overlapping_after == 0
    np.testing.assert_allclose(nl.q.mean(axis=0), q.mean(axis=0), atol=1e-12)
    assert resting_overlap(nl, 0.0, 1.0, 1e-4) == pytest.approx(3e-5, abs=1e-12)
    assert resting_overlap(nl, 0.0, 1.0, 1e-5) == 0.0  # no pair rests within that


def test_the_stepper_captures_with_the_models_own_value_unless_told(tiny_pbc_path):
    """``StepperSettings.contact_capture`` None: the model's hyperparameter; a value given wins;
    off without the correction; a capturing rollout pulls pairs; ``contact_overlap`` None
    measures the observed frame's resting contacts (the built-in DEM's: 1e-6-1e-4 d)."""
    model, dm = smoke_model(tiny_pbc_path, "scene=pbc", "model.contact_capture=0.002")
    perturb(model, scale=0.01)
    k = int(model.hparams.history_len)
    sims = list(dm.plan.test.sims)
    frames = np.stack([dm.datasets["test"].reader.read(s, 0, k + 1) for s in sims])
    times = dm._times[sims][:, : k + 1]
    own = Stepper(model, frames, times)
    off = Stepper(model, frames, times, StepperSettings(contact_capture=0.0, contact_overlap=0.0))
    raw = Stepper(model, frames, times, StepperSettings(contact_correction=False))
    assert (own.capture, off.capture, raw.capture) == (0.002, 0.0, 0.0)
    assert 1e-6 < own.overlap < 1e-4 and off.overlap == 0.0
    own.advance(6)
    off.advance(6)
    assert sum(own.report.pulled) > 0 and sum(off.report.pulled) == 0


def test_the_noise_scale_inflates_members_outside_training_only(tiny_pbc_path):
    model, _ = smoke_model(tiny_pbc_path, "scene=pbc", "model=ensemble", "model.noise_scale=2")
    model.noise_generator = torch.Generator().manual_seed(0)
    model.train()
    trained = model.sample_noise(1, 50)
    model.noise_generator = torch.Generator().manual_seed(0)
    model.eval()
    torch.testing.assert_close(model.sample_noise(1, 50), 2.0 * trained)


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"contact_capture": 0.5}, r"contact_capture is a gap in contact distances in \[0, 0.1\]"),
        ({"contact_capture": -1e-3}, r"contact_capture is a gap in contact distances"),
        ({"contact_capture": 0.002, "contact_correction": False}, "needs contact_correction on"),
        ({"contact_overlap": 1e-3}, r"contact_overlap .* in \[0, correction_tolerance = 0.0001\)"),
    ],
)
def test_bad_capture_settings_are_refused(settings, message):
    with pytest.raises(ValueError, match=message):
        StepperSettings(**settings)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("model.contact_capture=0.3", "model.contact_capture is a gap in contact distances"),
        ("model.noise_scale=0", "model.noise_scale scales the members' latent noise"),
    ],
)
def test_bad_rollout_hyperparameters_are_refused(tiny_pbc_path, override, message):
    with pytest.raises(ValueError, match=message):
        smoke_model(tiny_pbc_path, "scene=pbc", override)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (("--contact-capture", "0.5"), "--contact-capture must lie in [0, 0.1] contact distances"),
        (("--contact-capture", "nan"), "--contact-capture must lie in [0, 0.1] contact distances"),
        (("--contact-capture", "0.002", "--no-correction"), "drop --no-correction"),
        (("--noise-scale", "0"), "--noise-scale must be a positive number, got 0.0"),
    ],
)
def test_bad_capture_options_are_refused_in_one_line(tmp_path, capsys, extra, message):
    with pytest.raises(SystemExit) as stop:
        main(["pretrained:pbc", str(tmp_path / "d.h5"), *extra])
    assert stop.value.code == 2
    assert message in capsys.readouterr().err.strip().splitlines()[-1]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("provenance", "message"),
    [
        (None, "does not record its contact law"),
        ({"parameters": {"scene": {"hamaker": 0.0}}}, "scene has no cohesion (hamaker = 0.0)"),
    ],
)
def test_capturing_contacts_of_a_scene_without_known_cohesion_is_refused(
    tmp_path, capsys, le_file, le_checkpoint, provenance, message
):
    """Capture stands in for the DEM's cohesion: a file whose contact law is unknown (not made
    by the built-in DEM) or not cohesive is refused, naming the file; nothing is written."""
    data = tmp_path / "data.h5"
    shutil.copy(le_file, data)
    if provenance is not None:
        with h5py.File(data, "r+") as h5:
            h5.attrs["provenance"] = json.dumps(provenance)
    out = tmp_path / "out" / "pred.h5"
    out.parent.mkdir()
    argv = [str(le_checkpoint), str(data), "--out", str(out), "--contact-capture", "0.002"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert message in err and str(data) in err
    assert list(out.parent.iterdir()) == []


def test_a_noise_scale_for_a_deterministic_model_is_refused(
    tmp_path, capsys, le_file, le_checkpoint
):
    out = tmp_path / "pred.h5"
    argv = [str(le_checkpoint), str(le_file), "--out", str(out), "--noise-scale", "1.3"]
    assert main(argv) == 1
    assert "is a deterministic model (no latent noise to scale)" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_capturing_members_differ_and_the_same_seed_gives_the_same_members(tiny_pbc_path):
    """A (perturbed) ensemble with its own capture and inflation, 3 members: the members
    differ from each other, the same seed gives them again to the last bit, another seed
    does not."""
    from gripdem.inference.rollout import rollout

    model, dm = smoke_model(tiny_pbc_path, "scene=pbc", "model=ensemble")
    assert model.hparams.contact_capture > 0 and model.hparams.noise_scale > 1
    perturb(model, scale=0.02)
    k = int(model.hparams.history_len)
    sim = dm.plan.test.sims[0]
    observed = dm.datasets["test"].reader.read(sim, 0, k + 1)[None]
    times = dm._times[[sim]][:, : k + 1]

    def members(seed):
        run = rollout(model, dm.meta, observed, times, 6, check_overlap=False, members=3, seed=seed)
        assert sum(run.stepper.report.pulled) > 0
        return run.predicted

    first = members(7)
    np.testing.assert_array_equal(first, members(7))
    assert np.abs(first[0] - first[1]).max() > 0 and np.abs(first[1] - first[2]).max() > 0
    assert np.abs(first - members(8)).max() > 0
