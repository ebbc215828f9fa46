"""Fixtures shared by the lighting tests."""
import pytest

from recon.scene import load_scene
from tests.conftest import shared_scene


@pytest.fixture(scope="module")
def room():
    """sun_room's scene, its patches (0.18 m, emitters 0.1 m) and the room's occluder on the CPU."""
    from app.stages.precompute import scene_meshes
    from kernels import runtime
    from recon.patches import build_patches

    runtime.init()
    s = load_scene(shared_scene("sun_room"), load_textures=False)
    pm = build_patches(s, 0.18, 0.1)
    occ, _ = scene_meshes(pm, "cpu")
    return s, pm, occ
