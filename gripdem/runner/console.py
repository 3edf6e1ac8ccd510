"""A clean console for the command-line entry points (``gripdem.run``, ``gripdem.simulate``).

Three things made a run's output hard to read:

- every Lightning INFO line came twice: once through the console handler that ``lightning``
  (the top-level package) installs at import, and once through Hydra's root handlers;
- Lightning prints advertising "Tip" lines for its cloud products on every Trainer;
- dependencies raise deprecation warnings about each other (not about gripdem's code).

:func:`quiet_console` routes Lightning's records to Hydra's handlers only (console and the
job's log file), drops the tips, and filters the known third-party deprecation warnings by
their exact message. Everything else (gripdem's own warnings included) is left alone.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Iterator
from contextlib import contextmanager

#: Lightning's loggers that carry console handlers of their own
LIGHTNING_LOGGERS = ("lightning", "lightning.pytorch", "lightning.fabric")
#: the loggers Lightning's ``rank_zero_info`` lines (the tips among them) are created on; a
#: logger's filters see only the records created on it, not those propagated from children
RANK_ZERO_LOGGERS = (
    "lightning.pytorch.utilities.rank_zero",
    "lightning.fabric.utilities.rank_zero",
)
#: messages of third-party advertising lines (Lightning's cloud products)
ADVERTISING_PREFIXES = ("💡 Tip:",)
#: (message regex, category) of deprecation warnings that dependencies raise about each
#: other; nothing a gripdem user can act on
KNOWN_DEPENDENCY_WARNINGS = (
    # Lightning's pytree helper on torch >= 2.10 (lightning/pytorch/utilities/_pytree.py)
    (r"`isinstance\(treespec, LeafSpec\)` is deprecated", Warning),
    # TensorBoard's use of pkg_resources / np.bool8 on recent setuptools and numpy
    (r"pkg_resources is deprecated as an API", Warning),
)


class DropAdvertising(logging.Filter):
    """Drops log records whose message starts with one of :data:`ADVERTISING_PREFIXES`."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.getMessage()).startswith(ADVERTISING_PREFIXES)


_FILTER = DropAdvertising()


def quiet_console() -> None:
    """Idempotent: each Lightning line once (through Hydra's handlers), no tips, no known
    dependency deprecation warnings. Call after Hydra has configured logging."""
    for name in LIGHTNING_LOGGERS:
        logger = logging.getLogger(name)
        logger.handlers.clear()
        logger.propagate = True
    for name in RANK_ZERO_LOGGERS:
        child = logging.getLogger(name)
        if _FILTER not in child.filters:
            child.addFilter(_FILTER)
    for message, category in KNOWN_DEPENDENCY_WARNINGS:
        warnings.filterwarnings("ignore", message=message, category=category)


@contextmanager
def lightning_info_muted() -> Iterator[None]:
    """Lightning's INFO lines off inside the block (e.g. a second Trainer that would repeat
    which devices are available); warnings still pass."""
    loggers = [logging.getLogger(name) for name in RANK_ZERO_LOGGERS]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.WARNING)
    try:
        yield
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)
