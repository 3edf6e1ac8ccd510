"""Where a result file comes from: the one header line that every file under
``experiments/results/`` starts with, and the writer that puts it there.

A header reads::

    > Measured 2026-12-07 at commit 99ea07c on AMD EPYC (2 CPUs, torch 2 thread(s)) by `python
    experiments/benchmarks/end_to_end/split_sweep.py`

(one line in the file, wrapped here)

(date in UTC; ``+`` after the commit where tracked files had uncommitted changes; the command
with paths inside the repository relative to it and the home folder written ``~``, so that a
result file names no machine's folders). ``HEADER_PATTERN`` parses it; the JSON twin of a
Markdown result carries the same fields under ``"header"``. ``tests/test_results_provenance.py``
fails on a result file without it. Standard library only: the CLIs and the benchmark scripts
both write through it.

Example:
    >>> from gripdem.provenance import HEADER_PATTERN, result_header
    >>> line = result_header({"date": "2026-12-07", "commit": "99ea07c", "cpu": "AMD EPYC",
    ...                       "cpus": 2, "torch_threads": 1, "command": "python x.py"})
    >>> HEADER_PATTERN.match(line)["cpu"]
    'AMD EPYC'
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import re
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

#: the repository this package sits in (where it is installed editable; else the working folder)
REPO = Path(__file__).resolve().parents[1]
#: the first characters of every result file's header line
HEADER_MARK = "> Measured "
#: one header line, parsed (the fields of :func:`result_fields`)
HEADER_PATTERN = re.compile(
    r"^> Measured (?P<date>\d{4}-\d{2}-\d{2}) at commit (?P<commit>[0-9a-f]{7,40}\+?|unknown)"
    r" on (?P<cpu>.+?) \((?P<cpus>\d+|\?) CPUs, torch (?P<torch_threads>\d+|\?) thread\(s\)\)"
    r" by (?:`(?P<command>[^`]+)`|an unrecorded command)"
)
#: the second line of a header added later to a file written before the header existed: it
#: says which fields were read from the file's text or from git (``?``: not recorded)
RECONSTRUCTED_MARK = "> Header reconstructed "
#: what a result file may not contain: a folder of the machine that wrote it
MACHINE_PATH = re.compile(r"(?<![\w.~$])/(?:work|home|root|tmp|Users)/[\w.+-]+")


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``; the platform's processor elsewhere)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def available_cpus() -> int:
    """CPUs this process may run on (its affinity mask, not the machine's count)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def relative(argument: str) -> str:
    """``argument`` with paths inside the repository made relative to it, the home folder
    written ``~`` and the temporary folder ``$TMPDIR``.

    >>> relative(str(REPO / "experiments" / "results"))
    'experiments/results'
    """
    shorts = (
        (str(REPO) + "/", ""),
        (str(REPO), "."),
        (str(Path.home()) + "/", "~/"),
        (tempfile.gettempdir().rstrip("/") + "/", "$TMPDIR/"),
    )
    for prefix, short in shorts:
        argument = argument.replace(prefix, short)
    return argument


def _git(*args: str) -> str:
    try:
        out = subprocess.run(
            ["git", *args], cwd=REPO, capture_output=True, text=True, timeout=10, check=True
        )
        return out.stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def _torch_threads() -> int:
    torch = sys.modules.get("torch")  # never imported here: a CLI without torch reports 1
    return int(torch.get_num_threads()) if torch is not None else 1


def result_fields(argv: list[str] | None = None) -> dict[str, Any]:
    """What a header says: ``date`` (UTC), ``commit`` (``+`` where tracked files had
    uncommitted changes), ``cpu``, ``cpus``, ``torch_threads`` and ``command`` (``argv``,
    default ``sys.argv``, with a script's path relative to the repository, or ``python -m
    MODULE`` for a module run)."""
    argv = list(sys.argv if argv is None else argv)
    commit = _git("rev-parse", "--short", "HEAD") or "unknown"
    if commit != "unknown" and _git("status", "--porcelain", "--untracked-files=no"):
        commit += "+"
    script = Path(argv[0]).resolve() if argv else None
    if script is not None and script.suffix == ".py" and script.is_relative_to(REPO / "gripdem"):
        head = ["python", "-m", ".".join(script.relative_to(REPO).with_suffix("").parts)]
    else:
        head = ["python", relative(str(script))] if script is not None else ["python"]
    return {
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d"),
        "commit": commit,
        "cpu": cpu_model(),
        "cpus": available_cpus(),
        "torch_threads": _torch_threads(),
        "command": shlex.join([*head, *map(relative, argv[1:])]),
    }


def result_header(fields: dict[str, Any] | None = None) -> str:
    """The header line of a Markdown result file, from :func:`result_fields`."""
    f = fields or result_fields()
    return (
        f"{HEADER_MARK}{f['date']} at commit {f['commit']} on {f['cpu']} ({f['cpus']} CPUs, "
        f"torch {f['torch_threads']} thread(s)) by `{f['command']}`"
    )


def atomic_write(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` whole or not at all (a temporary file, then a rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


def write_result(path: str | Path, text: str, fields: dict[str, Any] | None = None) -> None:
    """A Markdown result file: the header line, a blank line, then ``text``."""
    atomic_write(Path(path), f"{result_header(fields)}\n\n{text.rstrip()}\n")


def write_report(stem: str | Path | None, text: str, data: Any, echo: bool = True) -> None:
    """``STEM.md`` (the header line, then the report) and ``STEM.json`` (the header's fields
    under ``header`` beside the keys of ``data``, a mapping; other data under ``results``; paths
    written as :func:`relative` writes them), each written whole; then print the report
    (``echo``). Without a ``stem`` (a script run with no ``--out``) the report is only printed."""
    if stem is None:
        if echo:
            print(text)
        return
    stem = Path(stem)
    fields = result_fields()
    write_result(stem.parent / f"{stem.name}.md", text, fields)
    payload = (
        {"header": fields, **data}
        if isinstance(data, dict)
        else {
            "header": fields,
            "results": data,
        }
    )
    # paths in the data (arguments, inputs) as the header writes them: no folder of this machine
    text_json = relative(json.dumps(payload, indent=1, default=str))
    atomic_write(stem.parent / f"{stem.name}.json", text_json + "\n")
    if echo:
        print(text)
