"""What a sweep's console shows of its running jobs' long work: the dataset cache's lines (which
job generates a dataset, which waits for it, when it is ready) as they come, and the DEM's
progress every :data:`PROGRESS_SECONDS`, read from each job's ``console.log``.

Without it a sweep whose jobs first generate their data prints nothing for minutes after "job
#0 ... started". The parallel launcher (:mod:`gripdem.runner.parallel_launcher`) polls a
:class:`ConsoleRelay` per running job.
"""

from __future__ import annotations

import re
from pathlib import Path

#: seconds between two relayed progress lines of one job
PROGRESS_SECONDS = 30.0
#: the dataset cache's own lines (gripdem.data.cache): relayed as they come
CACHE_LINE = re.compile(r"(?:\[gripdem\.data\.cache\]\[\w+\] - |^)(?P<text>gripdem: .*)$")
#: a DEM progress bar's update (tqdm: ``DEM pbc/default:  40%|###   | 1010/2526 [01:02<01:33``)
PROGRESS = re.compile(
    r"(?P<what>DEM [\w/.-]+):\s*(?P<percent>\d+)%\|[^|]*\|\s*(?P<done>\d+)/(?P<total>\d+)"
    r"(?: \[(?P<elapsed>[\d:]+)<(?P<left>[\d:?]+))?"
)


class ConsoleRelay:
    """Reads a job's ``console.log`` as it grows and returns the lines worth showing."""

    def __init__(self, path: Path, progress_seconds: float = PROGRESS_SECONDS):
        self.path = path
        self.progress_seconds = progress_seconds
        self._offset = 0
        self._partial = ""
        self._last_progress = float("-inf")

    def _new_segments(self) -> list[str]:
        try:
            with open(self.path, "rb") as log:
                log.seek(self._offset)
                chunk = log.read()
        except OSError:  # not there yet
            return []
        self._offset += len(chunk)
        text = self._partial + chunk.decode("utf-8", errors="replace")
        parts = re.split(r"[\r\n]", text)
        self._partial = parts.pop()  # an unfinished line or bar update waits for the next poll
        return [p for p in parts if p.strip()]

    def poll(self, now: float) -> list[str]:
        """The lines to show since the last poll, at ``now`` (seconds, any monotonic clock):
        every cache line, and the latest progress update once per ``progress_seconds``."""
        lines, progress = [], None
        for segment in self._new_segments() + ([self._partial] if "%|" in self._partial else []):
            cache = CACHE_LINE.search(segment)
            if cache is not None:
                lines.append(cache["text"])
                continue
            bar = PROGRESS.search(segment)
            if bar is not None:
                progress = bar
        if progress is not None and now - self._last_progress >= self.progress_seconds:
            self._last_progress = now
            left = f", about {progress['left']} left" if progress["left"] not in (None, "?") else ""
            lines.append(
                f"{progress['what']}: {progress['percent']}% ({progress['done']}/"
                f"{progress['total']} frames{left})"
            )
        return lines
