"""The structure's rules that a test can hold (docs/architecture.md): no import cycles, no new oversized module,
each stage's table written by its ``<stage>_file`` function only.

The import graph counts every ``import pipeline…`` / ``from pipeline… import`` and the same for ``stucco_cli``, at
module top and inside functions alike, and importing ``a.b.c`` also runs the ``__init__`` of ``a.b`` and ``a``, so
those are edges too. Both lists below may only shrink: the structure issue removes what is left in them.
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Cycles that remain (each a sorted group of modules that import one another), to be removed.
KNOWN_CYCLES: list[list[str]] = []
#: Modules over 450 lines, to be split.
KNOWN_LARGE: set[str] = set()


def _modules() -> dict[str, Path]:
    mods = {}
    for f in sorted([*ROOT.glob("pipeline/**/*.py"), *ROOT.glob("stucco_cli/**/*.py")]):
        parts = f.relative_to(ROOT).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        mods[name] = f
    return mods


def import_graph() -> dict[str, set[str]]:
    """Module -> the modules whose code runs when it is imported (direct imports and their parent packages)."""
    mods = _modules()

    def targets(dotted: str) -> set[str]:
        out = set()
        while dotted:
            if dotted in mods:
                out.add(dotted)
            dotted = dotted.rpartition(".")[0]
        return out

    graph: dict[str, set[str]] = {}
    for name, f in mods.items():
        edges: set[str] = set()
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.Import):
                for a in node.names:
                    edges |= targets(a.name)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                for a in node.names:
                    edges |= targets(f"{node.module}.{a.name}")
        graph[name] = {e for e in edges if e != name and not name.startswith(e + ".")}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected groups of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def test_cycle_finder_finds_a_cycle_through_a_package_init():
    g = {"p": {"p.a"}, "p.a": {"p.b"}, "p.b": {"p"}, "q": {"p.a"}}
    assert cycles(g) == [["p", "p.a", "p.b"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_beyond_the_known_ones():
    found = cycles(import_graph())
    new = [c for c in found if not any(set(c) <= set(k) for k in KNOWN_CYCLES)]
    assert not new, f"new import cycle(s): {new}"
    gone = [k for k in KNOWN_CYCLES if not any(set(k) <= set(c) for c in found)]
    assert not gone, f"cycle(s) removed, delete them from KNOWN_CYCLES: {gone}"


def test_no_new_oversized_module():
    sizes = {str(f.relative_to(ROOT)): len(f.read_text().splitlines()) for f in _modules().values()}
    large = {f for f, n in sizes.items() if n > 450}
    assert large <= KNOWN_LARGE, f"over 450 lines: {sorted(large - KNOWN_LARGE)}"
    assert not KNOWN_LARGE - large, f"now under 450 lines, delete from KNOWN_LARGE: {sorted(KNOWN_LARGE - large)}"


#: Stage tables written outside their stage's ``<stage>_file`` function: the training study's cache of the
#: training set's contacts (its own metadata: the run files it holds, docs/studies.md).
KNOWN_OTHER_WRITERS = {("contacts", "pipeline.study.training._isolate_training")}


def stage_table_writers() -> dict[str, set[str]]:
    """Table kind -> the functions (``module.function``) that call ``write_table(..., kind=...)`` for it."""
    writers: dict[str, set[str]] = {}
    for name, f in _modules().items():
        tree = ast.parse(f.read_text())
        for fn in ast.walk(tree):
            if not isinstance(fn, ast.FunctionDef):
                continue
            for node in ast.walk(fn):
                if not (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None))
                        == "write_table"):
                    continue
                for kw in node.keywords:
                    if kw.arg == "kind":
                        kind = kw.value.value if isinstance(kw.value, ast.Constant) else ast.unparse(kw.value)
                        writers.setdefault({"RUN_KIND": "sim_run"}.get(kind, kind), set()).add(f"{name}.{fn.name}")
    return writers


def test_each_stage_table_is_written_by_its_stage_file_function_only():
    expected = {"sim_run": "pipeline.collect.collect_file", "contacts": "pipeline.isolate.isolate_file",
                "tracks": "pipeline.track.stage.track_file", "diagnostics": "pipeline.track.stage.track_file",
                "segments": "pipeline.segment.segment_file", "retrieval": "pipeline.retrieve.stage.retrieve_file",
                "candidates": "pipeline.retrieve.stage.retrieve_file", "scores": "pipeline.score.score_file"}
    writers = stage_table_writers()
    for kind, fn in expected.items():
        others = writers.get(kind, set()) - {fn} - {w for k, w in KNOWN_OTHER_WRITERS if k == kind}
        assert fn in writers.get(kind, set()) and not others, f"{kind} written by {sorted(writers.get(kind, ()))}"
