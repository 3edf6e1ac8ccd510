"""The index of ``experiments/results/``: one folder per question, each file with its title and
its header (date, commit, CPU, threads), superseded files under each folder's ``history/``.

The questions are listed here (``QUESTIONS``); every file's line comes from the file itself, so
the index cannot disagree with what it lists. ``--check`` exits with status 1, naming the
difference, when ``experiments/results/README.md`` is stale or a folder is not a listed
question (a default-tier test runs it).

    python experiments/release/results_index.py            # rewrite the index
    python experiments/release/results_index.py --check    # status 1 if it is stale
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
from gripdem.provenance import HEADER_PATTERN, atomic_write  # noqa: E402

RESULTS = ROOT / "experiments" / "results"
INDEX = RESULTS / "README.md"
#: folder -> the question its files answer (the index's order)
QUESTIONS = {
    "first_run": "How long does the README's main command, `python -m gripdem.run`, take on a "
    "fresh clone (the built-in DEM included), and at what error?",
    "split_sweep": "How long does `python -m gripdem.run -m split=190-10,100-100 model=vct` take, "
    "job by job, and at what error?",
    "rollout_training": "Does training on the model's own chained, corrected rollouts "
    "(`model.rollout`) pay, at 100-100 and over 2000-frame surrogate runs?",
    "decoder_modes": "How do grip, pct and vct compare on the default encoder, both scenes, "
    "190-10 and 100-100, against the baselines and the paper's claims?",
    "time_vs_error": "Is a trained model worth its time: wall time against error, and what each "
    "speed lever of training costs in accuracy?",
    "model_cost": "Where do a forward pass and a training step spend their time, and how do they "
    "scale with particles, history, threads and precision?",
    "surrogate_speed": "How much faster than the built-in DEM and LAMMPS is the model per "
    "predicted frame?",
    "long_rollouts": "Can the model replace the DEM over 2000 frames: contacts, g(r), MSD, "
    "diffusion, and the contact correction's part?",
    "ensembles": "Which ensemble levers bring the DEM's microstructure back (the shipped "
    "ensembles' ablation and its runs)?",
    "paper_models": "How do the paper's own models (graph-conv encoder, GRU decoders) compare with "
    "the contact model and the baselines at every split, and do the paper's claims hold (0.1.0)?",
    "dem_data": "Do the built-in scenes' datasets look like the physics they claim (the "
    "generator's validation: overlaps, flow profile, crossings, non-affine motion)?",
    "fine_tuning": "Which optimiser settings should fine-tuning use?",
    "studies": "Do gripdem's hyperparameter studies (stored, pruned, asynchronous) find as good a "
    "setting in less time than the sweeper they replaced, which pruner, and which storage "
    "survives a kill?",
    "test_suite": "Do the tests' thresholds hold on every CPU path and thread count, and does a "
    "killed command leave anything behind?",
}
SUFFIXES = (".md", ".json")


def header_of(path: Path) -> dict | None:
    """The header's fields of a result file (``None`` without one)."""
    text = path.read_text(errors="replace")
    if path.suffix == ".md":
        match = HEADER_PATTERN.match(text.splitlines()[0] if text else "")
        return match.groupdict() if match else None
    try:
        data = json.loads(text)
    except json.JSONDecodeError:
        return None
    header = data.get("header") if isinstance(data, dict) else None
    return header if isinstance(header, dict) else None


def title_of(path: Path) -> str:
    """A Markdown file's first heading, else its first prose line (cut to 100 characters)."""
    if path.suffix != ".md":
        return ""
    for line in path.read_text(errors="replace").splitlines()[1:]:
        line = line.strip()
        if not line or line.startswith((">", "machine:")):
            continue
        line = line.lstrip("#").strip().replace("|", "\\|")
        return line if len(line) <= 100 else line[:99] + "…"
    return ""


def _rows(folder: Path) -> list[str]:
    """One row per result (a Markdown file and its JSON twin share a row)."""
    rows = ["| result | what | measured | CPU (CPUs, torch threads) |", "|---|---|---|---|"]
    stems: dict[Path, list[Path]] = {}
    for path in sorted(p for p in folder.rglob("*") if p.suffix in SUFFIXES):
        rel = path.relative_to(folder)
        if rel.parts[0] != "history" and path.name != "README.md":
            stems.setdefault(rel.with_suffix(""), []).append(path)
    for paths in stems.values():
        links = " · ".join(
            f"[{p.relative_to(folder).as_posix()}]({folder.name}/{p.relative_to(folder).as_posix()})"
            for p in sorted(paths, key=lambda p: p.suffix != ".md")
        )
        first = sorted(paths, key=lambda p: p.suffix != ".md")[0]
        h = header_of(first) or {}
        machine = f"{h.get('cpu', '?')} ({h.get('cpus', '?')}, {h.get('torch_threads', '?')})"
        when = f"{h.get('date', '?')}, {h.get('commit', '?')}"
        rows.append(f"| {links} | {title_of(first)} | {when} | {machine} |")
    return rows


def index_text() -> str:
    lines = [
        "# Results, one folder per question",
        "",
        "Generated by `python experiments/release/results_index.py` from the files themselves: "
        "each file starts with the header that `gripdem.provenance.result_header` writes (date, "
        "commit, CPU model and thread count, command; a JSON file carries it under `header`). "
        "Files of earlier versions, superseded by a newer measurement of the same question, "
        "are under the folder's `history/`.",
        "",
    ]
    for name, question in QUESTIONS.items():
        folder = RESULTS / name
        lines += [f"## [{name}/]({name}/)", "", question, "", *_rows(folder), ""]
        history = sorted(p for p in folder.glob("history/*") if p.suffix in SUFFIXES)
        if history:
            listed = ", ".join(f"[{p.name}]({name}/history/{p.name})" for p in history)
            lines += [f"History: {listed}.", ""]
    return "\n".join(lines).rstrip() + "\n"


def problems() -> list[str]:
    found = []
    folders = {p.name for p in RESULTS.iterdir() if p.is_dir()}
    for name in sorted(folders - set(QUESTIONS)):
        found.append(f"experiments/results/{name}/: not a question of QUESTIONS in {__file__}")
    for name in sorted(set(QUESTIONS) - folders):
        found.append(f"experiments/results/{name}/: listed in QUESTIONS, but no such folder")
    loose = sorted(p.name for p in RESULTS.glob("*") if p.is_file() and p.name != "README.md")
    found += [f"experiments/results/{n}: outside a question's folder" for n in loose]
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="status 1 if the index is stale")
    args = parser.parse_args(argv)
    found = problems()
    if found:
        print("\n".join(found), file=sys.stderr)
        return 1
    text = index_text()
    if args.check:
        if not INDEX.is_file() or INDEX.read_text() != text:
            print(
                f"{INDEX.relative_to(ROOT)} is stale: "
                "run python experiments/release/results_index.py",
                file=sys.stderr,
            )
            return 1
        return 0
    atomic_write(INDEX, text)
    print(f"wrote {INDEX.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
