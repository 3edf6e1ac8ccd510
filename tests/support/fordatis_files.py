"""Archives in the authors' Fordatis layout, written here for the importer's tests: each file
holds one group ``Step#k`` per frame with attrs Time/Lower/Upper and datasets
Identifier/Coords_0..2, particles shuffled in every frame. Lees-Edwards trajectories are
integrated in continuous coordinates under ``u_z = sign*shear_rate*x`` plus small random motion
and wrapped frame by frame with the offset of their own sign convention (the authors' is -1).
"""

from __future__ import annotations

import tarfile
from pathlib import Path

import h5py
import numpy as np

from gripdem.boundary import Box, LeesEdwards, wrap_coordinate, wrap_positions
from gripdem.formats.fordatis import DEFAULT_DIAMETER

BOX = Box(3.2e-5, 2.8e-5, 3.6e-5)  # not cubic on purpose
D = DEFAULT_DIAMETER
SHEAR = 1000.0
DT = 5e-6
T_START = 1.1e-3  # absolute frame times, as in the authors' data


# --------------------------------------------------------------------------------------------
# writing the authors' layout
# --------------------------------------------------------------------------------------------
def make_trajectory(
    seed, n=80, frames=40, sign=None, time_origin=0.0, t_start=T_START, x_band=None, vx=0.02
):
    """Wrapped positions ``(frames, n, 3)`` (centred box), times ``(frames,)``, identifiers.

    sign=None: periodic. Particle i has identifier ids[i]; x moves at a constant velocity (up
    to ``vx*lx`` per frame, so particles cross the x faces) plus noise.
    """
    rng = np.random.default_rng(seed)
    times = t_start + DT * np.arange(frames)
    cont = np.empty((frames, n, 3))
    cont[0] = (rng.random((n, 3)) - 0.5) * BOX.lengths
    if x_band is not None:
        cont[0, :, 0] *= x_band
    step = np.zeros((n, 3))
    step[:, 0] = rng.uniform(-vx, vx, n) * BOX.lx
    for f in range(1, frames):
        noise = rng.normal(0.0, 2e-3 * D, (n, 3))
        flow = 0.0 if sign is None else sign * SHEAR * cont[f - 1, :, 0] * DT
        cont[f] = cont[f - 1] + step + noise
        cont[f, :, 2] += flow
    if sign is None:
        wrapped = wrap_positions(cont, BOX)
    else:
        offsets = LeesEdwards(SHEAR, sign, time_origin).offset(BOX, times)
        wrapped = wrap_positions(cont, BOX, offsets[:, None])
    ids = rng.permutation(n) + 7
    return wrapped, times, ids


def write_h5(
    path,
    positions,
    times,
    ids,
    *,
    centre=(0.0, 0.0, 0.0),
    first_step=0,
    time_scalar=False,
    seed=0,
    edit=None,
):
    """Write one file in the authors' layout; particles shuffled anew in every frame.

    edit(f, group) may change frame f after it is written (bad-input tests)."""
    rng = np.random.default_rng(seed)
    centre = np.asarray(centre)
    with h5py.File(path, "w") as h5:
        for f, t in enumerate(times):
            group = h5.create_group(f"Step#{first_step + f}")
            group.attrs["Time"] = float(t) if time_scalar else np.array([t])
            group.attrs["Lower"] = -0.5 * BOX.lengths + centre
            group.attrs["Upper"] = 0.5 * BOX.lengths + centre
            order = rng.permutation(len(ids))
            group["Identifier"] = ids[order].astype(np.int64)
            for axis in range(3):
                group[f"Coords_{axis}"] = positions[f, order, axis] + centre[axis]
            if edit is not None:
                edit(f, group)
    return path


def write_archive(path, files: dict[str, Path]):
    with tarfile.open(path, "w:gz") as tar:
        for name, file in files.items():
            tar.add(file, arcname=name)
    return path


def by_id(positions, ids):
    """Truth in the importer's order (ascending identifier)."""
    return positions[:, np.argsort(ids)]


def assert_same_positions(got, want, box=BOX):
    """Equal modulo the box (a coordinate at -l/2 may come back as -l/2 or +l/2 - eps)."""
    diff = got - want
    for axis, length in enumerate(box.lengths):
        np.testing.assert_allclose(wrap_coordinate(diff[..., axis], length), 0.0, atol=1e-12)


def le_archive(tmp_path, sign, time_origin=0.0, files=2, **kw):
    members, truths = {}, []
    for i in range(files):
        pos, times, ids = make_trajectory(10 + i, sign=sign, time_origin=time_origin, **kw)
        members[f"lebc/run{i}.h5"] = write_h5(tmp_path / f"le{i}.h5", pos, times, ids, seed=i)
        truths.append((pos, times, ids))
    return write_archive(tmp_path / "le.tar.gz", members), truths
