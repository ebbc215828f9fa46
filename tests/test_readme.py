"""README: short enough to read (the measurements live in docs/benchmarks.md), its links resolve,
and every source its accuracy table names exists."""
import re

from tests.conftest import ROOT

MAX_LINES = 250


def _readme() -> str:
    return (ROOT / "README.md").read_text()


def test_readme_is_short():
    n = len(_readme().splitlines())
    assert n <= MAX_LINES, f"README.md is {n} lines; move measurements to docs/benchmarks.md"


def test_readme_links_resolve():
    text = _readme()
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    assert "docs/benchmarks.md" in links and "docs/history.md" in links, links
    for link in links:
        if "://" not in link:
            assert (ROOT / link).exists(), link


def test_accuracy_table_names_real_sources():
    """Each row of the accuracy table ends in the bench, test or command that prints its numbers."""
    text = _readme()
    table = text[text.index("## Accuracy and speed"):]
    rows = [ln for ln in table.splitlines() if ln.startswith("| ") and not ln.startswith("| ---")][1:]
    assert len(rows) >= 9, rows
    for row in rows:
        source = row.rstrip(" |").rsplit("|", 1)[-1].strip().strip("`")
        path = source.split()[0]
        if path.startswith(("bench/", "tests/")):
            assert (ROOT / path.split("::")[0]).is_file(), row
        else:
            assert source.startswith("photoar "), row
