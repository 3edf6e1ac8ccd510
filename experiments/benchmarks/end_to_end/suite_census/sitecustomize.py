"""Process census of a test run (``test_command.py --census``): every Python process that
starts with this folder on ``PYTHONPATH`` and ``GRIPDEM_CENSUS_DIR`` set writes one file when it
starts and one when it exits (its argv, wall and CPU seconds, and whether it imported torch or
Lightning). A process killed by a signal leaves only its start file. Nothing happens without
``GRIPDEM_CENSUS_DIR``."""

import os

_CENSUS = os.environ.get("GRIPDEM_CENSUS_DIR")

if _CENSUS:
    import atexit
    import json
    import sys
    import time

    _START = time.time()

    def _write(kind: str, record: dict) -> None:
        path = os.path.join(_CENSUS, f"{kind}-{os.getpid()}.json")
        try:
            with open(path, "w") as handle:
                json.dump(record, handle)
        except OSError:  # the folder is gone: the census is over
            pass

    _write("start", {"pid": os.getpid(), "ppid": os.getppid(), "start": _START})

    def _at_exit() -> None:
        times = os.times()
        _write(
            "end",
            {
                "pid": os.getpid(),
                "ppid": os.getppid(),
                "argv": [os.path.basename(sys.argv[0])] + sys.argv[1:4] if sys.argv else [],
                "wall_s": time.time() - _START,
                "cpu_s": times.user + times.system,
                "torch": "torch" in sys.modules,
                "lightning": "lightning" in sys.modules,
                # set in pytest-xdist's workers (and inherited by what their tests start: a
                # worker is also a child of pytest's own process)
                "xdist_env": "PYTEST_XDIST_WORKER" in os.environ,
            },
        )

    atexit.register(_at_exit)
