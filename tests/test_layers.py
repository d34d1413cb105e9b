"""The packages of jsrte form layers: no two packages import each other (directly or lazily)."""

import ast
from collections import defaultdict
from pathlib import Path

import jsrte

ROOT = Path(jsrte.__file__).parent


def _package_imports() -> dict[str, dict[str, set[str]]]:
    """{package: {imported package: files importing it}}, top-level modules counted as packages."""
    edges: dict[str, dict[str, set[str]]] = defaultdict(lambda: defaultdict(set))
    for path in ROOT.rglob("*.py"):
        parts = path.relative_to(ROOT).parts
        package = parts[0] if len(parts) > 1 else parts[0].removesuffix(".py")
        for node in ast.walk(ast.parse(path.read_text())):
            names = [node.module] if isinstance(node, ast.ImportFrom) and node.module else (
                [a.name for a in node.names] if isinstance(node, ast.Import) else [])
            for name in names:
                if name.startswith("jsrte.") and name.split(".")[1] != package:
                    edges[package][name.split(".")[1]].add(str(path.relative_to(ROOT)))
    return edges


def test_no_two_packages_import_each_other():
    edges = _package_imports()
    assert "fit" in edges["cli"] and "scans" in edges["fit"]  # the walk sees imports, lazy ones included
    cycles = [(a, b, sorted(edges[a][b]), sorted(edges[b][a]))
              for a in edges for b in edges[a] if a < b and a in edges.get(b, {})]
    assert not cycles, cycles
