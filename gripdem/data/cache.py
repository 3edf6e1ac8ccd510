"""Dataset cache (docs/spec/data.md#cache): generated datasets live in one documented place, keyed
by a hash.

Location: ``$GRIPDEM_DATA`` if set, else the user cache directory
(``platformdirs.user_cache_dir("gripdem")``, e.g. ``~/.cache/gripdem`` on Linux). A file name
carries a key that hashes everything the data depends on (:func:`content_key`), so a changed
parameter or a new generator version never reuses a stale file. A file lock (``<file>.lock``)
makes parallel sweep jobs wait for one generation instead of racing; generators write
atomically, so a crash or Ctrl-C leaves nothing half-written, and the temporary files a
SIGKILL leaves behind are removed by the next job that finds the entry's lock free.

The cache does not know what generates the data: :func:`cached_file` asks the caller for a
generator (the built-in DEM's is :func:`gripdem.dem.output.ensure_scene_dataset`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from filelock import FileLock

from gripdem.data.h5io import temporaries_of

log = logging.getLogger(__name__)

ENV_VAR = "GRIPDEM_DATA"


def data_root(root: str | os.PathLike | None = None) -> Path:
    """``root``, else ``$GRIPDEM_DATA``, else the user cache directory."""
    if root is not None:
        return Path(root)
    if os.environ.get(ENV_VAR):
        return Path(os.environ[ENV_VAR])
    from platformdirs import user_cache_dir

    return Path(user_cache_dir("gripdem"))


def content_key(payload: Any) -> str:
    """16 hex digits of SHA-256 over ``payload`` as sorted JSON (non-JSON values as strings)."""
    text = json.dumps(payload, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def cached_file(path: Path, generate: Callable[[Path], Any], message: str) -> Path:
    """``path`` if it exists, else ``generate(path)`` under a file lock (another job that
    generates the same file first makes this one wait, then find it). ``message`` is logged
    (or printed when logging is not configured) before generating."""
    if path.exists():
        _remove_temporaries_when_idle(path)
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(_lock_name(path)):
        _remove_temporaries(path)
        if path.exists():  # another job generated it while we waited
            return path
        if log.hasHandlers():  # Hydra / Lightning configured logging
            log.info(message)
        else:
            print(message, flush=True)
        generate(path)
    return path


def _lock_name(path: Path) -> str:
    return str(path) + ".lock"


def _remove_temporaries(path: Path) -> None:
    """Under the lock: temporary files of ``path`` and its companions (``<stem>.*``: the
    report beside a dataset) are a killed generator's; every writer of them holds the lock."""
    for stale in temporaries_of(path.parent, path.stem):
        stale.unlink(missing_ok=True)
        log.debug("removed %s (left by a killed generation)", stale)


def _remove_temporaries_when_idle(path: Path) -> None:
    """The same for an existing entry, when nobody holds its lock (else left for later)."""
    if not temporaries_of(path.parent, path.stem):
        return
    try:
        with FileLock(_lock_name(path), timeout=0):
            _remove_temporaries(path)
    except OSError:  # held by a generator at work (filelock's Timeout), or a read-only cache
        pass
