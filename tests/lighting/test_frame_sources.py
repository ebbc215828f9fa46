"""The all-sources frame's source list (lighting.frame_sources): its single-source transfers read
from the per-scene table (ShadowSources.keep_single_transfers) equal the per-frame products they
replace, bit for bit, for a list of every source (the table's own rows) and for a partial list
(ColumnView); a table over its memory bound falls back to the per-frame products; the receiver
pairs on the coarse grid of the rectangles' edges equal a dense count; and a composited
all-sources frame is the same with the table and without it."""
import copy

import numpy as np
import pytest

from lighting.frame_sources import ColumnView, _column_transfers

DEMO = dict(patch_size=0.35, emitter_patch_size=0.2)


@pytest.fixture(scope="module")
def engine(tmp_path_factory):
    from app.cli import demo_scene_dir
    from app.engine import Engine, EngineParams
    from recon.scene import load_scene

    scene = load_scene(demo_scene_dir())
    eng = Engine(scene, EngineParams(**DEMO), cache_dir=tmp_path_factory.mktemp("cache"), device="cpu", quiet=True)
    return scene, eng


def _old(ss, ids):
    """The per-frame transfers of one pass per source `ids` (the code before the table)."""
    B = ss.B[ids].astype(np.float32)
    return _column_transfers(ss.G_v, ids, B), _column_transfers(ss.G_c, ids, B)


def test_all_sources_transfers_come_from_the_table_unchanged(engine):
    scene, eng = engine
    ss = eng.shadow_sources
    assert ss.single is not None and ss.stats()["single_table_mb"] > 0
    v = scene.obj.vertices
    fs = ss.select(v.min(0), v.max(0), None)
    marked = ss.traverse(v.min(0), v.max(0))[0]
    ids = ss.src_ids[np.flatnonzero(marked)]
    assert marked.all() and len(ids) == fs.W_v.shape[1] > 1  # a room: every box meets every source
    W_v, W_c = _old(ss, ids)
    np.testing.assert_array_equal(fs.W_v, W_v)
    np.testing.assert_array_equal(fs.W_c, W_c)
    # the table's own rows: no copy per frame, read-only
    assert np.shares_memory(fs.W_v, ss.single) and np.shares_memory(fs.W_c, ss.single)
    assert not fs.W_v.flags.writeable and fs.W_v.dtype == fs.W_c.dtype == np.float32


def test_a_partial_list_reads_its_columns_of_the_table(engine):
    scene, eng = engine
    ss = eng.shadow_sources
    rng = np.random.default_rng(3)
    pos = np.sort(rng.choice(len(ss.src_ids), len(ss.src_ids) // 3, replace=False))
    ids = ss.src_ids[pos]
    W_v, W_c = ss._single_transfers(ids, pos=pos)
    got_v, got_c = ss._single_transfers(ids)  # the positions found from the ids
    assert isinstance(W_v, ColumnView) and isinstance(W_c, ColumnView)
    want_v, want_c = _old(ss, ids)
    for view, want in ((W_v, want_v), (W_c, want_c), (got_v, want_v), (got_c, want_c)):
        assert view.shape == want.shape and view.dtype == want.dtype and len(view) == len(want)
        np.testing.assert_array_equal(np.asarray(view), want)
        # every way the consumers index it (app.stages.shadow_pass, compose) gives numpy's answer
        rows = rng.choice(len(want), 17, replace=False)
        mask = rng.random(len(want)) < 0.3
        for key in ((slice(None), slice(5, 21)), (rows, slice(3, 40)), (slice(2, 9), rows[:5] % want.shape[1]),
                    (rows, rows % want.shape[1]), (mask, slice(None, 7)), (4, slice(1, 3)), (slice(None), 6),
                    rows, slice(-5, None), (slice(None, None, -2), slice(0, 4)), (-1, -1), (Ellipsis, 0)):
            np.testing.assert_array_equal(view[key], want[key], err_msg=str(key))
        np.testing.assert_array_equal(np.ones(3, np.float32) * view, want)  # arithmetic: the full array


def test_a_table_over_its_memory_bound_falls_back_to_per_frame_transfers(engine):
    scene, eng = engine
    ss = copy.copy(eng.shadow_sources)
    assert not ss.keep_single_transfers(max_bytes=ss.single.nbytes - 1) and ss.single is None
    assert ss.stats()["single_table_mb"] == 0.0
    v = scene.obj.vertices
    fs = ss.select(v.min(0), v.max(0), None)
    W_v, W_c = _old(ss, ss.src_ids)
    np.testing.assert_array_equal(fs.W_v, W_v)
    np.testing.assert_array_equal(fs.W_c, W_c)
    assert not isinstance(fs.W_v, ColumnView)


def test_receiver_pairs_equal_a_dense_count(engine):
    # random rectangles of (receiver leaves, passes), as the leaf shafts give them
    _, eng = engine
    ss = eng.shadow_sources
    L = ss.n_recv_leaves
    rng = np.random.default_rng(0)
    for n, m in ((1, 1), (7, 30), (200, 500), (50, 0)):
        l_lo = rng.integers(0, L, m)
        l_hi = np.minimum(l_lo + rng.integers(1, max(2, L // 3), m), L)
        k_lo = rng.integers(0, n, m)
        k_hi = np.minimum(k_lo + rng.integers(1, max(2, n // 2), m), n)
        dense = np.zeros((L, n), bool)
        for a, b, c, d in zip(l_lo, l_hi, k_lo, k_hi):
            dense[a:b, c:d] = True
        want = np.zeros((ss.P, n), bool)
        inside = ss.leaf_of_recv >= 0
        want[inside] = dense[ss.leaf_of_recv[inside]]
        got = ss._pairs(l_lo, l_hi, k_lo, k_hi, n)
        assert got.shape == (ss.P, n) and got.dtype == bool
        np.testing.assert_array_equal(got, want)


def test_the_all_sources_frame_is_the_same_with_and_without_the_table(engine):
    from app.engine import FrameConfig

    scene, eng = engine
    with_table = eng.render(scene.obj, FrameConfig(passes=None))
    ss = eng.shadow_sources
    table = ss.single
    try:
        ss.single = None
        ss._single = None
        without = eng.render(scene.obj, FrameConfig(passes=None))
    finally:
        ss.single = table
    assert with_table.stats["passes"] == without.stats["passes"] > 1
    np.testing.assert_array_equal(with_table.radiance, without.radiance)
    np.testing.assert_array_equal(with_table.pixels, without.pixels)


def test_near_factor_is_a_node_extent_over_its_distance_to_the_box(engine):
    # near_factor: 1 + min((node box diagonal) / max(distance between the node's box and the object's,
    # NEAR_FLOOR_M), NEAR_MAX_RATIO), against a box-to-box distance computed axis by axis for each node
    from lighting.frame_sources import NEAR_FLOOR_M, NEAR_MAX_RATIO

    scene, eng = engine
    ss = eng.shadow_sources
    t = ss.src_tree
    v = scene.obj.vertices
    lo, hi = v.min(0), v.max(0)
    f = ss.near_factor(lo, hi)
    size = np.linalg.norm(t.box_max - t.box_min, axis=1)
    # the gap between two boxes: per axis, how far apart their intervals are (0 where they overlap)
    d = np.array([np.sqrt(sum(max(0.0, t.box_min[n, a] - hi[a], lo[a] - t.box_max[n, a]) ** 2 for a in range(3)))
                  for n in range(t.n_nodes)])
    np.testing.assert_allclose(f, 1 + np.minimum(size / np.maximum(d, NEAR_FLOOR_M), NEAR_MAX_RATIO), rtol=1e-12)
    assert (f >= 1).all() and f[0] == 1 + NEAR_MAX_RATIO  # the root holds the box
    far = d > size  # nodes farther than their own size: below the cap, the plain ratio
    assert far.any() and np.allclose(f[far], 1 + size[far] / d[far], rtol=1e-12)


def test_near_split_splits_the_clusters_beside_the_object_first(engine):
    # with the same pass budget, the drag frame's rule (near_split) leaves the sources nearest the object's
    # box in smaller clusters than the plain key: the nodes within 0.3 m of the box hold fewer members each
    scene, eng = engine
    ss = eng.shadow_sources
    t = ss.src_tree
    v = scene.obj.vertices
    lo, hi = np.floor(v.min(0) * 1e3) / 1e3, np.ceil(v.max(0) * 1e3) / 1e3
    marked = ss.traverse(lo, hi)[0]
    key = ss.blocked_key(lo, hi)
    passes = 16
    assert marked.sum() > 4 * passes
    plain = ss.representatives(marked, passes, key)
    near = ss.representatives(marked, passes, key, ss.near_factor(lo, hi))
    assert len(plain) == len(near) == passes
    for nodes in (plain, near):  # both cover every marked source once
        cover = np.zeros(len(marked), int)
        for n in nodes:
            cover[t.lo[n]:t.hi[n]] += 1
        assert (cover[marked] == 1).all()
    pos_near = ss.near_factor(lo, hi) > 1 + np.linalg.norm(t.box_max - t.box_min, axis=1) / 0.3  # within 0.3 m

    def members_near(nodes):
        c = [marked[t.lo[n]:t.hi[n]].sum() for n in nodes if pos_near[n]]
        return np.mean(c) if c else 0.0

    assert any(pos_near[n] for n in near)
    assert members_near(near) < members_near(plain)
    # and the frame that uses it has as many passes
    fs = ss.select(v.min(0), v.max(0), passes, near_split=True)
    assert len(fs.eyes) == passes and fs.W_v.shape[1] == passes
