"""The design's layering (../shared/DESIGN.md "Layering"): kernels/ <- recon/ <- lighting/ <- app/.

Every import statement of every module (top level and inside functions) is read with ast; a
package may import only from the packages below it.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ORDER = ("kernels", "recon", "lighting", "app")  # bottom to top


def imported_packages(path: Path) -> list[tuple[int, str]]:
    """(line, top-level package) of every absolute import in `path`."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name.split(".")[0]) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.lineno, node.module.split(".")[0]))
    return out


def upward_imports(package: str) -> list[str]:
    above = set(ORDER[ORDER.index(package) + 1:])
    return [f"{p.relative_to(ROOT)}:{line} imports {mod}"
            for p in sorted((ROOT / package).rglob("*.py"))
            for line, mod in imported_packages(p) if mod in above]


@pytest.mark.parametrize("package", ORDER[:-1])
def test_no_upward_imports(package):
    assert upward_imports(package) == []


def test_the_check_sees_an_upward_import(tmp_path):
    """The parser finds imports inside functions and `from x.y import z` forms."""
    f = tmp_path / "m.py"
    f.write_text("import numpy\n\ndef g():\n    from app.engine import Engine\n    import lighting.hdr\n")
    assert [m for _, m in imported_packages(f)] == ["numpy", "app", "lighting"]


def test_helpers_live_once():
    """No module below app/ re-implements the atomic temp-file write that recon/io.py owns."""
    offenders = [f"{p.relative_to(ROOT)}" for pkg in ORDER for p in sorted((ROOT / pkg).rglob("*.py"))
                 if p != ROOT / "recon" / "io.py" and ("os.replace(" in p.read_text() or "mkstemp(" in p.read_text())]
    assert offenders == []


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def import_graph() -> dict[str, set[str]]:
    """Project module -> the project modules it imports (every import statement, top level and inside
    functions; `from a.b import c` names a.b.c when that is a module, else a.b)."""
    files = {module_name(p): p for pkg in ORDER for p in sorted((ROOT / pkg).rglob("*.py"))}
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                deps |= {a.name for a in node.names if a.name in files}
            elif isinstance(node, ast.ImportFrom) and node.module:
                base = node.module
                if node.level:  # relative: from the importing module's package
                    pkg = name.split(".")[: -node.level] if path.name != "__init__.py" else \
                        name.split(".")[: len(name.split(".")) - node.level + 1]
                    base = ".".join([*pkg, node.module])
                for a in node.names:
                    sub = f"{base}.{a.name}"
                    deps.add(sub if sub in files else base)
        graph[name] = {d for d in deps if d in files and d != name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles():
    assert cycles(import_graph()) == []


def test_the_cycle_check_sees_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_stages_never_import_the_engine():
    """The stages take data and their config; they never import app.engine (nor receive an Engine)."""
    graph = import_graph()
    assert [m for m in graph if m.startswith("app.stages") and "app.engine" in graph[m]] == []
