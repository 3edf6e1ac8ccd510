"""A clean console for the command-line entry points: user errors in one line, Ctrl-C in one
line, and each log line once.

Errors (:func:`run_command`, used by every ``python -m gripdem.<command>``): bad input, a bad
option or config, a missing or existing file end the command with one line on stderr,
``error: <file>: field '<field>': <found>, <expected>``, and exit status 1; a Ctrl-C ends it
with ``interrupted: <command> ...: <what was kept or removed>`` and status 130; SIGTERM (a
scheduler's or ``kill``'s stop) the same way, with status 143. A traceback is printed only for
a bug (any other exception), or always with ``GRIPDEM_TRACEBACK=1`` (also honoured: Hydra's
own ``HYDRA_FULL_ERROR=1``).

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

import _thread
import logging
import os
import signal
import sys
import threading
import traceback
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

#: set by the parallel launcher (gripdem.runner.parallel_launcher) for each job it starts: a
#: job's user error also goes to its error.txt, which the sweep's summary reads
SWEEP_JOB_ENV = "GRIPDEM_SWEEP_JOB"
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
#: exit status of a command stopped by SIGTERM (128 + SIGTERM)
TERMINATED_STATUS = 143
#: exception types that document bad input in their message (file, field, found, expected);
#: other ValueErrors / OSErrors are user errors too, but come with a hint to see where
DOCUMENTED = (
    "DatasetError",  # gripdem.data.schema (FordatisError, DumpError are subclasses)
    "SplitError",  # gripdem.data.windows
    "IncompatibleError",  # gripdem.inference.checkpoint
    "CheckpointError",  # gripdem.inference.model_file
    "ValidationFailed",  # gripdem.dem.output
    "SweepJobsFailed",  # gripdem.runner.sweep_callback (a multirun with failed jobs)
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


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the command is, as Ctrl-C raises KeyboardInterrupt: everything
    that cleans up after a Ctrl-C (temporary files, worker processes, Lightning's graceful
    shutdown) does so after a SIGTERM too."""


class _Sigint:
    """Remembers which of Ctrl-C / SIGTERM stopped the command (Lightning turns either into
    ``sys.exit(1)``)."""

    seen: int | None = None
    previous_hook = sys.__unraisablehook__

    @classmethod
    def handler(cls, signum, frame) -> None:
        cls.seen = signum
        if signum == signal.SIGTERM:
            raise Terminated
        raise KeyboardInterrupt

    @classmethod
    def unraisable(cls, unraisable) -> None:
        """``sys.unraisablehook``: the handler's exception raised where Python cannot
        propagate it (a weakref callback, a ``__del__``: "Exception ignored in ...", measured
        inside importlib's module locks) is delivered again, so the command still stops."""
        if cls.seen is not None and isinstance(unraisable.exc_value, KeyboardInterrupt):
            # from another thread, a moment later: delivered here it would land in this hook
            again = threading.Timer(0.01, _thread.interrupt_main, args=(cls.seen,))
            again.daemon = True
            again.start()
            return
        cls.previous_hook(unraisable)


#: (signal, the handler it must have for :func:`run_command` to take it over)
_TAKEN_OVER = ((signal.SIGINT, signal.default_int_handler), (signal.SIGTERM, signal.SIG_DFL))


def run_command(
    command: str | Callable[[], str],
    body: Callable[[], int | None],
    interrupted: str | Callable[[], str] = "nothing half-written is left (files are written "
    "to a temporary name and renamed when complete)",
    error_status: int = 1,
) -> int:
    """Run ``body`` (a command's work); returns the exit status. User errors print one line
    ``error: ...`` (status 1), Ctrl-C one line ``interrupted: ...`` (status 130) saying
    ``interrupted`` (text, or a function called then: what was kept or removed), SIGTERM the
    same line (status 143); anything else is a bug and raises (its traceback printed by
    Python). ``error_status``: the status of a user error (``claims`` and ``summary`` keep
    their documented 2). ``command`` may be a function too (a name that depends on what
    ``body`` parsed): a command that parses and imports inside ``body`` answers a Ctrl-C or
    SIGTERM within a fraction of a second of its start."""
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for signum, default in _TAKEN_OVER:
            if signal.getsignal(signum) is default:  # not ignored, not someone else's
                previous[signum] = signal.signal(signum, _Sigint.handler)
    _Sigint.seen = None
    _Sigint.previous_hook, sys.unraisablehook = sys.unraisablehook, _Sigint.unraisable
    try:
        try:
            status = body()
        except SystemExit as exc:
            if _Sigint.seen and exc.code not in (0, None):  # Lightning's graceful Ctrl-C exit
                return _interrupted(command, interrupted, _Sigint.seen)
            raise
        except Exception as exc:
            if not isinstance(exc, _user_error_types()):
                raise
            report_error(exc)
            return error_status
    except KeyboardInterrupt as exc:  # in the work, or while an error was being reported
        return _interrupted(command, interrupted, _Sigint.seen or _signal_of(exc))
    finally:
        sys.unraisablehook = _Sigint.previous_hook
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    if _Sigint.seen is not None:  # its exception swallowed by a library: stopped all the same
        return _interrupted(command, interrupted, _Sigint.seen)
    return 0 if status is None else int(status)


def _signal_of(exc: KeyboardInterrupt) -> int:
    return signal.SIGTERM if isinstance(exc, Terminated) else signal.SIGINT


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


def in_multirun() -> bool:
    """Whether this Hydra job runs in-process in a multirun (Hydra's own launchers)."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    return HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN


def in_sweep_job() -> bool:
    """Whether this job is one of a sweep's: in a multirun, or a job of the parallel
    launcher (its own process, :data:`SWEEP_JOB_ENV` set)."""
    return in_multirun() or bool(os.environ.get(SWEEP_JOB_ENV))


@contextmanager
def single_run_errors(out_dir: Path | None = None) -> Iterator[None]:
    """Around the work of a Hydra job: in a single run a user error prints its line and exits
    with status 1 right here, before Hydra adds a line of its own. In a multirun the job's
    error line goes to ``out_dir/error.txt`` (when given) and is printed, and the error is
    swallowed, so the other jobs run and the sweep's summary names this job with its error
    (the command still ends with status 1: :class:`gripdem.runner.sweep_callback.SweepSummary`);
    without ``out_dir`` it is re-raised (Hydra's ``Error executing job with overrides``). A job
    of the parallel launcher (a single run in its own process, :data:`SWEEP_JOB_ENV` set)
    writes its error.txt too and exits with status 1."""
    try:
        yield
    except _user_error_types() as exc:
        multirun = in_multirun()
        sweep_job = in_sweep_job()
        if multirun and out_dir is None:
            raise
        report_error(exc)
        if sweep_job and out_dir is not None:
            from gripdem.data.h5io import atomic_write_text
            from gripdem.evaluation.sweep_summary import ERROR_FILE

            atomic_write_text(Path(out_dir) / ERROR_FILE, one_line(exc) + "\n", overwrite=True)
            if multirun:
                return
        raise SystemExit(1) from None


def _interrupted(
    command: str | Callable[[], str], interrupted: str | Callable[[], str], signum: int
) -> int:
    if traceback_wanted() and sys.exc_info()[0] is not None:
        traceback.print_exc()
    what = interrupted() if callable(interrupted) else interrupted
    command = command() if callable(command) else command
    by = "SIGTERM" if signum == signal.SIGTERM else "Ctrl-C"
    print(f"interrupted: {command} stopped by {by}; {what}", file=sys.stderr, flush=True)
    return TERMINATED_STATUS if signum == signal.SIGTERM else INTERRUPTED_STATUS
