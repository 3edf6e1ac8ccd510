"""Importer of the authors' Fordatis format, on archives written here in their layout.

Each file holds one group ``Step#k`` per frame with attrs Time/Lower/Upper and datasets
Identifier/Coords_0..2, particles shuffled in every frame. Lees-Edwards trajectories are
integrated in continuous coordinates under ``u_z = sign*shear_rate*x`` plus small random motion
and wrapped frame by frame with the offset of their own sign convention (the authors' is -1).
"""

from __future__ import annotations

import subprocess
import sys

import h5py
import numpy as np
import pytest
from fordatis_files import (
    BOX,
    DT,
    SHEAR,
    T_START,
    D,
    assert_same_positions,
    by_id,
    le_archive,
    make_trajectory,
    write_archive,
    write_h5,
)

from gripdem.boundary import LeesEdwards, wrap_coordinate
from gripdem.convert import main
from gripdem.data.dataset_io import read_dataset
from gripdem.data.schema import DatasetError
from gripdem.formats.fordatis import read_fordatis


# --------------------------------------------------------------------------------------------
# periodic data, layout variants
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("time_scalar", [False, True])
def test_periodic_archive_all_files_become_simulations(tmp_path, time_scalar):
    truths = [make_trajectory(seed, frames=12) for seed in (1, 2, 3)]
    members = {
        f"pbc/file{i}.h5": write_h5(tmp_path / f"{i}.h5", *t, time_scalar=time_scalar, seed=i)
        for i, t in enumerate(truths)
    }
    archive = write_archive(tmp_path / "pbc.tar.gz", members)
    data, report = read_fordatis(archive)
    assert data.positions.shape == (3, 12, 80, 3)
    assert data.boundary.kind == "periodic"
    assert data.radius == pytest.approx(D / 2)
    assert report.evidence.n_crossers > 0  # periodic crossers were checked, not ignored
    for s, (pos, times, ids) in enumerate(truths):
        assert_same_positions(data.positions[s], by_id(pos, ids))
        np.testing.assert_array_equal(data.times[s], times)
    assert [sim.name for sim in report.files] == [f"{archive}[pbc/file{i}.h5]" for i in range(3)]


def test_single_file_off_centre_box_and_drop_frames(tmp_path):
    pos, times, ids = make_trajectory(4, frames=15)
    centre = (1.6e-5, 1.4e-5, 1.8e-5)  # Lower = 0, Upper = box lengths (a common layout)
    path = write_h5(tmp_path / "one.h5", pos, times, ids, centre=centre, first_step=3)
    data, report = read_fordatis(path, drop_frames=5)
    assert data.positions.shape == (1, 10, 80, 3)
    assert_same_positions(data.positions[0], by_id(pos, ids)[5:])
    np.testing.assert_array_equal(data.times[0], times[5:])
    assert (np.abs(data.positions) <= 0.5 * BOX.lengths).all()
    assert report.files[0].first_step == 3 and report.files[0].dropped == 5
    np.testing.assert_allclose(report.files[0].centre, centre)


def test_files_of_different_length_are_trimmed_and_said(tmp_path):
    a = make_trajectory(1, frames=14)
    b = make_trajectory(2, frames=10)
    archive = write_archive(
        tmp_path / "x.tar.gz",
        {"a.h5": write_h5(tmp_path / "a.h5", *a), "b.h5": write_h5(tmp_path / "b.h5", *b)},
    )
    data, report = read_fordatis(archive, drop_frames=2)
    assert data.positions.shape[:2] == (2, 8)
    assert any("a.h5]: trimmed from 12 to 8" in note for note in report.notes)


def test_os_metadata_skipped_and_member_names_never_used_as_paths(tmp_path):
    pos, times, ids = make_trajectory(5, frames=6)
    good = write_h5(tmp_path / "good.h5", pos, times, ids)
    junk = tmp_path / "junk"
    junk.write_bytes(b"\x00\x05\x16\x07 AppleDouble")
    work = tmp_path / "work"
    work.mkdir()
    archive = write_archive(work / "a.tar.gz", {"../evil.h5": good, "._evil.h5": junk})
    data, report = read_fordatis(archive)
    assert data.n_sims == 1 and report.skipped == ["._evil.h5"]
    assert not (tmp_path / "evil.h5").exists()


# --------------------------------------------------------------------------------------------
# Lees-Edwards: sign and time origin
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("sign", [-1, 1])
def test_le_sign_inferred_both_ways(tmp_path, sign):
    archive, truths = le_archive(tmp_path, sign)
    data, report = read_fordatis(archive, shear_rate=SHEAR)
    le = data.boundary.lees_edwards
    assert (le.sign, le.time_origin, le.shear_rate) == (sign, 0.0, SHEAR)
    ev = report.evidence
    assert ev.n_crossers > 10
    assert ev.max_crosser[f"sign {sign:+d}"] <= ev.threshold < ev.max_crosser[f"sign {-sign:+d}"]
    for s, (pos, _, ids) in enumerate(truths):
        assert_same_positions(data.positions[s], by_id(pos, ids))
    # the given sign is verified, and the wrong one refused with its evidence
    read_fordatis(archive, shear_rate=SHEAR, le_sign=sign)
    with pytest.raises(DatasetError, match="no Lees-Edwards setting .* --le-sign"):
        read_fordatis(archive, shear_rate=SHEAR, le_sign=-sign, time_origin=0.0)


def test_le_time_origin_at_first_stored_frame(tmp_path):
    archive, _ = le_archive(tmp_path, -1, time_origin=T_START, files=1)
    data, report = read_fordatis(archive, shear_rate=SHEAR, drop_frames=3)
    assert data.boundary.lees_edwards.time_origin == pytest.approx(T_START, rel=1e-12)
    assert "first stored frame" in report.evidence.origin


@pytest.mark.parametrize("sign", [-1, 1])
def test_le_time_origin_estimated_when_no_candidate_fits(tmp_path, sign):
    true_origin = T_START + 37.3 * DT
    archive, truths = le_archive(tmp_path, sign, time_origin=true_origin)
    data, report = read_fordatis(archive, shear_rate=SHEAR)
    assert data.boundary.lees_edwards.sign == sign
    assert "estimated" in report.evidence.origin
    times = truths[0][1]
    got = data.boundary.offset(times)
    want = LeesEdwards(SHEAR, sign, true_origin).offset(BOX, times)
    assert np.abs(wrap_coordinate(got - want, BOX.lz)).max() < 0.02 * D


def test_le_without_crossers_needs_le_sign(tmp_path):
    pos, times, ids = make_trajectory(3, sign=-1, x_band=0.5, vx=0.0)
    path = write_h5(tmp_path / "calm.h5", pos, times, ids)
    with pytest.raises(DatasetError, match=r"calm\.h5.*no particle crosses the x faces.*--le-sign"):
        read_fordatis(path, shear_rate=SHEAR)
    data, report = read_fordatis(path, shear_rate=SHEAR, le_sign=-1)
    assert data.boundary.lees_edwards.sign == -1
    assert "unverified" in report.evidence.origin


def test_le_both_signs_fit_is_refused(tmp_path):
    # times near the origin: delta ~ 0 at every crossing, so the data cannot tell the sign
    pos, times, ids = make_trajectory(6, sign=1, frames=6, t_start=0.0, vx=0.05)
    path = write_h5(tmp_path / "early.h5", pos, times, ids)
    with pytest.raises(DatasetError, match="both Lees-Edwards signs fit.*pass --le-sign"):
        read_fordatis(path, shear_rate=SHEAR)


def test_le_data_read_as_periodic_or_with_wrong_rate_is_refused(tmp_path):
    archive, _ = le_archive(tmp_path, -1, files=1)
    with pytest.raises(DatasetError, match="looks like Lees-Edwards data; give --shear-rate"):
        read_fordatis(archive)
    with pytest.raises(DatasetError, match="no Lees-Edwards setting.*Check --shear-rate"):
        read_fordatis(archive, shear_rate=SHEAR * 2.5)
    # 10% off: every displacement stays small over 40 frames, but the offsets drift
    with pytest.raises(DatasetError, match=r"drift against --shear-rate 900 1/s: they fit 1000"):
        read_fordatis(archive, shear_rate=SHEAR * 0.9)


def test_le_given_time_origin_is_verified(tmp_path):
    archive, _ = le_archive(tmp_path, 1, files=1)
    data, report = read_fordatis(archive, shear_rate=SHEAR, time_origin=0.0)
    assert "0 s (given)" in report.evidence.origin
    with pytest.raises(DatasetError, match=r"the crossers put the time origin at .*--time-origin"):
        read_fordatis(archive, shear_rate=SHEAR, time_origin=2 * DT)


# --------------------------------------------------------------------------------------------
# the command line
# --------------------------------------------------------------------------------------------
def test_cli_converts_and_reports(tmp_path):
    archive, truths = le_archive(tmp_path, -1)
    out = tmp_path / "out" / "le.h5"
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "gripdem.convert",
            "fordatis",
            str(archive),
            str(out),
            "--shear-rate",
            "1000",
            "--drop-frames",
            "4",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    text = run.stdout
    for expected in (
        "files (simulations): 2",
        "frames per simulation: 36 kept, 4 dropped",
        "particles: 80",
        "boundary: lees_edwards",
        "LE sign: -1",
        "LE time origin: 0 s",
        "x-face crossing(s)",
        "with sign +1",
        "volume fraction",
        f"wrote {out}",
    ):
        assert expected in text, text
    data = read_dataset(out)
    assert data.positions.shape == (2, 36, 80, 3)
    assert data.boundary.lees_edwards.sign == -1
    assert data.provenance["generator"] == "gripdem.formats.fordatis"
    pos, times, ids = truths[1]
    assert_same_positions(data.positions[1], by_id(pos, ids)[4:])


def test_cli_refuses_to_overwrite_and_reports_bad_input(tmp_path, capsys):
    pos, times, ids = make_trajectory(1, frames=6)
    path = write_h5(tmp_path / "p.h5", pos, times, ids)
    out = tmp_path / "p_gripdem.h5"
    assert main(["fordatis", str(path), str(out)]) == 0
    before = out.read_bytes()
    capsys.readouterr()
    assert main(["fordatis", str(path), str(out)]) == 1
    assert "refusing to overwrite" in capsys.readouterr().err
    assert out.read_bytes() == before
    assert main(["fordatis", str(path), str(out), "--overwrite", "--drop-frames", "1"]) == 0
    assert read_dataset(out).n_frames == 5
    with h5py.File(path, "a") as h5:
        del h5["Step#2/Coords_0"]
    assert main(["fordatis", str(path), str(tmp_path / "new.h5")]) == 1
    err = capsys.readouterr().err
    assert "p.h5: field 'Step#2/Coords_0': missing dataset" in err and "Traceback" not in err
    assert not (tmp_path / "new.h5").exists()


# --------------------------------------------------------------------------------------------
# --body-force: the periodic drive recorded, checked and printed
# --------------------------------------------------------------------------------------------
def test_body_force_is_recorded_printed_and_checked(tmp_path, capsys):
    pos, times, ids = make_trajectory(3, frames=8)
    path = write_h5(tmp_path / "p.h5", pos, times, ids)
    out = tmp_path / "driven.h5"
    assert main(["fordatis", str(path), str(out), "--body-force", "5864.5"]) == 0
    printed = capsys.readouterr().out
    assert "body force: A = 5864.5 (a_z = A cos(2 pi x / lx)" in printed
    assert "flow profile: mean z velocity = " in printed
    data = read_dataset(out)
    assert data.body_force_amplitude == 5864.5
    assert data.provenance["parameters"]["body_force_amplitude"] == 5864.5
    with h5py.File(out) as h5:
        assert h5.attrs["body_force_amplitude"] == 5864.5
    assert main(["fordatis", str(path), str(tmp_path / "plain.h5")]) == 0
    assert "body force: none (give --body-force A" in capsys.readouterr().out
    assert read_dataset(tmp_path / "plain.h5").body_force_amplitude == 0.0
    for bad in ("-1", "nan", "inf"):
        assert main(["fordatis", str(path), str(tmp_path / "bad.h5"), "--body-force", bad]) == 1
        err = capsys.readouterr().err
        assert "--body-force must be a finite acceleration >= 0" in err and bad in err
    assert not (tmp_path / "bad.h5").exists()


def test_body_force_on_lees_edwards_data_is_refused(tmp_path, capsys):
    archive, _ = le_archive(tmp_path, -1)
    out = tmp_path / "le.h5"
    args = ["fordatis", str(archive), str(out), "--shear-rate", "1000", "--body-force", "10"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "--shear-rate 1000.0: --body-force 10: the data is Lees-Edwards" in err
    assert "has no body force" in err and not out.exists()
    assert main([*args[:-1], "0"]) == 0  # 0 is no drive
    assert "body force: none (Lees-Edwards data" in capsys.readouterr().out
