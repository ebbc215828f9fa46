"""The distribution holds every package of the project: `pip install .` (not only an editable
install) must give a working photoar, sub-packages (app.stages) and the bundled demo scene included."""
from __future__ import annotations

import tomllib
from pathlib import Path

from setuptools import find_namespace_packages, find_packages

ROOT = Path(__file__).resolve().parents[1]
TOP = ("recon", "lighting", "kernels", "app")


def _config() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def _distributed() -> set[str]:
    packages = _config().get("packages", [])
    if isinstance(packages, list):  # listed by hand: only these, not their sub-packages
        return set(packages)
    find = packages["find"]
    finder = find_namespace_packages if find.get("namespaces", True) else find_packages
    return set(finder(where=str(ROOT), include=find["include"]))


def test_every_python_package_is_distributed():
    dist = _distributed()
    for top in TOP:
        for init in (ROOT / top).rglob("__init__.py"):
            name = ".".join(init.parent.relative_to(ROOT).parts)
            assert name in dist, f"{name} has an __init__.py but is not in the distribution"
    assert not any(p.split(".")[0] in ("tests", "bench") for p in dist), sorted(dist)


def test_the_demo_scene_is_distributed():
    # make demo reads app/demo (scene.json, the photo, the chair, the room's textures) from the package
    dist, data = _distributed(), _config()["package-data"]
    demo_files = [p for p in (ROOT / "app" / "demo").rglob("*") if p.is_file()]
    assert demo_files
    for f in demo_files:
        pkg = ".".join(f.parent.relative_to(ROOT).parts)
        assert pkg in dist, f"{f.relative_to(ROOT)}: its folder {pkg} is not in the distribution"
        assert data.get(pkg) == ["*"], f"{f.relative_to(ROOT)}: {pkg} ships no data files"
