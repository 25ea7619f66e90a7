"""The engine's layers (issue 25): a graph's way through runs one way — load (graphfile: YAML →
plain data) → validate (→ the plain model) → plan → run (runner per node, executor over the
plan) → publish — with no import cycles, each rule in one place, and small functions.

Read from the source with ``ast`` (nothing is imported), so a new import that breaks a layer
fails here with the module that made it."""
from __future__ import annotations

import ast
from pathlib import Path

import networkx as nx
import pytest

ROOT = Path(__file__).resolve().parents[1] / "graphkit"
#: the modules of a graph's way through the engine, held to the size limits below
WAY_THROUGH = ("api", "graphfile", "model", "validate", "plan", "runner", "executor", "publish", "paths")
MAX_LINES, MAX_CC = 60, 15


def _modules() -> dict[str, Path]:
    out = {}
    for p in ROOT.rglob("*.py"):
        parts = list(p.relative_to(ROOT.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = p
    return out


MODULES = _modules()
TREES = {m: ast.parse(p.read_text(), str(p)) for m, p in MODULES.items()}


def _type_checking_only(tree: ast.AST) -> set[int]:
    """ids of the import statements under ``if TYPE_CHECKING:`` (never run)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and getattr(node.test, "id", None) == "TYPE_CHECKING":
            out.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    return out


def _imports(mod: str) -> tuple[set[str], set[str]]:
    """(graphkit modules, other top-level packages) that ``mod`` imports, at module level or
    inside a function (a lazy import still ties the two modules together)."""
    tree = TREES[mod]
    skip = _type_checking_only(tree)
    pkg = mod if MODULES[mod].name == "__init__.py" else mod.rpartition(".")[0]
    ours, theirs = set(), set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            subs = [f"{target}.{a.name}" for a in node.names if f"{target}.{a.name}" in MODULES]
            names = subs if subs and len(subs) == len(node.names) else [target] + subs
        else:
            continue
        for name in names:
            if name in MODULES:
                ours.add(name)
            elif not name.startswith("graphkit"):
                theirs.add(name.split(".")[0])
    ours.discard(mod)
    return ours, theirs


IMPORTS = {m: _imports(m) for m in MODULES}
GRAPH = nx.DiGraph([(m, t) for m, (ours, _) in IMPORTS.items() for t in ours])
GRAPH.add_nodes_from(MODULES)


def _closure(mod: str) -> set[str]:
    return {mod} | nx.descendants(GRAPH, mod)


def test_no_import_cycles_among_graphkit_modules():
    cycles = sorted(" → ".join(c + [c[0]]) for c in nx.simple_cycles(GRAPH))
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_the_model_holds_no_yaml():
    """The plain model, and all it imports, know nothing of YAML or of the loader."""
    reach = _closure("graphkit.model")
    assert "graphkit.graphfile" not in reach, nx.shortest_path(GRAPH, "graphkit.model", "graphkit.graphfile")
    assert not [m for m in reach if "yaml" in IMPORTS[m][1]], [m for m in reach if "yaml" in IMPORTS[m][1]]


@pytest.mark.parametrize("stage, later", [
    ("graphkit.model", ("graphkit.validate", "graphkit.plan", "graphkit.runner", "graphkit.executor", "graphkit.publish")),
    ("graphkit.validate", ("graphkit.graphfile", "graphkit.plan", "graphkit.runner", "graphkit.executor", "graphkit.publish")),
    ("graphkit.plan", ("graphkit.graphfile", "graphkit.validate", "graphkit.runner", "graphkit.executor", "graphkit.publish")),
    ("graphkit.runner", ("graphkit.graphfile", "graphkit.validate", "graphkit.executor", "graphkit.publish")),
    ("graphkit.executor", ("graphkit.graphfile", "graphkit.validate", "graphkit.publish")),
])
def test_a_stage_does_not_reach_into_another(stage, later):
    """validate does not import the loader; plan and run do not call back into each other or
    into publishing (directly or through another module)."""
    reach = _closure(stage)
    bad = {m: nx.shortest_path(GRAPH, stage, m) for m in later if m in reach}
    assert not bad, bad


def test_api_calls_the_stages_in_order():
    """run_graph: load (+ validate), plan, run, publish — each from its own module."""
    fn = next(n for n in ast.walk(TREES["graphkit.api"]) if isinstance(n, ast.FunctionDef) and n.name == "run_graph")
    calls = [n.func.id for n in ast.walk(fn) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)]
    order = [calls.index(c) for c in ("load", "make_plan", "Session", "locked_run")]
    assert order == sorted(order), calls
    assert {"load", "make_plan", "run_local", "export_outputs"} <= set(calls), calls


def _functions(mod: str):
    for node in ast.walk(TREES[mod]):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield node


def _calls(fn) -> set[str]:
    return {n.func.attr if isinstance(n.func, ast.Attribute) else getattr(n.func, "id", "")
            for n in ast.walk(fn) if isinstance(n, ast.Call)}


def test_lock_then_commit_is_written_once():
    """Holding the store's run lock and committing what ran: one function (executor.locked_run)."""
    both = [f"{m}.{fn.name}" for m in MODULES if not m.startswith("graphkit.store")
            for fn in _functions(m) if {"run_lock", "commit"} <= _calls(fn)]
    assert both == ["graphkit.executor.locked_run"], both


def test_output_names_have_one_rule():
    """Validation, the plan and publishing admit output names through paths.OutputNames; the
    names of the run's own files are written in paths only."""
    users = sorted(m for m in MODULES if m != "graphkit.paths"
                   and any(isinstance(n, ast.Name) and n.id == "OutputNames" for n in ast.walk(TREES[m])))
    assert users == ["graphkit.plan", "graphkit.publish", "graphkit.validate"], users
    spelled = [(m, n.lineno) for m in WAY_THROUGH if m != "paths" for n in ast.walk(TREES[f"graphkit.{m}"])
               if isinstance(n, ast.Constant) and n.value in ("manifest.json", "report.html", ".graphkit-")]
    assert not spelled, spelled


def test_output_names_rule():
    from graphkit.paths import OutputNames

    names = OutputNames()
    assert names.claim("a/b.npy", "x") is None and names.claim("c.json", "y") is None
    assert names.claim("a/b.npy", "z") == ("'a/b.npy' is written by two outputs", "x")
    assert names.claim("manifest.json")[0] == "'manifest.json' is the name of the run's own manifest.json in --out"
    assert names.claim("report.html")[0].startswith("'report.html' is the name of the run's own report.html")
    assert "graphkit's own" in names.claim(".graphkit-stage-1/x.npy")[0]
    assert names.claim("c.json/d.npy")[0] == "output 'c.json' is a file but 'c.json/d.npy' needs it to be a folder"
    assert names.claim("a")[0] == "output 'a' is a file but 'a/b.npy' needs it to be a folder"
    assert names.claim("a/c.npy") is None  # a folder may hold many files


# ---------------------------------------------------------------------------------------------
# size: no function of the way through over MAX_LINES lines or cyclomatic complexity MAX_CC


def complexity(fn: ast.FunctionDef) -> int:
    """McCabe's cyclomatic complexity as radon counts it (``radon cc``): 1, plus one per if,
    conditional expression, loop (and its else), except handler (and try's else), extra
    operand of and/or, comprehension (and its ifs), assert and match case; functions and
    classes defined inside are counted on their own."""
    return 1 + sum(_decisions(stmt) for stmt in fn.body)


def _decisions(node: ast.AST) -> int:
    if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
        return 0
    if isinstance(node, ast.Assert):
        return 1
    n = 0
    if isinstance(node, ast.Try):
        n = len(node.handlers) + bool(node.orelse)
    elif isinstance(node, ast.BoolOp):
        n = len(node.values) - 1
    elif isinstance(node, (ast.If, ast.IfExp)):
        n = 1
    elif isinstance(node, (ast.For, ast.AsyncFor, ast.While)):
        n = 1 + bool(node.orelse)
    elif isinstance(node, ast.comprehension):
        n = 1 + len(node.ifs)
    elif isinstance(node, ast.Match):
        wildcard = any(getattr(c.pattern, "pattern", False) is None for c in node.cases)
        n = max(0, len(node.cases) - wildcard)
    return n + sum(_decisions(c) for c in ast.iter_child_nodes(node))


def test_complexity_counts_as_radon_does():
    src = ("def f(a, b):\n"
           "    if a and b or a:\n"                      # if +1, and/or +2
           "        return [x for x in a if x if b]\n"   # comprehension +1, its ifs +2
           "    for x in a:\n"                           # loop +1, its else +1
           "        try:\n"
           "            pass\n"
           "        except ValueError:\n"                # handlers +2, try's else +1
           "            pass\n"
           "        except KeyError:\n"
           "            pass\n"
           "        else:\n"
           "            pass\n"
           "    else:\n"
           "        assert a\n"                          # assert +1
           "    def g():\n"                              # counted on its own
           "        return 1 if a else 2\n"
           "    return (lambda: 3 if b else 4)()\n")     # a lambda's inside counts: +1
    f, g = [n for n in ast.walk(ast.parse(src)) if isinstance(n, ast.FunctionDef)]
    assert (complexity(f), complexity(g)) == (14, 2)


@pytest.mark.parametrize("mod", WAY_THROUGH)
def test_functions_are_small(mod):
    big = [f"{fn.name} (line {fn.lineno}): {fn.end_lineno - fn.lineno + 1} lines, cc {complexity(fn)}"
           for fn in _functions(f"graphkit.{mod}")
           if fn.end_lineno - fn.lineno + 1 > MAX_LINES or complexity(fn) > MAX_CC]
    assert not big, big


@pytest.mark.parametrize("a, b, message", [
    (".graphkit-x.txt", "y.txt", "node 'a' (WriteText), param 'path': '.graphkit-x.txt': names starting with "
                                 ".graphkit- are graphkit's own; choose another name"),
    ("d.txt", "d.txt/e.txt", "node 'b' (WriteText), param 'path': output 'd.txt' is a file but 'd.txt/e.txt' "
                             "needs it to be a folder; choose another name"),
    ("./r.txt", "r.txt", "nodes 'a' and 'b' both write 'r.txt' into --out"),
])
def test_validation_admits_output_files_by_the_one_rule(engine_registry, a, b, message):
    """What publishing would refuse after the run is refused when the graph is loaded."""
    import sweepnodes

    from graphkit.errors import GraphError
    from graphkit.graphfile import load_dict

    engine_registry.add_provider("nodes", "tests", sweepnodes)
    graph = {"graphkit": 1, "nodes": {"a": {"type": "WriteText", "params": {"path": a}},
                                      "b": {"type": "WriteText", "params": {"path": b}}}}
    with pytest.raises(GraphError) as ei:
        load_dict(graph, engine_registry)
    assert [d.message for d in ei.value.diagnostics] == [message]
