"""Screenshots of TensorBoard on a sweep, in a real browser: the HParams table, the HParams
scatter view, the Scalars (Time Series: training and validation curves, the error per horizon
step) and Custom Scalars tabs, for the how-to "Compare runs in TensorBoard"
(docs/how-to/tensorboard.md).

Starts ``tensorboard --logdir LOGDIR --host 127.0.0.1`` on a free port, opens it in headless
Chromium (Debian's ``chromium`` package, driven by Playwright: ``pip install playwright``; no
browser download is needed) and saves one PNG per view. It also prints what TensorBoard's own
reader finds in LOGDIR (runs, HParams keys with types, hp/ metrics, tag counts), the same
account the tests check (gripdem.evaluation.tensorboard_runs).

    python -m gripdem.run -m split=190-10,100-100 model=vct        # the split sweep
    python experiments/tensorboard/screenshots.py multirun/<date>
    cp experiments/figures/tensorboard_*.png docs/assets/   # the docs' copies
"""

from __future__ import annotations

import argparse
import re
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

from gripdem.evaluation.tensorboard_runs import describe, read_runs

VIEWPORT = {"width": 1920, "height": 1000}


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def start_tensorboard(logdir: Path, port: int) -> subprocess.Popen:
    """TensorBoard on 127.0.0.1, answering once it has read the runs."""
    command = [
        *(sys.executable, "-m", "tensorboard.main", "--logdir", str(logdir)),
        *("--host", "127.0.0.1", "--port", str(port), "--load_fast", "false"),
    ]
    server = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise RuntimeError(f"tensorboard exited: {server.stderr.read().decode()[-2000:]}")
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/data/runs", timeout=2) as r:
                if r.read().strip() not in (b"", b"[]"):
                    return server
        except OSError:
            pass
        time.sleep(0.5)
    server.terminate()
    raise RuntimeError("tensorboard did not list any run within 120 s")


def chromium_path() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    raise SystemExit("no Chromium found: apt-get install chromium (Debian's package)")


def shoot(url: str, out: Path, differing: set[str], hparams: set[str]) -> list[Path]:
    """The views as PNG files under ``out``: the HParams table as it first shows, the scatter
    view with the settings that do not differ unticked, two Time Series filters (training and
    validation curves; the error per horizon step) and Custom Scalars."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        raise SystemExit("needs Playwright to drive the browser: pip install playwright") from None
    out.mkdir(parents=True, exist_ok=True)
    saved = []
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium_path(), headless=True)
        page = browser.new_page(viewport=VIEWPORT, device_scale_factor=1)

        def save(name: str) -> None:
            path = out / f"tensorboard_{name}.png"
            page.screenshot(path=str(path))
            saved.append(path)

        page.goto(f"{url}/#hparams")
        page.get_by_text("Trial ID").first.wait_for(timeout=60_000)
        page.wait_for_timeout(3000)  # the session groups arrive after the columns
        save("hparams_table")
        boxes = page.locator("paper-checkbox")
        for i in range(boxes.count()):  # untick the shown settings that are equal in all runs
            box = boxes.nth(i)
            label = box.inner_text().strip()
            if label in hparams and label not in differing:
                if box.get_attribute("aria-checked") == "true":
                    box.click()
        page.get_by_text("Scatter Plot Matrix View", exact=False).first.click()
        page.wait_for_timeout(4000)
        save("hparams_scatter")
        page.goto(f"{url}/#timeseries")
        page.wait_for_timeout(4000)
        page.get_by_role("button", name="Close side pane").click()
        page.locator("button", has_text=re.compile(r"^\s*Scalars\s*$")).first.click()
        tag_filter = page.get_by_role("combobox", name="Filter tags (regex)")
        for name, tags in (
            (
                "scalars",
                r"^(train/loss|val/rmse_over_d|val/rmse_ratio_(constant_velocity|linear_ar))$",
            ),
            ("scalars_horizon", r"^test_per_horizon_step/rmse_over_d/"),
        ):
            tag_filter.fill(tags)
            tag_filter.press("Escape")  # the suggestions list closed
            page.wait_for_timeout(4000)
            save(name)
        page.goto(f"{url}/#custom_scalars")
        page.wait_for_timeout(5000)
        save("custom_scalars")
        browser.close()
    return saved


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("logdir", type=Path, help="the folder above one or more sweeps")
    parser.add_argument("--out", type=Path, default=Path("experiments/figures"))
    args = parser.parse_args(argv)
    runs = read_runs(args.logdir)
    account = describe(runs)
    print(account)
    import datetime

    import tensorboard

    args.out.mkdir(parents=True, exist_ok=True)
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    (args.out / "tensorboard_runs.txt").write_text(
        f"{stamp}, TensorBoard {tensorboard.__version__}, log folder {args.logdir}\n{account}\n"
    )
    hparams = {key for run in runs.values() for key in run.hparams}
    differing = {
        key for key in hparams if len({repr(r.hparams.get(key)) for r in runs.values()}) > 1
    }
    port = free_port()
    server = start_tensorboard(args.logdir, port)
    try:
        for path in shoot(f"http://127.0.0.1:{port}", args.out, differing, hparams):
            print(f"saved {path}")
    finally:
        server.terminate()
        server.wait(10)


if __name__ == "__main__":
    main()
