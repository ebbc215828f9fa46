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


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a).view(np.uint32 if a.dtype == np.float32 else np.uint64)


def test_cluster_weights_kernel_gives_numpys_bytes(engine):
    # kernels.cluster_weights writes the same float32 weights as the numpy sums it replaced
    # (weights_reference), bit for bit: one whole-block run per node (every source marked) and many runs
    # (random and periodic marks: float64 run sums and raw columns at every run end), plain and near-split keys
    scene, eng = engine
    ss = eng.shadow_sources
    t = ss.src_tree
    assert ss.cluster is not None  # the engine's source list uses the kernel
    v = scene.obj.vertices
    lo, hi = np.floor(v.min(0) * 1e3) / 1e3, np.ceil(v.max(0) * 1e3) / 1e3
    rng = np.random.default_rng(5)
    one_run_seen = set()
    for trial in range(3):
        marked = ss.traverse(lo, hi)[0].copy()
        if trial:
            marked &= rng.random(len(marked)) < 0.5 if trial == 1 else np.arange(len(marked)) % 7 != 3
        key = ss.blocked_key(lo, hi)
        for passes, factor in ((1, None), (7, None), (50, None), (64, ss.near_factor(lo, hi)),
                               (int(marked.sum()) - 1, None)):
            nodes = ss.representatives(marked, passes, key, factor)
            a, b = t.lo[nodes], t.hi[nodes]
            one_run_seen.add(ss._weight_plan(a, b, marked)[-1])
            for got, want in zip(ss.weights(a, b, marked), ss.weights_reference(a, b, marked)):
                assert got.shape == want.shape and got.dtype == want.dtype == np.float32
                np.testing.assert_array_equal(_bits(got), _bits(want), err_msg=f"trial {trial}, {passes} passes")
    assert one_run_seen == {True, False}  # both of the kernel's sums were exercised


def test_cluster_weights_kernel_made_on_the_first_clustered_frame(engine):
    # ShadowSources.cluster, whose G table is a copy of G (57 MB on window_room), is made on the first frame whose
    # passes are clusters, not with the device buffers: an all-sources select leaves it unmade; a select of fewer
    # passes makes it and sums with it (its weights those of weights_reference, bit for bit); later selects keep it
    scene, eng = engine
    ss = eng.shadow_sources
    ss._cluster_made, ss._cluster = False, None  # as use_receivers leaves it (the fixture's engine may have made it)
    v = scene.obj.vertices
    lo, hi = v.min(0), v.max(0)
    every = ss.select(lo, hi, None)
    assert every.n_listed > 20 and ss.__dict__["_cluster"] is None and not ss._cluster_made
    calls = []
    weights = ss.weights
    ss.weights = lambda *a, **k: calls.append(a) or weights(*a, **k)
    try:
        fs = ss.select(lo, hi, 20)
    finally:
        del ss.weights
    assert ss._cluster_made and len(calls) == 1
    made = ss.__dict__["_cluster"]
    assert made is not None and ss.cluster is made
    got, want = ss.weights(*calls[0][:3]), ss.weights_reference(*calls[0][:3])
    np.testing.assert_array_equal(fs.W_v, want[0])
    for g, w in zip(got, want):
        np.testing.assert_array_equal(_bits(g), _bits(w))
    ss.select(lo + 0.1, hi + 0.1, 20)
    assert ss.cluster is made


def test_shaft_traversal_kernel_lists_numpys_shafts_in_order(engine):
    # kernels.shaft_traverse: the leaf shafts of the numpy level-by-level traversal, in its order, for the
    # object's box along a drag, boxes anywhere in the room (small to room-sized), and one outside it
    from app.dragpath import drag_offsets

    scene, eng = engine
    sh = eng.shadow_sources.shafts
    assert getattr(sh, "_kernel", None) is not None
    v = scene.obj.vertices
    boxes = [(v.min(0) + o, v.max(0) + o) for o in drag_offsets(scene, scene.obj, 5)]
    rng = np.random.default_rng(7)
    span = scene.room_max - scene.room_min
    for size in (0.02, 0.3, 1.0):
        for _ in range(4):
            c = scene.room_min + rng.random(3) * span
            boxes.append((c - size * rng.random(3), c + size * rng.random(3)))
    boxes += [(scene.room_min, scene.room_max), (scene.room_max + 1.0, scene.room_max + 2.0)]
    hits = 0
    for lo, hi in boxes:
        for keep_weak in (True, False):
            got, want = sh.traverse(lo, hi, keep_weak), sh.traverse_reference(lo, hi, keep_weak)
            np.testing.assert_array_equal(got[0], want[0])
            np.testing.assert_array_equal(got[1], want[1])
            hits += len(got[0])
    assert hits > 0 and len(sh.traverse(*boxes[-1])[0]) == 0  # boxes in the room meet shafts, the outside one none


def test_blocked_key_shares_made_once_equal_the_per_frame_form(engine):
    # blocked_key's per-block shares (made on its first call, kept) give the key of the per-frame formula
    scene, eng = engine
    ss = eng.shadow_sources
    v = scene.obj.vertices
    for off in (0.0, 0.4):
        lo, hi = v.min(0) + off, v.max(0) + off
        got = ss.blocked_key(lo, hi)
        so, k = ss.src_ids, ss.block
        starts = np.arange(0, len(so), k)
        size = np.diff(np.append(starts, len(so)))
        wsum = np.add.reduceat(ss.strength, starts)
        share = np.where(np.repeat(wsum, size) > 0, ss.strength / np.repeat(np.where(wsum > 0, wsum, 1), size),
                         1.0 / np.repeat(size, size))
        want = np.repeat(ss.blocked(lo, hi), size) * share
        np.testing.assert_array_equal(got, want)
        assert got.sum() > 0


def test_cuts_are_numpys_unique_and_searchsorted():
    # _pairs' cuts by flags: the sorted distinct values of 0, size and the bounds, and each bound's index in
    # them, as np.unique and np.searchsorted give them (random bounds, repeats, the ends, an empty list)
    from lighting.frame_sources import _cuts

    rng = np.random.default_rng(3)
    for size, m in ((1045, 7407), (63, 200), (5, 0), (1, 3)):
        lo, hi = rng.integers(0, size + 1, m), rng.integers(0, size + 1, m)
        cuts, at = _cuts(size, lo, hi)
        want = np.unique(np.concatenate([[0, size], lo, hi]))
        np.testing.assert_array_equal(cuts, want)
        np.testing.assert_array_equal(at[lo], np.searchsorted(want, lo))
        np.testing.assert_array_equal(at[hi], np.searchsorted(want, hi))
        assert at[size] == len(want) - 1 and at[0] == 0
