"""Numerical-stability stress suite, fast cases (1/2): DEM time steps, particles exactly on the
faces, LE offsets and DEM restarts at very late absolute times, sin/cos pairs far off the unit
circle. The slow cases run in ``experiments/benchmarks/robustness/stress.py``.

Every test's docstring says what was tried and what must hold. Real components throughout: the
built-in DEM, real HDF5 files, models built by :mod:`gripdem.runner.experiment`. Models that are
not trained are either untrained (an exact-frame model is then constant velocity,
docs/spec/model.md#exact-frame) or "perturbed" (``tests/support/stress_models.py``).
"""

from __future__ import annotations

import h5py
import numpy as np
import pytest
import torch
import yaml
from stress_models import (
    CONF,
    DT,
    D,
    collate_all,
    generator_config,
    inside,
    perturb,
    predict_windows,
    rmse_over_d,
    smoke_model,
)

from gripdem.boundary import Boundary, Box, LeesEdwards, minimum_image, wrap_positions
from gripdem.data.batch import collate_windows
from gripdem.data.dataset_io import write_dataset
from gripdem.data.schema import TrajectoryData
from gripdem.dem.config import GeneratorConfig
from gripdem.dem.engine import Simulation
from gripdem.dem.scenes import simulate_one
from gripdem.models.baselines import constant_velocity


# --------------------------------------------------------------------------------------------
# a DEM time step too large for the contact stiffness
# --------------------------------------------------------------------------------------------
def test_dem_time_step_too_large_is_refused_naming_the_option():
    """Tried: DEM steps of 5 per contact time (the explicit step diverges near 2-3), a drag and
    a lubrication (5 nm regularisation gap) whose damping time is shorter than twice the step.
    Held: each configuration is refused when it is built, naming the option that sets the step
    and the coefficient that makes it too large; the default scenes are accepted."""
    for scene in ("pbc", "lebc"):
        cfg = generator_config(scene)
        assert cfg.contact_time / cfg.dt > 30
    with pytest.raises(ValueError, match=r"contact stiffness.*preset\.steps_per_contact \(now 5\)"):
        generator_config("lebc", steps_per_contact=5)
    with pytest.raises(ValueError, match=r"scene\.fluid_viscosity"):
        generator_config("pbc", fluid_viscosity=0.05)
    with pytest.raises(ValueError, match=r"scene\.lubrication_viscosity"):
        generator_config("lebc", lubrication_viscosity=1e-3, lubrication_min_gap_d=0.002)
    generator_config("lebc", lubrication_viscosity=1e-3)  # the documented 0.02 d gap is fine


def test_dem_divergence_is_detected_when_the_refusal_is_bypassed():
    """Tried: the tiny LE scene at 2 steps per contact time with the refusal switched off.
    The state stays finite (drag bounds the speeds), so a NaN check alone would miss it.
    Held: the run stops in the first spin-up frame with an error naming the overlap and
    preset.steps_per_contact."""

    class Unchecked(GeneratorConfig):
        def check_time_step(self) -> None:
            pass

    s = yaml.safe_load((CONF / "scene" / "lebc.yaml").read_text())
    p = yaml.safe_load((CONF / "preset" / "tiny.yaml").read_text())
    p.update(frames=3, spinup_time=2e-5, steps_per_contact=2)
    config = Unchecked.from_mappings(s, p, sims=1)
    with pytest.raises(FloatingPointError, match=r"spin-up frame 1 .*steps_per_contact"):
        simulate_one(config, np.random.default_rng(0))


# --------------------------------------------------------------------------------------------
# particles exactly on faces
# --------------------------------------------------------------------------------------------
def on_face_data(lees_edwards: bool, n_sims: int = 3, k: int = 3, f: int = 4) -> TrajectoryData:
    """Random walkers plus 8 particles that sit exactly on faces, edges and corners at the last
    observed frame ``k`` (one of them stored as exactly +l/2) and move at constant velocity in
    lattice-continuous coordinates, in and out through those faces."""
    box = Box(8 * D, 7 * D, 9 * D)
    le = LeesEdwards(1e4, time_origin=0.3e-3) if lees_edwards else None
    boundary = Boundary(box, le)
    rng = np.random.default_rng(3)
    frames = k + 1 + f
    times = 1.1e-3 + DT * (np.arange(frames)[None, :] + 3 * frames * np.arange(n_sims)[:, None])
    half = 0.5 * box.lengths
    faces = np.array(
        [
            [-half[0], 0.1 * D, 0.2 * D],
            [-half[0], -half[1], -half[2]],
            [np.nextafter(half[0], 0), 0.0, 0.0],
            [0.0, -half[1], 0.3 * D],
            [0.1 * D, 0.2 * D, -half[2]],
            [-half[0], np.nextafter(half[1], 0), np.nextafter(half[2], 0)],
            [half[0], 0.4 * D, -0.1 * D],  # +l/2: stored so (same point as -l/2)
            [-half[0], -half[1], 0.0],
        ]
    )
    velocity = (
        0.05
        * D
        * np.array(
            [
                [1, 0, 0],
                [-1, -1, -1],
                [1, 0, 0],
                [0, -1, 0],
                [0, 0, -1],
                [-1, 1, 1],
                [1, 0, 1],
                [-1, 0, 1],
            ]
        )
    )
    positions = np.empty((n_sims, frames, 8 + 24, 3))
    steps = (np.arange(frames) - k)[:, None, None]
    for s in range(n_sims):
        offsets = boundary.offset(times[s])
        face_cont = faces[None] + steps * velocity[None]
        walk = np.cumsum(rng.normal(0, 0.05 * D, (frames, 24, 3)), axis=0)
        walk += (rng.random((1, 24, 3)) - 0.5) * box.lengths
        cont = np.concatenate([face_cont, walk], axis=1)
        positions[s] = wrap_positions(cont, box, offsets[:, None])
        positions[s, k, :8] = faces  # exactly on the faces, +l/2 included
    return TrajectoryData(positions, times, boundary, D / 2, provenance={"generator": "faces"})


@pytest.mark.parametrize("lees_edwards", [True, False])
@pytest.mark.parametrize("model_name", ["contact", "grip"])
def test_particles_exactly_on_faces(tmp_path, lees_edwards, model_name):
    """Tried: 8 particles exactly on the lower faces, edges and corners, just below the upper
    faces and exactly on +lx/2, at the last observed frame, moving out through the faces they
    sit on (LE offset non-zero), through windows, graph, encoding, model and decoding.
    Held: the graph has every particle's self pair; the untrained model equals constant
    velocity to 1e-12 of the box and predicts the face particles' exact constant-velocity
    frames; a perturbed model stays finite and inside [-l/2, l/2) on every axis."""
    path = write_dataset(tmp_path / "faces.h5", on_face_data(lees_edwards))
    scene = "lebc" if lees_edwards else "pbc"
    overrides = [f"scene={scene}", f"model={model_name}", "split=custom"]
    overrides += ["split.history=3", "split.horizon=4", "data.history_len=3"]
    model, dm = smoke_model(path, *overrides)
    pred, true, offsets, batches = predict_windows(model, dm, "train")
    box = model.boundary.box
    for b in batches:
        n = b.last_positions.shape[1]
        self_pairs = b.edge_index[0] == b.edge_index[1]
        assert int(self_pairs.sum()) == n
    observed = torch.cat([b.input_positions.double().transpose(1, 2) for b in batches])
    in_off = torch.cat([b.input_offsets.double() for b in batches])
    cv = constant_velocity(observed, in_off, offsets, box)
    err = minimum_image(pred - cv, box, offsets[..., None] if lees_edwards else None)
    assert float(err.abs().max()) < 1e-12 * box.lx
    face = minimum_image(pred[:, :, :8] - true[:, :, :8], box, offsets[..., None])
    assert float(face.abs().max()) < 1e-12 * box.lx
    assert inside(pred, box)
    pred, *_ = predict_windows(perturb(model, 0.2), dm, "train")
    assert torch.isfinite(pred).all() and inside(pred, box)


# --------------------------------------------------------------------------------------------
# LE offsets at very late absolute times
# --------------------------------------------------------------------------------------------
def sheared_walk(t0: float, n_sims: int = 3, frames: int = 20, n: int = 40) -> TrajectoryData:
    """One lattice-continuous sheared random walk (seeded), observed from absolute time
    ``t0``: each frame wrapped with its own float64 LE offset."""
    box = Box(8 * D, 7 * D, 9 * D)
    boundary = Boundary(box, LeesEdwards(1000.0, time_origin=0.0))
    rng = np.random.default_rng(5)
    times = t0 + DT * (np.arange(frames)[None, :] + 2 * frames * np.arange(n_sims)[:, None])
    cont = np.empty((n_sims, frames, n, 3))
    cont[:, 0] = (rng.random((n_sims, n, 3)) - 0.5) * box.lengths
    for t in range(1, frames):
        step = rng.normal(0, 0.05 * D, (n_sims, n, 3))
        step[..., 2] += 1000.0 * cont[:, t - 1, :, 0] * DT
        cont[:, t] = cont[:, t - 1] + step
    offsets = boundary.offset(times)
    positions = wrap_positions(cont, box, offsets[:, :, None])
    return TrajectoryData(positions, times, boundary, D / 2, provenance={"generator": "walk"})


def test_le_offsets_at_very_late_absolute_times(tmp_path):
    """Tried: the same sheared flow observed from t = 1.1 ms and about 1e6 frame intervals
    later (t ~ 5 s, k*lx*t ~ 1e4 box lengths; the shift is a whole number of LE periods, so the
    image lattice has the same phase and the two are one physical state): windows, batches,
    every baseline and a perturbed default model, all reading absolute times from the file.
    Held: the batches carry the float64 offsets exactly as the boundary computes them; the
    late windows' RMSE / d equals the early ones' to 1e-9 relative (baselines, float64) and
    1e-5 (model, float32 network). A float32 product anywhere would be off by ~1e-8 x 1e4
    box lengths = 1e-4 box lengths in every offset."""
    box = sheared_walk(0.0).box
    period = box.lz / (1000.0 * box.lx)  # s per LE period (the offset's repeat time)
    shift = round(1e6 * DT / period) * period
    results = []
    for t0 in (1.1e-3, 1.1e-3 + shift):
        path = write_dataset(tmp_path / f"t{t0:.3g}.h5", sheared_walk(t0))
        overrides = ["scene=lebc", "split=custom", "split.history=5", "split.horizon=4"]
        model, dm = smoke_model(path, *overrides, "data.history_len=5")
        pred, true, offsets, batches = predict_windows(perturb(model, 0.01), dm)
        for b in batches:
            assert b.offsets.dtype == torch.float64
            expected = dm.meta.boundary.offset(b.times.numpy())
            np.testing.assert_array_equal(b.offsets.numpy(), expected)
        out = {"model": rmse_over_d(pred, true, offsets, model)}
        for name, value in model.predict_baselines(collate_all(batches)).items():
            out[name] = rmse_over_d(value, true, offsets, model)
        results.append(out)
    early, late = results
    assert late["model"] != early["constant_velocity"]  # the network matters
    for name in early:
        tolerance = 1e-5 if name == "model" else 1e-9
        assert late[name] == pytest.approx(early[name], rel=tolerance), name


def test_dem_restart_at_very_late_absolute_time(tiny_lebc_path):
    """Tried: the built-in DEM restarted from a stored frame of the tiny LE dataset, once at
    the frame's own time and once 1e6 frame intervals later (4.6e8 steps: the same offset,
    5000 LE periods later, from a product k*lx*t ~ 1e4 box lengths).
    Held: the restarts see the same offset to 1e-9 of the box, and two frames later the
    positions agree to 1e-9 d."""
    config = generator_config("lebc")
    with h5py.File(tiny_lebc_path, "r") as h5:
        pos = np.asarray(h5["positions"][0, 30])
        vel = np.asarray(h5["velocities"][0, 30])
        t = float(h5["times"][0, 30])
    period = round(1.0 / (config.scene.shear_rate * config.dt))  # steps per LE period
    late = 1_000_000 * config.steps_per_frame
    assert late % period == 0
    sims = [Simulation(config, pos, vel, step=round(t / config.dt) + extra) for extra in (0, late)]
    assert abs(sims[0].offset() - sims[1].offset()) < 1e-9 * config.box.lz
    out = []
    for sim in sims:
        sim.run(2 * config.steps_per_frame)
        out.append(sim.snapshot()[0])
    assert np.abs(out[0] - out[1]).max() < 1e-9 * D


# --------------------------------------------------------------------------------------------
# (sin, cos) pairs far off the unit circle
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("model_name", ["grip_paper", "vct_paper"])
def test_sincos_pairs_far_off_the_unit_circle(tiny_lebc_path, model_name):
    """Tried: predictions of the paper-frame models (decoded in sin/cos space) whose feature
    pairs are scaled by 1e-3, 1e3 and 1e6 off the unit circle, collapse to (0, 0), or are
    random outputs of size 1e6. (Pairs of any length decode by direction in the boundary
    module's own property tests; here the whole decode path of a model runs.)
    Held: scaled pairs decode to the same positions (the last observed ones) to 1e-9 of the
    box, and everything decoded, (0, 0) included, is finite and inside the box."""
    model, dm = smoke_model(tiny_lebc_path, "scene=lebc", f"model={model_name}")
    batch = collate_windows([dm.datasets["test"][0]])
    box, last = model.boundary.box, batch.last_positions.double()
    features = model.encoding.position_features(last)  # (B, N, 6) on the unit circle
    f, c = int(model.hparams.horizon), model.encoding.n_channels
    for scale in (1e-3, 1e3, 1e6, 0.0):
        deltas = torch.zeros(*last.shape[:2], f, c, dtype=torch.float64)
        deltas[..., 0, :6] = (scale - 1.0) * features  # the accumulated pairs: scale * features
        pred = torch.as_tensor(model.normalizer.normalize(deltas.numpy()))
        positions = model.decode(pred, batch)
        assert torch.isfinite(positions).all() and inside(positions, box)
        if scale:  # (0, 0) up to the normaliser's round-off: any direction, but finite
            for j in range(f):
                err = minimum_image(positions[:, j] - last, box, 0.0)
                assert float(err.abs().max()) < 1e-9 * box.lx, (scale, j)
    g = torch.Generator().manual_seed(0)
    wild = 1e6 * torch.randn(*last.shape[:2], f, c, generator=g, dtype=torch.float64)
    positions = model.decode(wild, batch)
    assert torch.isfinite(positions).all() and inside(positions, box)
