"""Every citation of the specification points at a page and an anchor that exist.

Code, configs, tests and experiments cite the specification as ``docs/spec/<page>.md#<anchor>``;
docs pages link to it (``../spec/<page>.md#<anchor>``), which ``mkdocs build --strict`` checks
too. The anchors are the explicit ``{#id}`` of the specification's headings. No file may cite the
former external specification ("SPEC §n"), which the repository does not contain.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SPEC = ROOT / "docs" / "spec"
#: where citations may appear
CITING = ("gripdem", "conf", "tests", "experiments", "docs", "examples", "hydra_plugins")
SUFFIXES = {".py", ".yaml", ".yml", ".md", ".toml"}
CITATION = re.compile(r"(?:docs/)?spec/([a-z0-9-]+)\.md(?:#([A-Za-z0-9_-]+))?")
HEADING_ID = re.compile(r"^#+ .*\{#([A-Za-z0-9_-]+)\}\s*$", re.MULTILINE)
FORMER = re.compile(r"SPEC(?: ?§|'s)")


def _citing_files():
    for top in CITING:
        for path in (ROOT / top).rglob("*"):
            if path.suffix in SUFFIXES and path.is_file() and "__pycache__" not in path.parts:
                yield path
    yield ROOT / "README.md"


def anchors_of(page: Path) -> set[str]:
    """The explicit heading ids of one specification page."""
    return set(HEADING_ID.findall(page.read_text()))


def broken_citations(text: str, where: str) -> list[str]:
    """``where: citation (why)`` for each citation in ``text`` whose page or anchor is missing."""
    broken = []
    for match in CITATION.finditer(text):
        page, anchor = SPEC / f"{match.group(1)}.md", match.group(2)
        if not page.exists():
            broken.append(f"{where}: {match.group(0)} (no page docs/spec/{page.name})")
        elif anchor and anchor not in anchors_of(page):
            broken.append(
                f"{where}: {match.group(0)} (docs/spec/{page.name} has no heading "
                f"{{#{anchor}}}; it has {sorted(anchors_of(page))})"
            )
    return broken


def test_every_spec_citation_resolves():
    broken, count = [], 0
    for path in _citing_files():
        if path == Path(__file__):
            continue
        text = path.read_text()
        count += len(CITATION.findall(text))
        broken += broken_citations(text, path.relative_to(ROOT).as_posix())
    assert count >= 50, f"only {count} citations of docs/spec/ found: is the pattern right?"
    assert broken == [], "citations of missing specification pages or anchors:\n" + "\n".join(
        broken
    )


def test_nothing_cites_the_former_external_specification():
    former = [
        f"{path.relative_to(ROOT).as_posix()}:{n}"
        for path in _citing_files()
        if path != Path(__file__)
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if FORMER.search(line)
    ]
    assert former == [], "cite docs/spec/<page>.md#<anchor> instead of SPEC §n:\n" + "\n".join(
        former
    )


def test_a_missing_anchor_is_named_with_the_file():
    text = "see docs/spec/conventions.md#no-such-heading and docs/spec/nowhere.md#x"
    broken = broken_citations(text, "conf/example.yaml")
    assert len(broken) == 2
    assert broken[0].startswith("conf/example.yaml: docs/spec/conventions.md#no-such-heading")
    assert "has no heading {#no-such-heading}" in broken[0]
    assert "no page docs/spec/nowhere.md" in broken[1]


def test_every_specification_page_has_anchored_sections():
    for page in SPEC.glob("*.md"):
        assert anchors_of(page), f"docs/spec/{page.name}: no heading with an explicit {{#id}}"
