"""``python -m gripdem.predict``: a real checkpoint applied to a dataset, its outputs, and the
refusal of scenes, encodings and particle counts the model cannot serve."""

from __future__ import annotations

import json
import re
from dataclasses import replace

import h5py
import numpy as np
import pytest

from gripdem.boundary import Boundary, Box, LeesEdwards, brute_force_pairs
from gripdem.data.dataset_io import read_dataset, read_meta, write_dataset
from gripdem.evaluation.evaluate import evaluate_predictions
from gripdem.evaluation.predictions import read_predictions
from gripdem.inference.checkpoint import IncompatibleError, check_compatible
from gripdem.inference.in_sample import training_overlap
from gripdem.inference.precision import resolve_precision
from gripdem.predict import main


def run(checkpoint, data, out, *extra):
    return main([str(checkpoint), str(data), "--out", str(out), *map(str, extra)])


def test_predict_writes_predictions_trajectory_and_report(tmp_path, capsys, le_file, le_checkpoint):
    out = tmp_path / "pred.h5"
    # start 25: frames 25..30 observed, 31..39 have a truth, 40..52 do not
    args = ("--start", 25, "--frames", 22, "--sims", 0, 2, "--no-correction")
    assert run(le_checkpoint, le_file, out, *args) == 0
    printed = capsys.readouterr().out
    assert "predicted 22 of 22 frame(s) (31..52) in links of 5" in printed
    assert "constant_velocity" in printed and "note: in-sample check" in printed
    p = read_predictions(out)
    assert p.pred_positions.shape == (2, 9, 24, 3) and p.horizon == 9
    assert list(p.sim_index) == [0, 2] and list(p.window_start) == [25, 25]
    assert set(p.baselines) == {"stay", "constant_velocity", "linear_ar", "mean_flow"}
    # the untrained model is constant velocity, chained or not
    assert np.abs(p.pred_positions - p.baselines["constant_velocity"]).max() < 1e-15
    truth = read_dataset(le_file)
    np.testing.assert_array_equal(p.true_positions[1], truth.positions[2, 31:40])
    metrics = evaluate_predictions(out)
    report = json.loads((tmp_path / "pred_rollout.json").read_text())
    assert report["truth_frames"] == 9 and report["predicted_frames"] == [31, 52]
    assert report["rmse_over_d"]["model"] == pytest.approx(
        [metrics[f"rmse_step/{j:03d}"] / truth.diameter for j in range(1, 10)]
    )
    assert len(report["divergence"]["max_step_over_d"]) == 22
    trajectory = read_dataset(tmp_path / "pred_trajectory.h5")
    assert trajectory.positions.shape == (2, 6 + 22, 24, 3)
    np.testing.assert_array_equal(trajectory.positions[:, :6], truth.positions[[0, 2], 25:31])
    assert trajectory.boundary == truth.boundary
    assert trajectory.provenance["parameters"]["checkpoint"] == str(le_checkpoint)
    # existing outputs are kept
    assert run(le_checkpoint, le_file, out, "--start", 25) == 1
    assert "refusing to overwrite" in capsys.readouterr().err


def test_predict_corrects_contacts_by_default(tmp_path, le_file, le_checkpoint):
    """The stable setting (the default): no predicted pair closer than a diameter, although the
    random walk of the data (and so constant velocity) packs particles into each other."""
    out = tmp_path / "pred.h5"
    assert run(le_checkpoint, le_file, out, "--start", 25, "--frames", 12) == 0
    report = json.loads((tmp_path / "pred_rollout.json").read_text())
    assert report["settings"]["contact_correction"] is True
    # the encoder's precision: auto by default, bf16 where the CPU has bf16 units
    assert report["settings"]["precision"] == "auto"
    assert report["precision"] == resolve_precision("auto")
    trajectory = read_dataset(tmp_path / "pred_trajectory.h5")
    offsets = trajectory.offsets()
    d = trajectory.diameter
    for s in range(trajectory.n_sims):
        for t in range(6, trajectory.n_frames):
            i, j, vec = brute_force_pairs(
                trajectory.positions[s, t], trajectory.box, offsets[s, t], d
            )
            assert (np.linalg.norm(vec, axis=1) > d * (1 - 2e-4)).all(), (s, t)
    p = read_predictions(out)
    cv = p.baselines["constant_velocity"]
    assert np.abs(p.pred_positions - cv).max() > 1e-3 * d  # the correction moved particles


def test_a_looser_correction_tolerance_leaves_overlaps_below_it(tmp_path, le_file, le_checkpoint):
    """``--correction-tolerance``: recorded in the report; no pair closer than the contact
    distance by more than it; the help states the stepper's default."""
    from gripdem.inference.contacts import CORRECTION_TOLERANCE
    from gripdem.predict import build_parser

    stated = re.search(
        r"left \(default ([0-9.e-]+),", " ".join(build_parser().format_help().split())
    )
    assert stated and float(stated.group(1)) == CORRECTION_TOLERANCE
    out = tmp_path / "pred.h5"
    args = ("--start", 25, "--frames", 12, "--correction-tolerance", "0.01")
    assert run(le_checkpoint, le_file, out, *args) == 0
    report = json.loads((tmp_path / "pred_rollout.json").read_text())
    assert report["settings"]["correction_tolerance"] == 0.01
    trajectory = read_dataset(tmp_path / "pred_trajectory.h5")
    offsets, d = trajectory.offsets(), trajectory.diameter
    for t in range(6, trajectory.n_frames):
        _, _, vec = brute_force_pairs(trajectory.positions[0, t], trajectory.box, offsets[0, t], d)
        assert (np.linalg.norm(vec, axis=1) > d * (1 - 0.0101)).all(), t


@pytest.mark.parametrize("value", ["0", "1", "nan"])
def test_a_correction_tolerance_outside_0_1_is_refused_in_one_line(tmp_path, capsys, value):
    with pytest.raises(SystemExit) as stop:
        main(["pretrained:pbc", str(tmp_path / "d.h5"), "--correction-tolerance", value])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith(
        f"--correction-tolerance must lie in (0, 1) contact distances, got {float(value)}"
    )
    assert list(tmp_path.iterdir()) == []


def test_predict_from_the_last_frames_writes_the_rollout_only(
    tmp_path, capsys, le_file, le_checkpoint
):
    out = tmp_path / "pred.h5"
    assert run(le_checkpoint, le_file, out, "--start", 34, "--frames", 7, "--no-overlap") == 0
    assert "not written" in capsys.readouterr().out
    assert not out.exists() and (tmp_path / "pred_trajectory.h5").exists()
    assert run(le_checkpoint, le_file, tmp_path / "b.h5", "--start", 35) == 1
    assert "--start 35: the model reads 6 observed frames" in capsys.readouterr().err


def _variant(source, tmp_path, name, **changes):
    data = read_dataset(source)
    box = changes.pop("box", None)
    if box is not None:
        scale = box.lengths / data.box.lengths
        le = data.boundary.lees_edwards
        data = replace(data, positions=data.positions * scale, boundary=Boundary(box, le))
    return write_dataset(tmp_path / f"{name}.h5", replace(data, **changes))


def test_incompatible_scenes_are_refused_with_the_field(
    tmp_path, capsys, le_file, pbc_file, le_checkpoint
):
    data = read_dataset(le_file)
    le = data.boundary.lees_edwards
    flipped = Boundary(data.box, LeesEdwards(le.shear_rate, -le.sign, le.time_origin))
    cases = {
        "boundary": pbc_file,
        "diameter": _variant(le_file, tmp_path, "d", radius=0.6 * data.diameter),
        "frame_interval": _variant(le_file, tmp_path, "dt", times=data.times * 1.5),
        "shear_rate": _variant(le_file, tmp_path, "sign", boundary=flipped),
    }
    for field, path in cases.items():
        assert run(le_checkpoint, path, tmp_path / f"{field}.h5") == 1
        err = capsys.readouterr().err
        assert f"field '{field}'" in err and str(path) in err and str(le_checkpoint) in err
        assert not (tmp_path / f"{field}.h5").exists()
    assert "opposite flow directions: mirror the data's z axis" in err


def test_another_body_force_is_refused(tmp_path, capsys, pbc_file, pbc_checkpoint):
    drive = read_dataset(pbc_file).body_force_amplitude
    other = _variant(pbc_file, tmp_path, "a", body_force_amplitude=2.0 * drive + 1.0)
    assert run(pbc_checkpoint, other, tmp_path / "a_pred.h5") == 1
    err = capsys.readouterr().err
    assert "field 'body_force_amplitude'" in err and "another drive" in err


def test_box_rules_and_the_dense_graph_particle_count(
    tmp_path, le_file, le_checkpoint, make_checkpoint
):
    bigger = Box(*(1.25 * read_meta(le_file).box.lengths))
    other_box = _variant(le_file, tmp_path, "box", box=bigger)
    # the default model reads relative geometry only: applied in the data's box, with a note
    _, notes = check_compatible(le_checkpoint, read_meta(other_box))
    assert any("applied in the data's box" in n for n in notes)
    paper = make_checkpoint(le_file, tmp_path / "paper", ["scene=lebc", "model=grip_paper"])
    with pytest.raises(IncompatibleError, match="field 'box'.*sincos encoding"):
        check_compatible(paper, read_meta(other_box))
    dense = make_checkpoint(
        le_file,
        tmp_path / "dense",
        ["scene=lebc", "model=grip_paper", "model.encoder.trainable_graph=dense"],
    )
    check_compatible(dense, read_meta(le_file))
    data = read_dataset(le_file)
    fewer = _variant(le_file, tmp_path, "fewer", positions=data.positions[:, :, :20])
    with pytest.raises(IncompatibleError, match="dense n x n graph.*24 particles.*has 20"):
        check_compatible(dense, read_meta(fewer))
    with pytest.raises(ValueError, match="not a readable PyTorch checkpoint"):
        check_compatible(le_file, read_meta(le_file))


def test_scenes_within_the_tolerance_are_applied_with_a_note(
    tmp_path, capsys, pbc_file, pbc_checkpoint, le_file, le_checkpoint
):
    data = read_dataset(pbc_file)
    # the case: the data's box 0.04 % larger (the periodic model reads x phases: it
    # is not a relative-only model, so this is the tolerance at work)
    box = _variant(pbc_file, tmp_path, "box", box=Box(*(1.0004 * data.box.lengths)))
    _, notes = check_compatible(pbc_checkpoint, read_meta(box))
    lengths = ", ".join(f"{v:.5g}" for v in read_meta(box).box.lengths)
    trained = ", ".join(f"{v:.5g}" for v in data.box.lengths)
    assert notes == [
        f"box: data ({lengths}) vs model ({trained}) (+0.04 %), within the 1 % tolerance, "
        "applied in the data's box"
    ]
    assert run(pbc_checkpoint, box, tmp_path / "box_pred.h5", "--frames", 2) == 0
    assert "note: box: data" in capsys.readouterr().out
    scene = _variant(
        pbc_file, tmp_path, "scene", radius=1.005 * data.radius, times=data.times * 0.996
    )
    _, notes = check_compatible(pbc_checkpoint, read_meta(scene))
    assert [n.split(":")[0] for n in notes] == ["diameter", "frame_interval"]
    assert "(+0.5 %), within the 1 % tolerance" in notes[0] and "(-0.4 %)" in notes[1]
    le = read_dataset(le_file).boundary.lees_edwards
    faster = Boundary(read_dataset(le_file).box, replace(le, shear_rate=1.006 * le.shear_rate))
    _, notes = check_compatible(
        le_checkpoint, read_meta(_variant(le_file, tmp_path, "k", boundary=faster))
    )
    assert notes[0].startswith("shear_rate: data ") and "(+0.6 %), within" in notes[0]


def test_a_drive_within_the_tolerance_and_beyond_it(tmp_path, pbc_file, make_checkpoint):
    driven = _variant(pbc_file, tmp_path, "driven", body_force_amplitude=100.0)
    checkpoint = make_checkpoint(driven, tmp_path / "driven_run", ["scene=pbc"])
    close = _variant(pbc_file, tmp_path, "close", body_force_amplitude=100.8)
    _, notes = check_compatible(checkpoint, read_meta(close))
    assert notes == [
        "body_force_amplitude: data 100.8 vs model 100 (+0.8 %), within the 1 % tolerance, the "
        "model predicts the flow of its own drive"
    ]
    for amplitude, shown in ((0.0, "data 0 vs model 100 (-100.0 %)"), (103.0, "(+3.0 %)")):
        other = _variant(pbc_file, tmp_path, f"a{amplitude:g}", body_force_amplitude=amplitude)
        with pytest.raises(IncompatibleError, match="beyond the 1 % tolerance: another drive"):
            check_compatible(checkpoint, read_meta(other))
        with pytest.raises(IncompatibleError, match=re.escape(shown)):
            check_compatible(checkpoint, read_meta(other))


def test_beyond_the_tolerance_the_field_both_values_and_the_tolerance_are_named(
    tmp_path, pbc_file, pbc_checkpoint
):
    data = read_dataset(pbc_file)
    cases = {
        "box": dict(box=Box(*(1.02 * data.box.lengths))),
        "diameter": dict(radius=1.011 * data.radius),
        "frame_interval": dict(times=data.times * 0.98),
    }
    texts = {}
    for field, change in cases.items():
        path = _variant(pbc_file, tmp_path, field, **change)
        with pytest.raises(IncompatibleError) as info:
            check_compatible(pbc_checkpoint, read_meta(path))
        texts[field] = text = str(info.value)
        assert f"field '{field}': {field}: data " in text and " vs model " in text
        assert "beyond the 1 % tolerance" in text and str(pbc_checkpoint) in text
    assert "(+2.0 %)" in texts["box"] and "(+1.1 %)" in texts["diameter"]
    assert "(-2.0 %)" in texts["frame_interval"]


def test_in_sample_check_reads_the_run_metrics(tmp_path, le_file, le_checkpoint):
    metrics = le_checkpoint.parent.parent / "metrics.json"
    summary = {"path": str(le_file), "protocol": "sims", "sims_train": [0], "sims_val": [1]}
    metrics.write_text(json.dumps({"data": summary}))
    try:
        assert training_overlap(le_checkpoint, le_file, [0, 2], 10)[:2] == (True, "in_sample")
        assert training_overlap(le_checkpoint, le_file, [2], 10)[:2] == (False, "sims")
        assert "validation" in training_overlap(le_checkpoint, le_file, [1], 10)[2]
        assert training_overlap(le_checkpoint, tmp_path / "x.h5", [0], 10)[0] is False
        summary.update(protocol="time", sims_train=[0, 1, 2], time_boundaries=[24, 32])
        metrics.write_text(json.dumps({"data": summary}))
        assert training_overlap(le_checkpoint, le_file, [0], 20)[:2] == (True, "in_sample")
        assert training_overlap(le_checkpoint, le_file, [0], 24)[:2] == (False, "time")
        out = tmp_path / "p.h5"
        assert run(le_checkpoint, le_file, out, "--start", 0, "--sims", 1, "--no-overlap") == 0
        p = read_predictions(out)
        assert p.in_sample and p.protocol == "in_sample"
        with h5py.File(out) as h5:
            assert json.loads(h5.attrs["run"])["sims"] == [1]
    finally:
        metrics.unlink()


@pytest.fixture(scope="module")
def le_ensemble_checkpoint(tmp_path_factory, le_file, make_checkpoint):
    """The untrained ensemble model (model=ensemble) on ``le_file``."""
    out = tmp_path_factory.mktemp("le_ensemble_run")
    return make_checkpoint(le_file, out, ["scene=lebc", "model=ensemble"])


def test_predict_rolls_out_ensemble_members(tmp_path, capsys, le_file, le_ensemble_checkpoint):
    out = tmp_path / "pred.h5"
    args = ("--start", 25, "--frames", 12, "--sims", 0, 2, "--members", 3, "--seed", 5)
    args += ("--no-correction",)
    assert run(le_ensemble_checkpoint, le_file, out, *args) == 0
    printed = capsys.readouterr().out
    assert "ensemble of 3: spread/skill" in printed and "CRPS / d" in printed
    assert "pred_ensemble.h5" in printed
    trajectory = read_dataset(tmp_path / "pred_trajectory.h5")
    assert trajectory.positions.shape == (6, 6 + 12, 24, 3)  # sims x members rows
    assert trajectory.provenance["parameters"]["members"] == 3
    truth = read_dataset(le_file)
    for row, sim in enumerate([0, 0, 0, 2, 2, 2]):
        np.testing.assert_array_equal(trajectory.positions[row, :6], truth.positions[sim, 25:31])
    report = json.loads((tmp_path / "pred_rollout.json").read_text())
    assert report["ensemble"] is True and report["members"] == 3 and report["seed"] == 5
    assert len(report["member_rmse_over_d"]) == 3 and len(report["spread_skill"]) == 9
    assert len(report["rank_histogram_frames_1_100"]) == 4
    assert set(report["crps_over_d"]) == set(report["rmse_over_d"])
    with h5py.File(tmp_path / "pred_ensemble.h5", "r") as h5:
        assert h5["mean_positions"].shape == (2, 18, 24, 3) and h5["spread"].shape == (2, 18, 24)
        assert h5.attrs["members"] == 3
    # the untrained members are constant velocity: their mean is CV's prediction
    p = read_predictions(out)
    assert np.abs(p.pred_positions - p.baselines["constant_velocity"]).max() < 1e-15


def test_more_members_than_memory_holds_are_refused_in_one_line(
    tmp_path, capsys, le_file, le_ensemble_checkpoint
):
    """Ten million members of 3 simulations x 16 frames x 24 particles (about 80 KB each) do not
    fit on any machine: one line naming the members and the most that fit; nothing written."""
    out = tmp_path / "p.h5"
    assert run(le_ensemble_checkpoint, le_file, out, "--start", 25, "--members", 10**7) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "members 10000000:" in err[0], err
    assert re.search(r"GiB are available: at most \d+ members fit \(1\.\.\d+\)", err[0])
    assert list(tmp_path.iterdir()) == []


def test_a_deterministic_model_has_no_members(tmp_path, capsys, le_file, le_checkpoint):
    assert run(le_checkpoint, le_file, tmp_path / "p.h5", "--members", 2) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "deterministic" in err[0] and "--members 1" in err[0]
