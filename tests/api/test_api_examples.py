"""The examples of the Python API reference (docs/reference/python-api.md) run.

Every name of ``gripdem.api.__all__`` has at least one example (``>>>``) in its docstring, and
its examples, with those of the members the page lists for it under ``members:``, run under
:mod:`doctest` with ``ELLIPSIS`` and ``NORMALIZE_WHITESPACE``. One test per name; a failure
names the object and shows the failing example, what it expected and what it got.

Each name's examples run in a fresh temporary working folder, so an example writes its files
(``"mine.h5"``) where a user would. The examples of a class's members use ``model`` and
``data`` as the class's own example makes them, and their docstrings say so;
:func:`example_namespace` makes them once per test process, the same way. The listed methods
and properties also say what they take, return and raise (google sections, as the page
renders them).

Run them alone: ``python -m pytest tests/api/test_api_examples.py -n 0``.
"""

from __future__ import annotations

import ast
import doctest
import inspect
import re
from pathlib import Path

import pytest

import gripdem
import gripdem.api

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "reference" / "python-api.md"
#: as the examples are written: ``...`` elides part of an output, line breaks are spaces
FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE
#: the names the members' examples use, made as their class's example makes them
SHARED = {
    "model": 'gripdem.load_model("pretrained:lebc")',
    "data": 'gripdem.generate("lebc", "tiny", sims=1, particles=300, frames=21)',
}


def listed_members() -> dict[str, list[str]]:
    """``{dotted path: members}`` of each ``::: path`` entry of the reference page."""
    members: dict[str, list[str]] = {}
    path = None
    for line in PAGE.read_text().splitlines():
        if line.startswith(":::"):
            path = line[3:].strip()
            members[path] = []
        elif path and (found := re.match(r"\s+members:\s*\[(.*)\]\s*$", line)):
            members[path] = [m.strip() for m in found.group(1).split(",") if m.strip()]
        elif line.strip() and not line.startswith(" "):
            path = None
    return members


def page_path(name: str) -> str:
    """The dotted path of ``gripdem.api.<name>`` as the page names it."""
    obj = getattr(gripdem.api, name)
    if isinstance(obj, str):  # a constant: the module that defines it
        for module in ("gripdem.api.model", "gripdem.api.scene", "gripdem.api.dem_physics"):
            if getattr(__import__(module, fromlist=["_"]), name, None) is obj:
                return f"{module}.{name}"
        raise AssertionError(f"{name}: no module of gripdem.api defines it")
    return f"{obj.__module__}.{obj.__qualname__}"


def constant_docstring(path: str) -> tuple[str, str, int]:
    """``(docstring, file, line)`` of a module constant: the string literal that follows its
    assignment (an attribute docstring, as mkdocstrings reads it)."""
    module_name, name = path.rsplit(".", 1)
    file = inspect.getsourcefile(__import__(module_name, fromlist=["_"]))
    body = ast.parse(Path(file).read_text()).body
    for node, after in zip(body, body[1:], strict=False):
        targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", 0)]
        if any(isinstance(t, ast.Name) and t.id == name for t in targets):
            is_doc = isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
            if is_doc and isinstance(after.value.value, str):
                return inspect.cleandoc(after.value.value), file, after.lineno - 1
    return "", file, 0


def documented(name: str) -> list[tuple[str, object, str, str, int]]:
    """``(qualified name, object, docstring, file, line)``: the name, then its listed members
    (``line``: 0-based, of the docstring's first line, for doctest's reports)."""
    path = page_path(name)
    obj = getattr(gripdem.api, name)
    if isinstance(obj, str):
        return [(path, obj, *constant_docstring(path))]
    entries = [(path, obj)]
    for member in listed_members().get(path, []):
        entries.append((f"{path}.{member}", inspect.getattr_static(obj, member)))
    out = []
    for qualname, target in entries:
        function = target.fget if isinstance(target, property) else target
        function = getattr(function, "__func__", function)  # classmethod, staticmethod
        doc = inspect.getdoc(function) or ""
        file = inspect.getsourcefile(function)
        lines, start = inspect.getsourcelines(function)
        first = next((i for i, text in enumerate(lines) if '"""' in text), 0)
        out.append((qualname, target, doc, file, start + first - 1))
    return out


@pytest.fixture(scope="session")
def example_namespace() -> dict[str, object]:
    """``gripdem``, ``model`` and ``data`` as the class examples make them (once a process)."""
    names: dict[str, object] = {"gripdem": gripdem}
    for name, code in SHARED.items():
        names[name] = eval(code, {"gripdem": gripdem})
    return names


def examples(docstring: str, qualname: str) -> list[doctest.Example]:
    return doctest.DocTestParser().get_examples(docstring, qualname)


@pytest.mark.parametrize("name", gripdem.api.__all__)
def test_every_name_has_an_example_that_runs(name, example_namespace, tmp_path, monkeypatch):
    entries = documented(name)
    own = entries[0]
    assert examples(own[2], own[0]), (
        f"gripdem.{name} ({own[0]}): its docstring has no example; add an Examples: section "
        "with >>> lines"
    )
    monkeypatch.chdir(tmp_path)
    parser = doctest.DocTestParser()
    runner = doctest.DocTestRunner(optionflags=FLAGS)
    report: list[str] = []
    for qualname, _, doc, file, line in entries:
        if not examples(doc, qualname):
            continue
        test = parser.get_doctest(doc, dict(example_namespace), qualname, file, line)
        runner.run(test, out=report.append, clear_globs=True)
    assert runner.failures == 0, (
        f"gripdem.{name}: {runner.failures} of {runner.tries} examples failed\n" + "".join(report)
    )


def _parameters(function) -> list[str]:
    signature = inspect.signature(function)
    return [p for p in signature.parameters if p not in ("self", "cls")]


def _returns_something(function) -> bool:
    annotation = inspect.signature(function).return_annotation
    return annotation not in (None, "None", inspect.Signature.empty)


def _sections(doc: str) -> set[str]:
    return set(re.findall(r"^\s*(Args|Returns|Raises|Examples?|Attributes):\s*$", doc, re.M))


def test_the_listed_members_say_what_they_take_return_and_raise():
    """Functions and the listed methods: ``Args:`` when they take arguments, ``Returns:`` when
    they return something, ``Raises:`` (their own errors, or a word that they raise none);
    listed properties: ``Returns:``."""
    missing = []
    for name in gripdem.api.__all__:
        for qualname, target, doc, _, _ in documented(name):
            if isinstance(target, str) or inspect.isclass(target):
                continue
            sections = _sections(doc)
            if isinstance(target, property):
                wanted = {"Returns"}
            else:
                function = getattr(target, "__func__", target)
                wanted = {"Args"} if _parameters(function) else set()
                wanted |= {"Returns"} if _returns_something(function) else set()
                if "Raises" not in doc:  # "Raises nothing of its own" counts
                    wanted.add("Raises")
            missing += [f"{qualname}: no {section}:" for section in sorted(wanted - sections)]
    assert missing == [], "\n".join(missing)


def test_the_shared_names_are_said_where_they_come_from():
    """A docstring whose examples use ``model`` or ``data`` without making them says what they
    are, in the words of :data:`SHARED` (what :func:`example_namespace` makes)."""
    unsaid = []
    for name in gripdem.api.__all__:
        for qualname, _, doc, _, _ in documented(name):
            sources = [  # the code without its string literals
                re.sub(r"\"[^\"]*\"|'[^']*'", "", example.source)
                for example in examples(doc, qualname)
            ]
            prose = " ".join(doc.split())
            for shared, code in SHARED.items():
                used = any(re.search(rf"(?<![.\w]){shared}\b", s) for s in sources)
                made = any(re.match(rf"{shared}\s*=", s) for s in sources)
                if used and not made and not (f"``{shared}``" in doc and code in prose):
                    unsaid.append(f"{qualname}: uses {shared} without saying it is {code}")
    assert unsaid == [], "\n".join(unsaid)
