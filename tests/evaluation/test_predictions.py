"""predictions.h5: round trip, atomic writes, validation, and metrics recomputed from the file."""

import json
import math
import os

import h5py
import numpy as np
import pytest

from gripdem.boundary import Boundary, Box, LeesEdwards, rewrap_trajectory
from gripdem.data.schema import DatasetError
from gripdem.evaluation.evaluate import evaluate_predictions
from gripdem.evaluation.predictions import Predictions, read_predictions, write_predictions

BOX = Box(2.0, 2.5, 3.0)
LE = LeesEdwards(shear_rate=2.0, sign=-1, time_origin=0.1)
DT = 0.05


def make_predictions(w=3, n=40, horizon=6, le=True, seed=0, noise=0.01) -> Predictions:
    """Ballistic truth (crossing LE faces), a noisy prediction and a 'stay' baseline."""
    rng = np.random.default_rng(seed)
    boundary = Boundary(BOX, LE if le else None)
    start = (rng.random((w, 1, n, 3)) - 0.5) * BOX.lengths
    velocity = rng.normal(0, 0.05, (w, 1, n, 3)) * BOX.lengths
    continuous = start + np.arange(horizon + 1)[None, :, None, None] * velocity
    times = 2.3 + DT * np.arange(horizon + 1)[None, :] + 0.7 * np.arange(w)[:, None]
    offsets = boundary.offset(times)
    wrapped = np.stack(
        [rewrap_trajectory(c, BOX, o) for c, o in zip(continuous, offsets, strict=True)]
    )
    true = wrapped[:, 1:]
    pred = rewrap_trajectory(
        (true + rng.normal(0, noise, true.shape)).reshape(-1, n, 3),
        BOX,
        offsets[:, 1:].reshape(-1),
    ).reshape(true.shape)
    return Predictions(
        pred_positions=pred.astype(np.float32),
        true_positions=true,
        last_positions=wrapped[:, 0],
        times=times[:, 1:],
        boundary=boundary,
        radius=0.05,
        protocol="sims",
        sim_index=np.arange(w),
        window_start=np.full(w, 11),
        baselines={"stay": np.repeat(wrapped[:, :1], horizon, axis=1)},
        info={"scene": "lebc" if le else "pbc", "split": "5-6", "model": "vct"},
    )


def slow_rmse(pred, true, times, boundary):
    """The RMSE of docs/spec/evaluation.md#rmse with a per-particle Python loop and the
    minimum-image if-tests of docs/spec/conventions.md#minimum-image."""
    box = boundary.box
    total, count = 0.0, 0
    w, f, n, _ = true.shape
    for a in range(w):
        for t in range(f):
            delta = float(boundary.offset(times[a, t]))
            for i in range(n):
                r = [float(true[a, t, i, k]) - float(pred[a, t, i, k]) for k in range(3)]
                if r[0] >= box.lx / 2:
                    r[0], r[2] = r[0] - box.lx, r[2] - delta
                elif r[0] < -box.lx / 2:
                    r[0], r[2] = r[0] + box.lx, r[2] + delta
                r[1] -= box.ly * math.floor(r[1] / box.ly + 0.5)
                r[2] -= box.lz * math.floor(r[2] / box.lz + 0.5)
                total += sum(c * c for c in r)
                count += 1
    return math.sqrt(total / count)


def test_round_trip_keeps_everything(tmp_path):
    p = make_predictions()
    path = write_predictions(tmp_path / "predictions.h5", p)
    back = read_predictions(path)
    assert back.pred_positions.dtype == np.float32  # the model's own precision is kept
    for name in (
        "pred_positions",
        "true_positions",
        "last_positions",
        "times",
        "sim_index",
        "window_start",
    ):
        np.testing.assert_array_equal(getattr(back, name), getattr(p, name))
    np.testing.assert_array_equal(back.baselines["stay"], p.baselines["stay"])
    assert back.boundary == p.boundary and back.radius == 0.05
    assert back.frame_interval == pytest.approx(DT)
    assert (back.in_sample, back.protocol, back.info) == (False, "sims", p.info)
    assert back.title() == "lebc / 5-6 / vct (out-of-sample, sims)"
    with h5py.File(path) as h5:
        assert h5.attrs["format"] == "gripdem-predictions"
        assert h5.attrs["boundary"] == "lees_edwards" and h5.attrs["le_sign"] == -1
        assert json.loads(h5.attrs["run"])["model"] == "vct"
        assert h5["pred_positions"].shape == (3, 6, 40, 3)


def test_evaluate_recomputes_metrics_from_the_file(tmp_path):
    p = make_predictions()
    path = write_predictions(tmp_path / "predictions.h5", p)
    out = evaluate_predictions(path)
    assert out["rmse"] == pytest.approx(
        slow_rmse(p.pred_positions, p.true_positions, p.times, p.boundary), rel=1e-6
    )
    assert out["rmse"] == pytest.approx(0.01 * math.sqrt(3), rel=0.15)
    assert out["rmse_over_d"] == pytest.approx(out["rmse"] / 0.1)
    assert out["baseline/stay/rmse"] == pytest.approx(
        slow_rmse(p.baselines["stay"], p.true_positions, p.times, p.boundary), rel=1e-9
    )
    steps = [out[f"rmse_step/{k:03d}"] for k in range(1, 7)]
    assert math.sqrt(np.mean(np.square(steps))) == pytest.approx(out["rmse"])
    assert out["n_crossers"] > 0 and math.isfinite(out["rmse_crossers"])
    assert out["physics/truth/overlap_fraction"] >= 0
    assert out["physics/model/profile_error_over_d"] > 0
    assert out["physics/truth/msd_last_over_d2"] > 0
    assert out["crossers/n"] == out["n_crossers"]
    assert out["crossers/model/rmse_over_d"] == pytest.approx(out["rmse_crossers"] / 0.1)
    assert (out["n_windows"], out["n_particles"], out["horizon"], out["in_sample"]) == (
        3,
        40,
        6,
        False,
    )
    json.dumps(out)  # metrics.json-ready
    # periodic data: no crosser keys; a perfect prediction has zero error
    q = make_predictions(le=False)
    q.pred_positions = q.true_positions.copy()
    per = evaluate_predictions(q, physics=False)
    assert (
        per["rmse"] == 0.0
        and "n_crossers" not in per
        and not any(k.startswith("physics/") for k in per)
    )


def test_writer_refuses_to_overwrite_and_leaves_nothing_on_failure(tmp_path, monkeypatch):
    path = write_predictions(tmp_path / "predictions.h5", make_predictions(seed=1))
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match="refusing to overwrite"):
        write_predictions(path, make_predictions(seed=2))
    assert path.read_bytes() == before

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(json, "dumps", interrupted)  # dies after the arrays are written
    with pytest.raises(KeyboardInterrupt):
        write_predictions(path, make_predictions(seed=2), overwrite=True)
    assert sorted(os.listdir(tmp_path)) == ["predictions.h5"]
    assert path.read_bytes() == before
    monkeypatch.undo()
    write_predictions(path, make_predictions(seed=2), overwrite=True)
    np.testing.assert_array_equal(
        read_predictions(path).true_positions, make_predictions(seed=2).true_positions
    )


def _nan_pred(p):
    p.pred_positions[0, 1, 2, 0] = np.nan


def _outside(p):
    p.true_positions[0, 0, 0, 2] = 0.6 * BOX.lz


@pytest.mark.parametrize(
    ("edit", "field", "message"),
    [
        (_nan_pred, "pred_positions", "NaN"),
        (_outside, "true_positions", "axis z"),
        (lambda p: setattr(p, "times", p.times[:, :-1]), "times", "expected shape"),
        (
            lambda p: setattr(p, "last_positions", p.last_positions[:, :-1]),
            "last_positions",
            "expected shape",
        ),
        (
            lambda p: p.baselines.update(stay=p.baselines["stay"][:1]),
            "baseline/stay",
            "expected shape",
        ),
        (lambda p: setattr(p, "sim_index", np.arange(5)), "sim_index", "expected shape"),
        (lambda p: setattr(p, "in_sample", True), "in_sample", "in_sample"),
        (lambda p: setattr(p, "protocol", "auto"), "protocol", "expected one of"),
    ],
)
def test_bad_predictions_are_refused_with_the_field_named(tmp_path, edit, field, message):
    p = make_predictions()
    edit(p)
    with pytest.raises(DatasetError, match=f"field '{field}'.*{message}"):
        write_predictions(tmp_path / "predictions.h5", p)
    assert os.listdir(tmp_path) == []


def test_reader_errors_name_the_file_and_field(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_predictions(tmp_path / "nope.h5")
    path = write_predictions(tmp_path / "predictions.h5", make_predictions())
    with h5py.File(path, "a") as h5:
        del h5["times"]
    with pytest.raises(DatasetError, match="predictions.h5: field 'times': missing"):
        read_predictions(path)
    with h5py.File(path, "a") as h5:
        h5.attrs["format"] = "gripdem"
    with pytest.raises(DatasetError, match="field 'format'"):
        read_predictions(path)


def test_in_sample_protocol_is_labelled_in_sample_and_short_horizons_need_an_interval(tmp_path):
    q = make_predictions()
    q.protocol, q.in_sample = "in_sample", True
    back = read_predictions(write_predictions(tmp_path / "p.h5", q))
    assert back.in_sample and "in-sample" in back.title()
    with h5py.File(tmp_path / "p.h5", "a") as h5:  # a file written before the rename
        h5.attrs["protocol"] = "paper"
    assert read_predictions(tmp_path / "p.h5").protocol == "in_sample"
    assert evaluate_predictions(back, physics=False)["in_sample"] is True
    with pytest.raises(ValueError, match="frame_interval"):
        Predictions(
            q.pred_positions[:, :1],
            q.true_positions[:, :1],
            q.last_positions,
            q.times[:, :1],
            q.boundary,
            0.05,
        )


def test_torch_outputs_are_accepted(tmp_path):
    torch = pytest.importorskip("torch")
    p = make_predictions()
    q = Predictions(
        torch.tensor(p.pred_positions),
        torch.tensor(p.true_positions),
        torch.tensor(p.last_positions),
        torch.tensor(p.times),
        p.boundary,
        p.radius,
        baselines={"stay": torch.tensor(p.baselines["stay"])},
        sim_index=torch.arange(3),
    )
    assert isinstance(q.true_positions, np.ndarray) and q.pred_positions.dtype == np.float32
    assert q.sim_index.dtype == np.int64
    back = read_predictions(write_predictions(tmp_path / "t.h5", q))
    np.testing.assert_array_equal(back.pred_positions, p.pred_positions)
    assert evaluate_predictions(back)["rmse"] == evaluate_predictions(p)["rmse"]
