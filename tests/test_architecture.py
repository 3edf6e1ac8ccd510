"""The package's shape (docs/explanation/architecture.md): the top level holds only the entry
points and the ground module, every layer folder says what it holds, and every file keeps to the
400-line style. The import layers themselves are checked by ``lint-imports`` (pyproject.toml),
which the README's test command runs before the tests."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import gripdem

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = Path(gripdem.__file__).resolve().parent
ENTRY_POINTS = {
    "run",
    "simulate",
    "convert",
    "predict",
    "handback",
    "claims",
    "physics_report",
    "summary",
}
#: the package version, one place (imported by the layers that stamp files with it), and where
#: the configuration files are (read by the entry points and the API), and the result files'
#: header (``provenance``: standard library only, written by the CLIs and the benchmarks)
GROUND_MODULES = {"_version", "config_files", "errors", "provenance"}
LAYERS = {
    "api",  # the Python entry point: the stable names re-exported at ``gripdem``
    "boundary",
    "data",
    "dem",
    "formats",
    "evaluation",
    "nn",
    "models",
    "inference",
    "plots",
    "runner",
    "study",  # hyperparameter studies: the study sweeper and a trial's side of it
}
MAX_LINES = 400


def test_top_level_holds_entry_points_and_the_ground_module_only():
    modules = {p.stem for p in PACKAGE.glob("*.py")} - {"__init__"}
    assert modules == ENTRY_POINTS | GROUND_MODULES
    folders = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists()}
    assert folders == LAYERS


def test_every_entry_point_has_a_main_and_is_runnable():
    for name in ENTRY_POINTS:
        tree = ast.parse((PACKAGE / f"{name}.py").read_text())
        functions = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
        assert "main" in functions, name
        assert "__main__" in (PACKAGE / f"{name}.py").read_text(), name


def test_every_layer_says_what_it_holds():
    for name in LAYERS:
        doc = ast.get_docstring(ast.parse((PACKAGE / name / "__init__.py").read_text()))
        assert doc and len(doc.split()) >= 20, f"gripdem/{name}/__init__.py needs a docstring"


def test_every_file_keeps_to_400_lines():
    long = {}
    for folder in ("gripdem", "experiments", "tests"):
        for path in (ROOT / folder).rglob("*.py"):
            lines = len(path.read_text().splitlines())
            if lines > MAX_LINES:
                long[str(path.relative_to(ROOT))] = lines
    assert not long, f"files over {MAX_LINES} lines: {long}"


def test_the_clis_help_imports_neither_torch_nor_lightning():
    """``--help`` answers at once: the CLIs import torch and Lightning only for work."""
    code = (
        "import runpy, sys\n"
        "for module in ('gripdem.predict', 'gripdem.run'):\n"
        "    sys.argv = [module, '--help']\n"
        "    try:\n"
        "        runpy.run_module(module, run_name='__main__')\n"
        "    except SystemExit:\n"
        "        pass\n"
        "print(sorted(m for m in ('torch', 'lightning') if m in sys.modules))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout[-500:]


def test_the_modules_sent_whole_to_one_test_worker_exist():
    """tests/conftest.py's ONE_WORKER_MODULES name test files by path: a renamed file would
    silently be spread over the workers again (its fixture made once per worker)."""
    conftest = ast.parse((ROOT / "tests" / "conftest.py").read_text())
    (value,) = [
        node.value
        for node in conftest.body
        if isinstance(node, ast.Assign) and ast.unparse(node.targets[0]) == "ONE_WORKER_MODULES"
    ]
    modules = ast.literal_eval(value)
    assert modules and all((ROOT / path).is_file() for path in modules), modules
