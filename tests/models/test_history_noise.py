"""Random-walk noise on the training history: the last observed position is off by the chosen
std, everything the model reads is recomputed from the noisy frames (the graph's pair vectors
equal the minimum images of the noisy positions), and the targets stay the truth."""

from __future__ import annotations

import numpy as np
import torch
from stress_models import smoke_model

from gripdem.boundary import minimum_image
from gripdem.data.batch import collate_windows
from gripdem.models.history_noise import noisy_history


def test_noisy_history_is_consistent(tiny_lebc_path):
    model, dm = smoke_model(tiny_lebc_path, "scene=lebc")
    batch = collate_windows([dm.datasets["train"][i] for i in range(3)])
    d = dm.meta.diameter
    g = torch.Generator().manual_seed(0)
    noisy = noisy_history(batch, 1e-2, d, model.boundary, model.normalizer, generator=g)
    moved = (noisy.input_positions - batch.input_positions) / d
    assert moved[:, :, 0].abs().max() == 0  # the first observed frame is kept
    std = float(moved[:, :, -1].std())
    assert 0.8e-2 < std < 1.2e-2
    assert torch.equal(noisy.target_positions, batch.target_positions)
    last = noisy.input_positions[:, :, -1].reshape(-1, 3).numpy()
    i, j = noisy.edge_index.numpy()
    keep = i != j
    offset = batch.input_offsets[:, -1].repeat_interleave(batch.n_particles).numpy()
    want = minimum_image(last[j[keep]] - last[i[keep]], dm.meta.box, offset[i[keep]]) / d
    np.testing.assert_allclose(noisy.edge_vector.numpy()[keep], want, atol=1e-5)
    np.testing.assert_allclose(
        noisy.edge_gap.numpy()[keep], np.linalg.norm(want, axis=1) - 1.0, atol=1e-5
    )
    steps = model.normalizer.denormalize(noisy.inputs.double())
    assert not torch.allclose(noisy.inputs, batch.inputs)
    assert torch.isfinite(steps).all()


def test_zero_noise_changes_nothing_that_the_model_reads(tiny_pbc_path):
    model, dm = smoke_model(tiny_pbc_path, "scene=pbc")
    batch = collate_windows([dm.datasets["train"][0]])
    same = noisy_history(batch, 0.0, dm.meta.diameter, model.boundary, model.normalizer)
    with torch.no_grad():
        np.testing.assert_allclose(model(same).numpy(), model(batch).numpy(), atol=1e-5)
