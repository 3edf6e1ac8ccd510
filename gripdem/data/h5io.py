"""Atomic file writes shared by every writer in gripdem (datasets, predictions, exports,
summaries): write to a temporary file in the target's folder, then rename over the target.

A reader never sees a half-written file, an interrupted write leaves nothing behind, and an
existing file is replaced only when the caller asks (``overwrite=True``). A write killed by
SIGKILL (no code runs to clean up) leaves only its temporary file, never a file under the final
name; the dataset cache removes those of its entries (:func:`temporaries_of`).
"""

from __future__ import annotations

import glob
import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import h5py


def _refuse_overwrite(path: Path, overwrite: bool) -> None:
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path}: exists; refusing to overwrite it (pass overwrite=True)")


#: what marks a temporary name: ``.NAME.tmp-PID-RANDOM``
TEMPORARY_MARK = ".tmp-"


def temporaries_of(folder: str | os.PathLike, stem: str) -> list[Path]:
    """Temporary files in ``folder`` of writes to ``<stem>.*`` (e.g. ``data.h5`` and its
    ``data.validation.json``), as a killed writer leaves them: only their writer (or, once it
    is gone, nobody) uses them, so remove them only where no other writer can be at work."""
    return sorted(Path(folder).glob(f".{glob.escape(stem)}.*{TEMPORARY_MARK}*"))


@contextmanager
def atomic_path(path: str | os.PathLike, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on normal exit rename it onto ``path``.

    On any exception (including KeyboardInterrupt) the temporary file is removed and an existing
    ``path`` is untouched. Raises FileExistsError up front if ``path`` exists and
    ``overwrite`` is false. The temporary name matches the ``*.h5.tmp*`` ignore pattern for
    HDF5 targets: ``.NAME.tmp-PID-RANDOM``.
    """
    path = Path(path)
    _refuse_overwrite(path, overwrite)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}{TEMPORARY_MARK}{os.getpid()}-{uuid.uuid4().hex[:8]}")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextmanager
def atomic_h5_write(path: str | os.PathLike, overwrite: bool = False) -> Iterator[h5py.File]:
    """Open a temporary HDF5 file for writing; it becomes ``path`` when the block ends."""
    with atomic_path(path, overwrite) as tmp:
        with h5py.File(tmp, "w") as h5:
            yield h5


def atomic_write_text(path: str | os.PathLike, text: str, overwrite: bool = False) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns ``Path(path)``."""
    with atomic_path(path, overwrite) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)
