"""Screenshots of entries of the Python API reference as a user sees them in the built site.

    mkdocs build --strict --site-dir /tmp/site
    python experiments/release/api_screenshots.py /tmp/site [--names NAME ...]

Opens ``reference/python-api/index.html`` of the built site in headless Chromium (Debian's
``chromium``, driven by ``pip install playwright``; no browser download) and saves one PNG per
entry (its heading, signature and docstring) into ``experiments/figures/api_reference_<name>.png``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_NAMES = ("gripdem.api.loading.load_model", "gripdem.api.scene.Scene")
#: pixels of an entry kept (a class with its members is many screens long)
MAX_HEIGHT = 1800


def screenshot(page: Path, name: str, out: Path) -> None:
    """One PNG of the entry ``name`` of ``page`` (its heading, signature and docstring), as the
    browser renders it with the site's theme."""
    from playwright.sync_api import sync_playwright

    browser_path = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser_path is None:
        raise SystemExit("chromium not found: apt-get install chromium")
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=browser_path, headless=True)
        tab = browser.new_page(viewport={"width": 1100, "height": 1400})
        tab.goto(page.as_uri())
        tab.add_style_tag(content=".md-header { display: none; }")  # it would cover the heading
        entry = tab.locator(f'[id="{name}"]').locator("xpath=..")  # the entry's doc block
        box = entry.bounding_box()  # a class's entry runs on through its members: its top part
        clip = {**box, "height": min(box["height"], MAX_HEIGHT)}
        tab.screenshot(path=str(out), full_page=True, clip=clip)
        browser.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("site", type=Path, help="the built site (mkdocs build --site-dir)")
    parser.add_argument("--names", nargs="+", default=list(DEFAULT_NAMES))
    parser.add_argument("--out", type=Path, default=ROOT / "experiments" / "figures")
    args = parser.parse_args(argv)
    page = (args.site / "reference" / "python-api" / "index.html").resolve()
    if not page.is_file():
        raise SystemExit(f"{page}: no such page; build the site first (mkdocs build)")
    for name in args.names:
        if f'id="{name}"' not in page.read_text():
            raise SystemExit(f"{name}: no entry of that id on {page}")
        out = args.out / f"api_reference_{name.rsplit('.', 1)[-1]}.png"
        screenshot(page, name, out)
        print(f"wrote {out.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
