"""The rule for measured figures in prose (``docs/how-to/develop.md#figures-in-the-docs``).

A *measured figure* is a number with a unit of time, a rate, a speed-up (``3.7x``), a
percentage, a memory size or a ratio to a baseline (``0.702 of CV``, ``0.72 ÷ CV``). On the
pages users read (``README.md``, ``docs/`` outside the specification, the comments of
``conf/``), such a figure may appear only

1. inside a file included from ``experiments/results/`` (``--8<--``: not in the page's source),
2. inside a block that a script generates and checks (between ``<!-- generated: SCRIPT -->``
   and ``<!-- /generated -->``), or
3. in a paragraph (or a table, with the paragraph before it) that cites a result file under
   ``experiments/results/`` in which the same figure is written: the same number, or one that
   rounds to it at the precision it is written with. A setting rather than a measurement (a
   tolerance, a timeout) is backed the same way by the config file (``conf/...yaml``) or the
   module (``gripdem/...py``) that defines it; a config file's comments are backed by the file
   itself.

Figures in code spans (``trainer.max_steps=3640``, a command's option) are options, not
measurements. The specification (``docs/spec/``) states definitions and the paper's own
figures and is not scanned; the model cards are generated from the model files and checked
by their own test. :func:`unbacked_figures` lists every figure that breaks the rule, with its
page and line.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "experiments" / "results"

#: a measured figure: the number (group ``n``) with its unit
FIGURE = re.compile(
    r"""(?x)
    (?<![\w.\-+/])(?P<n>\d+(?:\.\d+)?)(?:\s?(?:-|–|to)\s?\d+(?:\.\d+)?)?\s?
    (?: (?:ms|µs|us|s|sec|min|minutes|seconds|hours?|h)\b(?![-/]\w)
      | (?:x|×)(?![\w]|\s?\d)
      | %
      | (?:GB|GiB|MB|MiB)\b
      | (?:steps|frames|particle-steps|trials)/(?:s|h|hour)\b
      | (?:of\s+(?:CV|constant\s+velocity(?:'s)?|AR|the\s+AR\s+filter's))\b
      | ÷\s?(?:CV|AR)
    )"""
)
#: a cited file: a result file or a config file, by its path from the repository root or by a
#: result file's name alone (``split_sweep_before_100steps.md``)
CITATION = re.compile(
    r"(?:experiments/results/[\w./*-]+|conf/[\w./-]+\.yaml|gripdem/[\w/]+\.py"
    r"|\b[\w-]+\.(?:md|json))"
)
GENERATED_BEGIN = re.compile(r"<!-- (?:generated|results table): [^>]+ -->")
GENERATED_END = re.compile(r"<!-- /(?:generated|results table) -->")
NUMBER = re.compile(r"(?<![\w.])-?\d+(?:\.\d+)?(?:e[-+]?\d+)?")


@dataclass(frozen=True)
class Figure:
    path: str
    line: int
    text: str
    reason: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.text!r} {self.reason}"


def pages() -> list[Path]:
    """The files the rule applies to."""
    docs = [p for p in sorted((ROOT / "docs").rglob("*.md")) if "spec" not in p.parts]
    conf = sorted((ROOT / "conf").rglob("*.yaml"))
    return [ROOT / "README.md", *docs, *conf]


def _prose_lines(path: Path) -> list[tuple[int, str]]:
    """(line number, text) of the prose: code blocks, code spans, link targets, includes,
    HTML comments and generated blocks blanked; a YAML file's comments only."""
    out, fence, generated = [], False, False
    yaml = path.suffix == ".yaml"
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if yaml:
            line = line.split("#", 1)[1] if "#" in line else ""
        elif line.lstrip().startswith(("```", "~~~")):
            fence = not fence
            line = ""
        elif GENERATED_BEGIN.search(line):
            generated = True
        elif GENERATED_END.search(line):
            generated, line = False, ""
        if fence or generated or line.lstrip().startswith("--8<--"):
            line = ""
        line = re.sub(r"<!--.*?-->", "", line)
        line = re.sub(r"\]\(([^)]*)\)", r"] \1 ", line)  # keep a link's target as a citation
        out.append((number, line))
    return out


def _paragraphs(lines: list[tuple[int, str]]) -> list[list[tuple[int, str]]]:
    blocks, block = [], []
    for number, line in lines:
        if line.strip():
            block.append((number, line))
        elif block:
            blocks.append(block)
            block = []
    if block:
        blocks.append(block)
    return blocks


def _resolve(name: str) -> list[Path]:
    name = name.rstrip(".,;:)")
    if "*" in name:
        return sorted(ROOT.glob(name))
    path = ROOT / name
    if path.is_file():
        return [path]
    if path.is_dir():
        return sorted(p for p in path.rglob("*") if p.suffix in (".md", ".json"))
    if "/" not in name:  # a result file named alone
        return sorted(RESULTS.rglob(name))
    return []


def _numbers(paths: list[Path]) -> set[str]:
    found: set[str] = set()
    for path in paths:
        found |= set(NUMBER.findall(path.read_text(errors="replace")))
    return found


def _name(path: Path) -> str:
    return path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else str(path)


def _backed(value: str, numbers: set[str]) -> bool:
    if value in numbers:
        return True
    decimals = len(value.split(".")[1]) if "." in value else 0
    target = float(value)
    for n in numbers:
        try:
            x = float(n)
        except ValueError:
            continue
        if round(x, decimals) == target or round(100 * x, decimals) == target:
            return True
    return False


def unbacked_figures(paths: list[Path] | None = None) -> list[Figure]:
    """Every measured figure on ``paths`` (default :func:`pages`) that breaks the rule."""
    problems = []
    for path in paths or pages():
        blocks = _paragraphs(_prose_lines(path))
        for index, block in enumerate(blocks):
            scope = list(block)
            if block[0][1].lstrip().startswith("|") and index:
                scope = blocks[index - 1] + scope  # a table: the paragraph that introduces it
            text = " ".join(line for _, line in scope)
            cited = [p for name in CITATION.findall(text) for p in _resolve(name)]
            if path.suffix == ".yaml":  # a config file's comment describes its own values
                cited.append(path)
            numbers = _numbers(cited) if cited else set()
            for number, line in block:
                stripped = re.sub(r"`[^`]*`", "``", line)
                for match in FIGURE.finditer(stripped):
                    rel = _name(path)
                    if not cited:
                        reason = "cites no result file in its paragraph"
                    elif not _backed(match["n"], numbers):
                        names = ", ".join(_name(p) for p in cited[:3])
                        reason = f"is not in the file(s) its paragraph cites ({names})"
                    else:
                        continue
                    problems.append(Figure(rel, number, match.group(0), reason))
    return problems
