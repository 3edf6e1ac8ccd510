"""The run figures are drawn from the figure data of a predictions file, written as non-trivial
PNGs and logged to TensorBoard; a synthetic sheared packing stands in for a DEM scene."""

import numpy as np
import pytest
import torch
from matplotlib.image import imread

from gripdem.boundary import Boundary, Box, LeesEdwards, rewrap_trajectory
from gripdem.evaluation.figure_data import pick_crossers, rmse_curves, run_figure_data
from gripdem.evaluation.predictions import Predictions, read_predictions, write_predictions
from gripdem.models.baselines import predict_baseline
from gripdem.plots import figure_to_array
from gripdem.plots.run import FIGURES, make_run_figures, plot_rmse_per_step

D = 2.5e-6  # diameter (m), as the default scenes
DT = 5e-6


def sheared_scene(le=True, windows=2, n_in=4, horizon=12, seed=0):
    """Jittered lattice (spacing 1.15 d, one plane on the x faces so particles cross them) in
    an 8 x 6 x 7 (x 1.15) d box, affine flow plus a random walk
    in lattice-continuous coordinates, wrapped at each frame's LE offset. The prediction is the
    truth plus noise growing along the horizon."""
    rng = np.random.default_rng(seed)
    box = Box(8 * 1.15 * D, 6 * 1.15 * D, 7 * 1.15 * D)
    rate = 1000.0
    boundary = Boundary(box, LeesEdwards(rate, 1, 0.0) if le else None)
    grid = np.stack(np.meshgrid(*(np.arange(k) for k in (8, 6, 7)), indexing="ij"), -1)
    lattice = grid.reshape(-1, 3) * 1.15 * D - 0.5 * box.lengths  # a plane on the x faces
    n, frames = len(lattice), n_in + horizon
    out = []
    for _ in range(windows):
        pos = np.empty((frames, n, 3))
        pos[0] = lattice + rng.normal(0, 0.03 * D, lattice.shape)
        for t in range(1, frames):
            step = rng.normal(0, 0.04 * D, (n, 3))
            if le:
                step[:, 2] += rate * pos[t - 1, :, 0] * DT
            else:
                step[:, 2] += 0.05 * D * np.cos(2 * np.pi * pos[t - 1, :, 0] / box.lx)
            pos[t] = pos[t - 1] + step
        out.append(pos)
    continuous = np.stack(out)
    times = 1.1e-3 + DT * (np.arange(frames)[None] + 40 * np.arange(windows)[:, None])
    offsets = boundary.offset(times)
    wrapped = np.stack(
        [rewrap_trajectory(c, box, o) for c, o in zip(continuous, offsets, strict=True)]
    )
    observed, target = wrapped[:, :n_in], wrapped[:, n_in:]
    growth = np.sqrt(np.arange(1, horizon + 1))[None, :, None, None]
    noisy = target + rng.normal(0, 0.02 * D, target.shape) * growth
    pred = rewrap_trajectory(noisy.reshape(-1, n, 3), box, offsets[:, n_in:].reshape(-1)).reshape(
        target.shape
    )
    args = (
        torch.tensor(observed),
        torch.tensor(offsets[:, :n_in]),
        torch.tensor(offsets[:, n_in:]),
        box,
        "linear" if le else "cosine",
    )
    baselines = {
        name: predict_baseline(name, *args).numpy()
        for name in ("stay", "constant_velocity", "mean_flow")
    }
    return Predictions(
        pred_positions=pred.astype(np.float32),
        true_positions=target,
        last_positions=observed[:, -1],
        times=times[:, n_in:],
        boundary=boundary,
        radius=D / 2,
        baselines=baselines,
        info={
            "scene": "lebc" if le else "pbc",
            "split": f"{n_in - 1}-{horizon}",
            "model": "pct",
            "split_name": "test",
        },
    )


@pytest.mark.parametrize("le", [True, False])
def test_figures_are_written_as_readable_pngs_and_logged(tmp_path, le):
    p = sheared_scene(le=le)
    path = write_predictions(tmp_path / "predictions.h5", p)

    class Writer:
        def __init__(self):
            self.images = {}

        def add_image(self, tag, image, step, dataformats):
            assert dataformats == "HWC" and image.dtype == np.uint8
            self.images[tag] = image.shape

    writer = Writer()
    data = run_figure_data(read_predictions(path))
    paths = make_run_figures(data, tmp_path / "figures", writer=writer, step=3)
    assert tuple(paths) == FIGURES
    for name, png in paths.items():
        assert png.exists() and png.stat().st_size > 20_000, name
        image = imread(png)
        assert image.shape[0] > 300 and image.shape[1] > 500
        assert image[..., :3].std() > 0.05  # not a blank canvas
        assert writer.images[f"figures/{name}"] == image.shape[:2] + (3,)
    assert sorted(p.name for p in (tmp_path / "figures").iterdir()) == sorted(
        f"{name}.png" for name in FIGURES
    )


def test_figures_go_into_a_real_tensorboard_event_file(tmp_path):
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(tmp_path / "tb")
    data = run_figure_data(sheared_scene(windows=1, horizon=4))
    make_run_figures(data, tmp_path / "f", writer=writer)
    writer.close()
    events = list((tmp_path / "tb").glob("events.out.tfevents*"))
    assert events and events[0].stat().st_size > 50_000


def test_crossers_are_chosen_from_the_truth():
    shifts = np.zeros((2, 6, 5, 3))
    shifts[1, 4, 3, 0] = -1  # window 1, particle 3 crosses +x at step 4
    shifts[0, 2, 1, 0] = 1  # window 0, particle 1 crosses -x at step 2 (nearer the middle)
    shifts[0, 1, 2, 2] = 1  # a z crossing
    assert pick_crossers(shifts, 0, 5) == [(0, 1), (1, 3)]
    assert pick_crossers(shifts, 2, 5) == [(0, 2)]
    assert pick_crossers(np.zeros_like(shifts), 0, 5) == []


def test_figure_to_array_is_rgb():
    curves = rmse_curves(sheared_scene(windows=1, horizon=3))
    image = figure_to_array(plot_rmse_per_step(curves, "title", 3))
    assert image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8
