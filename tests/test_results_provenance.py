"""Figures that stay true by construction (docs/how-to/develop.md#figures-in-the-docs): every
result file starts with the header that one function writes (date, commit, CPU model, threads,
command), names no machine's folders, and is listed in the results index under its question;
every measured figure in the README, the docs and the config comments is included from a result
file, generated, or written in a paragraph that cites the result file holding it
(``tests/support/prose_figures.py`` states the rule)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from prose_figures import FIGURE, unbacked_figures

from gripdem.provenance import (
    HEADER_PATTERN,
    MACHINE_PATH,
    result_fields,
    result_header,
    write_report,
)

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "experiments" / "results"
INDEX = RESULTS / "README.md"


def result_files() -> list[Path]:
    return sorted(p for p in RESULTS.rglob("*") if p.suffix in (".md", ".json") and p != INDEX)


def test_every_result_file_starts_with_its_header():
    missing = []
    for path in result_files():
        rel = path.relative_to(ROOT)
        if path.suffix == ".md":
            first = path.read_text().splitlines()[0] if path.read_text() else ""
            if not HEADER_PATTERN.match(first):
                missing.append(f"{rel}:1: no header line (gripdem.provenance.write_result)")
        else:
            data = json.loads(path.read_text())
            header = data.get("header") if isinstance(data, dict) else None
            keys = {"date", "commit", "cpu", "cpus", "torch_threads", "command"}
            if not isinstance(header, dict) or not keys <= set(header):
                missing.append(f"{rel}:1: no 'header' with {sorted(keys)} (write_report)")
    assert len(result_files()) > 100
    assert missing == [], "\n".join(missing)


def test_no_result_file_names_a_folder_of_the_machine_that_wrote_it():
    found = [
        f"{path.relative_to(ROOT)}:{number}: {match.group(0)}"
        for path in result_files()
        for number, line in enumerate(path.read_text().splitlines(), 1)
        for match in MACHINE_PATH.finditer(line)
    ]
    assert found == [], "\n".join(found[:20])


def test_the_results_index_is_current():
    proc = subprocess.run(
        [sys.executable, "experiments/release/results_index.py", "--check"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr


def test_every_measured_figure_on_the_pages_is_backed_by_a_result_file():
    problems = unbacked_figures()
    assert problems == [], "measured figures not from a result file:\n" + "\n".join(
        map(str, problems)
    )


def test_the_header_writer_writes_a_relative_command_and_parses_back(tmp_path, monkeypatch):
    script = ROOT / "experiments" / "benchmarks" / "end_to_end" / "split_sweep.py"
    monkeypatch.setattr(sys, "argv", [str(script), "--out", str(ROOT / "experiments/results")])
    fields = result_fields()
    assert fields["command"] == (
        "python experiments/benchmarks/end_to_end/split_sweep.py --out experiments/results"
    )
    line = result_header(fields)
    parsed = HEADER_PATTERN.match(line)
    assert parsed and parsed["cpu"] == fields["cpu"] and int(parsed["cpus"]) == fields["cpus"]
    write_report(tmp_path / "r", "| a |\n|---|\n| 1 |", {"rows": [1]}, echo=False)
    text = (tmp_path / "r.md").read_text()
    assert HEADER_PATTERN.match(text.splitlines()[0]) and text.splitlines()[1] == ""
    data = json.loads((tmp_path / "r.json").read_text())
    assert data["header"] == fields | {"date": data["header"]["date"]} and data["rows"] == [1]
    assert not list(tmp_path.glob(".*.tmp"))  # written whole: no temporary left


def test_a_report_without_a_stem_is_printed_and_writes_nothing(tmp_path, monkeypatch, capsys):
    """A script run without ``--out`` hands ``write_report`` no stem: it prints, writes nothing."""
    monkeypatch.chdir(tmp_path)
    write_report(None, "| a |", {"rows": [1]})
    assert capsys.readouterr().out == "| a |\n" and not list(tmp_path.iterdir())


def _page(tmp_path: Path, text: str) -> list[str]:
    page = tmp_path / "page.md"
    page.write_text(text)
    return [p.text for p in unbacked_figures([page])]


@pytest.mark.parametrize(
    "text, flagged",
    [
        # a time copied by hand with no result file behind it (a config comment's "6 min 13 s")
        ("The job took 6 min 13 s on the 2-core machine.", ["6 min", "13 s"]),
        # a figure that its cited file does not say (the sweep's "3.9 min" where the file says 3.72)
        (
            "The sweep takes 3.9 min (experiments/results/split_sweep/split_sweep.md).",
            ["3.9 min"],
        ),
        # a claim without a result ("CV within about 2 % of every paper model")
        ("CV is within about 2 % of every paper model.", ["2 %"]),
        ("A step takes 0.2 s per step ([resume](../x.md)).", ["0.2 s"]),
        ("Side by side it runs at 17.5 steps/s.", ["17.5 steps/s"]),
        ("The model reaches 0.702 of CV.", ["0.702 of CV"]),
        # options and commands are not measurements
        ("Run `trainer.max_steps=3640` or `--timeout 600 s`.", []),
        # a figure its cited result file holds, at the precision it is written with
        (
            "The sweep took 5.5 min "
            "(`experiments/results/split_sweep/history/split_sweep_0.2.0.md`).",
            [],
        ),
        # included and generated blocks are not the page's prose
        ('--8<-- "experiments/results/split_sweep/split_sweep.md"', []),
        ("<!-- generated: x.py -->\n| a | 9.9 s |\n<!-- /generated -->", []),
    ],
)
def test_the_figure_rule_catches_the_cases_it_was_written_for(tmp_path, text, flagged):
    assert _page(tmp_path, text) == flagged


def test_the_figure_pattern_reads_the_units_users_write():
    for text in (
        "5 min",
        "34 s",
        "3.7x",
        "12 %",
        "1.3 GB",
        "23.0 steps/s",
        "0.45 of CV",
        "0.4 ÷ CV",
    ):
        assert FIGURE.search(text), text
    for text in ("5e-6 s", "190-10", "2000 particles", "1e-3 d", "v0.2.0"):
        assert not FIGURE.search(text), text


def test_a_report_names_no_folder_of_the_machine_in_its_data(tmp_path):
    """``write_report``'s JSON writes the paths in its data as its header does: the repository
    relative, the home folder ``~`` and the temporary folder ``$TMPDIR``."""
    import tempfile

    from gripdem.provenance import write_report

    data = {
        "args": {
            "checkpoint": str(Path.home() / "runs" / "best.ckpt"),
            "out": str(Path(tempfile.gettempdir()) / "work" / "sr"),
            "data": str(ROOT / "experiments" / "results" / "x.h5"),
        }
    }
    write_report(tmp_path / "report", "# report\n", data, echo=False)
    written = json.loads((tmp_path / "report.json").read_text())["args"]
    assert written == {
        "checkpoint": "~/runs/best.ckpt",
        "out": "$TMPDIR/work/sr",
        "data": "experiments/results/x.h5",
    }
