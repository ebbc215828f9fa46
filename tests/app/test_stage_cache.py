"""Per-scene artefacts cached by their inputs (issue 17, item 1): a second engine on the same scene
reads the shaft hierarchy and the SH volume from the cache instead of building them, and gets the
same frames; a changed input misses; an unreadable file is rebuilt; the store runs no code from
the file."""
import dataclasses

import numpy as np
import pytest

from app.cli import demo_scene_dir
from app.engine import Engine, EngineParams, FrameConfig
from app.stages import artefact_cache
from app.stages import precompute as stage
from recon.scene import load_scene

PARAMS = EngineParams(patch_size=0.35, emitter_patch_size=0.2)


@pytest.fixture(scope="module")
def engines(tmp_path_factory):
    scene = load_scene(demo_scene_dir())
    cache = tmp_path_factory.mktemp("cache")
    cold = Engine(scene, PARAMS, cache_dir=cache, device="cpu", quiet=True)
    warm = Engine(scene, PARAMS, cache_dir=cache, device="cpu", quiet=True)
    return scene, cache, cold, warm


def test_second_engine_reads_the_artefacts_and_renders_the_same(engines):
    scene, cache, cold, warm = engines
    assert (cold.n_precompute, cold.n_cache_loads) == (3, 0)  # precompute, shafts, SH volume: built
    assert (warm.n_precompute, warm.n_cache_loads) == (0, 3)  # ... and read back, which is no work
    assert warm.cache_hit and len(list(cache.glob("*-shafts-*.npz"))) == len(list(cache.glob("*-sh-*.npz"))) == 1
    a, b = cold.room_light.volume, warm.room_light.volume
    for f in ("origin", "cell", "coeffs", "valid"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
    np.testing.assert_array_equal(cold.room_light.emitters, warm.room_light.emitters)
    # the loaded shafts select the same sources, eyes and weights as the built ones, for boxes all
    # over the room and every budget
    assert warm.shadow_sources.G_v is warm.pre.G_v and warm.shadow_sources.stats() == cold.shadow_sources.stats()
    rng = np.random.default_rng(1)
    lo, hi = scene.room_min, scene.room_max
    for _ in range(6):
        c = rng.uniform(lo, hi)
        for passes in (1, 7, None):
            x, y = cold.shadow_sources.select(c - 0.3, c + 0.3, passes), warm.shadow_sources.select(c - 0.3, c + 0.3,
                                                                                                    passes)
            for f in ("eyes", "W_v", "W_c", "cand"):
                np.testing.assert_array_equal(getattr(x, f), getattr(y, f), err_msg=f)
    for cfg in (FrameConfig(passes=10), FrameConfig(passes=None)):
        np.testing.assert_array_equal(cold.render(scene.obj, cfg).pixels, warm.render(scene.obj, cfg).pixels)


def test_keys_follow_exactly_their_inputs(engines):
    scene, cache, cold, _ = engines
    pre, p = cold.pre, cold.params
    shafts = stage.shadow_sources_key(pre, cold.B_src, p.source_fraction, p.leaf_size, p.shaft_threshold)
    assert shafts == stage.shadow_sources_key(pre, cold.B_src.copy(), p.source_fraction, p.leaf_size,
                                              p.shaft_threshold)
    for changed in (dict(B=cold.B_src * 1.01), dict(fraction=0.7), dict(leaf=4), dict(threshold=0.05),
                    dict(pre=dataclasses.replace(pre, key="another precompute"))):
        k = stage.shadow_sources_key(changed.get("pre", pre), changed.get("B", cold.B_src),
                                     changed.get("fraction", p.source_fraction), changed.get("leaf", p.leaf_size),
                                     changed.get("threshold", p.shaft_threshold))
        assert k != shafts, changed
    pm = pre.patches
    sh = stage.room_light_key(pm, cold.B_src, scene.room_min, scene.room_max, cold.scene_occ, p.volume_spacing)
    for changed in (dict(B=cold.B_src * 1.01), dict(spacing=0.5), dict(room_max=scene.room_max + 0.1),
                    dict(occ=cold.cam_occ)):
        k = stage.room_light_key(pm, changed.get("B", cold.B_src), scene.room_min,
                                 changed.get("room_max", scene.room_max), changed.get("occ", cold.scene_occ),
                                 changed.get("spacing", p.volume_spacing))
        assert k != sh, changed
    # through the engine: a frame knob reuses everything, a shaft knob rebuilds only the shafts,
    # the SH volume's spacing only the volume
    again = Engine(scene, dataclasses.replace(PARAMS, passes=5, map_res=128), cache_dir=cache, device="cpu",
                   quiet=True)
    assert (again.n_precompute, again.n_cache_loads) == (0, 3)
    shaft = Engine(scene, dataclasses.replace(PARAMS, shaft_threshold=0.05), cache_dir=cache, device="cpu",
                   quiet=True)
    assert (shaft.n_precompute, shaft.n_cache_loads) == (1, 2)
    vol = Engine(scene, dataclasses.replace(PARAMS, volume_spacing=0.5), cache_dir=cache, device="cpu", quiet=True)
    assert (vol.n_precompute, vol.n_cache_loads) == (1, 2)
    assert vol.room_light.volume.coeffs.shape != cold.room_light.volume.coeffs.shape


def test_unreadable_artefact_is_rebuilt(engines):
    scene, cache, cold, _ = engines
    for f in cache.glob("*-shafts-*.npz"):
        f.write_bytes(f.read_bytes()[:100])  # truncated
    eng = Engine(scene, PARAMS, cache_dir=cache, device="cpu", quiet=True)
    assert (eng.n_precompute, eng.n_cache_loads) == (1, 2)
    np.testing.assert_array_equal(eng.render(scene.obj, FrameConfig(passes=10)).pixels,
                                  cold.render(scene.obj, FrameConfig(passes=10)).pixels)
    assert Engine(scene, PARAMS, cache_dir=cache, device="cpu", quiet=True).n_cache_loads == 3  # rewritten


def test_store_round_trip_and_no_foreign_classes(tmp_path):
    from kernels.irradiance_volume import IrradianceVolume

    shared = np.arange(6.0)
    vol = IrradianceVolume(np.zeros(3), np.ones(3), np.full((2, 2, 2, 9, 3), 0.5), np.ones((2, 2, 2), bool))
    obj = {"a": (1, 2.5, None, "x"), 3: [np.int64(7), np.float32(0.25), True], "vol": vol, "shared": shared,
           "nested": [[1, 2], []]}
    artefact_cache.save(tmp_path / "o.npz", obj, {"s": shared})
    back = artefact_cache.load(tmp_path / "o.npz", {"s": shared})
    assert back["a"] == (1, 2.5, None, "x") and back["nested"] == [[1, 2], []] and back["shared"] is shared
    assert type(back[3][0]) is np.int64 and back[3][0] == 7 and type(back[3][1]) is np.float32 and back[3][2] is True
    assert isinstance(back["vol"], IrradianceVolume)
    np.testing.assert_array_equal(back["vol"].coeffs, vol.coeffs)
    with pytest.raises(TypeError):
        artefact_cache.save(tmp_path / "f.npz", {"f": open})  # not the project's: not stored
    # a file naming a class outside the project's packages is refused, not instantiated
    artefact_cache.write_npz(tmp_path / "evil.npz", __skeleton__=np.array('{"$obj": "subprocess:Popen", "attrs": {}}'))
    with pytest.raises(ValueError, match="not the project"):
        artefact_cache.load(tmp_path / "evil.npz")
    built, hit = artefact_cache.cached(tmp_path / "evil.npz", lambda: {"rebuilt": 1})
    assert not hit and built == {"rebuilt": 1} and artefact_cache.load(tmp_path / "evil.npz") == {"rebuilt": 1}


def test_probe_response_is_recovered_once_per_bracket(tmp_path, monkeypatch):
    # photo light's response from the probe bracket (lighting.photolight.recover_response, seconds a run) is cached
    # keyed by the bracket's files and times: a second run reads it (the same table, no fit), a changed image or
    # exposure time fits again; the table recovered is the scene's true inverse response in shape (within 5 %
    # over levels 20-235, as tests/lighting/test_photoalbedo.py checks the uncached one)
    import shutil

    import cv2

    from lighting import hdr
    from lighting import photolight as PL
    from tests.conftest import shared_scene

    src = shared_scene("window_room")
    calls = []
    fit = PL.recover_response
    monkeypatch.setattr(PL, "recover_response", lambda f, t: calls.append(1) or fit(f, t))
    files, times, sj = hdr.scene_probe_files(src)
    (tmp_path / "cache").mkdir()
    recover = stage.cached_probe_response(tmp_path / "cache", load_scene(src))
    g1 = recover(files, times)
    g2 = recover(files, times)
    assert len(calls) == 1 and np.array_equal(g1, g2) and g1.shape == (256, 3)
    true_inv = np.asarray(sj["camera_response"]["inverse_table"], float)
    lv = np.arange(20, 236)
    shape = (g1.T[:, lv] / g1.T[:, 128:129]) / (true_inv[:, lv] / true_inv[:, 128:129])
    assert np.abs(shape - 1).max() < 0.05
    # a changed image of the bracket (one pixel a level brighter) and a changed exposure time: each a miss
    moved = [tmp_path / f.name for f in files]
    for f, m in zip(files, moved):
        shutil.copy(f, m)
    img = cv2.imread(str(moved[0]), cv2.IMREAD_UNCHANGED)
    img[0, 0, 0] = min(int(img[0, 0, 0]) + 1, 254) if img[0, 0, 0] < 255 else 254
    cv2.imwrite(str(moved[0]), img)
    recover(moved, times)
    assert len(calls) == 2
    recover(files, [t * 1.01 for t in times])
    assert len(calls) == 3
    recover(files, times)
    assert len(calls) == 3
    assert len(list((tmp_path / "cache").glob("*-response-*.npz"))) == 3


def test_captured_light_reads_the_cached_probe_response(tmp_path, monkeypatch):
    # captured light merges its probe bracket with the response cached per bracket (cached_probe_response, as
    # photo light's): the merged radiance and the table bit for bit those of the uncached merge (merge_bracket's
    # own fit, the same one); a second load reads the table (no fit), and photo light's response of the same
    # bracket is that cached table (no fit either)
    from lighting import hdr
    from lighting import photolight as PL
    from lighting.radiance import load_captured_probe
    from tests.conftest import shared_scene

    src = shared_scene("window_room")
    scene = load_scene(src)
    plain = load_captured_probe(scene)
    calls = []
    fit = PL.recover_response
    monkeypatch.setattr(PL, "recover_response", lambda f, t: calls.append(1) or fit(f, t))
    (tmp_path / "cache").mkdir()
    recover = stage.cached_probe_response(tmp_path / "cache", scene)
    first, second = load_captured_probe(scene, recover), load_captured_probe(scene, recover)
    assert len(calls) == 1 and len(list((tmp_path / "cache").glob("*-response-*.npz"))) == 1
    for p in (first, second):
        np.testing.assert_array_equal(p.radiance, plain.radiance)
        np.testing.assert_array_equal(p.inverse_response, plain.inverse_response)
    files, times, _ = hdr.scene_probe_files(src)
    np.testing.assert_array_equal(recover(files, times), plain.inverse_response)
    assert len(calls) == 1
