"""The structure's rules that a test can hold (docs/architecture.md): no import cycles, imports pointing down the
layers (CLI -> studies -> evaluate -> stages -> algorithms -> schema/geometry/io), no new oversized module, each
stage's table written by its ``<stage>_file`` function only.

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
#: Most lines of a module.
MAX_LINES = 400
#: Modules over MAX_LINES lines, to be split.
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
    large = {f for f, n in sizes.items() if n > MAX_LINES}
    assert large <= KNOWN_LARGE, f"over {MAX_LINES} lines: {sorted(large - KNOWN_LARGE)}"
    assert not KNOWN_LARGE - large, \
        f"now at most {MAX_LINES} lines, delete from KNOWN_LARGE: {sorted(KNOWN_LARGE - large)}"


#: Stage tables written outside their stage's ``<stage>_file`` function: the training study's cache of the
#: training set's contacts (its own metadata: the run files it holds, docs/studies.md).
KNOWN_OTHER_WRITERS = {("contacts", "pipeline.studies.training._isolate_training")}


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
                "segments": "pipeline.segment.segment_file",
                # the retrieve stage's two file functions (simulated runs, a robot's log) write through one helper
                "retrieval": "pipeline.retrieve.stage.write_retrieval_tables",
                "candidates": "pipeline.retrieve.stage.write_retrieval_tables", "scores": "pipeline.score.score_file"}
    writers = stage_table_writers()
    for kind, fn in expected.items():
        others = writers.get(kind, set()) - {fn} - {w for k, w in KNOWN_OTHER_WRITERS if k == kind}
        assert fn in writers.get(kind, set()) and not others, f"{kind} written by {sorted(writers.get(kind, ()))}"


#: The layers, top to bottom (docs/architecture.md): a module may import its own layer and the ones below, never
#: one above. Each entry is a module or a package prefix; the longest match decides. The package
#: ``pipeline.retrieve`` re-exports its stage, so it sits with the stages; its algorithm modules sit below.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("cli", ("stucco_cli",)),
    ("studies", ("pipeline.studies",)),
    # The active protocol's probing policy runs the stages (isolate, track, segment, the estimators) between probes;
    # collect and retrieve reach it through the registry by import path, never by an import.
    ("evaluate", ("pipeline.evaluate", "pipeline.report", "pipeline.figures", "pipeline.probe")),
    ("stages", ("pipeline.collect", "pipeline.isolate", "pipeline.track.stage", "pipeline.segment",
                "pipeline.retrieve", "pipeline.score")),
    ("algorithms", ("pipeline.track", "pipeline.estimators", "pipeline.grasp", "pipeline.grasp_rule", "pipeline.sim",
                    "pipeline.robot", "pipeline.policies", "pipeline.guarded_replay", "pipeline.components",
                    "pipeline.metrics",
                    "pipeline.labels", "pipeline.detection", "pipeline.contact_isolation",
                    "pipeline.grasp_judge", "pipeline.action_summary")),
    ("schema/geometry/io", ("pipeline", "pipeline.schema", "pipeline.geometry", "pipeline.atomic",
                            "pipeline.registry", "pipeline.constraints", "pipeline.layout", "pipeline.scenes",
                            "pipeline.seeds", "pipeline.parallel", "pipeline.portable", "pipeline.pairwise_sum",
                            "pipeline.spd", "pipeline.environment", "pipeline.bytecode")),
)


def layer_of(module: str) -> int:
    """Index of the module's layer in :data:`LAYERS` (0 = the top): the longest prefix listed decides."""
    best, rank = -1, None
    for i, (_, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and len(p) > best:
                best, rank = len(p), i
    assert rank is not None, f"{module} is in no layer; add it to LAYERS"
    return rank


def test_layer_of_takes_the_longest_prefix():
    assert LAYERS[layer_of("pipeline.retrieve.stage")][0] == "stages"
    assert LAYERS[layer_of("pipeline.estimators.paper.icp")][0] == "algorithms"
    assert LAYERS[layer_of("pipeline.studies.retrieval_ladder")][0] == "studies"
    assert LAYERS[layer_of("pipeline.track.stage")][0] == "stages"
    assert LAYERS[layer_of("pipeline.track.kernels")][0] == "algorithms"
    assert LAYERS[layer_of("stucco_cli.main")][0] == "cli"


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    """Every edge of the import graph that points to a higher layer, as 'a (layer) -> b (layer)'."""
    return sorted(f"{a} ({LAYERS[layer_of(a)][0]}) -> {b} ({LAYERS[layer_of(b)][0]})"
                  for a, targets in graph.items() for b in targets if layer_of(b) < layer_of(a))


def test_the_layer_check_finds_the_leaks_it_was_written_for():
    leaks = {"pipeline.layout": {"pipeline.estimators.estimate"},  # paths imported an estimator module
             "pipeline.retrieve.stage": {"pipeline.evaluate"},  # the stage imported the evaluate driver
             "pipeline.track.soft": {"pipeline.segment"},  # the tracker imported the segment stage
             "pipeline.segment": {"pipeline.components"}}  # (down: allowed)
    assert upward_imports(leaks) == [
        "pipeline.layout (schema/geometry/io) -> pipeline.estimators.estimate (algorithms)",
        "pipeline.retrieve.stage (stages) -> pipeline.evaluate (evaluate)",
        "pipeline.track.soft (algorithms) -> pipeline.segment (stages)"]


def test_imports_point_down_the_layers():
    up = upward_imports(import_graph())
    assert not up, "imports pointing up the layers:\n" + "\n".join(up)


def test_the_registry_imports_only_the_bottom_layer():
    bottom = len(LAYERS) - 1
    assert all(layer_of(m) == bottom for m in import_graph()["pipeline.registry"])
