"""The dataset cache after a generator killed by SIGKILL (issue 24): its temporary files (never
under a final name) are removed by the next job that finds the entry's lock free, and only
then: a generator at work keeps its own."""

from __future__ import annotations

from pathlib import Path

from filelock import FileLock

from gripdem.data.cache import cached_file
from gripdem.data.h5io import atomic_write_text, temporaries_of


def _killed_generation(folder: Path, stem: str) -> list[Path]:
    """What a generation killed while writing leaves: temporary files only."""
    folder.mkdir(parents=True, exist_ok=True)
    names = [f".{stem}.h5.tmp-99999-0badf00d", f".{stem}.validation.json.tmp-99999-0badf00d"]
    for name in names:
        (folder / name).write_bytes(b"half")
    return [folder / name for name in names]


def test_a_new_generation_removes_a_killed_ones_temporaries(tmp_path):
    path = tmp_path / "pbc-tiny-0123456789abcdef.h5"
    left = _killed_generation(tmp_path, path.stem)
    other = _killed_generation(tmp_path, "lebc-tiny-fedcba9876543210")  # another entry's

    def generate(target: Path) -> None:
        assert not any(p.exists() for p in left)  # removed before generating
        atomic_write_text(target, "data")

    assert cached_file(path, generate, "generating") == path
    assert path.read_text() == "data" and all(p.exists() for p in other)
    assert temporaries_of(tmp_path, path.stem) == []


def test_an_existing_entry_is_swept_only_when_its_lock_is_free(tmp_path):
    path = tmp_path / "pbc-tiny-0123456789abcdef.h5"
    path.write_text("data")
    left = _killed_generation(tmp_path, path.stem)

    def never(target: Path) -> None:
        raise AssertionError("an existing entry is not generated again")

    with FileLock(str(path) + ".lock"):  # a generator at work (writing the report)
        assert cached_file(path, never, "") == path
    assert all(p.exists() for p in left)
    assert cached_file(path, never, "") == path
    assert not any(p.exists() for p in left) and path.read_text() == "data"
