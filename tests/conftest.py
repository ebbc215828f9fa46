"""Shared fixtures: the ../shared folder (skip with a reason where it is absent), Warp device."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SHARED = Path(os.environ.get("PHOTOAR_SHARED", ROOT.parent / "shared"))


def _devices():
    import warp as wp

    from kernels import runtime

    runtime.init()
    return ["cpu"] + (["cuda:0"] if wp.is_cuda_available() else [])


@pytest.fixture(params=_devices())
def device(request):
    """Every kernel test runs on the CPU and, where present, on CUDA."""
    return request.param


def shared_scene(name: str) -> Path:
    path = SHARED / "scenes" / name
    if not (path / "scene.json").is_file():
        pytest.skip(f"benchmark scene {path} not available (../shared is absent)")
    return path


def score(scene_dir: Path, composite_png: Path) -> dict:
    """Run the shared scorer (../shared/tools/score.py) and return its JSON figures."""
    scorer = SHARED / "tools" / "score.py"
    if not scorer.is_file():
        pytest.skip(f"scorer {scorer} not available")
    out = subprocess.run([sys.executable, str(scorer), str(scene_dir), str(composite_png)], capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def segments_blocked(vertices, faces, points, targets):
    """(N,J) bool: the segment points_i -> targets_j meets the mesh (Open3D's ray casts: the reference
    the blocked-pair kernels are tested against)."""
    import numpy as np
    import open3d as o3d

    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(np.asarray(vertices, np.float32))
    mesh.triangle.indices = o3d.core.Tensor(np.asarray(faces, np.int32))
    sc = o3d.t.geometry.RaycastingScene()
    sc.add_triangles(mesh)
    d = np.asarray(targets)[None] - np.asarray(points)[:, None]
    r = np.linalg.norm(d, axis=-1)
    rays = np.concatenate([np.broadcast_to(np.asarray(points)[:, None], d.shape), d / r[..., None]], -1)
    hit = sc.cast_rays(o3d.core.Tensor(rays.reshape(-1, 6).astype(np.float32)))["t_hit"].numpy().reshape(r.shape)
    return hit < r


@pytest.fixture(scope="session")
def own_room_cache(tmp_path_factory) -> Path:
    """One precompute cache for the own-room tests: the same user files give the same room
    folder (content-hashed), so the walkthrough's composite reuses test_own_room's precompute."""
    return tmp_path_factory.mktemp("own_room_cache")


@pytest.fixture(scope="session")
def shared_scenes_cache(tmp_path_factory) -> Path:
    """One precompute cache for the shared benchmark scenes over the session (content-hashed, so
    every test that composites window_room or lamps_room with default parameters pays its
    precompute once)."""
    return tmp_path_factory.mktemp("shared_scenes_cache")
