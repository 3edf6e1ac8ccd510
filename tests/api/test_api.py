"""The Python API (``gripdem.*``): the same rollouts as ``gripdem.predict``, scenes in memory
that match the files, the surrogate stepped from outside, the DEM and the physics report, and a
light ``import gripdem``."""

from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import gripdem
import gripdem.api
from gripdem.data.dataset_io import read_dataset
from gripdem.inference.checkpoint import IncompatibleError
from gripdem.predict import main as predict_main

#: the stable surface, frozen here: a name that disappears or is renamed fails this module
STABLE_NAMES = set(
    "Model RolloutResult RolloutError Scene Surrogate Trajectory PhysicsReport TRAINING generate "
    "load_model physics read_trajectory write_trajectory".split()
)
#: the exceptions, one hierarchy (gripdem/errors.py, documented in docs/reference/errors.md)
ERRORS = set(
    "GripdemError DatasetError SplitError CheckpointError IncompatibleError GenerationError "
    "RolloutDiverged".split()
)


def test_import_gripdem_imports_no_torch():
    code = (
        "import sys, gripdem\n"
        "scene = gripdem.Scene(box=(1e-5, 1e-5, 1e-5), diameter=1e-6, frame_interval=1e-6)\n"
        "assert gripdem.load_model and gripdem.generate\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'lightning')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_the_stable_names_are_exported_and_documented():
    assert set(gripdem.api.__all__) == STABLE_NAMES | ERRORS
    assert set(gripdem.API_NAMES) == STABLE_NAMES | ERRORS
    for name in STABLE_NAMES - {"TRAINING"}:
        obj = getattr(gripdem, name)
        assert obj is getattr(gripdem.api, name)
        assert obj.__doc__ and len(obj.__doc__.strip()) > 40, name
    classes = (gripdem.Model, gripdem.Surrogate, gripdem.RolloutResult, gripdem.Scene)
    for cls in (*classes, gripdem.Trajectory):
        for attr, value in vars(cls).items():
            if not attr.startswith("_") and (callable(value) or isinstance(value, property)):
                assert getattr(value, "__doc__", None), f"{cls.__name__}.{attr}"
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        gripdem.nothing_here  # noqa: B018


def test_no_name_is_shadowed_by_a_module_of_the_package():
    """``gripdem.<name>`` must stay the API's object after any ``import gripdem.<module>``
    (an entry point such as ``gripdem.simulate`` would replace the attribute)."""
    package = Path(gripdem.__file__).parent
    modules = {p.stem for p in package.glob("*.py")} | {p.name for p in package.iterdir()}
    assert STABLE_NAMES.isdisjoint(modules)


def test_a_renamed_name_warns_and_still_works(monkeypatch):
    monkeypatch.setitem(gripdem.api.DEPRECATED, "load", ("load_model", "0.2"))
    with pytest.warns(DeprecationWarning, match=r"gripdem.load is deprecated.*gripdem.load_model"):
        assert gripdem.load is gripdem.load_model
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert gripdem.load_model  # the new name is quiet


def test_a_scene_in_memory_matches_the_file(tiny_lebc_path):
    from_file = gripdem.Scene.from_file(tiny_lebc_path)
    data = read_dataset(tiny_lebc_path)
    by_hand = gripdem.Scene(
        box=tuple(data.box.lengths),
        diameter=2.5e-6,
        frame_interval=5e-6,
        boundary="lees_edwards",
        shear_rate=1000.0,
    )
    assert by_hand.matches(from_file) and from_file.matches(by_hand)
    assert by_hand.to_boundary() == data.boundary
    np.testing.assert_array_equal(by_hand.offsets(data.times), data.offsets())
    assert not by_hand.matches(by_hand.with_(shear_rate=1001.0))


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"box": (1.0, 2.0)}, "Scene.box: expected 3 positive lengths"),
        ({"diameter": -1.0}, "Scene.diameter: expected a positive finite number"),
        ({"frame_interval": float("nan")}, "Scene.frame_interval"),
        ({"boundary": "walls"}, "Scene.boundary: expected one of"),
        ({"boundary": "lees_edwards"}, "Scene.shear_rate: a lees_edwards scene needs"),
        ({"shear_rate": 5.0}, "Scene.shear_rate: a periodic scene has no shear rate"),
        ({"le_sign": 2}, r"Scene.le_sign: expected \+1 or -1"),
    ],
)
def test_bad_scenes_name_the_field(changes, message):
    base = {"box": (1e-5, 1e-5, 1e-5), "diameter": 1e-6, "frame_interval": 1e-6}
    with pytest.raises(ValueError, match=message):
        gripdem.Scene(**{**base, **changes})


def _predict_trajectory(tmp_path, checkpoint, data, start, frames):
    out = tmp_path / "pred.h5"
    argv = [str(checkpoint), str(data), "--out", str(out), "--start", str(start)]
    assert predict_main([*argv, "--frames", str(frames), "--sims", "0", "1"]) == 0
    return read_dataset(tmp_path / "pred_trajectory.h5")


@pytest.mark.parametrize("scene", ["lebc", "pbc"])
def test_the_api_rollout_equals_predict(tmp_path, scene, request):
    """Both scenes, chained beyond the horizon, with the contact correction: the same frames
    to round-off (lebc: the shipped model on DEM data; pbc: a run's checkpoint)."""
    if scene == "lebc":
        checkpoint, data_path = "pretrained:lebc", request.getfixturevalue("tiny_lebc_path")
    else:
        checkpoint = request.getfixturevalue("pbc_checkpoint")
        data_path = request.getfixturevalue("pbc_file")
    model = gripdem.load_model(checkpoint)
    start, frames = 3, 3 * model.horizon + 2
    expected = _predict_trajectory(tmp_path, checkpoint, data_path, start, frames)
    data = gripdem.read_trajectory(data_path)
    k1 = model.history_len + 1
    window = slice(start, start + k1)
    run = model.rollout(
        data.positions[:2, window], data.times[:2, window], frames=frames, scene=data.scene
    )
    assert run.positions.shape == expected.positions.shape
    assert np.abs(run.positions - expected.positions).max() < 1e-12 * data.scene.box[0]
    np.testing.assert_array_equal(run.times, expected.times)
    assert run.n_predicted == frames and run.divergence["stopped"] is None
    assert sum(run.correction["overlapping_before"]) >= 0 and run.timings["forward"] > 0
    # one simulation without a leading axis, times defaulting to the scene's frame interval
    single = model.rollout(data.positions[0, window], frames=2, scene=data.scene)
    assert single.positions.shape == (k1 + 2,) + data.positions.shape[2:]


def test_ensemble_members_equal_predicts(tmp_path, le_file, le_ensemble_checkpoint):
    """Members get their own axis, ``(S, M, frames, N, 3)``: the rows ``s * M + m`` of
    ``gripdem.predict --members M`` with the same seed (untrained, the members coincide: the
    noise path's output starts at zero, so this checks the rows and the seed plumbing)."""
    argv = [str(le_ensemble_checkpoint), str(le_file), "--out", str(tmp_path / "pred.h5")]
    argv += ["--start", "4", "--frames", "9", "--sims", "0", "1", "--members", "3", "--seed", "5"]
    assert predict_main(argv) == 0
    expected = read_dataset(tmp_path / "pred_trajectory.h5")
    model = gripdem.load_model(le_ensemble_checkpoint)
    assert model.is_ensemble
    data = gripdem.read_trajectory(le_file)
    window = slice(4, 5 + model.history_len)
    run = model.rollout(
        data.positions[:2, window], data.times[:2, window], frames=9, members=3, seed=5,
        scene=data.scene,
    )  # fmt: skip
    assert run.positions.shape == (2, 3) + expected.positions.shape[1:]
    np.testing.assert_array_equal(
        run.positions.reshape(expected.positions.shape), expected.positions
    )
    assert run.trajectory().positions.shape == expected.positions.shape
    error = run.error(data.positions[:2, window.stop : window.stop + 9])  # members pooled
    assert error.per_frame_over_d.shape == (9,) and error.members == 3


def test_the_surrogate_steps_hands_back_and_times(tiny_lebc_path):
    model = gripdem.load_model("pretrained:lebc", precision="fp32")
    data = gripdem.read_trajectory(tiny_lebc_path)
    k1 = model.history_len + 1
    history, times = data.positions[0, :k1], data.times[0, :k1]
    whole = model.rollout(history, times, frames=13, scene=data.scene, precision="fp32")
    sim = model.surrogate(history, times, scene=data.scene)
    pieces = [sim.advance(1), sim.advance(7), sim.advance(5)]
    np.testing.assert_array_equal(np.concatenate(pieces), whole.predicted)
    assert sim.frames_advanced == 13 and sim.time == pytest.approx(whole.times[-1], rel=1e-12)
    assert set(sim.timings) >= {"neighbour_list", "features", "forward", "correction"}
    assert len(sim.correction["overlapping_before"]) == 13
    # hand the DEM's own frames back: the surrogate continues from them as a fresh start does
    truth = data.positions[0, 20 : 20 + k1]
    sim.set_state(truth, data.times[0, 20 : 20 + k1])
    fresh = model.rollout(truth, data.times[0, 20 : 20 + k1], frames=4, scene=data.scene)
    np.testing.assert_array_equal(sim.advance(4), fresh.predicted)
    frames, state_times = sim.state
    assert frames.shape == (k1,) + truth.shape[1:] and state_times[-1] == sim.time
    with pytest.raises(ValueError, match=r"set_state: expected \(frames >= 11, particles, 3\)"):
        sim.set_state(truth[:3])


def test_bad_histories_and_scenes_are_refused_clearly(pbc_checkpoint, pbc_file):
    model = gripdem.load_model(pbc_checkpoint)
    data = gripdem.read_trajectory(pbc_file)
    k1 = model.history_len + 1
    with pytest.raises(ValueError, match=rf"history: expected \(frames >= {k1}"):
        model.rollout(data.positions[0, :2], scene=data.scene)
    bad = data.positions[0, :k1].copy()
    bad[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match="history: positions must be finite"):
        model.rollout(bad, scene=data.scene)
    with pytest.raises(ValueError, match="times: the last .* frames must be .* s apart"):
        model.rollout(data.positions[0, :k1], 2.0 * data.times[0, :k1], scene=data.scene)
    other = data.scene.with_(box=tuple(1.5 * np.asarray(data.scene.box)))  # another box
    with pytest.raises(IncompatibleError, match=r"<scene in memory>: field 'box'"):
        model.rollout(data.positions[0, :k1], scene=other)
    with pytest.raises(ValueError, match="deterministic"):
        model.rollout(data.positions[0, :k1], scene=data.scene, members=3)


def test_generate_is_the_generator_and_the_files_round_trip(tmp_path, tiny_pbc_path):
    generated = gripdem.generate("pbc", preset="tiny", sims=1, seed=0)
    cached = gripdem.read_trajectory(tiny_pbc_path)  # sims 3, seed 0: its first simulation
    np.testing.assert_array_equal(generated.positions[0], cached.positions[0])
    assert generated.scene.matches(cached.scene)
    path = gripdem.write_trajectory(tmp_path / "mine.h5", generated)
    back = gripdem.read_trajectory(path)
    np.testing.assert_array_equal(back.positions, generated.positions)
    assert back.scene == generated.scene and back.provenance["generator"] == "gripdem.dem"
    with pytest.raises(FileExistsError, match="refusing to overwrite"):
        gripdem.write_trajectory(path, generated)
    with pytest.raises(ValueError, match="scene 'walls': no .*walls.yaml; expected one of"):
        gripdem.generate("walls")


def test_the_physics_report_of_dem_data(tiny_lebc_path):
    data = gripdem.read_trajectory(tiny_lebc_path)
    report = gripdem.physics(data, sim=1)
    assert 0.95 < report.peak_over_d < 1.05 and report.gr.max() > 3  # the contact peak
    assert 2.5 < report.coordination < 6 and report.overlap_fraction == 0.0
    assert report.profile_kind == "linear"
    assert report.profile[0] == pytest.approx(1000.0, rel=0.1)  # the imposed shear rate
    assert list(report.lags[:3]) == [1, 2, 5]
    assert np.all(np.diff(report.non_affine_msd_over_d2) > 0)
    assert np.all(report.non_affine_msd_over_d2 < report.msd_over_d2)  # the flow removed
    assert report.diffusion is None and "1000 frames" in report.notes[0]
    assert "| coordination (< 1.01 d) |" in report.table()
    with pytest.raises(ValueError, match=r"sim 5: the trajectory holds simulations 0..2"):
        gripdem.physics(data, sim=5)


def test_the_exceptions_form_one_documented_hierarchy():
    """One base, each class also the built-in it has always been, each on the errors page."""
    builtin = {
        "DatasetError": ValueError,
        "SplitError": ValueError,
        "CheckpointError": ValueError,
        "IncompatibleError": ValueError,
        "GenerationError": RuntimeError,
        "RolloutDiverged": FloatingPointError,
    }
    page = (Path(__file__).resolve().parents[2] / "docs/reference/errors.md").read_text()
    for name in ERRORS:
        cls = getattr(gripdem, name)
        assert issubclass(cls, gripdem.GripdemError) and f"`{name}`" in page, name
        if name in builtin:
            assert issubclass(cls, builtin[name]), name
    from gripdem.formats.fordatis.files import FordatisError
    from gripdem.formats.lammps.dump import DumpError

    assert issubclass(DumpError, gripdem.DatasetError)
    assert issubclass(FordatisError, gripdem.DatasetError)
    assert IncompatibleError is gripdem.IncompatibleError  # one class, wherever imported


def _public_callables():
    yield from (getattr(gripdem, n) for n in ("load_model", "generate", "physics"))
    yield from (gripdem.read_trajectory, gripdem.write_trajectory)
    classes = (gripdem.Model, gripdem.Surrogate, gripdem.RolloutResult, gripdem.Scene)
    for cls in (*classes, gripdem.Trajectory):
        for attr, value in vars(cls).items():
            value = value.__func__ if isinstance(value, classmethod | staticmethod) else value
            doc = getattr(value, "__doc__", None) or ""
            if attr.startswith("_") or not callable(value) or doc.startswith("Deprecated"):
                continue
            yield value


def test_every_public_function_says_what_it_raises():
    missing = [f.__qualname__ for f in _public_callables() if "Raises" not in (f.__doc__ or "")]
    assert missing == []


def test_the_scene_is_explicit(pbc_checkpoint, pbc_file):
    model = gripdem.load_model(pbc_checkpoint)
    data = gripdem.read_trajectory(pbc_file)
    history = data.positions[0, : model.history_len + 1]
    with pytest.raises(ValueError, match=r"needs scene= \(required since gripdem 0.2.0\)"):
        model.rollout(history, frames=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        explicit = model.rollout(history, frames=2, scene=gripdem.TRAINING)
        model.surrogate(history, scene="training")
    with pytest.raises(ValueError, match=r"Model.surrogate\(\) needs scene="):
        model.surrogate(history)
    assert explicit.scene == model.scene
    for cls, name in [(gripdem.Scene, n) for n in ("from_meta", "to_meta", "from_model_scene")] + [
        (gripdem.Trajectory, n) for n in ("from_data", "to_data")
    ]:
        assert not hasattr(cls, name), f"{cls.__name__}.{name} was removed in 0.2.0"
    with pytest.raises(ValueError, match="scene: expected a Scene or 'training', got 'mine'"):
        model.rollout(history, frames=2, scene="mine")


def test_rollout_and_advance_raise_the_same_error_at_nan(pbc_checkpoint, pbc_file):
    """A model whose weights are NaN: both entry points raise RolloutDiverged, and keep the
    frames before it in ``partial`` (none here: the first prediction is already NaN)."""
    model = gripdem.load_model(pbc_checkpoint)
    data = gripdem.read_trajectory(pbc_file)
    history = data.positions[0, : model.history_len + 1]
    for parameter in model.module(data.scene).parameters():
        parameter.data.fill_(float("nan"))
    with pytest.raises(gripdem.RolloutDiverged, match="non-finite positions") as info:
        model.rollout(history, frames=3, scene=data.scene)
    assert isinstance(info.value.partial, gripdem.RolloutResult)
    assert info.value.partial.n_predicted == 0
    assert np.isfinite(info.value.partial.positions).all()
    sim = model.surrogate(history, scene=data.scene)
    with pytest.raises(gripdem.RolloutDiverged, match="non-finite positions") as info:
        sim.advance(3)
    assert info.value.partial.shape == (0,) + history.shape[1:]
    assert isinstance(info.value, FloatingPointError)  # what advance raised before


def test_a_rollout_is_saved_and_scored_against_the_truth(tmp_path, pbc_checkpoint, pbc_file):
    """``save`` writes a dataset every command reads; ``error`` scores the predicted frames and
    constant velocity's: the untrained model without correction IS constant velocity."""
    from gripdem.evaluation.metrics import position_residuals

    model = gripdem.load_model(pbc_checkpoint)
    data = gripdem.read_trajectory(pbc_file)
    k1, frames = model.history_len + 1, 6
    run = model.rollout(
        data.positions[:2, :k1], data.times[:2, :k1], frames=frames, scene=data.scene,
        correction=False,
    )  # fmt: skip
    path = run.save(tmp_path / "rollout.h5")
    back = gripdem.read_trajectory(path)
    np.testing.assert_array_equal(back.positions, run.positions)
    assert back.provenance["model"] == str(pbc_checkpoint)
    assert back.provenance["observed_frames"] == k1
    with pytest.raises(FileExistsError, match="refusing to overwrite"):
        run.save(path)
    truth = data.positions[:2, k1 : k1 + frames]
    error = run.error(truth)
    assert error.per_frame_over_d.shape == (frames,)
    assert error.ratio_to_constant_velocity == pytest.approx(1.0, abs=1e-9)
    offsets = data.scene.offsets(data.times[:2, k1 : k1 + frames])
    box = data.scene.to_boundary().box
    by_hand = position_residuals(run.predicted, truth, box, offsets)
    expected = np.sqrt((by_hand**2).sum(-1).mean()) / data.scene.diameter
    assert error.rmse_over_d == pytest.approx(expected, rel=1e-12) and expected > 0
    with pytest.raises(ValueError, match=r"truth: expected \(2, 6, "):
        run.error(truth[0])


def test_set_state_checks_what_rollout_checks(tiny_lebc_path):
    model = gripdem.load_model("pretrained:lebc", precision="fp32")
    data = gripdem.read_trajectory(tiny_lebc_path)
    k1 = model.history_len + 1
    sim = model.surrogate(data.positions[0, :k1], data.times[0, :k1], scene=data.scene)
    bad = data.positions[0, :k1].copy()
    bad[2, 5, 1] = np.inf
    with pytest.raises(ValueError, match="set_state: positions must be finite"):
        sim.set_state(bad)
    with pytest.raises(ValueError, match="set_state: expected .* particles"):
        sim.set_state(data.positions[0, :k1, :-1])
    with pytest.raises(ValueError, match="times: the last .* frames must be"):
        sim.set_state(data.positions[0, :k1], 3.0 * data.times[0, :k1])
    sim.set_state(data.positions[0, 5 : 5 + k1], data.times[0, 5 : 5 + k1])  # a valid one
    assert sim.time == pytest.approx(data.times[0, 4 + k1], rel=1e-12)
