"""The hybrid surrogate (gripdem/inference/relaxation.py): the built-in DEM integrates the last
time steps of every predicted frame, on the tiny DEM scenes, in both boundaries."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from gripdem.boundary import displacement
from gripdem.data.dataset_io import read_meta
from gripdem.dem.config import GeneratorConfig
from gripdem.inference.checkpoint import load_model
from gripdem.inference.relaxation import DemRelaxation
from gripdem.inference.rollout import rollout
from gripdem.inference.stepper import StepperSettings


def generator_config(path) -> GeneratorConfig:
    with h5py.File(path, "r") as h5:
        params = json.loads(h5.attrs["provenance"])["parameters"]
    return GeneratorConfig.from_mappings(params["scene"], params["preset"], sims=1)


@pytest.mark.parametrize("scene", ["pbc", "lebc"])
def test_the_dem_finishes_every_predicted_frame(request, tmp_path, make_checkpoint, scene):
    """An untrained model is constant velocity; the DEM's last 30 steps of each frame move it
    towards the truth (the DEM's own trajectory from the same state) and leave no overlap."""
    path = request.getfixturevalue(f"tiny_{scene}_path")
    checkpoint = make_checkpoint(path, tmp_path, [f"scene={scene}"])
    meta = read_meta(path)
    model = load_model(checkpoint, meta)
    k = int(model.hparams.history_len)
    with h5py.File(path, "r") as h5:
        frames = np.asarray(h5["positions"][:1, : k + 4], np.float64)
        times = np.asarray(h5["times"][:1, : k + 4], np.float64)
    relax = DemRelaxation(generator_config(path), steps=30)
    settings = StepperSettings(contact_correction=False, relaxation=relax)
    hybrid = rollout(model, meta, frames[:, : k + 1], times[:, : k + 1], 3, settings)
    plain = rollout(
        model,
        meta,
        frames[:, : k + 1],
        times[:, : k + 1],
        3,
        StepperSettings(contact_correction=False),
    )
    assert hybrid.stepper.seconds["relaxation"] > 0
    assert "last 30 time steps" in hybrid.stepper.settings.to_dict()["relaxation"]
    offsets = meta.boundary.offset(times[0, k + 1 :])[:, None]
    moved = displacement(hybrid.predicted[0], plain.predicted[0], meta.box, offsets)
    to_truth = displacement(frames[0, k + 1 :], plain.predicted[0], meta.box, offsets)
    assert np.abs(moved).max() > 0  # the DEM did something
    assert np.abs(moved).max() < 0.05 * meta.diameter  # a correction, not a new frame
    assert np.linalg.norm(moved - to_truth) < np.linalg.norm(to_truth)  # towards the truth
    assert relax.max_overlap < 0.01


def test_a_relaxation_needs_steps(tiny_pbc_path):
    with pytest.raises(ValueError, match="at least 1 step"):
        DemRelaxation(generator_config(tiny_pbc_path), steps=0)
