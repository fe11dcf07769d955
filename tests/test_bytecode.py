"""pipeline.bytecode: the .pyc files of what the project imports are written once, lazy imports included."""

import sys

from pipeline.bytecode import compile_imports, imported_modules


def test_imported_modules_reads_module_level_and_lazy_imports_and_skips_relative_ones(tmp_path):
    source = tmp_path / "m.py"
    source.write_text(
        "import os, json.decoder\nfrom collections import abc\nfrom . import sibling\n"
        "def f():\n    import csv\n    from xml.dom import minidom\n"
    )
    assert imported_modules([source]) == ["collections", "csv", "json.decoder", "os", "xml.dom"]


def test_a_lazily_imported_module_gets_its_pyc_even_where_writing_is_turned_off_and_broken_ones_are_skipped(
        tmp_path, monkeypatch):
    library = tmp_path / "lib"
    library.mkdir()
    (library / "stucco_lazy_probe_module.py").write_text("VALUE = 1\n")
    (library / "stucco_broken_probe_module.py").write_text("raise OSError('a shared library is missing')\n")
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_x.py").write_text(
        "def test_f():\n    import stucco_lazy_probe_module\n    import stucco_module_not_installed\n"
        "    import stucco_broken_probe_module\n"
    )
    monkeypatch.syspath_prepend(str(library))
    monkeypatch.setattr(sys, "dont_write_bytecode", True)  # as PYTHONDONTWRITEBYTECODE=1 would
    monkeypatch.delitem(sys.modules, "stucco_lazy_probe_module", raising=False)

    assert compile_imports(tmp_path, packages=()) == 1
    assert list((library / "__pycache__").glob("stucco_lazy_probe_module.*.pyc"))
