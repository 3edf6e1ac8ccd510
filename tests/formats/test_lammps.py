"""LAMMPS/LIGGGHTS dump importer, on dumps written here in every supported column variant.

The reference trajectory moves particles at constant velocity in lattice-continuous
coordinates of a sheared cell (so they cross every face, the LE faces included) and is wrapped
with gripdem's LE rule. It is written in LAMMPS's axes (ours (x, y, z) = LAMMPS (y, z, x)) in
the tilted cell LAMMPS stores atoms in, with the LE offset as the xy tilt (so the tilt flips as
the offset wraps), particles and columns shuffled; the importer must give back the wrapped
positions, the velocities of the stored image and the LE settings.
"""

from __future__ import annotations

import gzip

import numpy as np
import pytest

from gripdem.boundary import Box, LeesEdwards, minimum_image, wrap_into_sheared_cell, wrap_positions
from gripdem.convert import main
from gripdem.data.dataset_io import read_dataset
from gripdem.formats.lammps import read_lammps
from gripdem.formats.lammps.series import AxisMap

D = 1.0e-3  # diameter (any units: the importer keeps the dump's)
BOX = Box(8 * D, 7 * D, 9 * D)  # ours; not cubic
SHEAR = 50.0  # 1/s: the offset grows 0.4 d per frame, so it wraps (the tilt flips) every ~22
ENGINE_DT = 2e-5  # engine time step; a frame every 50 steps
FRAME_STEPS = 50
FIRST_STEP = 1500
T0 = 0.004  # time at which the offset is 0
YZX = AxisMap.parse("yzx")


def reference(n=30, frames=40, seed=0, sheared=True):
    """Wrapped positions and box-image velocities ``(frames, n, 3)`` (ours), times."""
    rng = np.random.default_rng(seed)
    times = (FIRST_STEP + FRAME_STEPS * np.arange(frames)) * ENGINE_DT
    le = LeesEdwards(SHEAR, 1, T0) if sheared else None
    start = (rng.random((n, 3)) - 0.5) * BOX.lengths
    velocity = rng.normal(0.0, 0.15 * D, (n, 3)) / (FRAME_STEPS * ENGINE_DT)
    velocity[:, 2] *= 0.1
    t = (times - times[0])[:, None]
    continuous = start + t[..., None] * velocity
    velocities = np.broadcast_to(velocity, continuous.shape).copy()
    if sheared:  # the affine flow u_z = shear * x, integrated exactly
        continuous[..., 2] += SHEAR * (start[:, 0] * t + 0.5 * velocity[:, 0] * t**2)
        velocities[..., 2] += SHEAR * continuous[..., 0]
    offsets = le.offset(BOX, times) if sheared else np.zeros(frames)
    image_velocity = le.image_velocity(BOX) if sheared else 0.0
    wrapped, velocities = wrap_positions(
        continuous, BOX, offsets[:, None], velocities, image_velocity
    )
    return wrapped, velocities, times, offsets


def dump_variant(positions, velocities, times, offsets, columns, seed=0, tilted=True, images=True):
    """Dump text (LAMMPS axes) with ``columns`` in that order, particles shuffled per frame."""
    rng = np.random.default_rng(seed)
    frames, n, _ = positions.shape
    lo, lengths = YZX.to_lammps(-0.5 * BOX.lengths), YZX.to_lammps(BOX.lengths)
    out = []
    for f in range(frames):
        xy = offsets[f] if tilted else 0.0
        cell = np.array([[lengths[0], 0, 0], [xy, lengths[1], 0], [0, 0, lengths[2]]])
        inside = wrap_into_sheared_cell(positions[f], BOX, xy) if tilted else positions[f]
        r = YZX.to_lammps(inside)
        flags = rng.integers(-2, 3, (n, 3)) if images else np.zeros((n, 3), int)
        values = {
            "id": np.arange(1, n + 1) * 3 + 100,
            "type": np.ones(n, int),
            "x": r[:, 0],
            "y": r[:, 1],
            "z": r[:, 2],  # fmt: skip
            "vx": None,
            "vy": None,
            "vz": None,  # fmt: skip
        }
        v = YZX.to_lammps(velocities[f])
        values.update(vx=v[:, 0], vy=v[:, 1], vz=v[:, 2])
        scaled = (r - lo) @ np.linalg.inv(cell)
        unwrapped = r + flags @ cell
        for i, a in enumerate("xyz"):
            values[f"{a}s"] = scaled[:, i]
            values[f"{a}u"] = unwrapped[:, i]
            values[f"{a}su"] = scaled[:, i] + flags[:, i]
            values[f"i{a}"] = flags[:, i]
        low = lo + np.array([min(0.0, xy), 0.0, 0.0])
        high = lo + lengths + np.array([max(0.0, xy), 0.0, 0.0])
        head = "ITEM: BOX BOUNDS " + ("xy xz yz pp pp pp" if tilted else "pp pp pp") + "\n"
        rows = [
            f"{float(low[i])!r} {float(high[i])!r}"
            + (f" {float([xy, 0.0, 0.0][i])!r}" if tilted else "")
            for i in range(3)
        ]
        step = int(round(times[f] / ENGINE_DT))
        text = f"ITEM: TIMESTEP\n{step}\nITEM: NUMBER OF ATOMS\n{n}\n" + head
        text += "\n".join(rows) + f"\nITEM: ATOMS {' '.join(columns)}\n"
        order = rng.permutation(n)
        for i in order:
            text += " ".join(repr(float(values[c][i])) if c[0] in "xyzv" and not c.startswith("i")
                             else str(int(values[c][i])) for c in columns) + "\n"  # fmt: skip
        out.append(text)
    return out


def write(path, snapshots):
    text = "".join(snapshots)
    if str(path).endswith(".gz"):
        with gzip.open(path, "wt") as handle:
            handle.write(text)
    else:
        path.write_text(text)
    return path


def check_import(
    data, positions, velocities, times, offsets, with_velocities=True, offset_tol=1e-12 * BOX.lz
):
    assert data.boundary.lees_edwards is not None
    le = data.boundary.lees_edwards
    assert (le.sign, le.shear_rate) == (1, pytest.approx(SHEAR, rel=1e-9))
    np.testing.assert_allclose(data.times[0], times, rtol=1e-12)
    delta = minimum_image(np.asarray(data.offsets()[0] - offsets)[:, None] * [0, 0, 1], BOX)
    assert np.abs(delta).max() < offset_tol  # the same offsets (mod lz)
    assert np.abs(data.positions[0] - positions).max() < 1e-12 * BOX.lengths.max()
    if with_velocities:
        np.testing.assert_allclose(data.velocities[0], velocities, atol=1e-9 * D)


COLUMN_VARIANTS = {
    "wrapped": ["id", "type", "x", "y", "z", "vx", "vy", "vz"],
    "wrapped + image flags, shuffled columns": [
        "vz",
        "z",
        "iy",
        "x",
        "id",
        "ix",
        "y",
        "iz",
        "vx",
        "vy",
    ],  # fmt: skip
    "scaled": ["type", "xs", "ys", "zs", "id", "vx", "vy", "vz"],
    "scaled + image flags": ["id", "xs", "ys", "zs", "ix", "iy", "iz", "vx", "vy", "vz"],
    "unwrapped + image flags": ["id", "xu", "yu", "zu", "ix", "iy", "iz", "vx", "vy", "vz"],
    "scaled unwrapped + image flags": [
        "id",
        "vx",
        "vy",
        "vz",
        "xsu",
        "ysu",
        "zsu",
        "ix",
        "iy",
        "iz",
    ],  # fmt: skip
}


@pytest.mark.parametrize("variant", sorted(COLUMN_VARIANTS))
def test_every_column_variant_of_a_sheared_box_with_flips(tmp_path, variant):
    positions, velocities, times, offsets = reference()
    snaps = dump_variant(positions, velocities, times, offsets, COLUMN_VARIANTS[variant])
    path = write(tmp_path / "shear.dump.gz", snaps)
    data, report = read_lammps([path], diameter=D, timestep=ENGINE_DT, shear_rate=SHEAR)
    check_import(data, positions, velocities, times, offsets)
    text = "\n".join(report.lines())
    assert "axes: ours (x, y, z) = LAMMPS (y, z, x)" in text
    flips = int(text.split(" flip(s) undone")[0].rsplit(" ", 1)[1])
    assert flips >= 1  # the tilt wrapped: flips were undone
    assert "sign -1" in text and report.evidence.n_crossers > 0


def test_unwrapped_without_image_flags_keeps_positions_and_drops_velocities(tmp_path):
    positions, velocities, times, offsets = reference()
    cols = ["id", "xu", "yu", "zu", "vx", "vy", "vz"]
    path = write(tmp_path / "u.dump", dump_variant(positions, velocities, times, offsets, cols))
    data, report = read_lammps([path], diameter=D, timestep=ENGINE_DT)  # rate from the tilt
    check_import(data, positions, velocities, times, offsets, with_velocities=False)
    assert data.velocities is None
    assert any("velocities not imported" in note for note in report.notes)
    assert any("read from the tilt" in note for note in report.notes)


def test_one_snapshot_per_file_in_any_order_and_restart_duplicates(tmp_path):
    positions, velocities, times, offsets = reference()
    cols = COLUMN_VARIANTS["wrapped"]
    snaps = dump_variant(positions, velocities, times, offsets, cols)
    paths = [write(tmp_path / f"frame.{i}.dump", [s]) for i, s in enumerate(snaps)]
    repeat = write(tmp_path / "restart.dump", snaps[20:])  # a restart writes frame 20 again
    shuffled = list(np.random.default_rng(3).permutation([str(p) for p in paths[:21]]))
    data, report = read_lammps(
        [*shuffled, repeat], diameter=D, timestep=ENGINE_DT, shear_rate=SHEAR
    )
    check_import(data, positions, velocities, times, offsets)
    assert report.series[0].duplicates == 1


def test_split_files_are_simulations_and_the_cli_writes_the_dataset(tmp_path, capsys):
    a = reference(seed=1)
    b = reference(seed=2)
    cols = COLUMN_VARIANTS["scaled"]
    pa = write(tmp_path / "a.dump", dump_variant(*a, cols))
    pb = write(tmp_path / "b.dump.gz", dump_variant(*b, cols, seed=5))
    out = tmp_path / "out.h5"
    args = ["lammps", str(pa), str(pb), str(out), "--diameter", str(D)]
    args += ["--timestep", str(ENGINE_DT), "--shear-rate", str(SHEAR), "--split-files"]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "simulations: 2" in printed and "LE sign: +1" in printed and "wrote" in printed
    data = read_dataset(out)
    assert data.positions.shape == (2, 40, 30, 3)
    assert np.abs(data.positions[1] - b[0]).max() < 1e-12 * BOX.lengths.max()
    assert main(args) == 1  # never overwritten without --overwrite
    assert "refusing to overwrite" in capsys.readouterr().err


@pytest.mark.parametrize("coordinates", [["x", "y", "z"], ["xu", "yu", "zu"]])
def test_orthogonal_periodic_box_and_an_axis_map(tmp_path, coordinates):
    positions, velocities, times, offsets = reference(sheared=False)
    cols = ["id", *coordinates]
    snaps = dump_variant(positions, velocities, times, offsets, cols, tilted=False)
    path = write(tmp_path / "pbc.dump", snaps)
    data, report = read_lammps([path], diameter=D, timestep=ENGINE_DT, axes="yzx")
    assert data.boundary.kind == "periodic" and report.evidence.n_crossers > 0
    np.testing.assert_allclose(data.box.lengths, BOX.lengths)
    assert np.abs(data.positions[0] - positions).max() < 1e-12 * BOX.lengths.max()
    identity, _ = read_lammps([path], diameter=D, timestep=ENGINE_DT)
    np.testing.assert_allclose(identity.positions[0], YZX.to_lammps(positions), atol=1e-15)


def test_orthogonal_box_with_a_shear_rate_infers_the_le_convention(tmp_path):
    """LE data from an engine that keeps an orthogonal box: sign and origin from crossers."""
    positions, velocities, times, offsets = reference()
    snaps = dump_variant(positions, velocities, times, offsets, ["id", "x", "y", "z"], tilted=False)
    path = write(tmp_path / "le_orth.dump", snaps)
    data, report = read_lammps([path], diameter=D, timestep=ENGINE_DT, shear_rate=SHEAR, axes="yzx")
    # the origin is estimated from the crossers' z jumps (within 0.02 d, le_inference)
    check_import(data, positions, velocities, times, offsets, False, offset_tol=0.02 * D)
    assert report.tilt == [] and "estimated from the crossers" in "\n".join(report.lines())


# --------------------------------------------------------------------------------------------
# bad dumps: one clear message naming the file and the item, and nothing written
# --------------------------------------------------------------------------------------------
def _edit_snapshot(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new, 1)


def _bad(tmp_path, kind):
    positions, velocities, times, offsets = reference(n=12, frames=30)
    cols = COLUMN_VARIANTS["wrapped"]
    snaps = dump_variant(positions, velocities, times, offsets, cols)
    extra: list[str] = []
    if kind == "missing z column":
        snaps = dump_variant(positions, velocities, times, offsets, ["id", "x", "y", "vx"])
    elif kind == "missing id column":
        snaps = dump_variant(positions, velocities, times, offsets, ["x", "y", "z"])
    elif kind == "changing atom count":
        lines = snaps[7].splitlines()
        lines[3] = "11"
        snaps[7] = "\n".join(lines[:-1]) + "\n"
    elif kind == "atom lines short of the count":
        snaps[7] = "\n".join(snaps[7].splitlines()[:-1]) + "\n"
    elif kind == "box lengths change":
        lines = snaps[9].splitlines()
        lo, hi, tilt = lines[6].split()
        lines[6] = f"{lo} {float(hi) * 1.01!r} {tilt}"
        snaps[9] = "\n".join(lines) + "\n"
    elif kind == "tilt against shear rate":
        extra = ["--shear-rate", str(2 * SHEAR)]
    elif kind == "missing snapshot":
        del snaps[12]
    elif kind == "duplicate id":
        lines = snaps[3].splitlines()
        lines[-1] = " ".join([lines[-2].split()[0]] + lines[-1].split()[1:])
        snaps[3] = "\n".join(lines) + "\n"
    elif kind == "truncated file":
        snaps[-1] = "\n".join(snaps[-1].splitlines()[:-3]) + "\n"
    elif kind == "fixed boundary":
        snaps[0] = _edit_snapshot(snaps[0], "xy xz yz pp pp pp", "xy xz yz pp ff pp")
    elif kind == "two tilt factors":  # a yz tilt beside xy (y bounds widened to match)
        lines = snaps[4].splitlines()
        lo, hi, xz = lines[6].split()
        lines[6] = f"{lo} {float(hi) + 1e-4!r} {xz}"
        lines[7] = lines[7].rsplit(" ", 1)[0] + " 0.0001"
        snaps[4] = "\n".join(lines) + "\n"
    elif kind == "axes against the tilt":
        extra = ["--axes", "xyz"]
    elif kind == "same timestep, other coordinates":
        snaps.append(dump_variant(*reference(n=12, frames=30, seed=9), cols)[5])
    elif kind == "not a dump":
        snaps = ["hello\n"]
    path = write(tmp_path / "bad.dump", snaps)
    return path, extra


BAD = {
    "missing z column": ("ITEM: ATOMS", "expected a complete set of coordinate columns"),
    "missing id column": ("ITEM: ATOMS column id", "expected an 'id' column"),
    "changing atom count": ("ITEM: NUMBER OF ATOMS", "the atom count must not change"),
    "atom lines short of the count": ("ITEM: ATOMS", "expected 12 atom lines"),
    "box lengths change": ("ITEM: BOX BOUNDS", "box lengths"),
    "tilt against shear rate": ("tilt xy", "not --shear-rate 100"),
    "missing snapshot": ("ITEM: TIMESTEP", "expected equidistant snapshots"),
    "duplicate id": ("ITEM: ATOMS column id", "appears twice"),
    "truncated file": ("ITEM: ATOMS", "truncated?"),
    "fixed boundary": ("ITEM: BOX BOUNDS", "expected a periodic box"),
    "two tilt factors": ("ITEM: BOX BOUNDS", "one tilt factor"),
    "axes against the tilt": ("--axes xyz", "must be yzx"),
    "same timestep, other coordinates": ("ITEM: TIMESTEP", "appears twice with different"),
    "not a dump": ("ITEM: TIMESTEP", "is this a LAMMPS text dump?"),
}


@pytest.mark.parametrize("kind", sorted(BAD))
def test_bad_dumps_give_clear_errors_and_write_nothing(tmp_path, capsys, kind):
    path, extra = _bad(tmp_path, kind)
    out = tmp_path / "out.h5"
    args = ["lammps", str(path), str(out), "--diameter", str(D), "--timestep", str(ENGINE_DT)]
    assert main(args + extra) == 1
    err = capsys.readouterr().err
    field, message = BAD[kind]
    assert field in err and message in err, err
    if not kind.startswith("axes"):
        assert str(path) in err
    assert not out.exists()
    assert not list(tmp_path.glob(".out.h5*"))  # no temporary file left either


def test_body_force_is_recorded_for_periodic_dumps_and_refused_for_sheared_ones(tmp_path, capsys):
    positions, velocities, times, offsets = reference(sheared=False)
    path = write(
        tmp_path / "pbc.dump",
        dump_variant(positions, velocities, times, offsets, ["id", "x", "y", "z"], tilted=False),
    )
    out = tmp_path / "pbc.h5"
    common = ["--diameter", str(D), "--timestep", str(ENGINE_DT)]
    assert main(["lammps", str(path), str(out), *common, "--body-force", "250"]) == 0
    assert "body force: A = 250 (a_z = A cos(2 pi x / lx)" in capsys.readouterr().out
    assert read_dataset(out).body_force_amplitude == 250.0
    sheared = reference()
    tilted = write(tmp_path / "le.dump", dump_variant(*sheared, COLUMN_VARIANTS["scaled"]))
    le_out = tmp_path / "le.h5"
    assert main(["lammps", str(tilted), str(le_out), *common, "--body-force", "250"]) == 1
    err = capsys.readouterr().err
    assert f"{tilted}: --body-force 250: the data is Lees-Edwards" in err and not le_out.exists()
    assert main(["lammps", str(path), str(out), *common, "--body-force", "-3", "--overwrite"]) == 1
    assert "--body-force must be a finite acceleration >= 0" in capsys.readouterr().err
