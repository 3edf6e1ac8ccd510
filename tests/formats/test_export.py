"""Extended XYZ and LAMMPS dump exports read back to the same trajectories."""

import os
import shlex

import numpy as np
import pytest

from gripdem.boundary import Boundary, Box, LeesEdwards, minimum_image, rewrap_trajectory
from gripdem.evaluation.predictions import Predictions, write_predictions
from gripdem.formats.export import export_extxyz, export_lammps, write_lammps_dump
from gripdem.formats.lammps import read_lammps

BOX = Box(2.0, 2.5, 3.0)
DT = 0.05


def make_predictions(w=2, n=30, horizon=5, seed=0):
    rng = np.random.default_rng(seed)
    boundary = Boundary(BOX, LeesEdwards(2.0, 1, 0.0))
    start = (rng.random((w, 1, n, 3)) - 0.5) * BOX.lengths
    velocity = rng.normal(0, 0.06, (w, 1, n, 3)) * BOX.lengths
    continuous = start + np.arange(horizon + 1)[None, :, None, None] * velocity
    times = 1.0 + DT * np.arange(horizon + 1)[None, :] + np.arange(w)[:, None]
    offsets = boundary.offset(times)
    wrapped = np.stack(
        [rewrap_trajectory(c, BOX, o) for c, o in zip(continuous, offsets, strict=True)]
    )
    pred = wrapped[:, 1:].copy()
    pred[..., 1] = np.clip(pred[..., 1] + 0.01, -1.25, 1.2)  # a small error along y
    return Predictions(
        pred_positions=pred,
        true_positions=wrapped[:, 1:],
        last_positions=wrapped[:, 0],
        times=times[:, 1:],
        boundary=boundary,
        radius=0.05,
        baselines={"stay": np.repeat(wrapped[:, :1], horizon, axis=1)},
    )


def read_extxyz(path):
    """A small independent reader: frames of (comment key=value dict, rows)."""
    lines = path.read_text().splitlines()
    frames, i = [], 0
    while i < len(lines):
        n = int(lines[i])
        info = dict(item.split("=", 1) for item in shlex.split(lines[i + 1]))
        rows = [line.split() for line in lines[i + 2 : i + 2 + n]]
        frames.append((info, rows))
        i += 2 + n
    return frames


def test_extxyz_round_trip_of_true_and_predicted_trajectories(tmp_path):
    p = make_predictions()
    path = write_predictions(tmp_path / "predictions.h5", p)
    files = export_extxyz(path, tmp_path / "xyz", windows=[0, 1])
    assert sorted(files) == ["window000_pred", "window000_true", "window001_pred", "window001_true"]
    true = read_extxyz(files["window001_true"])
    pred = read_extxyz(files["window001_pred"])
    assert len(true) == len(pred) == 6  # last observed + 5 horizon steps
    info, rows = true[3]
    delta = float(p.boundary.offset(p.times[1, 2]))
    assert info["Lattice"] == f"2.0 0 {delta!r} 0 2.5 0 0 0 3.0"  # the LE lattice of the frame
    assert info["Origin"] == "-1.0 -1.25 -1.5" and info["pbc"] == "T T T"
    assert info["Properties"] == "species:S:1:pos:R:3:radius:R:1:id:I:1:crosser:I:1"
    assert float(info["Time"]) == pytest.approx(p.times[1, 2])
    assert float(info["le_offset"]) == pytest.approx(p.boundary.offset(p.times[1, 2]))
    positions = np.array([[float(v) for v in row[1:4]] for row in rows])
    # the same images, moved into the sheared parallelepiped the viewer draws from Origin
    same = minimum_image(positions - p.true_positions[1, 2], BOX, delta)
    np.testing.assert_allclose(same, 0.0, atol=1e-10)  # 12 digits written
    inside = positions[:, 2] - (positions[:, 0] / BOX.lx + 0.5) * delta
    assert (np.abs(positions[:, :2]) <= 0.5 * BOX.lengths[:2]).all()
    assert (np.abs(inside) <= 0.5 * BOX.lz + 1e-10).all()
    assert {row[0] for row in rows} == {"P"} and float(rows[0][4]) == 0.05
    assert [int(row[5]) for row in rows] == list(range(1, 31))
    assert sum(int(row[6]) for row in rows) > 0  # some particles cross an x face
    first = np.array([[float(v) for v in row[1:4]] for row in pred[0][1]])
    last_offset = float(pred[0][0]["le_offset"])
    same = minimum_image(first - p.last_positions[1], BOX, last_offset)
    np.testing.assert_allclose(same, 0.0, atol=1e-10)
    # the prediction file carries the minimum-image distance to the truth
    info, rows = pred[4]
    assert info["Properties"].endswith(":error:R:1")
    errors = np.array([float(row[7]) for row in rows])
    assert np.all(np.abs(errors - 0.01) < 0.02) and float(pred[0][1][0][7]) == 0.0


def test_extxyz_refuses_to_overwrite_and_exports_baselines(tmp_path):
    p = make_predictions()
    export_extxyz(p, tmp_path)
    with pytest.raises(FileExistsError):
        export_extxyz(p, tmp_path)
    files = export_extxyz(p, tmp_path, baselines=True, overwrite=True)
    assert "window000_stay" in files
    assert sorted(os.listdir(tmp_path)) == [
        "window000_pred.xyz",
        "window000_stay.xyz",
        "window000_true.xyz",
    ]
    with pytest.raises(IndexError, match="window 5"):
        export_extxyz(p, tmp_path, windows=[5], overwrite=True)


def test_extxyz_is_read_by_ase_when_available(tmp_path):
    ase_io = pytest.importorskip("ase.io")
    p = make_predictions()
    files = export_extxyz(p, tmp_path)
    atoms = ase_io.read(files["window000_pred"], index=":")
    assert len(atoms) == 6
    delta = p.boundary.offset(p.times[0, 1])
    same = minimum_image(atoms[2].positions - p.pred_positions[0, 1], BOX, delta)
    np.testing.assert_allclose(same, 0.0, atol=1e-11)
    np.testing.assert_allclose(atoms[2].cell.array, [[2.0, 0, delta], [0, 2.5, 0], [0, 0, 3.0]])
    assert atoms[2].info["window"] == 0 and "error" in atoms[2].arrays


def read_orthogonal_dump(path):
    lines = path.read_text().splitlines()
    frames, i = [], 0
    while i < len(lines):
        assert lines[i] == "ITEM: TIMESTEP"
        step, n = int(lines[i + 1]), int(lines[i + 3])
        bounds = np.array([[float(v) for v in lines[i + 5 + k].split()] for k in range(3)])
        assert lines[i + 8] == "ITEM: ATOMS id type x y z radius"
        table = np.array([[float(v) for v in line.split()] for line in lines[i + 9 : i + 9 + n]])
        frames.append((step, bounds, table))
        i += 9 + n
    return frames


def test_lammps_dump_round_trip(tmp_path):
    p = make_predictions()
    path = write_lammps_dump(
        tmp_path / "x.dump", p.true_positions[0], BOX.lengths, 0.05, timesteps=np.arange(5) * 100
    )  # no offsets: an orthogonal box in gripdem's axes
    frames = read_orthogonal_dump(path)
    step, bounds, table = frames[3]
    assert step == 300
    np.testing.assert_allclose(bounds, [[-1.0, 1.0], [-1.25, 1.25], [-1.5, 1.5]])
    np.testing.assert_allclose(table[:, 2:5], p.true_positions[0, 3], rtol=1e-11, atol=1e-12)
    assert (table[:, 0] == np.arange(1, 31)).all() and (table[:, 5] == 0.05).all()


def test_lees_edwards_dump_is_a_sheared_lammps_box_that_reads_back(tmp_path):
    p = make_predictions()
    files = export_lammps(p, tmp_path, window=1)
    text = files["window001_pred"].read_text()
    assert "ITEM: BOX BOUNDS xy xz yz pp pp pp" in text
    data, report = read_lammps([files["window001_pred"]], diameter=0.1, timestep=DT)
    assert report.axes.name == "yzx" and data.boundary.is_lees_edwards
    assert data.boundary.lees_edwards.shear_rate == pytest.approx(2.0)
    offsets = p.boundary.offset(np.concatenate([[p.times[1, 0] - DT], p.times[1]]))
    np.testing.assert_allclose(data.offsets()[0], offsets, atol=1e-12)
    expected = np.concatenate([p.last_positions[1][None], p.pred_positions[1]])
    same = minimum_image(data.positions[0] - expected, BOX, offsets[:, None])
    np.testing.assert_allclose(same, 0.0, atol=1e-10)  # 12 digits written
