"""The Fordatis importer refuses broken archives and files with one message naming the member,
the group or field and what was expected; nothing is written. Archives from
``tests/support/fordatis_files.py``."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from fordatis_files import (
    DT,
    D,
    make_trajectory,
    write_archive,
    write_h5,
)

from gripdem.data.schema import DatasetError
from gripdem.formats.fordatis import read_fordatis


# --------------------------------------------------------------------------------------------
# bad input: each message names the file and the group/field
# --------------------------------------------------------------------------------------------
def _bad(tmp_path, edit=None, frames=8, **kw):
    pos, times, ids = make_trajectory(8, frames=frames)
    return write_h5(tmp_path / "bad.h5", pos, times, ids, edit=edit, **kw)


def _drop(name):
    def edit(f, group):
        if f == 3:
            del group[name]

    return edit


def test_bad_member_in_archive(tmp_path):
    pos, times, ids = make_trajectory(1, frames=6)
    good = write_h5(tmp_path / "good.h5", pos, times, ids)
    notes = tmp_path / "notes.txt"
    notes.write_text("not hdf5")
    archive = write_archive(tmp_path / "a.tar.gz", {"good.h5": good, "data/notes.txt": notes})
    with pytest.raises(DatasetError, match=r"a\.tar\.gz\[data/notes\.txt\].*expected an HDF5"):
        read_fordatis(archive)


def test_truncated_archive(tmp_path):
    pos, times, ids = make_trajectory(1, frames=30)
    archive = write_archive(
        tmp_path / "a.tar.gz", {"x.h5": write_h5(tmp_path / "x.h5", pos, times, ids)}
    )
    cut = tmp_path / "cut.tar.gz"
    cut.write_bytes(archive.read_bytes()[: archive.stat().st_size // 2])
    with pytest.raises(DatasetError, match=r"cut\.tar\.gz.*unreadable archive"):
        read_fordatis(cut)


def test_not_hdf5_nor_tar(tmp_path):
    path = tmp_path / "x.h5"
    path.write_text("hello")
    with pytest.raises(DatasetError, match=r"x\.h5.*expected one HDF5 file or a tar archive"):
        read_fordatis(path)


def test_missing_identifier(tmp_path):
    with pytest.raises(DatasetError, match=r"bad\.h5: field 'Step#3/Identifier': missing dataset"):
        read_fordatis(_bad(tmp_path, _drop("Identifier")))


def test_missing_coords_and_attr(tmp_path):
    with pytest.raises(DatasetError, match=r"'Step#3/Coords_2': missing dataset"):
        read_fordatis(_bad(tmp_path, _drop("Coords_2")))

    def no_time(f, group):
        if f == 2:
            del group.attrs["Time"]

    with pytest.raises(DatasetError, match=r"'Step#2 attr Time': missing attribute"):
        read_fordatis(_bad(tmp_path, no_time))


def test_duplicate_identifiers(tmp_path):
    def dup(f, group):
        if f == 4:
            ids = group["Identifier"][()]
            ids[1] = ids[0]
            group["Identifier"][...] = ids

    with pytest.raises(DatasetError, match=r"bad\.h5: field 'Step#4/Identifier'.*duplicated"):
        read_fordatis(_bad(tmp_path, dup))


def test_identifier_set_changes(tmp_path):
    def renumber(f, group):
        if f == 5:
            ids = group["Identifier"][()]
            ids[ids == 7] = 10_000
            group["Identifier"][...] = ids

    with pytest.raises(
        DatasetError,
        match=r"'Step#5/Identifier': expected the same particles as Step#0.*"
        r"missing \[7\], new \[10000\]",
    ):
        read_fordatis(_bad(tmp_path, renumber))


def test_moving_box(tmp_path):
    def move(f, group):
        if f == 6:
            group.attrs["Upper"] = group.attrs["Upper"] * 1.01

    with pytest.raises(DatasetError, match=r"bad\.h5: field 'Step#6 attr Upper'.*moving"):
        read_fordatis(_bad(tmp_path, move))


def test_step_gap(tmp_path):
    path = _bad(tmp_path)
    with h5py.File(path, "a") as h5:
        del h5["Step#4"]
    with pytest.raises(
        DatasetError, match=r"bad\.h5: field 'Step#4'.*Step#3 is followed by Step#5"
    ):
        read_fordatis(path)


def test_non_equidistant_times(tmp_path):
    def late(f, group):
        if f == 5:
            group.attrs["Time"] = group.attrs["Time"] + 0.01 * DT

    with pytest.raises(DatasetError, match=r"'Step#5 attr Time': expected equidistant frames"):
        read_fordatis(_bad(tmp_path, late))


def test_non_finite_coordinates(tmp_path):
    def nan(f, group):
        if f == 1:
            group["Coords_1"][0] = np.nan

    with pytest.raises(DatasetError, match=r"'Step#1/Coords_1': expected finite"):
        read_fordatis(_bad(tmp_path, nan))


def test_files_disagree_on_particle_count(tmp_path):
    a = make_trajectory(1, frames=6)
    b = make_trajectory(2, frames=6, n=79)
    archive = write_archive(
        tmp_path / "x.tar.gz",
        {"a.h5": write_h5(tmp_path / "a.h5", *a), "b.h5": write_h5(tmp_path / "b.h5", *b)},
    )
    with pytest.raises(DatasetError, match=r"x\.tar\.gz\[b\.h5\]: field 'Identifier': expected 80"):
        read_fordatis(archive)


def test_bad_options(tmp_path):
    path = _bad(tmp_path)
    with pytest.raises(ValueError, match="above random close packing"):
        read_fordatis(path, diameter=2 * D * 4)
    with pytest.raises(ValueError, match="dropping 7 leaves fewer than.*--drop-frames"):
        read_fordatis(path, drop_frames=7)
    with pytest.raises(ValueError, match="give --shear-rate"):
        read_fordatis(path, le_sign=1)
