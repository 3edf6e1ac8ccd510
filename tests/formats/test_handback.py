"""``python -m gripdem.handback``: the LAMMPS data file and extended XYZ of a state, and the round
trip gripdem -> LAMMPS dump -> gripdem."""

from __future__ import annotations

import shlex

import numpy as np
import pytest

from gripdem.boundary import minimum_image, wrap_positions
from gripdem.convert import main as convert
from gripdem.data.dataset_io import read_dataset
from gripdem.formats.lammps.series import AxisMap
from gripdem.handback import main

YZX = AxisMap.parse("yzx")


def read_data_file(path):
    """A small independent reader of the data file handback writes: header values, the
    box, the tilt and the Atoms/Velocities rows."""
    lines = path.read_text().splitlines()
    out = {"bounds": [], "tilt": None}
    for line in lines[1:]:
        words = line.split()
        if line.endswith(" atoms"):
            out["atoms"] = int(words[0])
        elif len(words) == 4 and words[2].endswith("lo"):
            out["bounds"].append((float(words[0]), float(words[1])))
        elif line.endswith("xy xz yz"):
            out["tilt"] = [float(w) for w in words[:3]]
    start = lines.index("Velocities")
    atoms = [line.split() for line in lines[lines.index("Atoms # sphere") + 2 : start - 1]]
    velocities = [line.split() for line in lines[start + 2 :] if line.strip()]
    out["atoms_rows"] = np.array(atoms, dtype=float)
    out["velocity_rows"] = np.array(velocities, dtype=float)
    return out


def expected_velocities(data, sim, frame):
    """Velocity of each wrapped particle at ``frame``: its displacement from the previous frame
    (LE minimum image, later offset), minus one image velocity per x face it crossed."""
    offsets = data.offsets()[sim]
    last, prev = data.positions[sim, frame], data.positions[sim, frame - 1]
    step = minimum_image(last - prev, data.box, offsets[frame])
    crossed = np.round((prev[:, 0] + step[:, 0] - last[:, 0]) / data.box.lx)
    velocity = step / data.frame_interval
    velocity[:, 2] -= crossed * data.boundary.image_velocity
    return velocity, crossed


def test_data_file_and_extended_xyz_of_the_last_frame(tmp_path, capsys, le_file):
    data = read_dataset(le_file)
    out, xyz = tmp_path / "state.data", tmp_path / "state.xyz"
    args = [str(le_file), "--sim", "1", "--data", str(out), "--xyz", str(xyz)]
    assert main(args) == 1  # sphere style needs a density: the test data names none
    assert "give --density" in capsys.readouterr().err and not out.exists()
    assert main([*args, "--density", "2500"]) == 0
    printed = capsys.readouterr().out
    rate = data.boundary.lees_edwards.shear_rate
    assert f"fix ID all deform 1 xy erate {rate:.9g} remap v" in printed
    parsed = read_data_file(out)
    frame, offset = data.n_frames - 1, data.offsets()[1, -1]
    assert parsed["atoms"] == data.n_particles
    lengths = YZX.to_lammps(data.box.lengths)
    np.testing.assert_allclose([hi - lo for lo, hi in parsed["bounds"]], lengths)
    assert parsed["tilt"] == [pytest.approx(offset, abs=1e-18), 0.0, 0.0]
    assert -lengths[0] / 2 <= offset < lengths[0] / 2
    rows = parsed["atoms_rows"]
    np.testing.assert_allclose(rows[:, 2], data.diameter)  # id type diameter density x y z
    positions = YZX.to_ours(rows[:, 4:7])
    # inside LAMMPS's tilted cell: x fraction in [0, 1) along a = (Lx, 0, 0) after the tilt
    lam = rows[:, 4:7]
    frac_y = (lam[:, 1] - parsed["bounds"][1][0]) / lengths[1]
    frac_x = (lam[:, 0] - parsed["bounds"][0][0] - frac_y * offset) / lengths[0]
    assert ((0 <= frac_x) & (frac_x < 1) & (0 <= frac_y) & (frac_y < 1)).all()
    np.testing.assert_allclose(
        wrap_positions(positions, data.box, offset), data.positions[1, frame], atol=1e-18
    )
    velocity, crossed = expected_velocities(data, 1, frame)
    assert np.any(crossed != 0)  # a particle that just crossed an LE face carries the jump
    np.testing.assert_allclose(YZX.to_ours(parsed["velocity_rows"][:, 1:4]), velocity, rtol=1e-9)
    lines = xyz.read_text().splitlines()
    info = dict(item.split("=", 1) for item in shlex.split(lines[1]))
    lattice = np.array(info["Lattice"].split(), dtype=float).reshape(3, 3)
    np.testing.assert_allclose(lattice[0], [data.box.lx, 0, offset])
    assert info["Properties"].startswith("species:S:1:pos:R:3:velo:R:3")
    table = np.array([line.split()[1:] for line in lines[2:]], dtype=float)
    np.testing.assert_allclose(table[:, :3], positions, atol=1e-18)
    np.testing.assert_allclose(table[:, 3:6], velocity, rtol=1e-9)


@pytest.mark.parametrize("name", ["traj.dump", "traj.dump.gz"])
def test_round_trip_through_a_lammps_dump_reproduces_the_positions(tmp_path, name, le_file):
    data = read_dataset(le_file)
    dump, back = tmp_path / name, tmp_path / "back.h5"
    engine_dt = data.frame_interval / 50
    args = [str(le_file), "--sim", "2", "--dump", str(dump), "--timestep", repr(engine_dt)]
    assert main(args) == 0
    args = ["lammps", str(dump), str(back), "--diameter", repr(data.diameter)]
    args += [
        "--timestep",
        repr(engine_dt),
        "--shear-rate",
        repr(data.boundary.lees_edwards.shear_rate),
    ]
    assert convert(args) == 0
    again = read_dataset(back)
    assert np.abs(again.positions[0] - data.positions[2]).max() < 1e-12 * data.box.lengths.max()
    np.testing.assert_allclose(again.times[0], data.times[2], rtol=1e-12)
    same = np.abs(again.offsets()[0] - data.offsets()[2])
    assert np.minimum(same, data.box.lz - same).max() < 1e-12 * data.box.lz
    assert again.boundary.lees_edwards.sign == data.boundary.lees_edwards.sign


def test_periodic_state_in_an_orthogonal_box_and_atomic_style(tmp_path, capsys, pbc_file):
    out = tmp_path / "p.data"
    assert main([str(pbc_file), "--data", str(out), "--atom-style", "atomic"]) == 1
    assert "needs --mass" in capsys.readouterr().err
    assert main([str(pbc_file), "--data", str(out), "--atom-style", "atomic", "--mass", "2"]) == 0
    text = out.read_text()
    assert "xy xz yz" not in text and "Masses\n\n1 2.0" in text and "Atoms # atomic" in text
    assert main([str(pbc_file), "--data", str(out), "--atom-style", "atomic", "--mass", "2"]) == 1
    assert "refusing to overwrite" in capsys.readouterr().err
