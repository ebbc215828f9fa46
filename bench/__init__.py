"""Benchmarks (run as scripts: python bench/bench_*.py); what they share."""
from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path


def shared_scenes(shared: Path, names: Iterable[str]) -> Iterator[tuple[str, Path]]:
    """(name, folder) of each named scene under shared/scenes that is there; one line for each skipped."""
    for name in names:
        scene_dir = Path(shared) / "scenes" / name
        if not (scene_dir / "scene.json").is_file():
            print(f"skip {name}: {scene_dir} not found")
            continue
        yield name, scene_dir
