"""No two files of drivers/ or simulators/ import each other (issue 34): a name both need lives in
the lower file or a small module of its own. Every import counts — at the top, inside a function,
under ``if TYPE_CHECKING:`` — since a lazy import only hides a circle until the day it is hoisted."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("drivers", "simulators")


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for every Python file of PACKAGES."""
    out = {}
    for package in PACKAGES:
        for path in (REPO / package).rglob("*.py"):
            parts = path.relative_to(REPO).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _imported(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The modules of ``known`` that the file imports anywhere in it (``from a.b import c`` counts
    a.b, and a.b.c when c is a module)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*up, base] if base else up)
            found |= {base} | {f"{base}.{alias.name}" for alias in node.names}
    return {m for m in found if m in known and m != name}


def test_the_import_scanner_sees_imports_inside_functions_and_type_checking(tmp_path):
    """The scanner itself: a circle made only of a function-level and a TYPE_CHECKING import is seen."""
    a, b = tmp_path / "a.py", tmp_path / "b.py"
    a.write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg.b import B\n")
    b.write_text("def f():\n    from pkg import a\n")
    known = {"pkg.a": a, "pkg.b": b}
    assert _imported("pkg.a", a, known) == {"pkg.b"}
    assert _imported("pkg.b", b, known) == {"pkg.a"}


def test_no_two_files_import_each_other():
    known = _modules()
    imports = {name: _imported(name, path, known) for name, path in known.items()}
    circles = sorted({tuple(sorted((a, b))) for a, targets in imports.items() for b in targets if a in imports[b]})
    assert not circles, f"files that import each other: {circles}"
