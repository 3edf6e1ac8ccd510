"""A study as optuna-dashboard shows it, checked and photographed in a real browser.

    python experiments/release/dashboard_screenshot.py multirun/studies/gripdem/study.journal \\
        [--study gripdem] [--out experiments/figures/optuna_dashboard.png]
    cp experiments/figures/optuna_dashboard.png docs/assets/

Starts ``optuna-dashboard STORAGE`` (the command the how-to gives), opens the study's page in
headless Chromium (Debian's ``chromium``, driven by ``pip install playwright``), checks that the
page names the study and shows its trials' states (complete and pruned), and saves a PNG.
"""

from __future__ import annotations

import argparse
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(url: str, seconds: float = 60) -> None:
    deadline = time.time() + seconds
    while time.time() < deadline:
        try:
            urllib.request.urlopen(url, timeout=2)  # noqa: S310 - the local dashboard
            return
        except OSError:
            time.sleep(0.5)
    raise SystemExit(f"optuna-dashboard did not answer at {url} within {seconds:.0f} s")


def study_id(storage: str, name: str) -> int:
    """The dashboard's number for the study ``name`` (its id in the storage)."""
    from gripdem.study.storage import open_storage

    return open_storage(storage).get_study_id_from_name(name)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("storage", help="the study's storage (journal file or URL)")
    parser.add_argument("--study", default="gripdem", help="the study's name")
    parser.add_argument(
        "--out", type=Path, default=ROOT / "experiments" / "figures" / "optuna_dashboard.png"
    )
    args = parser.parse_args(argv)
    from playwright.sync_api import sync_playwright

    browser_path = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser_path is None:
        raise SystemExit("chromium not found: apt-get install chromium")
    dashboard = shutil.which("optuna-dashboard") or str(
        Path(sys.executable).parent / "optuna-dashboard"
    )
    port = free_port()
    server = subprocess.Popen(
        [dashboard, args.storage, "--port", str(port), "--host", "127.0.0.1"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        base = f"http://127.0.0.1:{port}"
        wait_for(f"{base}/api/meta")
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=browser_path, headless=True)
            tab = browser.new_page(viewport={"width": 1400, "height": 1000})
            tab.goto(f"{base}/dashboard/studies/{study_id(args.storage, args.study)}")
            tab.wait_for_selector("text=Best Trial", timeout=60_000)
            tab.wait_for_timeout(3000)  # the plots draw
            body = tab.inner_text("body")
            for expected in ("Complete", "Pruned"):
                if expected not in body:
                    raise SystemExit(f"the dashboard page does not show {expected!r} trials")
            args.out.parent.mkdir(parents=True, exist_ok=True)
            tab.screenshot(path=str(args.out), full_page=False)
            browser.close()
        print(f"{args.out}: the dashboard's page of study {args.study!r}")
    finally:
        server.terminate()
        server.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())
