"""Worker processes that die with the process that started them.

A pool's worker processes outlive a parent killed by SIGKILL (no code runs in the parent to
stop them): they finish their task at full CPU, then wait on their call queue forever.
:func:`die_with_parent`, run first in every worker (a pool's ``initializer``), ends a worker
as soon as its parent is gone, two ways:

- Linux: the parent-death signal (``prctl(PR_SET_PDEATHSIG, SIGKILL)``), sent by the kernel the
  moment the parent thread that started the worker exits; the parent pid is checked right
  after, in case the parent died before the call;
- everywhere (macOS too): a daemon thread that compares ``os.getppid()`` with the parent's pid
  every :data:`POLL_SECONDS` and calls ``os._exit`` when the worker has been re-parented.

Both need only the parent's pid (``os.getpid()`` there, passed in ``initargs``), so the
parent needs no helper process of its own (a ``multiprocessing.Manager`` is one, and outlives
a killed parent too: hand workers a plain ``multiprocessing`` queue through ``initargs``).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
import sys
import threading
import time

#: seconds between the watchdog's checks of the parent pid
POLL_SECONDS = 0.5
#: exit status of a worker whose parent is gone (as if killed by SIGKILL)
ORPHAN_STATUS = 128 + signal.SIGKILL
_PR_SET_PDEATHSIG = 1


def _parent_death_signal(sig: int) -> bool:
    """Ask the Linux kernel to send ``sig`` to this process when its parent exits; False
    where that is not available (other systems, no libc)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _watch(parent_pid: int) -> None:
    while True:
        time.sleep(POLL_SECONDS)
        if os.getppid() != parent_pid:
            os._exit(ORPHAN_STATUS)


def die_with_parent(parent_pid: int) -> None:
    """End this (worker) process when ``parent_pid``, its parent, is gone; call it first
    thing in the worker. Exits at once if the parent is already gone."""
    _parent_death_signal(signal.SIGKILL)
    if os.getppid() != parent_pid:  # the parent died before the signal was armed
        os._exit(ORPHAN_STATUS)
    threading.Thread(target=_watch, args=(parent_pid,), name="parent-watchdog", daemon=True).start()
