"""Byte-compile, once per machine, the modules the project imports (``make setup`` calls :func:`compile_imports`).

``make setup`` installs with ``pip --no-compile``: compiling every module of every distribution costs about 50 s
on 2 cores, mostly for modules nothing here imports. Without ``.pyc`` files, though, every new process (each
pytest-xdist, pool or Dask worker) compiles what it imports from source, and on a machine that sets
``PYTHONDONTWRITEBYTECODE`` it does so in every process, forever (what that cost the test suite:
docs/experiments/ci-time.md). :func:`compile_imports` imports what the pipeline, the CLI and the
tests import, with writing turned on for this process only, so exactly those modules get their ``.pyc``.

The list is read from the sources (every ``import`` statement, at module level or inside a function), so a new
lazy import is covered without anyone keeping a list.
"""

from __future__ import annotations

import ast
import importlib
import pkgutil
import sys
from pathlib import Path

OWN_PACKAGES = ("pipeline", "stucco_cli")


def imported_modules(sources: list[Path]) -> list[str]:
    """Absolute module names named by the ``import`` statements of ``sources`` (Python files), sorted."""
    names: set[str] = set()
    for path in sources:
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                names.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module)
    return sorted(names)


def compile_imports(root: Path | None = None, packages: tuple[str, ...] = OWN_PACKAGES) -> int:
    """Import every module of ``packages`` (found under ``root``, the checkout) and every module their sources and
    ``tests/`` (where the checkout has it) import, writing ``.pyc`` files as Python does by default. A library
    module that is not installed or fails to import here is skipped (only a cache is at stake). Returns how many
    modules were newly imported."""
    root = root or Path(__file__).resolve().parents[1]
    sys.dont_write_bytecode = False  # this process only: the point is to write them
    before = len(sys.modules)
    for package in packages:
        for info in pkgutil.walk_packages(importlib.import_module(package).__path__, package + "."):
            importlib.import_module(info.name)
    sources = [path for folder in (*packages, "tests") for path in sorted((root / folder).rglob("*.py"))]
    for name in imported_modules(sources):
        if name.split(".")[0] in (*OWN_PACKAGES, "tests", "conftest"):
            continue
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001 - a library that cannot load here just gets no .pyc
            continue
    return len(sys.modules) - before
