"""Fuzzing the importers through ``python -m gripdem.convert``: corrupted Fordatis files and
archives and LAMMPS text dumps are refused with one ``error:`` line of a documented type
(a DatasetError: FordatisError, DumpError), or converted into a valid dataset; never another
exception, a hang, a memory blow-up or a partial output file."""

from __future__ import annotations

import contextlib
import functools
import gzip
import io
import shutil
import tarfile
import tempfile
from pathlib import Path

import h5py
import numpy as np
import pytest
from fordatis_files import BOX, DT, D, make_trajectory, write_h5
from fuzzing import FUZZ, REFUSED, refuses_or_accepts
from hypothesis import given, reject, settings
from hypothesis import strategies as st

from gripdem.convert import main as convert
from gripdem.data.dataset_io import read_dataset
from gripdem.formats.lammps.dump import dump_text

VALUES = [np.nan, np.inf, -np.inf, 1e308, -1e308, 0.0, 1e-300, 7.5, -3.0]


def run_convert(args: list[str], out: Path, target: str) -> None:
    """convert ``args`` into ``out``: success writes a valid dataset; failure prints one
    ``error:`` line of a documented type (no hint of an undocumented one) and writes nothing."""
    stderr = io.StringIO()

    def call() -> int:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(stderr):
            return convert([*args])

    status, _ = refuses_or_accepts(target, call, (), watch=None)
    text = stderr.getvalue()
    REFUSED[target] += int(status != 0)
    if status == 0:
        read_dataset(out)  # a valid file
        return
    assert status == 1, (status, text)
    lines = text.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), text
    assert "GRIPDEM_TRACEBACK" not in text, f"undocumented error type: {text}"
    assert sorted(p.name for p in out.parent.iterdir() if p.name.startswith((".out", "out"))) == []


# --------------------------------------------------------------------------------------------
# Fordatis
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def fordatis_file(tmp_path_factory) -> Path:
    pos, times, ids = make_trajectory(3, n=16, frames=8, vx=0.005)
    return write_h5(tmp_path_factory.mktemp("fordatis") / "sim.h5", pos, times, ids)


@st.composite
def fordatis_edits(draw):
    kind = draw(
        st.sampled_from(
            ["delete", "ids", "value", "dtype", "shape", "absurd", "extra", "rename", "attr"]
        )
    )
    frame = draw(st.integers(0, 7))
    key = f"Step#{frame}"
    name = draw(st.sampled_from(["Identifier", "Coords_0", "Coords_1", "Coords_2"]))
    attr = draw(st.sampled_from(["Time", "Lower", "Upper"]))
    value = draw(st.sampled_from(VALUES))
    particle = draw(st.integers(0, 15))

    def edit(h5):
        group = h5[key]
        if kind == "delete":
            target = draw_choice
            if target == "group":
                del h5[key]
            elif target == "attr":
                del group.attrs[attr]
            else:
                del group[name]
        elif kind == "ids":  # a duplicated or a replaced (missing) identifier
            ids = group["Identifier"][()]
            ids[particle] = ids[(particle + 1) % ids.size] if value > 0 else 10**6
            del group["Identifier"]
            group["Identifier"] = ids
        elif kind == "value":
            if name == "Identifier":
                group.attrs[attr] = np.full(3 if attr != "Time" else 1, value)
            else:
                group[name][particle] = value
        elif kind == "dtype":
            old = group[name][()]
            del group[name]
            group[name] = old.astype(draw_dtype)
        elif kind == "shape":
            del group[name]
            group[name] = np.zeros(draw_shape)
        elif kind == "absurd":
            del group[name]
            group.create_dataset(name, shape=(draw_size,), dtype="f8", chunks=(1024,))
        elif kind == "extra":
            group.attrs["Comment"] = "extra"
            h5.create_group("Metadata").attrs["x"] = 1
        elif kind == "rename":
            h5.move(key, draw_new_name)
        else:
            group.attrs[attr] = draw_attr

    draw_choice = draw(st.sampled_from(["group", "attr", "dataset"]))
    draw_dtype = draw(st.sampled_from(["f4", "i2", "u8", "c16", "?", "S8", "f2"]))
    draw_shape = draw(st.lists(st.integers(0, 20), max_size=3).map(tuple))
    draw_size = draw(st.sampled_from([10**6, 10**9, 2**40]))
    draw_new_name = draw(st.sampled_from(["Step#99", "Step#x", "step#1", f"Step#{frame}0"]))
    draw_attr = draw(
        st.one_of(
            st.text(max_size=8),
            st.binary(min_size=1, max_size=8).map(np.bytes_),
            st.lists(st.floats(), max_size=4).map(np.asarray),
        )
    )
    return kind, edit


@settings(FUZZ, max_examples=300)
@given(mutation=fordatis_edits())
def test_fordatis_files(fordatis_file, mutation):
    _, edit = mutation
    with tempfile.TemporaryDirectory() as tmp:
        path, out = Path(tmp) / "fuzzed.h5", Path(tmp) / "out.h5"
        shutil.copyfile(fordatis_file, path)
        try:
            with h5py.File(path, "r+") as h5:
                edit(h5)
        except (TypeError, ValueError, KeyError, OSError):
            reject()  # h5py cannot store this mutation: not an input
        run_convert(["fordatis", str(path), str(out)], out, "fordatis fields")


def _archive(path: Path, name: str) -> bytes:
    """A tar.gz of one file, byte for byte the same in every session (fixed times)."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w", format=tarfile.PAX_FORMAT) as tar:
        info = tar.gettarinfo(path, arcname=name)
        info.mtime, info.uid, info.gid, info.uname, info.gname = 0, 0, 0, "", ""
        with open(path, "rb") as fh:
            tar.addfile(info, fh)
    return gzip.compress(buffer.getvalue(), mtime=0)


@settings(FUZZ, max_examples=150)
@given(data=st.data())
def test_fordatis_archives_truncated_and_flipped(fordatis_file, data):
    with tempfile.TemporaryDirectory() as tmp:
        archive, out = Path(tmp) / "a.tar.gz", Path(tmp) / "out.h5"
        name = data.draw(st.sampled_from(["sim.h5", "../../escape.h5", "dir/\udcff.h5", "/abs.h5"]))
        raw = bytearray(_archive(fordatis_file, name))
        if data.draw(st.booleans(), "truncate"):
            raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
        else:
            for _ in range(data.draw(st.integers(0, 8))):
                raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
        archive.write_bytes(bytes(raw))
        run_convert(["fordatis", str(archive), str(out)], out, "fordatis archives")
        assert not (Path(tmp).parent / "escape.h5").exists()


# --------------------------------------------------------------------------------------------
# LAMMPS dumps
# --------------------------------------------------------------------------------------------
@functools.cache
def base_dump() -> str:
    pos, times, _ = make_trajectory(5, n=12, frames=6, vx=0.005)
    return dump_text(np.arange(6) * 100, -0.5 * BOX.lengths, BOX.lengths, pos)


TOKENS = ["nan", "inf", "-inf", "1e400", "-0", "x", "", "10000000000000000000000", "-5", "0"]


@st.composite
def dump_edits(draw, text: str):
    lines = text.splitlines(keepends=True)
    kind = draw(st.sampled_from(["token", "truncate", "line", "count", "utf8", "id", "swap"]))
    k = draw(st.integers(0, len(lines) - 1))
    if kind == "token":  # one value replaced by an adversarial token
        words = lines[k].split(" ")
        words[draw(st.integers(0, len(words) - 1))] = draw(st.sampled_from(TOKENS))
        lines[k] = " ".join(words) + ("" if lines[k].endswith("\n") else "\n")
    elif kind == "truncate":
        return "truncate", "".join(lines)[: draw(st.integers(0, len(text) - 1))].encode()
    elif kind == "line":  # a line dropped or repeated
        lines.insert(k, lines[k]) if draw(st.booleans()) else lines.pop(k)
    elif kind == "count":  # NUMBER OF ATOMS or TIMESTEP absurd
        heads = [
            i for i, line in enumerate(lines) if line.startswith(("ITEM: NUMBER", "ITEM: TIME"))
        ]
        i = draw(st.sampled_from(heads))
        lines[i + 1] = draw(st.sampled_from(["1000000000000\n", "-3\n", str(2**70) + "\n", "0\n"]))
    elif kind == "utf8":  # bytes that are not UTF-8
        blob = "".join(lines).encode()
        at = draw(st.integers(0, len(blob)))
        return "utf8", blob[:at] + draw(st.binary(min_size=1, max_size=8)) + blob[at:]
    elif kind == "id":  # a duplicated or missing particle id
        atoms = [i for i, line in enumerate(lines) if line[:1].isdigit() and line.count(" ") >= 4]
        i = draw(st.sampled_from(atoms))
        words = lines[i].split(" ")
        words[0] = draw(st.sampled_from(["1", "2", "99", "12"]))
        lines[i] = " ".join(words)
    else:
        j = draw(st.integers(0, len(lines) - 1))
        lines[k], lines[j] = lines[j], lines[k]
    return kind, "".join(lines).encode()


@settings(FUZZ, max_examples=400)
@given(data=st.data())
def test_lammps_dumps(data):
    kind, blob = data.draw(dump_edits(base_dump()))
    gz = data.draw(st.booleans(), "gzip")
    with tempfile.TemporaryDirectory() as tmp:
        path, out = Path(tmp) / ("run.dump.gz" if gz else "run.dump"), Path(tmp) / "out.h5"
        path.write_bytes(gzip.compress(blob)[: None if kind != "truncate" else -3] if gz else blob)
        args = ["lammps", str(path), str(out), "--diameter", str(D), "--timestep", str(DT / 100)]
        run_convert(args, out, "lammps dumps")
