"""The dependency rule of docs/style.md, checked on the source: ``roadgraph`` never imports
``navsvc``; the pure packages (``fusion``, ``matching``, ``sim``) import only
``navsvc.types``, ``navsvc.errors``, their own package and ``roadgraph``, and do no I/O
through the service's modules (``wire``, ``api``, ``triplog``, ``cli``, ``session``)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PURE = ("fusion", "matching", "sim")
ALLOWED_FROM_PURE = ("navsvc.types", "navsvc.errors")


def imports_of(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
    return found


@pytest.mark.parametrize("path", sorted((ROOT / "roadgraph").rglob("*.py")),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_roadgraph_knows_nothing_of_navsvc(path: Path) -> None:
    assert not {m for m in imports_of(path) if m.split(".")[0] == "navsvc"}


@pytest.mark.parametrize("path", sorted(p for pkg in PURE
                                        for p in (ROOT / "navsvc" / pkg).rglob("*.py")),
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_pure_packages_import_only_types_errors_and_roadgraph(path: Path) -> None:
    own = "navsvc." + path.relative_to(ROOT / "navsvc").parts[0]
    bad = {m for m in imports_of(path) if m.startswith("navsvc")
           and not m.startswith(own) and m not in ALLOWED_FROM_PURE}
    assert not bad, f"{path.name} imports {sorted(bad)}"
