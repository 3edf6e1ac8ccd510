"""ASE and OVITO read every file gripdem writes for other tools (the optional extra
``viewers``): a run's extended XYZ (``gripdem.formats.export``, what every run writes under
``trajectories/``), LAMMPS dumps (``export_lammps``, ``handback --dump``), the hand-back's
extended XYZ and LAMMPS data files (``handback --xyz``, ``--data``), in both scenes.

For every frame each reader must give the particle count, the cell (in the Lees-Edwards scene
the LE lattice ``(lx, 0, delta), (0, ly, 0), (0, 0, lz)`` at that frame's offset; in the LAMMPS
files of a sheared box the same lattice in LAMMPS's axes, ours (x, y, z) = LAMMPS (y, z, x),
as LAMMPS orders it: a = our c, b = our a, c = our b) and the positions modulo that lattice.
Then each reader's own neighbour search through that cell must find gripdem's LE-aware
neighbours, particle by particle (the images across the x faces are right). Lengths are SI:
ASE's neighbour list and OVITO's analysis modifiers want cells far from 1e-14 m^3, so those
run in diameters (ASE: scaled copy; OVITO: an ``AffineTransformationModifier``). ASE's
``lammps-data`` reader has no ``sphere`` style: it reads ``--atom-style atomic`` data files.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from gripdem.data.dataset_io import read_dataset
from gripdem.evaluation.physics import coordination_numbers
from gripdem.evaluation.predictions import Predictions
from gripdem.formats.export import export_extxyz, export_lammps
from gripdem.formats.lammps.series import AxisMap
from gripdem.handback import main as handback

#: frames of simulation 0 used: observed frame 9, then a horizon of 5; the hand-back's state
FIRST, HORIZON, STATE = 9, 5, 12
CUTOFF = 1.5  # diameters, for the coordination check


@dataclass
class Written:
    """A file and what each of its frames must read as (in the file's own axes)."""

    path: Path
    kind: str  # "extxyz" | "dump" | "data"
    positions: list[np.ndarray]  # per frame, ours (particles, 3)
    offsets: list[float]
    axes: AxisMap  # ours -> the file's axes
    atom_style: str = ""


def _lattice(box, offset: float) -> np.ndarray:
    """Rows: gripdem's LE lattice vectors at ``offset`` (the box when 0)."""
    lx, ly, lz = box.lengths
    return np.array([[lx, 0.0, offset], [0.0, ly, 0.0], [0.0, 0.0, lz]])


def _in_file_axes(rows: np.ndarray, axes: AxisMap) -> np.ndarray:
    """Our lattice rows in a file's axes, ordered as LAMMPS orders a tilted cell (a along the
    file's x, b in its xy plane); the identity for gripdem's own axes."""
    if axes.name == "xyz":
        return rows
    turned = axes.to_lammps(rows)
    return turned[np.argsort([np.argmax(np.abs(v)) for v in turned])]


def _write_all(data_path: Path, out: Path) -> list[Written]:
    data = read_dataset(data_path)
    sheared = data.boundary.is_lees_edwards
    lammps_axes = AxisMap.for_tilt(0) if sheared else AxisMap.parse("xyz")
    ours = AxisMap.parse("xyz")
    pos, times, offsets = data.positions[0], data.times[0], data.offsets()[0]
    window = slice(FIRST + 1, FIRST + 1 + HORIZON)
    p = Predictions(
        pred_positions=pos[None, window],
        true_positions=pos[None, window],
        last_positions=pos[None, FIRST],
        times=times[None, window],
        boundary=data.boundary,
        radius=data.radius,
    )
    run = slice(FIRST, FIRST + 1 + HORIZON)
    frames = (list(pos[run]), [float(o) for o in offsets[run]])
    xyz = export_extxyz(p, out / "trajectories")["window000_true"]
    dump = export_lammps(p, out / "trajectories")["window000_true"]
    state = ([pos[STATE]], [float(offsets[STATE])])
    dumped = (list(pos[10:14]), [float(o) for o in offsets[10:14]])
    common = [str(data_path), "--frame", str(STATE), "--overwrite"]
    assert handback([*common, "--xyz", str(out / "state.xyz"), "--dump", str(out / "h.dump"),
                     "--dump-frames", "10:14", "--data", str(out / "sphere.data"),
                     "--density", "2500"]) == 0  # fmt: skip
    assert handback([*common, "--data", str(out / "atomic.data"), "--atom-style", "atomic",
                     "--mass", "2e-14"]) == 0  # fmt: skip
    return [
        Written(xyz, "extxyz", *frames, ours),
        Written(dump, "dump", *frames, lammps_axes),
        Written(out / "state.xyz", "extxyz", *state, ours),
        Written(out / "h.dump", "dump", *dumped, lammps_axes),
        Written(out / "sphere.data", "data", *state, lammps_axes, "sphere"),
        Written(out / "atomic.data", "data", *state, lammps_axes, "atomic"),
    ]


@pytest.fixture(scope="module")
def written(tmp_path_factory, le_file, pbc_file):
    out = tmp_path_factory.mktemp("viewers")
    return {
        "lebc": (read_dataset(le_file), _write_all(le_file, out / "lebc")),
        "pbc": (read_dataset(pbc_file), _write_all(pbc_file, out / "pbc")),
    }


def read_ase(w: Written) -> list[tuple[np.ndarray, np.ndarray, object]]:
    """``(cell rows, positions, atoms)`` of every frame as ASE reads them."""
    ase_io = pytest.importorskip("ase.io")
    if w.kind == "extxyz":
        frames = ase_io.read(w.path, index=":", format="extxyz")
    elif w.kind == "dump":
        frames = ase_io.read(w.path, index=":", format="lammps-dump-text")
    else:
        frames = [
            ase_io.read(w.path, format="lammps-data", atom_style=w.atom_style, units="metal")
        ]  # fmt: skip  (metal: lengths as written)
    return [(a.cell.array, a.positions, a) for a in frames]


def read_ovito(w: Written) -> list[tuple[np.ndarray, np.ndarray, object]]:
    """``(cell rows, positions, pipeline)`` of every frame as OVITO reads them."""
    ovito_io = pytest.importorskip("ovito.io")
    kwargs = {"atom_style": w.atom_style} if w.kind == "data" else {}
    pipeline = ovito_io.import_file(str(w.path), **kwargs)
    out = []
    for frame in range(pipeline.num_frames):
        data = pipeline.compute(frame)
        order = np.argsort(np.asarray(data.particles["Particle Identifier"]))
        positions = np.asarray(data.particles.positions)[order]
        out.append((np.asarray(data.cell)[:, :3].T, positions, (pipeline, frame, order)))
    return out


READERS = {"ase": read_ase, "ovito": read_ovito}


@pytest.mark.parametrize("scene", ["lebc", "pbc"])
@pytest.mark.parametrize("reader", ["ase", "ovito"])
def test_count_cell_and_positions_of_every_file(written, scene, reader):
    data, files = written[scene]
    for w in files:
        if reader == "ase" and w.atom_style == "sphere":
            continue  # ASE has no sphere style (module doc); OVITO reads it
        frames = READERS[reader](w)
        assert len(frames) == len(w.positions), w.path
        for (cell, positions, _), expected, offset in zip(
            frames, w.positions, w.offsets, strict=True
        ):
            rows = _in_file_axes(_lattice(data.box, offset), w.axes)
            scale = float(data.box.lengths.max())
            np.testing.assert_allclose(cell, rows, rtol=0, atol=1e-12 * scale, err_msg=str(w.path))
            assert positions.shape == (data.n_particles, 3)
            frac = (positions - w.axes.to_lammps(expected)) @ np.linalg.inv(rows)
            assert np.abs(frac - np.round(frac)).max() < 1e-9, w.path


def _ase_coordination(atoms, d: float) -> np.ndarray:
    from ase.neighborlist import neighbor_list

    scaled = atoms.copy()
    scaled.set_cell(atoms.cell.array / d, scale_atoms=True)
    return np.bincount(neighbor_list("i", scaled, CUTOFF), minlength=len(atoms))


def _ovito_coordination(handle, d: float) -> np.ndarray:
    from ovito.modifiers import AffineTransformationModifier, CoordinationAnalysisModifier

    pipeline, frame, order = handle
    scale = np.hstack([np.eye(3) / d, np.zeros((3, 1))])
    pipeline.modifiers.append(AffineTransformationModifier(transformation=scale))
    pipeline.modifiers.append(CoordinationAnalysisModifier(cutoff=CUTOFF, number_of_bins=20))
    counts = np.asarray(pipeline.compute(frame).particles["Coordination"])
    pipeline.modifiers.pop()
    pipeline.modifiers.pop()
    return counts[order]


@pytest.mark.parametrize("scene", ["lebc", "pbc"])
@pytest.mark.parametrize("reader", ["ase", "ovito"])
def test_the_readers_neighbour_search_finds_gripdems_images(written, scene, reader):
    data, files = written[scene]
    d = data.diameter
    for w in files:
        if reader == "ase" and w.atom_style == "sphere":
            continue
        frames = READERS[reader](w)
        k = len(frames) - 1  # the last frame: the largest offset of the run files
        _, _, handle = frames[k]
        got = (_ase_coordination if reader == "ase" else _ovito_coordination)(handle, d)
        truth = coordination_numbers(w.positions[k], data.box, CUTOFF * d, w.offsets[k])
        assert truth.sum() > 0
        np.testing.assert_array_equal(got, truth, err_msg=str(w.path))


def test_lees_edwards_frames_have_offsets_across_the_box(written):
    """The LE cases above are not trivial: the files' offsets are far from 0."""
    data, files = written["lebc"]
    offsets = np.concatenate([w.offsets for w in files])
    assert np.abs(offsets).max() > 0.2 * data.box.lz
