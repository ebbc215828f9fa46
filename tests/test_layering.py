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
