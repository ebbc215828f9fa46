"""Fixtures of the app tests: a shared room's engine, truth and all-sources frame, made once per module."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest


@dataclass
class SharedRoom:
    """One shared scene ready for scoring: its folder, scene, Engine (default params, the session's cache),
    truth.png and truth_mask.png, the all-sources frame at the scene's pose and that frame's score
    (lighting.metrics.score_regions: tools/score.py's measures)."""

    dir: Path
    scene: object
    engine: object
    truth: np.ndarray
    mask: np.ndarray
    full: object
    s_all: dict

    def score(self, pixels: np.ndarray) -> dict:
        """tools/score.py's measures of a frame's pixels (H,W,3) uint8 against the truth."""
        from lighting import metrics

        return metrics.score_regions(pixels, self.scene.photo, self.truth, self.mask)


@pytest.fixture(scope="module")
def shared_room(shared_scenes_cache):
    """shared_room(name) -> SharedRoom of a shared scene (window_room, lamps_room, sun_room), made on the first
    call in the module and kept for its other tests (a test that changes the engine's settings restores them)."""
    made: dict[str, SharedRoom] = {}

    def get(name: str) -> SharedRoom:
        if name not in made:
            import cv2

            from app.engine import Engine, EngineParams, FrameConfig
            from recon.io import read_image_rgb
            from recon.scene import load_scene
            from tests.conftest import shared_scene

            d = shared_scene(name)
            scene = load_scene(d)
            eng = Engine(scene, EngineParams(), cache_dir=shared_scenes_cache, quiet=True)
            truth = read_image_rgb(d / "truth.png")
            mask = cv2.imread(str(d / "truth_mask.png"), cv2.IMREAD_GRAYSCALE)
            room = SharedRoom(d, scene, eng, truth, mask, eng.render(scene.obj, FrameConfig(passes=None)), {})
            room.s_all = room.score(room.full.pixels)
            made[name] = room
        return made[name]

    return get
