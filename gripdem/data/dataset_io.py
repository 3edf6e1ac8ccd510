"""Reading and writing gripdem HDF5 datasets (the format of :mod:`gripdem.data.schema`).

:func:`write_dataset` validates, then writes to a temporary file in the target folder and
renames it, so an interrupted write leaves nothing behind; it refuses to replace an existing
file unless ``overwrite=True``. :func:`read_meta` (cheap: attributes, shapes, times) and
:func:`read_dataset` (everything) raise a :class:`~gripdem.data.schema.DatasetError` that names
the file, the field and what was expected.
"""

from __future__ import annotations

import json
import os
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


def read_attr(path, h5: h5py.File, name: str, default: Any = ...) -> Any:
    if name not in h5.attrs:
        if default is ...:
            raise DatasetError(path, name, "missing attribute")
        return default
    value = h5.attrs[name]
    if isinstance(value, bytes):
        value = value.decode()
    return value


def read_float_attr(path, h5, name: str, default: Any = ...) -> float:
    value = read_attr(path, h5, name, default)
    try:
        return float(np.asarray(value).reshape(()))
    except (TypeError, ValueError):
        raise DatasetError(path, name, f"expected a number, got {value!r}") from None


def boundary_from_attrs(path, h5: h5py.File) -> Boundary:
    box_attr = np.asarray(read_attr(path, h5, "box"), dtype=np.float64)
    if box_attr.shape != (3,) or not np.isfinite(box_attr).all() or not (box_attr > 0).all():
        raise DatasetError(
            path, "box", f"expected 3 positive lengths (lx, ly, lz), got {box_attr!r}"
        )
    box = Box.from_lengths(box_attr)
    kind = str(read_attr(path, h5, "boundary"))
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
    sign = int(read_float_attr(path, h5, "le_sign"))
    if sign not in (1, -1):
        raise DatasetError(path, "le_sign", f"expected +1 or -1, got {sign!r}")
    origin = read_float_attr(path, h5, "le_time_origin")
    return Boundary(box, LeesEdwards(shear_rate, sign, origin))


def read_meta(path: str | os.PathLike, h5: h5py.File | None = None) -> DatasetMeta:
    """Read and check attributes, shapes and dtypes, and the times (cheap: no positions)."""
    path = Path(path)
    if h5 is None:
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such dataset file")
        try:
            with h5py.File(path, "r") as handle:
                return read_meta(path, handle)
        except OSError as exc:
            raise DatasetError(path, "<file>", f"expected an HDF5 file ({exc})") from None
    fmt = read_attr(path, h5, "format", None)
    if fmt is not None and fmt != FORMAT_NAME:
        raise DatasetError(path, "format", f"expected {FORMAT_NAME!r}, got {fmt!r}")
    for name in ("positions", "times"):
        if name not in h5:
            raise DatasetError(path, name, "missing dataset")
    pos = h5["positions"]
    check_array(path, "positions", pos, (None, None, None, 3), "(sims, frames, particles, 3)")
    if pos.dtype != np.float64:
        raise DatasetError(path, "positions", f"expected float64, got {pos.dtype}")
    s, f, n, _ = pos.shape
    times = h5["times"]
    check_array(path, "times", times, (s, f), f"(sims, frames) = ({s}, {f})")
    interval = validate_times(path, np.asarray(times[()], dtype=np.float64))
    has_vel = "velocities" in h5
    if has_vel:
        check_array(path, "velocities", h5["velocities"], pos.shape, f"{pos.shape} like positions")
    radii = np.asarray(h5["radii"][()]) if "radii" in h5 else None
    if radii is not None:
        check_radii(path, float(np.mean(radii)), radii, n)
        radius = read_float_attr(path, h5, "radius", float(np.mean(radii)))
    else:
        radius = read_float_attr(path, h5, "radius")
        check_radii(path, radius, None, n)
    boundary = boundary_from_attrs(path, h5)
    check_packing(path, boundary.box, n, radius, radii)
    provenance_raw = read_attr(path, h5, "provenance", "{}")
    try:
        provenance = json.loads(provenance_raw)
    except json.JSONDecodeError:
        raise DatasetError(path, "provenance", "expected a JSON string") from None
    return DatasetMeta(
        path=path,
        n_sims=s,
        n_frames=f,
        n_particles=n,
        boundary=boundary,
        radius=radius,
        frame_interval=interval,
        body_force_amplitude=read_float_attr(path, h5, "body_force_amplitude", 0.0),
        provenance=provenance,
        has_velocities=has_vel,
    )


def read_dataset(path: str | os.PathLike, validate_positions_: bool = True) -> TrajectoryData:
    """Read a whole file into memory, validating everything (positions one simulation at a
    time, so the check itself needs no more memory than the result)."""
    path = Path(path)
    meta = read_meta(path)
    with h5py.File(path, "r") as h5:
        positions = np.asarray(h5["positions"][()], dtype=np.float64)
        times = np.asarray(h5["times"][()], dtype=np.float64)
        velocities = np.asarray(h5["velocities"][()]) if meta.has_velocities else None
        radii = np.asarray(h5["radii"][()]) if "radii" in h5 else None
    if validate_positions_:
        for sim in range(meta.n_sims):
            validate_positions(path, positions[sim], meta.box, sim)
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
