"""The documentation: the mkdocs site (``mkdocs.yml``, ``docs/``) builds in strict mode (no broken
link, anchor or snippet, no page left out of the navigation), the README stays a short front
page whose links resolve, the command-line reference names every option of every entry point,
the configuration reference includes every config file, and the figures copied into
``docs/assets/`` are the current ones."""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"
README_MAX_LINES = 250
#: where the figures in docs/assets/ come from (the experiments write them there)
FIGURE_SOURCES = (ROOT / "experiments" / "figures", ROOT / "experiments" / "results")


class _MkdocsLoader(yaml.SafeLoader):
    """Reads mkdocs.yml without mkdocs (its ``!relative`` tag becomes a plain string)."""


_MkdocsLoader.add_constructor("!relative", lambda loader, node: loader.construct_scalar(node))


def _nav_pages(entries) -> list[str]:
    pages = []
    for entry in entries:
        value = next(iter(entry.values())) if isinstance(entry, dict) else entry
        pages += _nav_pages(value) if isinstance(value, list) else [value]
    return pages


def _nav() -> list[str]:
    config = yaml.load((ROOT / "mkdocs.yml").read_text(), Loader=_MkdocsLoader)
    return _nav_pages(config["nav"])


def test_docs_build_in_strict_mode(tmp_path):
    if importlib.util.find_spec("mkdocs") is None:
        pytest.skip('mkdocs is not installed (pip install -e ".[docs]")')
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}  # Material's banner about its successor
    site = tmp_path / "site"
    start = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    seconds = time.perf_counter() - start
    output = proc.stdout + proc.stderr
    problems = [line for line in output.splitlines() if re.search(r"WARNING|ERROR", line)]
    assert proc.returncode == 0, (
        f"mkdocs build --strict failed after {seconds:.1f} s:\n"
        + "\n".join(problems or output.splitlines()[-30:])
    )
    assert (site / "index.html").exists()
    print(f"mkdocs build --strict: {seconds:.1f} s")
    check_api_reference(site / "reference" / "python-api" / "index.html")


def check_api_reference(page: Path) -> None:
    """Every stable name of ``gripdem.api`` has its own entry on the reference page, showing
    its docstring's first sentence (a name that disappears, or loses its docstring, fails)."""
    import html

    import gripdem.api

    raw = page.read_text()
    text = " ".join(html.unescape(re.sub(r"<[^>]+>", "", raw)).split())
    for name in gripdem.api.__all__:
        obj = getattr(gripdem.api, name)
        if isinstance(obj, str):  # a constant (TRAINING): named in the page's table
            assert f"`{name}`" in text or name in text, f"{name}: not on the reference page"
            continue
        anchor = f'id="{obj.__module__}.{obj.__qualname__}"'
        assert anchor in raw, f"{name}: no entry {anchor} on the Python API reference page"
        first = " ".join(re.split(r"\.\s", obj.__doc__.strip())[0].split())
        first = re.sub(r"``?([^`]+)``?", r"\1", first)
        assert first in text, f"{name}: its docstring ({first!r}) is not on the reference page"


def test_every_docs_page_is_in_the_nav_and_every_nav_entry_exists():
    pages = {p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md")}
    nav = _nav()
    assert len(nav) == len(set(nav)), "a page is listed twice in mkdocs.yml's nav"
    assert pages - set(nav) == set(), "pages missing from mkdocs.yml's nav"
    assert set(nav) - pages == set(), "nav entries without a page under docs/"


def test_readme_is_a_short_front_page_with_the_ci_test_command():
    text = README.read_text()
    assert len(text.splitlines()) <= README_MAX_LINES
    ci_command = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert ci_command.startswith("python3 -m venv .venv")
    assert ci_command in text.splitlines(), "the README's test command differs from .ci/run's"
    assert "python -m gripdem.run" in text


def test_readme_links_resolve():
    text = README.read_text()
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    assert links
    for link in links:
        if re.match(r"[a-z]+://", link):
            continue
        path = link.split("#", 1)[0]
        assert (ROOT / path).exists(), f"README links to {link}, which does not exist"


def _cli_sections() -> dict[str, str]:
    text = (DOCS / "reference" / "cli.md").read_text()
    parts = re.split(r"^## (gripdem\.\w+)\s*$", text, flags=re.M)
    return dict(zip(parts[1::2], parts[2::2], strict=True))


class _Captured(Exception):
    pass


def _parser_of(module: str, monkeypatch) -> argparse.ArgumentParser:
    """The argparse parser an entry point's ``main`` builds (captured at parse time)."""
    mod = importlib.import_module(f"gripdem.{module}")
    if hasattr(mod, "build_parser"):
        return mod.build_parser()
    captured: list[argparse.ArgumentParser] = []

    def capture(self, *args, **kwargs):
        captured.append(self)
        raise _Captured

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", capture)
    with pytest.raises(_Captured):
        mod.main(["x"])
    monkeypatch.undo()
    return captured[0]


def _options(parser: argparse.ArgumentParser) -> list[str]:
    names = []
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        if action.option_strings:
            names.append(max(action.option_strings, key=len))
        elif not isinstance(action, argparse._SubParsersAction):
            names.append(action.metavar or action.dest)
    return names


@pytest.mark.parametrize(
    "module", ["convert", "predict", "handback", "claims", "physics_report", "summary"]
)
def test_cli_reference_names_every_option(module, monkeypatch):
    section = _cli_sections()[f"gripdem.{module}"]
    parser = _parser_of(module, monkeypatch)
    parsers = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            parsers += list(action.choices.values())
    missing = [name for p in parsers for name in _options(p) if f"`{name}" not in section]
    assert missing == [], f"docs/reference/cli.md, gripdem.{module}: options not documented"


def test_cli_reference_covers_every_command_and_simulate_option():
    sections = _cli_sections()
    commands = {p.stem for p in (ROOT / "gripdem").glob("*.py") if "__main__" in p.read_text()}
    assert "run" in commands
    assert {f"gripdem.{c}" for c in commands} <= set(sections)
    config = yaml.safe_load((ROOT / "conf" / "simulate.yaml").read_text())
    keys = {k for k in config if k != "defaults"} | {"scene", "preset"}
    missing = [k for k in sorted(keys) if f"| `{k}` |" not in sections["gripdem.simulate"]]
    assert missing == [], "docs/reference/cli.md: gripdem.simulate options not documented"


def test_configuration_reference_includes_every_config_file():
    text = (DOCS / "reference" / "configuration.md").read_text()
    included = set(re.findall(r'--8<-- "([^"]+)"', text))
    files = {p.relative_to(ROOT).as_posix() for p in (ROOT / "conf").rglob("*.yaml")}
    assert files - included == set(), "config files missing from docs/reference/configuration.md"


def test_doc_figures_are_the_current_ones():
    """docs/assets/ holds copies (the site cannot reach files outside docs/): each must equal
    the figure the experiments wrote; re-copy it when it was regenerated."""
    for asset in (DOCS / "assets").glob("*.png"):
        sources = [p for d in FIGURE_SOURCES for p in sorted(d.rglob(asset.name))]
        assert sources, f"{asset.name}: no figure of that name under experiments/"
        assert asset.read_bytes() == sources[0].read_bytes(), (
            f"docs/assets/{asset.name} is stale: cp {sources[0].relative_to(ROOT)} docs/assets/"
        )


def _readme_results():
    import importlib.util

    path = ROOT / "experiments" / "release" / "readme_results.py"
    spec = importlib.util.spec_from_file_location("readme_results", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_readme_results_table_is_its_source_file():
    """The README's results table is regenerated from
    experiments/results/decoder_modes/decoder_modes.md by
    experiments/release/readme_results.py; its --check fails, naming both, when they differ."""
    proc = subprocess.run(
        [sys.executable, "experiments/release/readme_results.py", "--check"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    script = _readme_results()
    readme = (ROOT / "README.md").read_text()
    table = script.readme_table(script.SOURCE.read_text())
    row = re.search(r"^\| pbc \| 190-10 \| grip \(contact\) \| ([0-9.e-]+)", readme, re.M)
    assert row, "README: no pbc 190-10 grip row in the results table"
    stale = readme.replace(row.group(0), row.group(0)[: row.start(1) - row.start(0)] + "0.999")
    assert stale != readme and script.replace_block(stale, table) == readme


def test_the_model_cards_are_what_the_shipped_files_say():
    """gripdem/inference/pretrained/NAME.md is regenerated from NAME.safetensors (its card and
    hyperparameters) by experiments/release/ship_pretrained.py --cards; --check fails, naming
    the file, when they disagree (e.g. an encoder described by hand)."""
    proc = subprocess.run(
        [sys.executable, "experiments/release/ship_pretrained.py", "--cards", "pbc", "lebc"]
        + ["pbc-ensemble", "lebc-ensemble", "--check"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    card = (ROOT / "gripdem" / "inference" / "pretrained" / "pbc.md").read_text()
    assert "64 node and 32 pair channels" in card  # from the file's hyperparameters
