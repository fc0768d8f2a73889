"""The folders are layers (docs/architecture.md), and the layers are contracts: every import — at the top of a
file, inside a function, or for the type checker only — goes to the same layer or one below, never up; the
engine, the store and the procedures never reach the simulators (a run's bench is handed to them); a method's
folder is its own (only its folder and the registry's table reach into it); no file imports another that
imports it back; a file in a folder no layer lists is named, not a crash; and the sample plugins in
tests/plugins/ use rtcal only through its public face, rtcal.api (and rtcal.solvers for mathematics). Read
from the code's own import statements, as text (nothing is imported)."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("rtcal", "drivers", "simulators")

# bottom to top; a file belongs to the longest prefix that names it
LAYERS: tuple[tuple[str, ...], ...] = (
    ("rtcal/__init__.py", "rtcal/units.py", "rtcal/errors.py", "rtcal/clock.py", "rtcal/outputs.py", "rtcal/registry.py",
     "rtcal/moved.py", "rtcal/procedure/yamlfile.py", "drivers/"),
    ("rtcal/solvers/", "rtcal/compensation/"),
    ("simulators/",),
    ("rtcal/procedure/", "rtcal/results/"),
    ("rtcal/store/",),
    ("rtcal/engine/",),
    ("rtcal/deliverables/",),
    ("rtcal/methods/protocol.py", "rtcal/methods/estimates.py", "rtcal/methods/conditions.py", "rtcal/methods/planner.py",
     "rtcal/methods/recalibration.py", "rtcal/methods/base.py", "rtcal/methods/cycle.py", "rtcal/api.py"),
    # what methods share, and the public face
    ("rtcal/methods/multistation/", "rtcal/methods/abbe/", "rtcal/methods/rtest/"),  # peers: one method never reaches into another
    ("rtcal/methods/__init__.py",),  # the registry (a face: its table names the methods as strings)
    ("rtcal/run/",),
    ("rtcal/planning/", "rtcal/live/", "rtcal/catalog/"),
    ("rtcal/cli/",),
)
PEERS = ("rtcal/methods/multistation/", "rtcal/methods/abbe/", "rtcal/methods/rtest/")
REGISTRY = "rtcal/methods/__init__.py"  # the one file outside a method's folder that may name it (for the type checker)
# (importer, imported): what no layer order allows besides — the engine, the store and the procedures are handed
# a bench, they never reach for the simulators
FORBIDDEN = (("rtcal/engine/", "simulators/"), ("rtcal/store/", "simulators/"), ("rtcal/procedure/", "simulators/"))
PUBLIC = ("rtcal.api", "rtcal.solvers")  # what a plugin may import of rtcal (drivers and simulators: through rtcal.api)


def _modules() -> dict[str, Path]:
    found = {}
    for package in PACKAGES:
        for path in (REPO / package).rglob("*.py"):
            name = ".".join(path.relative_to(REPO).with_suffix("").parts)
            found[name.removesuffix(".__init__")] = path
    return found


def _imports(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Each module → the modules of this tree it imports (the longest module a dotted name names)."""

    def resolve(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    edges: dict[str, set[str]] = defaultdict(set)
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(parts + ([base] if base else []))
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
            for target in targets:
                found = resolve(target)
                if found is not None and found != name:
                    edges[name].add(found)
    return edges


def _layer(path: Path) -> tuple[int, str] | None:
    """(layer, the prefix that places it), or None for a file in a folder no layer lists."""
    rel = path.relative_to(REPO).as_posix()
    found = [(k, prefix) for k, layer in enumerate(LAYERS) for prefix in layer
             if rel == prefix or (prefix.endswith("/") and rel.startswith(prefix))]
    return max(found, key=lambda kp: len(kp[1])) if found else None


def _unlisted(modules: dict[str, Path]) -> list[str]:
    return sorted(p.relative_to(REPO).as_posix() for p in modules.values() if _layer(p) is None)


def _wrong_imports(modules: dict[str, Path], edges: dict[str, set[str]]) -> list[str]:
    """Every import that runs up a layer, across to a peer method, into a method's folder from outside it (the
    registry's type-checker names apart), or from the engine, store or procedures to the simulators."""
    wrong = []
    for a, targets in edges.items():
        here = _layer(modules[a])
        rel = modules[a].relative_to(REPO).as_posix()
        for b in targets:
            there, to = _layer(modules[b]), modules[b].relative_to(REPO).as_posix()
            if here is None or there is None:
                continue  # named by test_every_file_has_a_layer
            (la, pa), (lb, pb) = here, there
            private = pb in PEERS and pa != pb and rel != REGISTRY
            forbidden = any(rel.startswith(x) and to.startswith(y) for x, y in FORBIDDEN)
            if lb > la or private or forbidden:
                wrong.append(f"{rel} imports {to}")
    return sorted(wrong)


def test_every_file_has_a_layer():
    """A file in a folder no layer lists is named here (the other checks leave it out rather than crash)."""
    unlisted = _unlisted(_modules())
    assert unlisted == [], f"in no layer of tests/test_layers.py's LAYERS (add its folder where it belongs): {unlisted}"


def test_no_import_runs_up_or_across_or_into_a_method_or_to_the_simulators():
    modules = _modules()
    wrong = _wrong_imports(modules, _imports(modules))
    assert wrong == [], "\n".join(wrong)


def _circles(edges: dict[str, set[str]], nodes: list[str]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan's, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    for root in nodes:
        if root in index:
            continue
        work = [(root, iter(sorted(edges.get(root, ()))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on.add(root)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(edges.get(w, ())))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    component = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        component.append(w)
                        if w == v:
                            break
                    if len(component) > 1:
                        out.append(sorted(component))
    return out


def test_no_file_imports_one_that_imports_it_back():
    modules = _modules()
    assert _circles(_imports(modules), sorted(modules)) == []


def test_the_checker_sees_an_upward_import_a_private_one_a_forbidden_one_a_circle_and_an_unlisted_folder():
    """Every check can fail: an import from a lower layer up, one into a method's folder from outside, one from the
    engine to the simulators, a loop, and a file in a folder no layer lists (named, not a crash)."""
    paths = {"rtcal.engine.engine": REPO / "rtcal" / "engine" / "engine.py",
             "rtcal.methods.abbe.plan": REPO / "rtcal" / "methods" / "abbe" / "plan.py",
             "rtcal.run.runner": REPO / "rtcal" / "run" / "runner.py",
             "rtcal.methods": REPO / "rtcal" / "methods" / "__init__.py",
             "simulators.bench": REPO / "simulators" / "bench.py",
             "rtcal.newthing.x": REPO / "rtcal" / "newthing" / "x.py"}
    edges = {"rtcal.engine.engine": {"rtcal.methods.abbe.plan", "simulators.bench"},
             "rtcal.run.runner": {"rtcal.methods.abbe.plan"}, "rtcal.methods": {"rtcal.methods.abbe.plan"},
             "rtcal.newthing.x": {"rtcal.engine.engine"}}
    assert _wrong_imports(paths, edges) == ["rtcal/engine/engine.py imports rtcal/methods/abbe/plan.py",
                                            "rtcal/engine/engine.py imports simulators/bench.py",
                                            "rtcal/run/runner.py imports rtcal/methods/abbe/plan.py"]
    assert _unlisted(paths) == ["rtcal/newthing/x.py"]
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}, ["a", "b", "c", "d"]) == [["a", "b", "c"]]


def _plugin_imports(path: Path) -> list[str]:
    """The modules of rtcal, drivers and simulators a plugin's file imports (dotted names, as written)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level:
            found += [f"{node.module}.{a.name}" if node.module == "rtcal" else node.module or "" for a in node.names]
    return [name for name in found if name.split(".")[0] in PACKAGES]


def test_the_sample_plugins_use_rtcal_only_through_its_public_face():
    """tests/plugins/* import rtcal.api (and rtcal.solvers for mathematics), never another module of rtcal, drivers or
    simulators: what a plugin needs is there, and a newcomer needs no other module's docs."""
    plugins = sorted((REPO / "tests" / "plugins").rglob("*.py"))
    assert len(plugins) >= 5
    wrong = [f"{p.relative_to(REPO).as_posix()} imports {name}" for p in plugins for name in _plugin_imports(p)
             if not any(name == x or name.startswith(x + ".") for x in PUBLIC)]
    assert wrong == [], "\n".join(wrong)
    assert _plugin_imports(REPO / "tests" / "plugins" / "ball_runout" / "rtcal_ball_runout.py") == ["rtcal.api"]
