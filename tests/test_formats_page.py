"""Issue 26.3: ``docs/formats.md`` is ``tests/conformance.py``'s table rendered, names every
format imucal reads and writes, and names only tests that exist; the libraries installed are
at least the versions it names (``python -m tests.conformance`` regenerates it)."""

from __future__ import annotations

import ast
import importlib.metadata
from pathlib import Path

from imucal_cli.formats.importers import FORMATS as IMPORT_FORMATS
from imucal_cli.use.export import FORMATS as EXPORT_FORMATS

from .conformance import EXPORTS, IMPORTS, PAGE, ROWS, render

TESTS = Path(__file__).resolve().parent


def test_the_page_is_the_table():
    assert PAGE.is_file(), "run python -m tests.conformance"
    assert PAGE.read_text() == render(), "docs/formats.md differs: python -m tests.conformance"


def test_every_format_has_a_row():
    modules = {IMPORT_FORMATS[r.fmt] for r in IMPORTS}
    assert modules == set(IMPORT_FORMATS.values())  # every reader module
    assert {r.fmt for r in EXPORTS} == set(EXPORT_FORMATS)


def test_every_test_named_exists():
    defined: dict[str, set[str]] = {}
    for row in ROWS:
        for name in row.tests:
            file, _, function = name.partition("::")
            if file not in defined:
                tree = ast.parse((TESTS / file).read_text())
                defined[file] = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
            assert function in defined[file], name


def _version(text: str) -> tuple[int, ...]:
    return tuple(int(p) for p in text.split(".")[:2] if p.isdigit())


def test_installed_libraries_are_at_least_the_versions_named():
    for row in ROWS:
        for package, version in row.checked:
            try:
                installed = importlib.metadata.version(package)
            except importlib.metadata.PackageNotFoundError:
                continue  # not a PyPI package (gcc, a consumer's sources or schema)
            assert _version(installed) >= _version(version), (package, installed, version)
