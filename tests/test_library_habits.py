"""Habits of a maintained library, checked on the source text of plant/, observer/, controller/,
latency/ and experiments/ (parsed with ``ast``, nothing imported).

(a) **Every public name has a docstring**: module-level functions and classes whose names do
    not start with ``_``, and the methods and properties of those classes whose names do not
    start with ``_`` (dunder methods are skipped; so are property setters and deleters, which
    the property's docstring covers, and ``typing.overload`` stubs). There is no exception for
    a method that overrides a documented base or Protocol method (``nn.Module.forward``, a
    tracker's ``track``): the override still says in one line at least what it does with
    which units or shapes, since the base's docstring cannot know them.
(b) **No function or method longer than** ``MAX_FUNCTION_LINES`` lines, counted from its
    ``def`` line to its last line (decorators excluded, docstring and nested functions
    included), private ones too.
(c) **No file longer than** ``MAX_FILE_LINES`` lines unless its module docstring's first
    paragraph (the text before the first blank line) contains the words ``one file because``
    followed by the reason it is one concept that would read worse split.

The test prints the three counts (visible with ``pytest -s``) and fails listing every offender.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("plant", "observer", "controller", "latency", "experiments")
MAX_FUNCTION_LINES = 80
MAX_FILE_LINES = 600
#: The words the first paragraph of a long file's module docstring must contain.
LONG_FILE_MARKER = "one file because"


@dataclass(frozen=True)
class Offences:
    """The offenders of the three habits, each as ``path:line name (detail)`` strings."""

    undocumented: list[str]
    long_functions: list[str]
    long_files: list[str]


def _is_public(name: str) -> bool:
    return not name.startswith("_")


def _is_dunder(name: str) -> bool:
    return name.startswith("__") and name.endswith("__")


def _skipped_method(node: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    """Property setters and deleters (``@x.setter``) and ``@overload`` stubs."""
    for d in node.decorator_list:
        if isinstance(d, ast.Attribute) and d.attr in ("setter", "deleter"):
            return True
        if (isinstance(d, ast.Name) and d.id == "overload") or (
                isinstance(d, ast.Attribute) and d.attr == "overload"):
            return True
    return False


def _undocumented(tree: ast.Module, rel: str) -> list[str]:
    out = []
    defs = (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)
    for node in tree.body:
        if not isinstance(node, defs) or not _is_public(node.name):
            continue
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and _skipped_method(node):
            continue
        if ast.get_docstring(node) is None:
            out.append(f"{rel}:{node.lineno} {node.name}")
        if not isinstance(node, ast.ClassDef):
            continue
        for m in node.body:
            if (isinstance(m, ast.FunctionDef | ast.AsyncFunctionDef) and _is_public(m.name)
                    and not _is_dunder(m.name) and not _skipped_method(m)
                    and ast.get_docstring(m) is None):
                out.append(f"{rel}:{m.lineno} {node.name}.{m.name}")
    return out


def _long_functions(tree: ast.Module, rel: str) -> list[str]:
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            n = node.end_lineno - node.lineno + 1
            if n > MAX_FUNCTION_LINES:
                out.append(f"{rel}:{node.lineno} {node.name} ({n} lines)")
    return out


def _first_paragraph(tree: ast.Module) -> str:
    doc = ast.get_docstring(tree) or ""
    return " ".join(doc.split("\n\n", 1)[0].split())


def _long_file(tree: ast.Module, text: str, rel: str) -> list[str]:
    n = len(text.splitlines())
    if n > MAX_FILE_LINES and LONG_FILE_MARKER not in _first_paragraph(tree):
        return [f"{rel} ({n} lines)"]
    return []


def library_offences(root: Path = ROOT) -> Offences:
    """The offenders of the three habits in the packages under ``root``."""
    undocumented, long_functions, long_files = [], [], []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            text = path.read_text(encoding="utf-8")
            tree = ast.parse(text, filename=rel)
            undocumented += _undocumented(tree, rel)
            long_functions += _long_functions(tree, rel)
            long_files += _long_file(tree, text, rel)
    return Offences(undocumented, long_functions, long_files)


def test_public_names_documented_functions_short_files_short():
    """No offender of (a), (b) or (c) in the library's packages (module docstring)."""
    o = library_offences()
    counts = (f"{len(o.undocumented)} public names without a docstring, "
              f"{len(o.long_functions)} functions over {MAX_FUNCTION_LINES} lines, "
              f"{len(o.long_files)} files over {MAX_FILE_LINES} lines without a reason")
    print(counts)
    listing = "\n".join(
        [f"undocumented: {x}" for x in o.undocumented]
        + [f"long function: {x}" for x in o.long_functions]
        + [f"long file: {x}" for x in o.long_files])
    if o.undocumented or o.long_functions or o.long_files:
        pytest.fail(f"{counts}\n{listing}", pytrace=False)


def test_the_checks_see_each_kind_of_offence(tmp_path):
    """A made-up package with one offence of each kind (an undocumented public method, an
    81-line function, a 601-line file without the marker) and the same code kept within the
    habits: the checks report exactly the three offences and accept the clean copy."""
    body = "\n".join(f"    x{i} = {i}" for i in range(79))
    bad = ('"""A module."""\n\n\nclass Part:\n    """A part."""\n\n    def step(self):\n'
           '        return 1\n\n\n'
           f'def long():\n    """Long."""\n{body}\n')
    bad += "\n" * (MAX_FILE_LINES + 1 - len(bad.splitlines()))
    good = ('"""A module, one file because it is one made-up concept.\n\nMore."""\n\n\n'
            'class Part:\n    """A part."""\n\n    def step(self):\n        """One."""\n'
            '        return 1\n\n\n'
            'def short():\n    """Short."""\n    return 2\n')
    good += "\n" * (MAX_FILE_LINES + 5 - len(good.splitlines()))
    for package in PACKAGES:
        (tmp_path / package).mkdir()
    (tmp_path / "plant" / "bad.py").write_text(bad)
    (tmp_path / "latency" / "good.py").write_text(good)
    o = library_offences(tmp_path)
    assert o.undocumented == ["plant/bad.py:7 Part.step"]
    assert o.long_functions == ["plant/bad.py:11 long (81 lines)"]
    assert o.long_files == [f"plant/bad.py ({MAX_FILE_LINES + 1} lines)"]
