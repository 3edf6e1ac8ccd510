"""The gripdem HDF5 format: round trip, atomic writes, and one test per bad-input case."""

import json
import os

import h5py
import numpy as np
import pytest

from gripdem.boundary import Boundary, Box, LeesEdwards
from gripdem.data.dataset_io import read_dataset, read_meta, write_dataset
from gripdem.data.schema import DatasetError, TrajectoryData

BOX = Box(1.0, 1.2, 0.8)


def make_data(sims=2, frames=6, particles=10, le=True, seed=0) -> TrajectoryData:
    rng = np.random.default_rng(seed)
    positions = (rng.random((sims, frames, particles, 3)) - 0.5) * BOX.lengths
    times = 7.0 + 0.01 * np.arange(frames)[None, :] + np.zeros((sims, 1))
    boundary = Boundary(BOX, LeesEdwards(10.0, sign=-1, time_origin=6.5) if le else None)
    return TrajectoryData(
        positions=positions,
        times=times,
        boundary=boundary,
        radius=0.05,
        body_force_amplitude=0.0 if le else 3.0,
        provenance={"generator": "test", "version": "1", "parameters": {"seed": seed}},
        velocities=rng.normal(size=positions.shape),
    )


def test_round_trip_keeps_everything(tmp_path):
    data = make_data()
    path = write_dataset(tmp_path / "d.h5", data)
    back = read_dataset(path)
    np.testing.assert_array_equal(back.positions, data.positions)
    np.testing.assert_array_equal(back.times, data.times)
    np.testing.assert_array_equal(back.velocities, data.velocities)
    assert back.boundary == data.boundary
    assert back.radius == 0.05 and back.provenance == data.provenance
    meta = read_meta(path)
    assert (meta.n_sims, meta.n_frames, meta.n_particles) == (2, 6, 10)
    assert meta.frame_interval == pytest.approx(0.01)
    assert meta.boundary.lees_edwards.sign == -1
    np.testing.assert_allclose(back.offsets(), data.boundary.offset(data.times))
    with h5py.File(path) as h5:
        assert h5.attrs["boundary"] == "lees_edwards"
        assert json.loads(h5.attrs["provenance"])["generator"] == "test"


def test_periodic_round_trip_and_per_particle_radii(tmp_path):
    data = make_data(le=False)
    data.radii = np.full(10, 0.05)
    back = read_dataset(write_dataset(tmp_path / "p.h5", data))
    assert back.boundary.kind == "periodic" and back.body_force_amplitude == 3.0
    np.testing.assert_array_equal(back.radii, data.radii)


def test_writer_refuses_to_overwrite(tmp_path):
    path = write_dataset(tmp_path / "d.h5", make_data(seed=1))
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match="refusing to overwrite"):
        write_dataset(path, make_data(seed=2))
    assert path.read_bytes() == before
    write_dataset(path, make_data(seed=2), overwrite=True)
    np.testing.assert_array_equal(read_dataset(path).positions, make_data(seed=2).positions)


def test_failed_write_leaves_nothing_behind(tmp_path, monkeypatch):
    path = write_dataset(tmp_path / "d.h5", make_data(seed=1))
    before = path.read_bytes()

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(json, "dumps", interrupted)  # dies after the arrays are written
    with pytest.raises(KeyboardInterrupt):
        write_dataset(path, make_data(seed=2), overwrite=True)
    with pytest.raises(KeyboardInterrupt):
        write_dataset(tmp_path / "new.h5", make_data(seed=2))
    assert sorted(os.listdir(tmp_path)) == ["d.h5"]
    assert path.read_bytes() == before


def test_invalid_data_is_never_written(tmp_path):
    data = make_data()
    data.positions[0, 1, 2, 0] = np.nan
    with pytest.raises(DatasetError, match="positions.*NaN"):
        write_dataset(tmp_path / "d.h5", data)
    assert os.listdir(tmp_path) == []


# ---------------------------------------------------------------------------------------------
# bad files: one case each, the message names the file, the field and the expectation
# ---------------------------------------------------------------------------------------------
def _write_then_edit(tmp_path, edit, data=None):
    path = write_dataset(tmp_path / "bad.h5", data or make_data())
    with h5py.File(path, "r+") as h5:
        edit(h5)
    return path


def _replace(h5, name, values):
    del h5[name]
    h5.create_dataset(name, data=values)


CASES = {
    "missing positions": (lambda h5: h5.__delitem__("positions"), "positions", "missing dataset"),
    "missing times": (lambda h5: h5.__delitem__("times"), "times", "missing dataset"),
    "missing box": (lambda h5: h5.attrs.__delitem__("box"), "box", "missing attribute"),
    "missing radius": (lambda h5: h5.attrs.__delitem__("radius"), "radius", "missing attribute"),
    "missing boundary": (
        lambda h5: h5.attrs.__delitem__("boundary"),
        "boundary",
        "missing attribute",
    ),
    "unknown boundary": (
        lambda h5: h5.attrs.__setitem__("boundary", "shear"),
        "boundary",
        "expected one of",
    ),
    "LE without shear rate": (
        lambda h5: h5.attrs.__setitem__("shear_rate", 0.0),
        "shear_rate",
        "positive shear rate",
    ),
    "bad LE sign": (lambda h5: h5.attrs.__setitem__("le_sign", 3), "le_sign", r"\+1 or -1"),
    "box shape": (lambda h5: h5.attrs.__setitem__("box", [1.0, 1.0]), "box", "3 positive"),
    "positions shape": (
        lambda h5: _replace(h5, "positions", np.zeros((2, 6, 10, 2))),
        "positions",
        r"expected shape \(sims, frames, particles, 3\)",
    ),
    "positions dtype": (
        lambda h5: _replace(h5, "positions", np.zeros((2, 6, 10, 3), np.float32)),
        "positions",
        "expected float64",
    ),
    "integer positions": (
        lambda h5: _replace(h5, "positions", np.zeros((2, 6, 10, 3), np.int64)),
        "positions",
        "floating-point",
    ),
    "times shape": (
        lambda h5: _replace(h5, "times", np.zeros((2, 5))),
        "times",
        r"\(sims, frames\) = \(2, 6\)",
    ),
    "times NaN": (
        lambda h5: h5["times"].__setitem__((1, 3), np.nan),
        "times",
        "NaN/Inf",
    ),
    "times not increasing": (
        lambda h5: h5["times"].__setitem__((0, 3), 7.0),
        "times",
        "strictly increasing",
    ),
    "times not equidistant": (
        lambda h5: h5["times"].__setitem__((1, 3), 7.0305),
        "times",
        "equidistant",
    ),
    "velocities shape": (
        lambda h5: _replace(h5, "velocities", np.zeros((2, 6, 10))),
        "velocities",
        "like positions",
    ),
    "impossible volume fraction": (
        lambda h5: h5.attrs.__setitem__("radius", 0.25),
        "radius",
        "random close packing",
    ),
    "negative radius": (
        lambda h5: h5.attrs.__setitem__("radius", -1.0),
        "radius",
        "positive particle radius",
    ),
    "provenance not JSON": (
        lambda h5: h5.attrs.__setitem__("provenance", "{oops"),
        "provenance",
        "JSON",
    ),
    "not a gripdem file": (
        lambda h5: h5.attrs.__setitem__("format", "other"),
        "format",
        "expected 'gripdem'",
    ),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_file_errors_name_file_and_field(tmp_path, case):
    edit, field, message = CASES[case]
    path = _write_then_edit(tmp_path, edit)
    with pytest.raises(DatasetError, match=message) as info:
        read_dataset(path)
    assert str(path) in str(info.value)
    assert f"field '{field}'" in str(info.value)
    assert info.value.field == field


@pytest.mark.parametrize(
    ("value", "message"),
    [(np.inf, "NaN/Inf"), (0.75, r"\[-l/2, l/2\).*axis z")],
)
def test_bad_positions_are_found(tmp_path, value, message):
    def edit(h5):
        h5["positions"][1, 4, 3, 2] = value

    path = _write_then_edit(tmp_path, edit)
    with pytest.raises(DatasetError, match=message):
        read_meta(path)  # the load-time check streams the positions
    with pytest.raises(DatasetError, match=message) as info:
        read_dataset(path)
    assert "field 'positions'" in str(info.value)


def test_positions_on_the_upper_face_are_tolerated(tmp_path):
    data = make_data()
    data.positions[0, 0, 0] = 0.5 * BOX.lengths  # some writers wrap to (-l/2, l/2]
    read_dataset(write_dataset(tmp_path / "d.h5", data))


def test_missing_and_non_hdf5_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.h5"):
        read_meta(tmp_path / "nope.h5")
    junk = tmp_path / "junk.h5"
    junk.write_text("not hdf5")
    with pytest.raises(DatasetError, match="junk.h5.*expected an HDF5 file"):
        read_meta(junk)
