"""A clean console for the command-line entry points: user errors in one line, Ctrl-C in one
line, and each log line once.

Errors (:func:`run_command`, used by every ``python -m gripdem.<command>``): bad input, a bad
option or config, a missing or existing file end the command with one line on stderr,
``error: <file>: field '<field>': <found>, <expected>``, and exit status 1; a Ctrl-C ends it
with ``interrupted: <command> ...: <what was kept or removed>`` and status 130. A traceback is
printed only for a bug (any other exception), or always with ``GRIPDEM_TRACEBACK=1`` (also
honoured: Hydra's own ``HYDRA_FULL_ERROR=1``).

Logging: three things made a run's output hard to read:

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
import os
import signal
import sys
import threading
import traceback
import warnings
from collections.abc import Callable, Iterator
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


# --------------------------------------------------------------------------------------------
# user errors and Ctrl-C in one line
# --------------------------------------------------------------------------------------------
#: set to 1 for a traceback with every error (``HYDRA_FULL_ERROR=1`` works too)
TRACEBACK_ENV = "GRIPDEM_TRACEBACK"
#: exit status of a command stopped by Ctrl-C (128 + SIGINT, as a shell reports it)
INTERRUPTED_STATUS = 130
#: exception types that document bad input in their message (file, field, found, expected);
#: other ValueErrors / OSErrors are user errors too, but come with a hint to see where
DOCUMENTED = (
    "DatasetError",  # gripdem.data.schema (FordatisError, DumpError are subclasses)
    "SplitError",  # gripdem.data.windows
    "IncompatibleError",  # gripdem.inference.checkpoint
    "CheckpointError",  # gripdem.inference.model_file
    "ValidationFailed",  # gripdem.dem.output
    "FileNotFoundError",
    "FileExistsError",
    "IsADirectoryError",
    "NotADirectoryError",
    "PermissionError",
    "ConfigCompositionException",  # hydra: an unknown option or a value of the wrong type
    "MissingConfigException",
    "ValidationError",  # omegaconf
    "MissingMandatoryValue",
    "ConfigKeyError",
    "ConfigAttributeError",
    "InterpolationResolutionError",
)


#: True once :func:`run_hydra_command` has set HYDRA_FULL_ERROR itself (not the user)
_HYDRA_FORCED = False


def traceback_wanted() -> bool:
    names = (TRACEBACK_ENV,) if _HYDRA_FORCED else (TRACEBACK_ENV, "HYDRA_FULL_ERROR")
    return any(os.environ.get(name, "").strip() not in ("", "0") for name in names)


def _user_error_types() -> tuple[type[BaseException], ...]:
    types: list[type[BaseException]] = [ValueError, OSError]
    try:  # the Hydra commands: config errors (unknown option, wrong type, missing value)
        from hydra.errors import HydraException
        from omegaconf.errors import OmegaConfBaseException

        types += [HydraException, OmegaConfBaseException]
    except ImportError:  # pragma: no cover - hydra is a dependency
        pass
    return tuple(types)


def _is_documented(exc: BaseException) -> bool:
    """A documented error type, or an error gripdem raised itself (its message says what was
    wrong); not one that a library raised deep inside (that one gets a hint to see where)."""
    if any(cls.__name__ in DOCUMENTED for cls in type(exc).__mro__):
        return True
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    return tb is not None and str(tb.tb_frame.f_globals.get("__name__", "")).startswith("gripdem")


def one_line(exc: BaseException) -> str:
    """The message of ``exc`` (and of a config error's cause) on one line."""
    parts = [str(exc)]
    cause = exc.__cause__ or exc.__context__
    if (
        cause is not None
        and type(exc).__module__.startswith("hydra")
        and str(cause) not in parts[0]
    ):
        parts.append(str(cause))
    if isinstance(exc, KeyError) and len(exc.args) == 1:
        parts[0] = str(exc.args[0])
    text = ""
    for line in (line.strip() for p in parts for line in p.splitlines()):
        if line:
            text += "" if not text else " " if text.endswith(tuple(".,:;?!")) else "; "
            text += line
    return text or type(exc).__name__


class _Sigint:
    """Remembers that Ctrl-C was pressed (Lightning turns it into ``sys.exit(1)``)."""

    seen = False

    @classmethod
    def handler(cls, signum, frame) -> None:
        cls.seen = True
        raise KeyboardInterrupt


def run_command(
    command: str,
    body: Callable[[], int | None],
    interrupted: str | Callable[[], str] = "nothing half-written is left (files are written "
    "to a temporary name and renamed when complete)",
    error_status: int = 1,
) -> int:
    """Run ``body`` (a command's work); returns the exit status. User errors print one line
    ``error: ...`` (status 1), Ctrl-C one line ``interrupted: ...`` (status 130) saying
    ``interrupted`` (text, or a function called then: what was kept or removed); anything else
    is a bug and raises (its traceback printed by Python). ``error_status``: the status of a
    user error (``claims`` and ``summary`` keep their documented 2)."""
    previous = None
    if threading.current_thread() is threading.main_thread():
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            previous = signal.signal(signal.SIGINT, _Sigint.handler)
    _Sigint.seen = False
    try:
        status = body()
    except KeyboardInterrupt:
        return _interrupted(command, interrupted)
    except SystemExit as exc:
        if _Sigint.seen and exc.code not in (0, None):  # Lightning's graceful Ctrl-C exit
            return _interrupted(command, interrupted)
        raise
    except _user_error_types() as exc:
        report_error(exc)
        return error_status
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    return 0 if status is None else int(status)


def run_hydra_command(
    command: str, hydra_main: Callable[[], object], interrupted: str | Callable[[], str]
) -> int:
    """:func:`run_command` for a ``@hydra.main`` function: Hydra is asked to re-raise errors
    (``HYDRA_FULL_ERROR=1`` unless the user set it) instead of printing a stripped traceback
    and its hint, so config and input errors end in the same one line as everywhere else."""
    global _HYDRA_FORCED
    if "HYDRA_FULL_ERROR" not in os.environ:
        os.environ["HYDRA_FULL_ERROR"] = "1"
        _HYDRA_FORCED = True

    def body() -> int:
        hydra_main()
        return 0

    return run_command(command, body, interrupted)


def report_error(exc: BaseException) -> None:
    """Print the one line of a user error (after its traceback when asked for)."""
    if traceback_wanted():
        traceback.print_exception(exc)
    hint = "" if _is_documented(exc) else f" ({type(exc).__name__}; {TRACEBACK_ENV}=1 shows where)"
    print(f"error: {one_line(exc)}{hint}", file=sys.stderr, flush=True)


@contextmanager
def single_run_errors() -> Iterator[None]:
    """Around the work of a Hydra job: in a single run a user error prints its line and exits
    with status 1 right here, before Hydra adds a line of its own (``Error executing job with
    overrides``, which a multirun keeps: it says which job failed)."""
    try:
        yield
    except _user_error_types() as exc:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        if HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN:
            raise
        report_error(exc)
        raise SystemExit(1) from None


def _interrupted(command: str, interrupted: str | Callable[[], str]) -> int:
    if traceback_wanted():
        traceback.print_exc()
    what = interrupted() if callable(interrupted) else interrupted
    print(f"interrupted: {command} stopped by Ctrl-C; {what}", file=sys.stderr, flush=True)
    return INTERRUPTED_STATUS
