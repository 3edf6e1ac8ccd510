"""Shared helpers of the benchmark and stress scripts in ``experiments/`` (not a benchmark).

- :func:`machine_line`: the machine, CPUs, threads, torch/numba versions and load average that
  every script prints beside its tables (timings on a shared machine mean little without it);
- :func:`set_threads`: torch intra-op threads (numba kernels of the DEM run on one thread);
- :func:`markdown_table`;
- :func:`result_header` and :func:`write_report`: every result file starts with the header that
  one function writes (date, commit, CPU model and threads, the command with paths relative to
  the repository), and is written whole or not at all (a temporary file, then a rename);
- :class:`PeakMemory`: peak resident memory of a block of code above its starting level,
  sampled from ``/proc/self/statm`` in a thread (torch's CPU allocator has no statistics);
- :func:`scene_dataset`: the built-in dataset of a scene and preset (from the cache; generated
  there if missing, as ``python -m gripdem.run`` would).

The scripts live in one folder per question (``GROUPS``): ``end_to_end/`` (the README's
command, run time against error), ``surrogate/`` (the surrogate against the DEM and LAMMPS),
``model_cost/`` (where a forward pass and a training step spend their time, and how they
scale) and ``robustness/`` (killed commands, stress). A script puts this folder on
``sys.path`` and imports this module, which puts every group's folder there too, so a script
imports another group's module by its name (``from time_vs_error import find_runs``).
"""

from __future__ import annotations

import ctypes
import os
import sys
import threading
import time
from pathlib import Path

import numpy as np
import torch
import yaml

from gripdem.provenance import (  # noqa: F401  (re-exported: the scripts import them from here)
    HEADER_MARK,
    atomic_write,
    available_cpus,
    cpu_model,
    result_fields,
    result_header,
    write_report,
    write_result,
)

CONF = Path(__file__).resolve().parents[2] / "conf"
GIB = 2**30
#: the benchmark scripts' folders, one per question (see the module doc)
GROUPS = ("end_to_end", "surrogate", "model_cost", "robustness")
for _group in GROUPS:
    _folder = str(Path(__file__).resolve().parent / _group)
    if _folder not in sys.path:
        sys.path.append(_folder)


def memory_gib() -> tuple[float, float]:
    """(total, available) RAM in GiB from /proc/meminfo (nan where unknown)."""
    values = {}
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            key, rest = line.split(":", 1)
            values[key] = float(rest.split()[0]) * 1024 / GIB
    except (OSError, ValueError):
        return float("nan"), float("nan")
    return values.get("MemTotal", float("nan")), values.get("MemAvailable", float("nan"))


def machine_line() -> str:
    """One line: CPU, CPUs available, RAM, GPU, torch (threads), numba, load average."""
    import numba

    total, avail = memory_gib()
    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "no GPU"
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    return (
        f"machine: {cpu_model()}, {available_cpus()} CPUs, RAM {total:.0f} GiB "
        f"({avail:.0f} available), {gpu}; torch {torch.__version__} with "
        f"{torch.get_num_threads()} thread(s), numba {numba.__version__} (DEM kernels: 1 "
        f"thread); load average {load}"
    )


def set_threads(threads: int) -> None:
    torch.set_num_threads(int(threads))


def markdown_table(headers: list[str], rows: list[list]) -> str:
    out = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(out)


REPO = Path(__file__).resolve().parents[2]


def add_group_option(parser, what: str) -> None:
    """``--group LABEL FILE...`` (repeatable): a label, then ``what`` (the files of that group)."""
    parser.add_argument(
        "--group",
        nargs="+",
        action="append",
        required=True,
        metavar="LABEL FILE",
        help=f"a label, then {what}",
    )


def group_files(parser, groups: list[list[str]]) -> dict[str, list[Path]]:
    """The ``--group`` options as {label: files}; a group without files is a usage error."""
    out = {}
    for label, *files in groups:
        if not files:
            parser.error(f"--group {label!r} names no report file")
        out[label] = [Path(f) for f in files]
    return out


def fmt(value: float, digits: int = 3) -> str:
    """A number for a table: ``digits`` significant digits, '–' for None/nan."""
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "–"
    return f"{value:.{digits}g}"


# --------------------------------------------------------------------------------------------
# peak memory
# --------------------------------------------------------------------------------------------
_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def rss_bytes() -> int:
    try:
        return int(Path("/proc/self/statm").read_text().split()[1]) * _PAGE
    except OSError:
        return 0


def _glibc():
    try:
        return ctypes.CDLL("libc.so.6")
    except OSError:
        return None


def release_freed_memory() -> None:
    """Hand freed heap memory back to the OS (glibc), so the next RSS baseline is honest."""
    libc = _glibc()
    if libc is not None:
        libc.malloc_trim(0)


#: glibc's M_MMAP_THRESHOLD option, and the largest threshold its dynamic rule reaches on
#: 64-bit Linux (what a long-running process converges to)
_M_MMAP_THRESHOLD = -3
_DYNAMIC_MAX = 32 * 2**20


def _mmap_threshold(threshold: int) -> None:
    libc = _glibc()
    if libc is not None:
        libc.mallopt(_M_MMAP_THRESHOLD, int(threshold))


class PeakMemory:
    """``with PeakMemory() as m: ...`` -> ``m.peak`` bytes of resident memory above the level
    at entry, sampled every ``interval`` s (torch releases the GIL inside its kernels).

    Inside, allocations of 1 MiB and more are served by mmap, so freed tensors leave the
    resident set at once and the peak is honest; on exit the threshold goes to glibc's
    dynamic maximum (32 MiB). Never time code inside: the sampling thread competes for the GIL
    between torch's small kernels and every large tensor costs page faults (measured: a 2x
    slower model forward)."""

    def __init__(self, interval: float = 0.002):
        self.interval = interval
        self.peak = 0
        self._stop = threading.Event()

    def _sample(self) -> None:
        while not self._stop.is_set():
            self._max = max(self._max, rss_bytes())
            time.sleep(self.interval)

    def __enter__(self) -> PeakMemory:
        _mmap_threshold(1 << 20)
        release_freed_memory()
        self._start = rss_bytes()
        self._max = self._start
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._max = max(self._max, rss_bytes())
        self._stop.set()
        self._thread.join()
        self.peak = self._max - self._start
        _mmap_threshold(_DYNAMIC_MAX)
        release_freed_memory()


# --------------------------------------------------------------------------------------------
# data and configs
# --------------------------------------------------------------------------------------------
def load_yaml(group: str, name: str) -> dict:
    return yaml.safe_load((CONF / group / f"{name}.yaml").read_text())


def scene_dataset(scene: str, preset: str, overrides: dict | None = None) -> Path:
    """The built-in dataset of ``scene`` (pbc | lebc) and ``preset`` (tiny | default | paper),
    with ``overrides`` of the preset's keys (e.g. ``{"steps_per_contact": 20}``), through the
    dataset cache (generated where it lacks it)."""
    from gripdem.dem.output import ensure_scene_dataset

    return ensure_scene_dataset(
        load_yaml("scene", scene), {**load_yaml("preset", preset), **(overrides or {})}
    )


def tiling(factor: int) -> tuple[int, int]:
    """``(my, mz)`` with ``my * mz = factor`` and ``mz / my`` in {1, 2}: copies of a box along
    y and z (never x: the LE images slide along x, copies along y and z are consistent in
    both scenes, and the periodic drive depends on x only)."""
    if factor < 1 or factor & (factor - 1):
        raise ValueError(f"particle counts must be the data's times a power of 2, got x{factor}")
    my = 1 << (factor.bit_length() - 1) // 2
    return my, factor // my


def tile_frames(positions: np.ndarray, boundary, factor: int, times: np.ndarray | None = None):
    """A trajectory ``(T, N, 3)`` at ``times`` ``(T,)`` (or one frame ``(N, 3)``) of
    ``boundary`` tiled ``factor`` times along y and z: ``(positions (T, factor * N, 3),
    Boundary)``; the same state repeated, a valid configuration of the larger box (same volume
    fraction, same neighbourhoods, the same Lees-Edwards images: the state is periodic along z
    with the small box's length). A trajectory is tiled as one: its lattice-continuous form
    (frame 0's images, the small box's offsets) is copied and every frame wrapped into the
    larger box with the larger box's own offset at that time, so a particle that crosses a face
    keeps its small step in every copy (tiling the wrapped frames one by one would turn a y or z
    crossing into a jump of a box length, and the offsets of the small box would shift x
    crossers by whole small-box lengths)."""
    from gripdem.boundary import Boundary, Box, rewrap_trajectory, unwrap_trajectory

    positions = np.asarray(positions, np.float64)
    box = boundary.box
    my, mz = tiling(factor)
    big = Boundary(Box(box.lx, my * box.ly, mz * box.lz), boundary.lees_edwards)
    trajectory = positions.ndim == 3
    le = boundary.is_lees_edwards
    if trajectory:
        if le and times is None:
            raise ValueError("tile_frames: a Lees-Edwards trajectory needs its frame times")
        small = boundary.offset(np.asarray(times, np.float64)) if le else None
        source = unwrap_trajectory(positions, box, small)
    else:
        source = positions[None]
        times = np.zeros(1) if times is None else np.atleast_1d(np.asarray(times, np.float64))
    copies = []
    for j in range(my):
        for k in range(mz):
            shift = np.array([0.0, (j - (my - 1) / 2) * box.ly, (k - (mz - 1) / 2) * box.lz])
            copies.append(source + shift)
    tiled = np.concatenate(copies, axis=-2)
    out = rewrap_trajectory(tiled, big.box, big.offset(np.asarray(times)) if le else None)
    return (out if trajectory else out[0]), big


def train_run(run: Path, overrides: list[str]) -> Path:
    """Train and test ``python -m gripdem.run <overrides>`` in this process into ``run`` (no
    figures or XYZ files), with its config saved as a run directory's ``.hydra/`` would be."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from gripdem.run import CONFIG_DIR
    from gripdem.runner.experiment import run_experiment

    overrides = [
        *overrides,
        f"logger.save_dir={run}",
        "outputs.figures=false",
        "outputs.export_xyz=false",
    ]
    with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
        cfg = compose("config", overrides=overrides)
    run_experiment(cfg, run)
    (run / ".hydra").mkdir(parents=True, exist_ok=True)
    OmegaConf.save(cfg, run / ".hydra" / "config.yaml")
    OmegaConf.save(OmegaConf.create(overrides), run / ".hydra" / "overrides.yaml")
    return run


def best_of(fn, repeats: int) -> float:
    """Smallest wall time of ``repeats`` calls (s): the least disturbed by other jobs."""
    times = []
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)
