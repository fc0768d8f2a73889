"""The folders are layers (docs/architecture.md): every import — at the top of a file, inside a
function, or for the type checker only — goes to the same layer or one below, never up; the two
methods' folders never import each other; and no file imports another that imports it back.
Read from the code's own import statements, as text (nothing is imported)."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("rtcal", "drivers", "simulators")

# bottom to top; a file belongs to the longest prefix that names it
LAYERS: tuple[tuple[str, ...], ...] = (
    ("rtcal/__init__.py", "rtcal/units.py", "rtcal/errors.py", "rtcal/clock.py", "rtcal/outputs.py", "drivers/"),
    ("rtcal/solvers/", "rtcal/compensation/"),
    ("simulators/",),
    ("rtcal/procedure/", "rtcal/results/"),
    ("rtcal/store/",),
    ("rtcal/engine/",),
    ("rtcal/deliverables/",),
    ("rtcal/methods/protocol.py", "rtcal/methods/estimates.py", "rtcal/methods/conditions.py", "rtcal/methods/planner.py",
     "rtcal/methods/recalibration.py"),
    ("rtcal/methods/multistation/", "rtcal/methods/abbe/"),  # peers: one method never reaches into another
    ("rtcal/methods/__init__.py",),  # the registry
    ("rtcal/run/",),
    ("rtcal/planning/", "rtcal/live/", "rtcal/catalog/"),
    ("rtcal/cli/",),
)
PEERS = ("rtcal/methods/multistation/", "rtcal/methods/abbe/")


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


def _layer(path: Path) -> tuple[int, str]:
    rel = path.relative_to(REPO).as_posix()
    best = max(((k, prefix) for k, layer in enumerate(LAYERS) for prefix in layer
                if rel == prefix or (prefix.endswith("/") and rel.startswith(prefix))), key=lambda kp: len(kp[1]))
    return best


def test_every_file_has_a_layer_and_no_import_runs_up_or_across():
    modules = _modules()
    wrong = []
    for a, targets in _imports(modules).items():
        (la, pa), rel = _layer(modules[a]), modules[a].relative_to(REPO).as_posix()
        for b in targets:
            lb, pb = _layer(modules[b])
            if lb > la or (pa in PEERS and pb in PEERS and pa != pb):
                wrong.append(f"{rel} imports {modules[b].relative_to(REPO).as_posix()}")
    assert wrong == [], "\n".join(sorted(wrong))


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


def test_the_checker_sees_an_upward_import_and_a_circle():
    """The two checks can fail: an import from a lower layer up, and a loop, are both found."""
    assert _layer(REPO / "rtcal" / "engine" / "engine.py")[0] < _layer(REPO / "rtcal" / "methods" / "abbe" / "plan.py")[0]
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}, ["a", "b", "c", "d"]) == [["a", "b", "c"]]
