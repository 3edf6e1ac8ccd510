"""A sweep's console relays its jobs' long work (gripdem/runner/job_relay.py): read from a job's
console.log as the job writes it, in the formats Hydra's log and the DEM's tqdm bar write."""

from __future__ import annotations

from gripdem.runner.job_relay import ConsoleRelay

CACHE = "[2026-12-07 05:40:01,250][gripdem.data.cache][INFO] - gripdem: generating dataset x.h5"


def bar(done: int, total: int = 2526) -> str:
    percent = 100 * done // total
    return f"\rDEM pbc/default:  {percent}%|###      | {done}/{total} [01:02<01:33, 16.3frame/s]"


def test_cache_lines_come_at_once_and_progress_once_per_interval(tmp_path):
    log = tmp_path / "console.log"
    relay = ConsoleRelay(log, progress_seconds=30.0)
    assert relay.poll(0.0) == []  # the job has not written its log yet
    with open(log, "w") as out:
        out.write("[2026-12-07 05:40:00,000][gripdem.runner][INFO] - other lines stay out\n")
        out.write(CACHE + "\n" + bar(0) + bar(100))
        out.flush()
        lines = relay.poll(1.0)
        assert lines[0] == "gripdem: generating dataset x.h5"
        assert lines[1] == "DEM pbc/default: 3% (100/2526 frames, about 01:33 left)"
        out.write(bar(400) + bar(800))  # within the interval: nothing new to show
        out.flush()
        assert relay.poll(20.0) == []
        out.write(bar(1263))
        out.flush()
        assert relay.poll(31.5) == ["DEM pbc/default: 50% (1263/2526 frames, about 01:33 left)"]
        out.write(
            "\n[2026-12-07 05:42][gripdem.data.cache][INFO] - gripdem: generated x.h5 in 160 s\n"
        )
        out.flush()
        assert relay.poll(32.0) == ["gripdem: generated x.h5 in 160 s"]


def test_an_unfinished_line_waits_for_its_end(tmp_path):
    log = tmp_path / "console.log"
    relay = ConsoleRelay(log)
    log.write_text("gripdem: waiting for x.h5: another pro")
    assert relay.poll(0.0) == []
    with open(log, "a") as out:
        out.write("cess is generating it\n")
    assert relay.poll(1.0) == ["gripdem: waiting for x.h5: another process is generating it"]
