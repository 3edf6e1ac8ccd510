"""The README's results table, regenerated from the file it comes from.

The README shows the decoder modes' table (RMSE / d, ÷ CV, ÷ AR, overlap; mean ± std over
seeds) for both scenes; ``experiments/results/decoder_modes/decoder_modes.md`` is its source
(written by
``bash experiments/analyses/decoder_modes_sweep.sh``). The table sits between the markers
``<!-- results table: ... -->`` and ``<!-- /results table -->``. This script rewrites it
from the source; ``--check`` exits with status 1, naming both files, when the README
disagrees with the source (a default-tier test runs it). The results page includes its tables
from ``experiments/results/`` directly (``--8<--``), so it cannot disagree.

    python experiments/release/readme_results.py            # rewrite the README's table
    python experiments/release/readme_results.py --check    # status 1 if it is stale
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
SOURCE = ROOT / "experiments" / "results" / "decoder_modes" / "decoder_modes.md"
BEGIN = "<!-- results table: experiments/release/readme_results.py -->"
END = "<!-- /results table -->"
#: the source's columns shown in the README, and the scenes in the README's order
COLUMNS = ("RMSE / d", "÷ CV", "÷ AR", "overlap %")
SCENES = ("pbc", "lebc")
#: the default model (model=contact) is the grip mode
DEFAULT_MODE = "grip"


def source_rows(text: str) -> dict[str, list[dict[str, str]]]:
    """``{scene: [row as {column: cell}]}`` of the source's per-scene tables."""
    tables: dict[str, list[dict[str, str]]] = {}
    scene, header = None, None
    for line in text.splitlines():
        if line.startswith("### "):
            scene, header = line[4:].strip(), None
            continue
        if scene is None or not line.startswith("|"):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if header is None:
            header = cells
        elif not set(line) <= set("|- "):
            tables.setdefault(scene, []).append(dict(zip(header, cells, strict=True)))
    return tables


def readme_table(text: str) -> str:
    """The README's table from the source's text."""
    tables = source_rows(text)
    lines = [
        "| scene | split | model | " + " | ".join(COLUMNS) + " |",
        "|---|---|---|" + "---|" * len(COLUMNS),
    ]
    for scene in SCENES:
        if scene not in tables:
            raise ValueError(f"{SOURCE}: no table for scene {scene!r}")
        for row in tables[scene]:
            model = row["model"]
            shown = f"{model} (contact)" if model == DEFAULT_MODE else model
            cells = [scene, row["split"], shown, *(row[c] for c in COLUMNS)]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def replace_block(readme: str, table: str) -> str:
    """The README's text with the table between the markers replaced."""
    pattern = re.compile(re.escape(BEGIN) + r"\n.*?\n" + re.escape(END), re.DOTALL)
    if not pattern.search(readme):
        raise ValueError(f"{README}: the markers {BEGIN!r} ... {END!r} are missing")
    return pattern.sub(lambda _: f"{BEGIN}\n{table}\n{END}", readme)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only compare; status 1 if stale")
    args = parser.parse_args(argv)
    readme = README.read_text()
    updated = replace_block(readme, readme_table(SOURCE.read_text()))
    if args.check:
        if updated != readme:
            print(
                f"{README.name}: its results table disagrees with {SOURCE.relative_to(ROOT)}; "
                "run python experiments/release/readme_results.py",
                file=sys.stderr,
            )
            return 1
        print(f"{README.name}: results table matches {SOURCE.relative_to(ROOT)}")
        return 0
    if updated != readme:
        tmp = README.with_suffix(".md.tmp")
        tmp.write_text(updated)
        tmp.replace(README)  # atomically
        print(f"rewrote the results table of {README.name} from {SOURCE.relative_to(ROOT)}")
    else:
        print(f"{README.name}: results table already matches")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
