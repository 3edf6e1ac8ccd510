"""The files of a Fordatis archive (:mod:`gripdem.formats.fordatis`): one HDF5 file read into a
:class:`RawSimulation` (groups ``Step#k``, attributes ``Time``/``Lower``/``Upper``, particles
ordered by ``Identifier``, box, ids and frame interval checked across frames), and the members
of a tar archive streamed one at a time into a private temporary directory under generated
names (never the member's own name as a path: no path traversal).
"""

from __future__ import annotations

import re
import shutil
import tarfile
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from gripdem.data.dataset_io import check_stored
from gripdem.data.schema import TIME_RTOL, DatasetError

#: macOS metadata that archives made on a Mac carry beside the real files
#: corners must agree between frames and files to this fraction of the box length
BOX_RTOL = 1e-9
_OS_METADATA = re.compile(r"(^|/)(\._[^/]*|\.DS_Store)$")


_STEP = re.compile(r"^Step#(\d+)$")


_DATASETS = ("Identifier", "Coords_0", "Coords_1", "Coords_2")
_H5_ERRORS = (OSError, RuntimeError, KeyError, TypeError, ValueError)


class FordatisError(DatasetError):
    """Bad Fordatis input: the message names the file, the group/field and the expectation."""


@dataclass
class RawSimulation:
    """One file after reading: frames kept, particles sorted by identifier, box re-centred.

    positions: ``(frames, particles, 3)`` float64, shifted by ``-centre`` but not yet wrapped;
    times: ``(frames,)`` absolute; identifiers: ``(particles,)`` ascending.
    """

    name: str
    first_step: int
    n_steps: int
    dropped: int
    first_time: float
    times: np.ndarray
    positions: np.ndarray
    identifiers: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    @property
    def lengths(self) -> np.ndarray:
        return self.upper - self.lower

    @property
    def centre(self) -> np.ndarray:
        return 0.5 * (self.upper + self.lower)

    def step_name(self, frame: int) -> str:
        """Group name of kept frame ``frame``."""
        return f"Step#{self.first_step + self.dropped + frame}"


def _attr_vector(label: str, group: h5py.Group, key: str, name: str, size: int) -> np.ndarray:
    field_name = f"{key} attr {name}"
    if name not in group.attrs:
        raise FordatisError(label, field_name, "missing attribute")
    try:
        value = np.asarray(group.attrs[name], dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise FordatisError(
            label, field_name, f"expected numbers, got {group.attrs[name]!r}"
        ) from None
    if value.size != size:
        what = "a scalar or a 1-element array" if size == 1 else f"{size} numbers"
        raise FordatisError(label, field_name, f"expected {what}, got shape {value.shape}")
    if not np.isfinite(value).all():
        raise FordatisError(label, field_name, f"expected finite values, got {value!r}")
    return value


def _dataset(label: str, group: h5py.Group, key: str, name: str) -> np.ndarray:
    field_name = f"{key}/{name}"
    obj = group.get(name)
    if not isinstance(obj, h5py.Dataset):
        raise FordatisError(
            label, field_name, "missing dataset" if obj is None else "expected a dataset"
        )
    check_stored(label, field_name, obj)  # a declared size the file does not hold: refused
    if obj.ndim not in (1, 2) or (obj.ndim == 2 and obj.shape[1] != 1):
        raise FordatisError(
            label, field_name, f"expected a 1-D array (particles,), got shape {obj.shape}"
        )
    try:
        value = np.asarray(obj[()])
    except (OSError, RuntimeError, TypeError, ValueError) as exc:
        raise FordatisError(label, field_name, f"unreadable ({exc})") from None
    if value.ndim == 2 and value.shape[1] == 1:
        value = value[:, 0]
    if value.ndim != 1:
        raise FordatisError(
            label, field_name, f"expected a 1-D array (particles,), got shape {value.shape}"
        )
    if not (np.issubdtype(value.dtype, np.integer) or np.issubdtype(value.dtype, np.floating)):
        raise FordatisError(label, field_name, f"expected numbers, got dtype {value.dtype}")
    return value


def _identifiers(label: str, key: str, raw: np.ndarray) -> np.ndarray:
    if np.issubdtype(raw.dtype, np.floating):
        if not (np.isfinite(raw).all() and (raw == np.round(raw)).all()):
            raise FordatisError(label, f"{key}/Identifier", "expected whole-number identifiers")
    ids = raw.astype(np.int64)
    order_ids = np.sort(ids)
    dup = order_ids[1:][order_ids[1:] == order_ids[:-1]]
    if dup.size:
        raise FordatisError(
            label,
            f"{key}/Identifier",
            f"expected unique identifiers; {np.unique(dup).size} "
            f"duplicated, e.g. {np.unique(dup)[:5].tolist()}",
        )
    return ids


def _steps(label: str, h5: h5py.File) -> list[tuple[int, str]]:
    steps = sorted((int(m.group(1)), key) for key in h5 if (m := _STEP.match(key)))
    if not steps:
        raise FordatisError(
            label,
            "Step#k",
            f"expected groups named Step#0, Step#1, ... (one per frame); found {sorted(h5)[:5]}",
        )
    for (a, key_a), (b, key_b) in zip(steps[:-1], steps[1:], strict=True):
        if b == a:
            raise FordatisError(label, key_b, f"step number {a} appears twice ({key_a}, {key_b})")
        if b != a + 1:
            raise FordatisError(
                label,
                f"Step#{a + 1}",
                f"expected consecutive frames Step#{steps[0][0]}.."
                f"Step#{steps[-1][0]}; {key_a} is followed by {key_b} (step gap: "
                f"{b - a - 1} frame(s) missing)",
            )
    return steps


def read_simulation(path: Path, label: str, drop_frames: int = 0) -> RawSimulation:
    """Read one HDF5 file frame by frame (only kept frames are loaded)."""
    try:
        h5 = h5py.File(path, "r")
    except OSError as exc:
        raise FordatisError(label, "<file>", f"expected a readable HDF5 file ({exc})") from None
    with h5:
        try:
            return _read_simulation(h5, label, drop_frames)
        except DatasetError:
            raise
        except _H5_ERRORS as exc:  # h5py's errors for a corrupted file's structure
            raise FordatisError(
                label, "<file>", f"corrupted HDF5 content ({type(exc).__name__}: {exc})"
            ) from None


def _read_simulation(h5: h5py.File, label: str, drop_frames: int) -> RawSimulation:
    steps = _steps(label, h5)
    if len(steps) - drop_frames < 2:
        raise FordatisError(
            label,
            "Step#k",
            f"{len(steps)} frames; dropping {drop_frames} leaves fewer than "
            "the 2 frames a trajectory needs (lower --drop-frames)",
        )
    kept = steps[drop_frames:]
    key0 = steps[0][1]
    if not isinstance(h5[key0], h5py.Group):
        raise FordatisError(label, key0, "expected a group holding one frame")
    first_time = _attr_vector(label, h5[key0], key0, "Time", 1)[0]
    times = np.empty(len(kept))
    positions: np.ndarray | None = None
    for frame, (_, key) in enumerate(kept):
        group = h5[key]
        if not isinstance(group, h5py.Group):
            raise FordatisError(label, key, "expected a group holding one frame")
        times[frame] = _attr_vector(label, group, key, "Time", 1)[0]
        lower = _attr_vector(label, group, key, "Lower", 3)
        upper = _attr_vector(label, group, key, "Upper", 3)
        raw = [_dataset(label, group, key, name) for name in _DATASETS]
        n = raw[0].shape[0]
        for name, array in zip(_DATASETS[1:], raw[1:], strict=True):
            if array.shape[0] != n:
                raise FordatisError(
                    label,
                    f"{key}/{name}",
                    f"expected {n} values like {key}/Identifier, got {array.shape[0]}",
                )
        ids = _identifiers(label, key, raw[0])
        order = np.argsort(ids, kind="stable")
        coords = np.stack([np.asarray(a, dtype=np.float64)[order] for a in raw[1:]], axis=-1)
        if not np.isfinite(coords).all():
            p, bad = (int(i) for i in np.argwhere(~np.isfinite(coords))[0])
            raise FordatisError(
                label,
                f"{key}/Coords_{bad}",
                f"expected finite coordinates, found {float(coords[p, bad])!r} (Identifier "
                f"{int(ids[order][p])})",
            )
        if positions is None:
            if not ((upper > lower).all() and np.isfinite(upper - lower).all()):
                raise FordatisError(
                    label,
                    f"{key} attr Upper",
                    f"expected finite Upper > Lower on every axis, got "
                    f"Lower={lower.tolist()}, Upper={upper.tolist()}",
                )
            first_key, first_lower, first_upper, sorted_ids = key, lower, upper, ids[order]
            positions = np.empty((len(kept), n, 3))
        else:
            _check_same_box(label, key, first_key, lower, upper, first_lower, first_upper)
            _check_same_ids(label, key, first_key, ids[order], sorted_ids)
        _check_inside(label, key, coords, first_lower, first_upper, sorted_ids)
        positions[frame] = coords
    _check_times(label, times, [key for _, key in kept])
    centre = 0.5 * (first_lower + first_upper)
    positions -= centre
    return RawSimulation(
        name=label,
        first_step=steps[0][0],
        n_steps=len(steps),
        dropped=drop_frames,
        first_time=float(first_time),
        times=times,
        positions=positions,
        identifiers=sorted_ids,
        lower=first_lower,
        upper=first_upper,
    )


def _check_inside(label, key, coords, lower, upper, ids) -> None:
    """Coordinates within one box length of the box (a DEM code stores them wrapped, or
    just outside): anything farther is another unit or a corrupted file."""
    length = upper - lower
    with np.errstate(over="ignore"):  # a huge box: its bounds go to +-inf, still compared
        outside = (coords < lower - length) | (coords > upper + length)
    if outside.any():
        p, axis = (int(i) for i in np.argwhere(outside)[0])
        raise FordatisError(
            label,
            f"{key}/Coords_{axis}",
            f"expected coordinates inside the box [{lower[axis]:g}, {upper[axis]:g}] (Lower, "
            f"Upper; within one box length), found {coords[p, axis]:g} for Identifier "
            f"{int(ids[p])}: coordinates in another unit than the box, or a corrupted file?",
        )


def _check_same_box(label, key, first_key, lower, upper, first_lower, first_upper) -> None:
    tol = BOX_RTOL * np.max(first_upper - first_lower)
    for name, now, then in (("Lower", lower, first_lower), ("Upper", upper, first_upper)):
        if np.max(np.abs(now - then)) > tol:
            raise FordatisError(
                label,
                f"{key} attr {name}",
                f"expected the same box corners in every frame (a "
                f"moving or deforming box is not supported); {first_key} has {name}="
                f"{then.tolist()}, {key} has {name}={now.tolist()}",
            )


def _check_same_ids(label, key, first_key, ids: np.ndarray, first_ids: np.ndarray) -> None:
    if ids.shape == first_ids.shape and (ids == first_ids).all():
        return
    missing = np.setdiff1d(first_ids, ids)
    extra = np.setdiff1d(ids, first_ids)
    raise FordatisError(
        label,
        f"{key}/Identifier",
        f"expected the same particles as {first_key} "
        f"({first_ids.size} identifiers); {key} has {ids.size}: missing "
        f"{missing[:5].tolist()}{'...' if missing.size > 5 else ''}, new "
        f"{extra[:5].tolist()}{'...' if extra.size > 5 else ''}",
    )


def _check_times(label: str, times: np.ndarray, keys: list[str]) -> None:
    steps = np.diff(times)
    if not (steps > 0).all():
        f = int(np.argwhere(steps <= 0)[0][0])
        raise FordatisError(
            label,
            f"{keys[f + 1]} attr Time",
            f"expected increasing frame times; {keys[f]} has "
            f"Time={times[f]!r}, {keys[f + 1]} has Time={times[f + 1]!r}",
        )
    interval = float(np.median(steps))
    f = int(np.argmax(np.abs(steps - interval)))
    if abs(steps[f] - interval) > TIME_RTOL * interval:
        raise FordatisError(
            label,
            f"{keys[f + 1]} attr Time",
            f"expected equidistant frames (relative tolerance "
            f"{TIME_RTOL:g}); {keys[f]} -> {keys[f + 1]} is {steps[f]!r} s, median interval "
            f"{interval!r} s",
        )


def archive_members(source: Path, workdir: Path, skipped: list[str]) -> Iterator[tuple[str, Path]]:
    """Yield ``(label, path)`` for each HDF5 file of ``source`` (an HDF5 file or a tar archive);
    archive members are streamed to ``workdir`` one at a time."""
    if not source.exists():
        raise FileNotFoundError(f"{source}: no such file")
    if source.is_dir():
        raise FordatisError(
            source, "<file>", "expected an HDF5 file or a tar archive, got a folder"
        )
    if h5py.is_hdf5(source):
        yield str(source), source
        return
    try:
        is_tar = tarfile.is_tarfile(source)
    except (tarfile.TarError, EOFError, zlib.error, OSError, UnicodeDecodeError) as exc:
        raise FordatisError(source, "<archive>", f"unreadable archive ({exc})") from None
    if not is_tar:
        raise FordatisError(
            source, "<file>", "expected one HDF5 file or a tar archive (.tar.gz) of HDF5 files"
        )
    label = str(source)
    try:
        with tarfile.open(source, mode="r|*") as tar:
            for index, member in enumerate(tar):
                label = f"{source}[{member.name}]"
                if member.isdir():
                    continue
                if _OS_METADATA.search(member.name):
                    skipped.append(member.name)
                    continue
                if not member.isfile():
                    raise FordatisError(
                        label, "<member>", "expected a regular file (links, devices: not read)"
                    )
                target = workdir / f"member-{index}.h5"
                with tar.extractfile(member) as src, open(target, "wb") as dst:
                    shutil.copyfileobj(src, dst)
                if not h5py.is_hdf5(target):
                    raise FordatisError(label, "<file>", "expected an HDF5 file; this is not one")
                yield label, target
                target.unlink()
    except (tarfile.TarError, EOFError, zlib.error, OSError, UnicodeDecodeError) as exc:
        raise FordatisError(label, "<archive>", f"unreadable archive or member ({exc})") from None
