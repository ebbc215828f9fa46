"""The sun's changes passed on by the bounces each has left, and its loss not counted twice where the
object also hides the shadowed floor (app.stages.sun.SunStage.later_bounces / first_pass_blocked)."""
import numpy as np
import pytest

from recon.scene import load_scene
from tests.conftest import segments_blocked, shared_scene


@pytest.fixture(scope="module")
def coarse(tmp_path_factory):
    from app.engine import Engine, EngineParams, FrameConfig

    s = load_scene(shared_scene("sun_room"), load_textures=False)
    e = Engine(s, EngineParams(patch_size=0.4, emitter_patch_size=0.3), cache_dir=tmp_path_factory.mktemp("c"),
               quiet=True)
    e.render(s.obj, FrameConfig(passes=8))
    return s, e


def _sun_loss(coarse):
    """The sun's loss at the object's pose as first_pass_blocked takes it: (engine, patches, sun stage,
    dB1 (P,3) the patches' change, the proxy (pv, pf, its occluder), its box grown 1 mm, receiver points)."""
    s, e = coarse
    pm, st = e.pre.patches, e.sun_pixels.stage
    _, loss_c = st.frame(s.obj.vertices, s.obj.faces)
    pv, pf, occ, _, _ = e.object_shading.object_shape(s.obj)
    box = (pv.min(0) - 1e-3, pv.max(0) + 1e-3)
    return e, pm, st, -pm.albedo * loss_c, (pv, pf, occ), box, pm.vert_inset[e.pre.recv_vert]


def _dense(e, dB, passes):
    """G_v sum_{k=1}^{passes} (rho G)^k dB with the dense matrices."""
    pm = e.pre.patches
    G, G_v = e.pre.G_c.astype(np.float64), e.pre.G_v.astype(np.float64)
    cur, more = dB, np.zeros_like(dB)
    for _ in range(passes):
        cur = pm.albedo * (G @ cur)
        more += cur
    return G_v @ more


def test_each_change_gets_the_bounces_it_has_left(coarse):
    # the sun's loss (one reflection made) gets bounces-2 later passes, the sunlit object's light at the
    # patches (two made: sun -> object -> patch) bounces-3: with 4 bounces, 2 and 1 passes
    s, e = coarse
    pm = e.pre.patches
    loss, loss_c = e.sun_pixels.stage.frame(s.obj.vertices, s.obj.faces)
    dB1 = -pm.albedo * loss_c
    dB2 = np.zeros_like(dB1)
    near = np.linalg.norm(pm.centre - s.obj.vertices.mean(0), axis=1) < 1.0
    dB2[near & ~pm.is_emitter] = 0.05 * pm.albedo[near & ~pm.is_emitter]
    ours = e.sun_pixels.stage.later_bounces(dB1, pm.albedo, e.pre.G_c, e.pre.G_v, 4, dB2=dB2)
    ref = _dense(e, dB1, 2) + _dense(e, dB2, 1)
    err = np.abs(ours - ref).sum() / np.abs(ref).sum()
    assert err < 0.02, err
    # the same passes left at the patches (onto: the caller's one pass through G_v carries them)
    onto = np.zeros_like(dB1)
    assert e.sun_pixels.stage.later_bounces(dB1, pm.albedo, e.pre.G_c, e.pre.G_v, 4, dB2=dB2, onto=onto) is None
    assert np.allclose(e.pre.G_v.astype(np.float64) @ onto, ours, rtol=1e-4, atol=1e-5 * np.abs(ours).max())
    # the object's light alone: one later pass, not two (the count before: a fifth bounce)
    ours2 = e.sun_pixels.stage.later_bounces(0 * dB1, pm.albedo, e.pre.G_c, e.pre.G_v, 4, dB2=dB2)
    one, two = _dense(e, dB2, 1), _dense(e, dB2, 2)
    assert np.abs(ours2 - one).sum() < 0.25 * np.abs(two - one).sum()  # measured: 0.03 of it
    assert e.sun_pixels.stage.later_bounces(dB1, pm.albedo, e.pre.G_c, e.pre.G_v, 2, dB2=dB2) is None


def test_later_bounces_at_the_patches_for_the_object(coarse):
    # what the object gathers of its own sun shadow's later bounces: sum_{k=1}^{bounces-2} (rho G)^k dB1 at
    # every patch (the walls and ceiling the shadowed floor no longer lights), against the dense sum; on
    # sun_room's walls it is a sizeable share of the loss itself (the chair's back faced it in sun_101)
    s, e = coarse
    pm, st = e.pre.patches, e.sun_pixels.stage
    _, loss_c = st.frame(s.obj.vertices, s.obj.faces)
    dB1 = -pm.albedo * loss_c
    ours = st.later_at_patches(dB1, pm.albedo, e.pre.G_c, e.pre.G_v, 4)
    G = e.pre.G_c.astype(np.float64)
    one = pm.albedo * (G @ dB1)
    ref = one + pm.albedo * (G @ one)
    err = np.abs(ours - ref).sum() / np.abs(ref).sum()
    assert err < 0.05, err  # the passes after the first from the sunlit patches run on clusters
    lum = np.array([0.2126, 0.7152, 0.0722])
    ratio = ((ours @ lum) @ pm.area) / ((dB1 @ lum) @ pm.area)  # darker, and of the loss's own size (sun_room
    assert 0.3 < ratio < 2.0, ratio  # at the default patches: 1.0; rho G keeps power up to the albedo, 2 passes)
    assert st.later_at_patches(dB1, pm.albedo, e.pre.G_c, e.pre.G_v, 2) is None
    assert st.later_at_patches(0 * dB1, pm.albedo, e.pre.G_c, e.pre.G_v, 4) is None


def test_blocked_first_pass_matches_rays_to_every_lost_sample(coarse):
    # first_pass_blocked puts a sunlit patch's loss at the loss-weighted centre of its lost sample
    # points: against one ray per (receiver vertex, lost sample point) through the object's mesh
    e, pm, st, dB1, (pv, pf, occ), box, recv = _sun_loss(coarse)
    blk_v, blk_c = st.first_pass_blocked(occ, box, dB1, e.pre.G_c, e.pre.G_v, recv)
    # reference: every lost sample point as its own target, with its patch's transfer
    K = st.c_vis.shape[1]
    lost = st.lost
    i, k = np.nonzero(lost > 0)
    pts = st.c_pts.reshape(len(st.c_patch), K, 3)[i, k]
    w = (lost[i, k] / K)[:, None] * pm.albedo[st.c_patch[i]] * st.E_perp  # (M,3): minus each point's dB1 share
    hit = segments_blocked(pv, pf, recv, pts)
    Gs = e.pre.G_v[:, st.c_patch[i]].astype(np.float64)
    ref = -(Gs * hit) @ w
    total = -Gs @ w  # the whole first pass of the loss
    assert np.allclose(total, e.pre.G_v.astype(np.float64) @ dB1, rtol=1e-6, atol=1e-9)
    share = ref[:, 1].sum() / total[:, 1].sum()
    assert 0.02 < share < 0.5, share  # the object hides a real share of the shadowed floor here
    # one centre per 0.4 m patch (this coarse engine) against a ray per sample point: measured 0.87 of
    # the total, per-vertex correlation 0.82 on the vertices that carry it
    assert blk_v[:, 1].sum() == pytest.approx(ref[:, 1].sum(), rel=0.2)
    m = np.abs(ref[:, 1]) > 0.1 * np.abs(ref[:, 1]).max()
    assert m.sum() > 20 and np.corrcoef(blk_v[m, 1], ref[m, 1])[0, 1] > 0.7
    # the patch centres: the same pairs seen from G's rows
    assert np.abs(blk_c).sum() > 0 and np.all(blk_c <= 1e-12)


def test_two_bounces_correct_only_the_first_pass(coarse):
    # with 2 bounces there is no later pass: only the receivers' first pass of the loss loses the pairs
    # the object blocks, nothing is given back at the patches
    e, pm, st, dB1, (pv, pf, occ), box, recv = _sun_loss(coarse)
    first = np.zeros_like(dB1)
    out = st.later_bounces(dB1, pm.albedo, e.pre.G_c, e.pre.G_v, 2, occluder=occ, recv_points=recv, box=box,
                           first=first)
    blk_v, = st.first_pass_blocked(occ, box, dB1, e.pre.G_c, e.pre.G_v, recv, at_patches=False)
    assert not first.any() and np.abs(blk_v).sum() > 0 and np.allclose(out, -blk_v)
    out4 = st.later_bounces(dB1, pm.albedo, e.pre.G_c, e.pre.G_v, 4, occluder=occ, recv_points=recv, box=box,
                            first=first)
    assert first.sum() > 0 and np.all(first >= 0) and not np.allclose(out4, -blk_v)  # light given back


def test_patches_blocked_pairs_from_cluster_centres_match_rays_to_every_lost_sample(coarse):
    # first_pass_blocked tests the patches' pairs (G's pass of the loss over the pairs the object blocks, given
    # back at the patches and passed once through G_v) from their cluster's centre: at the receiver
    # vertices, against one ray per (patch centre, lost sample point), about as close as one ray per
    # (patch centre, loss-weighted centre)
    from app.stages.sun import _weighted_centres

    e, pm, st, dB1, (pv, pf, occ), box, recv = _sun_loss(coarse)
    _, blk_c = st.first_pass_blocked(occ, box, dB1, e.pre.G_c, e.pre.G_v, recv)
    K = st.c_vis.shape[1]
    lost = st.lost
    pts = st.c_pts.reshape(len(st.c_patch), K, 3)
    alive = pm.albedo.any(1)[:, None]
    G_s = e.pre.G_c[:, st.c_patch].astype(np.float64) * alive
    rows = pm.centre + pm.normal * 1e-3
    i, k = np.nonzero(lost > 0)
    hit = segments_blocked(pv, pf, rows, pts[i, k])
    w = -(lost[i, k] / K)[:, None] * pm.albedo[st.c_patch[i]] * st.E_perp
    ref = (G_s[:, i] * hit) @ w
    # the rows it replaced: one ray per (patch centre, its patch's loss-weighted centre)
    per_patch = (G_s * segments_blocked(pv, pf, rows, _weighted_centres(lost, pts))) @ dB1[st.c_patch]
    G_v = e.pre.G_v.astype(np.float64)
    at_v = [G_v @ (pm.albedo * x) for x in (ref, blk_c, per_patch)]
    err = [np.abs(x[:, 1] - at_v[0][:, 1]).sum() / np.abs(at_v[0][:, 1]).sum() for x in at_v[1:]]
    whole = G_v @ (pm.albedo * (G_s @ (dB1[st.c_patch])))
    assert np.abs(at_v[0][:, 1]).sum() > 0.02 * np.abs(whole[:, 1]).sum()  # a blocked share worth testing
    # measured: 0.17 from the cluster centres, 0.24 from the patch centres (sun_room, the full engine's drag:
    # 0.07-0.18 against 0.06-0.17)
    assert err[0] < 0.25 and err[0] < 1.2 * err[1], err


def test_passes_through_q_are_the_matrix_products():
    # LaterBounces' pass Q_c x_c per channel (row-by-vector dot products) equals the matrix product, to float32
    from app.stages.sun import _pass

    rng = np.random.default_rng(0)
    Q = rng.random((3, 300, 300)).astype(np.float32)
    x = rng.normal(size=(3, 300)).astype(np.float32)
    got = _pass(Q, x)
    ref = np.stack([Q[c].astype(np.float64) @ x[c].astype(np.float64) for c in range(3)])
    assert got.shape == (3, 300) and got.dtype == np.float32
    assert np.abs(got - ref).max() <= 1e-5 * np.abs(Q).sum(2).max() * np.abs(x).max()



def test_sunlit_patch_eye_at_its_light_centroid(coarse):
    # the shadow pass hides a source patch's whole radiance at its one eye; a sunlit patch's sun lies on its
    # sunlit sample points only (its edge, the object's shadow), the rest of its light over the whole patch:
    # the eye is that light's centroid, the mean of its sample points weighted by each one's light
    # (SunStage.source_eyes), and the engine's shadow sources use it
    from types import SimpleNamespace

    from app.stages.sun import SunStage
    from recon.response import luminance

    # one 0.1 m patch, 4 x 4 sample points, its x < 0.05 half sunlit; E_sun/pi 3 (grey), albedo 0.5, the rest 0.5
    f = (np.arange(4) + 0.5) / 4 * 0.1
    x, z = [a.ravel() for a in np.meshgrid(f, f)]
    pts = np.stack([x, np.full(16, 1e-3), z], 1)
    vis = (x < 0.05).astype(float)
    st = SimpleNamespace(c_vis=vis[None], c_pts=pts, c_patch=np.array([0]), E_perp=np.full(3, 3.0))
    albedo, eye0 = np.full((1, 3), 0.5), np.array([[0.05, 1e-3, 0.05]])
    B = albedo * 3.0 * vis.mean() + 0.5  # sun 0.75 + the rest 0.5
    ids, eyes = SunStage.source_eyes(st, B, albedo, eye0)
    w = 1.5 * vis + 0.5  # each point's light: its sun, and its share of the rest
    assert ids.tolist() == [0]
    assert np.allclose(eyes[0], (w[:, None] * pts).sum(0) / w.sum(), atol=1e-9)  # x = 0.035, not 0.05
    # a patch the sun lights whole keeps its centre
    st.c_vis = np.ones((1, 16))
    _, eyes = SunStage.source_eyes(st, albedo * 3.0 + 0.5, albedo, eye0)
    assert np.allclose(eyes[0], eye0[0], atol=1e-9)
    # the engine's sources: every sunlit patch's eye moved so, none other
    s, e = coarse
    st = e.sun_pixels.stage
    ids, eyes = st.source_eyes(e.shadow_sources.B, e.pre.patches.albedo,
                               e.pre.patches.centre + e.pre.patches.normal * 1e-3)
    assert len(ids) > 5
    assert np.allclose(e.shadow_sources.eye_pos[ids], eyes, atol=1e-9)
    moved = np.linalg.norm(e.shadow_sources.eye_pos - (e.pre.patches.centre + e.pre.patches.normal * 1e-3), axis=1)
    assert moved.max() > 0.01 and np.all(moved[np.setdiff1d(np.arange(len(moved)), ids)] < 1e-9)
    assert luminance(e.shadow_sources.B[ids]).min() > 0
