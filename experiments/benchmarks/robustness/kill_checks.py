"""Checks and report of ``kill_commands.py`` after a command was killed (a part of it, not a
script).

- :func:`marked_processes`: every live process whose environment carries a trial's marker
  (``GRIPDEM_KILL_TRIAL=<id>``, inherited by workers, Manager processes and resource trackers
  alike), read from ``/proc/<pid>/environ``; zombies (already dead, not yet reaped) are not
  counted;
- :func:`check_tree`: every file under a folder is either a temporary file (gripdem's
  ``.NAME.tmp-PID-RANDOM``, or anything under the trial's ``TMPDIR``), an append-only log
  (``run.log``, TensorBoard event files: readers stop at a torn last record), a lock file, or
  a file under its final name, which must open and validate with the reader of its kind.
"""

from __future__ import annotations

import gzip
import json
import os
import signal
import time
from pathlib import Path

MARKER = "GRIPDEM_KILL_TRIAL"
SIGNALS = (signal.SIGKILL, signal.SIGTERM, signal.SIGINT)
#: exit status after SIGTERM / SIGINT (gripdem.runner.console)
CLEAN_STATUS = {signal.SIGTERM: 143, signal.SIGINT: 130}
EXIT_WAIT = 60.0  # s a signalled command may take to stop before it counts as hung
RESUME_TOLERANCE = 1e-6  # relative difference of test/rmse counted as a match
#: kinds whose readers are below; anything else under a final name is listed as unchecked
CHECKED = (".h5", ".json", ".safetensors", ".png", ".ckpt", ".yaml", ".xyz", ".data", ".csv")


# --------------------------------------------------------------------------------------------
# processes
# --------------------------------------------------------------------------------------------
def _state(pid: int) -> str:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return "?"
    return stat.rsplit(")", 1)[-1].split()[0]


def marked_processes(trial: str) -> list[tuple[int, str]]:
    """``(pid, command line)`` of the live processes whose environment has ``MARKER=trial``."""
    wanted = f"{MARKER}={trial}".encode()
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        pid = int(entry)
        try:
            environ = Path(f"/proc/{pid}/environ").read_bytes()
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:  # gone, or not ours
            continue
        if wanted in environ.split(b"\0") and _state(pid) not in ("Z", "X", "?"):
            found.append((pid, cmdline.replace(b"\0", b" ").decode(errors="replace").strip()))
    return found


def kill_marked(trial: str) -> None:
    """SIGKILL what :func:`marked_processes` finds (after counting them), so the next trial
    starts on a quiet machine."""
    for pid, _ in marked_processes(trial):
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
    deadline = time.monotonic() + 5
    while marked_processes(trial) and time.monotonic() < deadline:
        time.sleep(0.1)


# --------------------------------------------------------------------------------------------
# files
# --------------------------------------------------------------------------------------------
def is_temporary(path: Path) -> bool:
    """gripdem's temporary name (``atomic_path``): ``.NAME.tmp-...``."""
    return path.name.startswith(".") and ".tmp-" in path.name


def is_log(path: Path) -> bool:
    return path.suffix == ".log" or path.name.startswith("events.out.tfevents")


def _h5(path: Path) -> None:
    import h5py

    with h5py.File(path, "r") as h5:
        fmt = h5.attrs.get("format")
        fmt = fmt.decode() if isinstance(fmt, bytes) else fmt
    if fmt == "gripdem":
        from gripdem.data.dataset_io import read_dataset

        read_dataset(path)
    else:
        from gripdem.evaluation.predictions import read_predictions

        read_predictions(path)


def _png(path: Path) -> None:
    from PIL import Image

    with Image.open(path) as image:
        image.load()


def _ckpt(path: Path) -> None:
    import torch

    torch.load(path, map_location="cpu", weights_only=True)


def _safetensors(path: Path) -> None:
    from gripdem.inference.model_file import load_model_file

    load_model_file(path)


def _yaml(path: Path) -> None:
    import yaml

    if yaml.safe_load(path.read_text()) is None:
        raise ValueError("empty YAML document")


def _xyz(path: Path) -> None:
    """Whole frames only: a count line, a comment line, that many atom lines."""
    lines = path.read_text().splitlines()
    i = 0
    while i < len(lines):
        n = int(lines[i])
        rows = lines[i + 2 : i + 2 + n]
        if len(rows) != n or any(len(r.split()) != len(rows[0].split()) for r in rows):
            raise ValueError(f"frame at line {i + 1}: {len(rows)} of {n} atom lines")
        i += 2 + n


def _lammps_data(path: Path) -> None:
    """A LAMMPS data file: as many Atoms and Velocities lines as the header's atom count."""
    lines = path.read_text().splitlines()
    atoms = next(int(line.split()[0]) for line in lines if line.strip().endswith(" atoms"))
    for section in ("Atoms", "Velocities"):
        start = next(i for i, line in enumerate(lines) if line.split()[:1] == [section])
        body = [line for line in lines[start + 2 : start + 2 + atoms] if line.strip()]
        if len(body) != atoms:
            raise ValueError(f"section {section}: {len(body)} of {atoms} lines")


def _dump(path: Path) -> None:
    from gripdem.formats.lammps.dump import read_dump

    for _ in read_dump(path):
        pass


def _csv(path: Path) -> None:
    import csv

    rows = list(csv.reader(path.read_text().splitlines()))
    if not rows or any(len(row) != len(rows[0]) for row in rows):
        raise ValueError("ragged or empty CSV")


def _gzip(path: Path) -> None:
    with gzip.open(path, "rb") as handle:
        while handle.read(1 << 20):
            pass


def _markdown(path: Path) -> None:
    if not path.read_text().strip():
        raise ValueError("empty")


#: the reader that validates each kind of file (by suffix)
READERS = {
    ".gz": _gzip,
    ".h5": _h5,
    ".json": lambda path: json.loads(path.read_text()),
    ".safetensors": _safetensors,
    ".png": _png,
    ".ckpt": _ckpt,
    ".yaml": _yaml,
    ".xyz": _xyz,
    ".data": _lammps_data,
    ".csv": _csv,
    ".md": _markdown,
}


def check_file(path: Path) -> str | None:
    """``None`` if ``path`` opens and validates with the reader of its kind, else why not."""
    try:
        if path.name.endswith((".dump", ".dump.gz")):
            _dump(path)
        elif path.suffix in READERS:
            READERS[path.suffix](path)
    except Exception as exc:  # noqa: BLE001 - any failure to read is the finding
        return f"{type(exc).__name__}: {str(exc).splitlines()[0][:160] if str(exc) else ''}"
    return None


def check_tree(roots: list[Path], tmp_root: Path | None = None) -> dict:
    """Every file under ``roots``: ``{"bad": [(path, why)], "temporary": [paths],
    "unchecked": [paths], "checked": n}``. Files under ``tmp_root`` (the trial's TMPDIR)
    count as temporary."""
    out: dict = {"bad": [], "temporary": [], "unchecked": [], "checked": 0}
    for root in roots:
        if not root.exists():
            continue
        for path in sorted(p for p in root.rglob("*") if p.is_file() and not p.is_symlink()):
            under_tmp = tmp_root is not None and tmp_root in path.parents
            if is_temporary(path) or under_tmp:
                out["temporary"].append(str(path))
            elif is_log(path) or path.suffix == ".lock":
                continue
            elif not path.name.endswith((*CHECKED, ".gz", ".md")):
                out["unchecked"].append(str(path))
            else:
                why = check_file(path)
                out["checked"] += 1
                if why is not None:
                    out["bad"].append((str(path), why))
    return out


# --------------------------------------------------------------------------------------------
# report
# --------------------------------------------------------------------------------------------
def exit_kind(row: dict, sig: signal.Signals) -> str:
    """``clean`` (one interrupted line, no traceback, the documented status or death by the
    signal itself after the line: both show 128 + signal to a shell), ``outside`` (ended by
    the signal's default action outside the command's handler: Python starting, before it,
    or shutting down, after it; nothing being written), ``finished`` (the command ended
    before the signal), ``killed`` (SIGKILL), else ``unclean``."""
    if not row["landed"]:
        return "finished"
    if sig == signal.SIGKILL:
        return "killed"
    quiet = not row["traceback"]
    if row["rc"] in (CLEAN_STATUS[sig], -sig) and row["interrupted_lines"] == 1 and quiet:
        return "clean"
    if row["rc"] == -sig and row["interrupted_lines"] == 0 and quiet:
        return "outside"
    return "unclean"


def summarise(rows: list[dict], commands: list[str]) -> tuple[list[str], list[list]]:
    headers = ["command", "kills (KILL/TERM/INT)", "landed mid-run", "stray processes"]
    headers += [
        "half-written files",
        "temp files left",
        "clean TERM/INT exits (default action outside the handler)",
    ]
    headers += [
        "next command ok",
        "cache temps after next",
        "resumes matched (max rel. diff of test/rmse)",
    ]
    table = []
    for name in commands:
        rs = [r for r in rows if r["command"] == name]
        if not rs:
            continue
        by = [sum(r["signal"] == s.name for r in rs) for s in SIGNALS]
        soft = [r for r in rs if r["signal"] != "SIGKILL" and r["landed"]]
        clean = sum(r["exit"] == "clean" for r in soft)
        outside = sum(r["exit"] == "outside" for r in soft)
        resume = "–"
        diffs = [r["resume_diff"] for r in rs if "resume_diff" in r]
        if name == "run":
            matched = sum(d <= RESUME_TOLERANCE for d in diffs)
            from_ckpt = sum(r["had_last_ckpt"] for r in rs)
            worst = f"{max(diffs):.2g}" if diffs else "–"
            resume = f"{matched}/{len(rs)} ({from_ckpt} from last.ckpt; {worst})"
        table.append(
            [
                name,
                f"{len(rs)} ({'/'.join(map(str, by))})",
                sum(r["landed"] for r in rs),
                sum(len(r["strays"]) + len(r["next_strays"]) + r["hung"] for r in rs),
                sum(len(r["bad_files"]) for r in rs),
                sum(len(r["temporary"]) for r in rs),
                f"{clean}/{len(soft)} ({outside})",
                f"{sum(r['next_rc'] == 0 for r in rs)}/{len(rs)}",
                sum(len(r["cache_temporary"]) for r in rs),
                resume,
            ]
        )
    return headers, table


def findings(rows: list[dict]) -> list[str]:
    lines = []
    for r in rows:
        tag = f"{r['command']} #{r['index']} ({r['signal']} at {r['delay_s']} s, rc {r['rc']})"
        for pid, cmd in r["strays"] + r["next_strays"]:
            lines.append(f"- {tag}: stray process {pid}: `{cmd[:200]}`")
        lines += [f"- {tag}: half-written `{path}`: {why}" for path, why in r["bad_files"]]
        if r["hung"]:
            lines.append(f"- {tag}: still running {EXIT_WAIT:.0f} s after the signal")
        if r["exit"] == "unclean":
            lines.append(f"- {tag}: unclean exit ({r['interrupted_lines']} interrupted lines)")
        if r["next_rc"] != 0:
            lines.append(f"- {tag}: the next command exited {r['next_rc']}")
        lines += [f"- {tag}: temporary file left in the cache `{p}`" for p in r["cache_temporary"]]
    return lines
