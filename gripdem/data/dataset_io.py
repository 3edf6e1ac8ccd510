"""Reading and writing gripdem HDF5 datasets (the format of :mod:`gripdem.data.schema`).

:func:`write_dataset` validates, then writes to a temporary file in the target folder and
renames it, so an interrupted write leaves nothing behind; it refuses to replace an existing
file unless ``overwrite=True``.

Reading checks a file once, at load, for everything the pipeline assumes:
:func:`read_meta` (what the DataModule and ``gripdem.predict`` open a file with) reads the
attributes, shapes and times and then streams the positions in bounded blocks (finite, inside
the box; the first offending simulation, frame and particle named); :func:`read_dataset` reads
everything and checks the arrays it holds in memory (no second pass over the file). A file
that passed is remembered (path, size, modification time), so opening it again costs no second
scan. Sizes are checked against what the file stores before anything is read: a dataset that
declares more data than the file holds (unwritten chunks, a truncated or crafted file) is
refused instead of filling memory. Every error is a
:class:`~gripdem.data.schema.DatasetError` naming the file, the field and what was expected.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from gripdem.boundary import (
    BOUNDARY_KINDS,
    Boundary,
    Box,
    LeesEdwards,
)
from gripdem.data.h5io import atomic_h5_write
from gripdem.data.schema import (
    FORMAT_NAME,
    FORMAT_VERSION,
    DatasetError,
    DatasetMeta,
    TrajectoryData,
    check_array,
    check_finite,
    check_packing,
    check_radii,
    check_units,
    validate,
    validate_positions,
    validate_times,
)


def write_dataset(path: str | os.PathLike, data: TrajectoryData, overwrite: bool = False) -> Path:
    """Validate and write ``data`` atomically (temporary file in the same folder, then rename).

    Refuses to replace an existing file unless ``overwrite=True``. On any error nothing is
    left behind and an existing file is untouched.
    """
    path = Path(path)
    validate(data, path)
    with atomic_h5_write(path, overwrite) as h5:
        h5.create_dataset(
            "positions",
            data=np.asarray(data.positions, dtype=np.float64),
            chunks=(1, 1, data.n_particles, 3),
        )
        h5.create_dataset("times", data=np.asarray(data.times, dtype=np.float64))
        if data.velocities is not None:
            h5.create_dataset(
                "velocities",
                data=np.asarray(data.velocities, dtype=np.float64),
                chunks=(1, 1, data.n_particles, 3),
            )
        if data.radii is not None:
            h5.create_dataset("radii", data=np.asarray(data.radii, dtype=np.float64))
        attrs = h5.attrs
        attrs["format"] = FORMAT_NAME
        attrs["format_version"] = FORMAT_VERSION
        for key, value in data.boundary.to_attrs().items():
            attrs[key] = value
        attrs["radius"] = float(data.radius)
        attrs["body_force_amplitude"] = float(data.body_force_amplitude)
        attrs["provenance"] = json.dumps(data.provenance, sort_keys=True, default=str)
    return path


#: arrays read whole (times, radii) may hold at most this many bytes
MAX_READ_BYTES = 1 << 30
#: positions are scanned in blocks of at most this many bytes
SCAN_BLOCK_BYTES = 16 << 20
#: a compressed dataset may declare at most this many times the bytes it stores
MAX_COMPRESSION = 1000
#: files that passed the load-time check: (path, size, mtime) -> True
_CHECKED: dict[tuple[str, int, int], bool] = {}
_H5_ERRORS = (OSError, RuntimeError, KeyError, TypeError, ValueError)


def _file_key(path: Path) -> tuple[str, int, int]:
    st = path.stat()
    return (str(path.resolve()), st.st_size, st.st_mtime_ns)


@contextmanager
def _reading(path, name: str) -> Iterator[None]:
    """h5py's errors while reading field ``name`` (a truncated or corrupted file) as a
    :class:`DatasetError` naming it."""
    try:
        yield
    except DatasetError:
        raise
    except _H5_ERRORS as exc:
        raise DatasetError(path, name, f"unreadable ({type(exc).__name__}: {exc})") from None


def dataset_of(path, h5: h5py.Group, name: str) -> h5py.Dataset:
    """``h5[name]`` if it is a dataset whose declared size the file actually stores."""
    with _reading(path, name):
        obj = h5.get(name)
    if obj is None:
        raise DatasetError(path, name, "missing dataset")
    if not isinstance(obj, h5py.Dataset):
        raise DatasetError(path, name, f"expected a dataset, got a {type(obj).__name__}")
    check_stored(path, name, obj)
    return obj


def check_stored(path, name: str, dset: h5py.Dataset) -> None:
    """Refuse a dataset that declares more bytes than the file stores for it (never written,
    external or virtual storage, a crafted shape): reading it would fill memory with made-up
    values. Compressed data may declare up to :data:`MAX_COMPRESSION` times what it stores."""
    with _reading(path, name):
        if dset.is_virtual or dset.external:
            raise DatasetError(path, name, "expected data stored in the file itself")
        declared = int(dset.size) * int(dset.dtype.itemsize)
        stored = int(dset.id.get_storage_size())
        compressed = dset.compression is not None or dset.scaleoffset is not None
    limit = stored * (MAX_COMPRESSION if compressed else 1)
    if declared > limit:
        raise DatasetError(
            path,
            name,
            f"declares shape {tuple(dset.shape)} ({declared} bytes) but the file stores "
            f"{stored} bytes for it: a truncated, unfinished or crafted file",
        )


def read_small(path, h5: h5py.Group, name: str) -> np.ndarray:
    """A dataset read whole (at most :data:`MAX_READ_BYTES`)."""
    dset = dataset_of(path, h5, name)
    if dset.size * dset.dtype.itemsize > MAX_READ_BYTES:
        raise DatasetError(
            path, name, f"expected at most {MAX_READ_BYTES} bytes, got shape {dset.shape}"
        )
    with _reading(path, name):
        return np.asarray(dset[()])


def read_attr(path, h5: h5py.File, name: str, default: Any = ...) -> Any:
    with _reading(path, name):
        if name not in h5.attrs:
            if default is ...:
                raise DatasetError(path, name, "missing attribute")
            return default
        value = h5.attrs[name]
    if isinstance(value, bytes):
        try:
            value = value.decode("utf-8")
        except UnicodeDecodeError:
            raise DatasetError(path, name, f"expected UTF-8 text, got {value[:40]!r}") from None
    return value


def read_str_attr(path, h5, name: str, default: Any = ...) -> str:
    value = read_attr(path, h5, name, default)
    if not isinstance(value, str):
        raise DatasetError(path, name, f"expected a string, got {value!r}")
    return value


def read_float_attr(path, h5, name: str, default: Any = ...) -> float:
    value = read_attr(path, h5, name, default)
    try:
        return float(np.asarray(value, dtype=np.float64).reshape(()))
    except (TypeError, ValueError):
        raise DatasetError(path, name, f"expected a number, got {value!r}") from None


def boundary_from_attrs(path, h5: h5py.File) -> Boundary:
    raw = read_attr(path, h5, "box")
    try:
        box_attr = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        box_attr = np.full(1, np.nan)
    if box_attr.shape != (3,) or not np.isfinite(box_attr).all() or not (box_attr > 0).all():
        raise DatasetError(path, "box", f"expected 3 positive lengths (lx, ly, lz), got {raw!r}")
    box = Box.from_lengths(box_attr)
    kind = read_str_attr(path, h5, "boundary")
    if kind not in BOUNDARY_KINDS:
        raise DatasetError(path, "boundary", f"expected one of {BOUNDARY_KINDS}, got {kind!r}")
    if kind == "periodic":
        return Boundary(box)
    shear_rate = read_float_attr(path, h5, "shear_rate")
    if not (np.isfinite(shear_rate) and shear_rate > 0):
        raise DatasetError(
            path,
            "shear_rate",
            f"expected a positive shear rate (1/s) for lees_edwards data, got {shear_rate!r}",
        )
    sign = read_float_attr(path, h5, "le_sign")
    if sign not in (1.0, -1.0):
        raise DatasetError(path, "le_sign", f"expected +1 or -1, got {sign!r}")
    origin = read_float_attr(path, h5, "le_time_origin")
    if not np.isfinite(origin):
        raise DatasetError(path, "le_time_origin", f"expected a finite time, got {origin!r}")
    return Boundary(box, LeesEdwards(shear_rate, int(sign), origin))


def read_meta(path: str | os.PathLike, h5: h5py.File | None = None) -> DatasetMeta:
    """Read and check a file at load: attributes, shapes, dtypes and times, then the positions
    streamed in blocks (finite, inside the box), once per file version (see the module doc)."""
    path = Path(path)
    if h5 is not None:
        meta = _read_meta(path, h5)
        _scan_positions(path, h5, meta)
        return meta
    key = _opened(path)
    try:
        with h5py.File(path, "r") as handle:
            meta = _read_meta(path, handle)
            if key not in _CHECKED:
                _scan_positions(path, handle, meta)
    except OSError as exc:
        raise DatasetError(path, "<file>", f"expected an HDF5 file ({exc})") from None
    _remember(key)
    return meta


def _opened(path: Path) -> tuple[str, int, int]:
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such dataset file")
    if not path.is_file():
        raise DatasetError(path, "<file>", "expected an HDF5 file, got a folder or device")
    return _file_key(path)


def _remember(key: tuple[str, int, int]) -> None:
    if len(_CHECKED) > 256:
        _CHECKED.clear()
    _CHECKED[key] = True


def _read_meta(path: Path, h5: h5py.File) -> DatasetMeta:
    """Everything but the positions' values (cheap)."""
    fmt = read_str_attr(path, h5, "format", FORMAT_NAME)
    if fmt != FORMAT_NAME:
        raise DatasetError(path, "format", f"expected {FORMAT_NAME!r}, got {fmt!r}")
    pos = dataset_of(path, h5, "positions")
    check_array(path, "positions", pos, (None, None, None, 3), "(sims, frames, particles, 3)")
    if pos.dtype != np.float64:
        raise DatasetError(path, "positions", f"expected float64, got {pos.dtype}")
    s, f, n, _ = pos.shape
    if min(s, f, n) == 0:
        raise DatasetError(
            path, "positions", f"expected non-empty sims/frames/particles, got {pos.shape}"
        )
    times = dataset_of(path, h5, "times")
    check_array(path, "times", times, (s, f), f"(sims, frames) = ({s}, {f})")
    interval = validate_times(path, np.asarray(read_small(path, h5, "times"), dtype=np.float64))
    has_vel = "velocities" in h5
    if has_vel:
        vel = dataset_of(path, h5, "velocities")
        check_array(path, "velocities", vel, pos.shape, f"{pos.shape} like positions")
    radii = None
    if "radii" in h5:
        radii = read_small(path, h5, "radii")
        check_array(path, "radii", radii, (n,), f"(particles,) = ({n},)")
        radius = read_float_attr(path, h5, "radius", float(np.mean(radii)))
        check_radii(path, radius, radii, n)
    else:
        radius = read_float_attr(path, h5, "radius")
        check_radii(path, radius, None, n)
    boundary = boundary_from_attrs(path, h5)
    check_packing(path, boundary.box, n, radius, radii)
    check_units(path, boundary.box, n, radius, radii)
    provenance_raw = read_str_attr(path, h5, "provenance", "{}")
    try:
        provenance = json.loads(provenance_raw)
    except (json.JSONDecodeError, RecursionError):
        provenance = None
    if not isinstance(provenance, dict):
        raise DatasetError(
            path, "provenance", f"expected a JSON string of an object, got {provenance_raw[:80]!r}"
        )
    amplitude = read_float_attr(path, h5, "body_force_amplitude", 0.0)
    if not np.isfinite(amplitude):
        raise DatasetError(
            path, "body_force_amplitude", f"expected a finite number, got {amplitude}"
        )
    return DatasetMeta(
        path=path,
        n_sims=s,
        n_frames=f,
        n_particles=n,
        boundary=boundary,
        radius=radius,
        frame_interval=interval,
        body_force_amplitude=amplitude,
        provenance=provenance,
        has_velocities=has_vel,
    )


def _scan_positions(path: Path, h5: h5py.File, meta: DatasetMeta) -> None:
    """Positions finite and inside the box, read in blocks of whole frames (bounded memory);
    the first offending simulation, frame and particle are named."""
    dset = h5["positions"]
    frame_bytes = meta.n_particles * 3 * 8
    block = max(1, SCAN_BLOCK_BYTES // frame_bytes)
    for sim in range(meta.n_sims):
        for first in range(0, meta.n_frames, block):
            with _reading(path, "positions"):
                values = dset[sim, first : first + block]
            validate_positions(path, values, meta.box, sim, first_frame=first)


def read_dataset(path: str | os.PathLike, validate_positions_: bool = True) -> TrajectoryData:
    """Read a whole file into memory, validating everything (positions one simulation at a
    time, so the check itself needs no more memory than the result)."""
    path = Path(path)
    key = _opened(path)
    try:
        with h5py.File(path, "r") as h5:
            meta = _read_meta(path, h5)
            with _reading(path, "positions"):
                positions = np.asarray(h5["positions"][()], dtype=np.float64)
            times = np.asarray(read_small(path, h5, "times"), dtype=np.float64)
            velocities = None
            if meta.has_velocities:
                with _reading(path, "velocities"):
                    velocities = np.asarray(h5["velocities"][()])
            radii = read_small(path, h5, "radii") if "radii" in h5 else None
    except OSError as exc:
        raise DatasetError(path, "<file>", f"expected an HDF5 file ({exc})") from None
    if validate_positions_:
        for sim in range(meta.n_sims):
            validate_positions(path, positions[sim], meta.box, sim)
        _remember(key)
    if velocities is not None:
        check_finite(path, "velocities", velocities)
    return TrajectoryData(
        positions=positions,
        times=times,
        boundary=meta.boundary,
        radius=meta.radius,
        body_force_amplitude=meta.body_force_amplitude,
        provenance=meta.provenance,
        velocities=velocities,
        radii=radii,
    )
