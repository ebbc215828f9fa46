"""app.stages.second_order.blocked_pass: the second order's (receiver, patch) pairs the object blocks,
against a ray per pair in numpy (analytic geometry, no scene needed)."""
import numpy as np

from app.stages import second_order as SO
from app.stages.second_order import blocked_pass
from kernels.visibility import Occluder
from tests.conftest import segments_blocked


def _cube(c, h):
    """A closed cube (centre c, half side h): vertices (8,3), faces (12,3)."""
    c = np.asarray(c, float)
    v = np.array([[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)]) + c
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def test_blocked_pairs_are_the_ones_the_object_hides(monkeypatch):
    # receivers on a wall (z = 0, facing +z), changed patches on the floor (y = 0) in front of it, a cube
    # (the object) between some of them: the pass over the blocked pairs equals G_v dB summed over the
    # pairs a ray per pair finds blocked, and nothing where the cube hides nothing
    recv, rn, cen, pn, area, dB, G_v = _wall_floor_case(seed=0, n_recv=200, n_side=9, area=0.0625,
                                                        lit_and_zero=False)
    v, f = _cube([0.0, 0.3, 1.0], 0.2)
    occ = Occluder(v, f, "cpu")
    sphere = (np.array([0.0, 0.3, 1.0]), 0.2 * np.sqrt(3))
    blk = segments_blocked(v, f, recv + rn * 1e-3, cen + pn * 1e-3)  # (200, P) bool, a ray per pair
    want = (G_v * blk) @ dB
    assert blk.sum() > 100 and (~blk).sum() > 1000  # the cube hides some pairs, not most
    # every changed patch tested: the ray-per-pair sum
    monkeypatch.setattr(SO, "KEEP", 1.0)
    np.testing.assert_allclose(blocked_pass(dB, G_v, recv, rn, cen, pn, area, occ, sphere), want,
                               rtol=1e-9, atol=1e-12)
    # the patches holding 99 % of the change's power tested: within 1 % of the whole change's pass
    monkeypatch.setattr(SO, "KEEP", 0.99)
    out = blocked_pass(dB, G_v, recv, rn, cen, pn, area, occ, sphere)
    assert np.abs(out - want).max() <= 0.01 * np.abs(G_v @ dB).max()
    # the cube moved off the segments (behind the wall): no pair is blocked
    v2, _ = _cube([0.0, 0.3, -1.0], 0.2)
    assert blocked_pass(dB, G_v, recv, rn, cen, pn, area, Occluder(v2, f, "cpu"),
                        (np.array([0.0, 0.3, -1.0]), 0.2 * np.sqrt(3))) is None


def _wall_floor_case(seed: int = 1, n_recv: int = 300, n_side: int = 11, area: float = 0.04,
                     lit_and_zero: bool = True):
    """Receivers on a wall (z = 0, facing +z), changed patches on the floor (y = 0) in front of it, G_v
    and dB drawn at random; with lit_and_zero, some patches the object lights (a positive change) and
    some zero G_v."""
    rng = np.random.default_rng(seed)
    recv = np.stack([rng.uniform(-1, 1, n_recv), rng.uniform(0.05, 1.5, n_recv), np.zeros(n_recv)], 1)
    rn = np.tile([0.0, 0.0, 1.0], (n_recv, 1))
    xs, zs = np.meshgrid(np.linspace(-1, 1, n_side), np.linspace(0.5, 2.5, n_side))
    cen = np.stack([xs.ravel(), np.zeros(xs.size), zs.ravel()], 1)
    pn = np.tile([0.0, 1.0, 0.0], (len(cen), 1))
    areas = np.full(len(cen), area)
    dB = np.zeros((len(cen), 3))
    dB[:, 0] = -rng.uniform(0.1, 1.0, len(cen))
    dB[:, 1] = 0.5 * dB[:, 0]
    G_v = rng.uniform(0.0, 1e-3, (n_recv, len(cen)))
    if lit_and_zero:
        dB[::7] *= -0.3
        G_v = G_v * (rng.uniform(size=(n_recv, len(cen))) > 0.1)
    return recv, rn, cen, pn, areas, dB, G_v


def test_kernel_equals_the_numpy_reference(monkeypatch):
    # BlockedSecondOrder (one Warp launch) against blocked_pass (numpy pair search + a ray per candidate):
    # the same blocked pairs, so the same sums up to float32 rounding (rtol 1e-5), with the upright box and
    # with an oriented box about a turned cube, at KEEP 1 and 0.99, and None where nothing is blocked
    from app.stages.second_order import BlockedSecondOrder
    from app.stages.sun import upright_box

    recv, rn, cen, pn, area, dB, G_v = _wall_floor_case()
    kern = BlockedSecondOrder(G_v, recv, rn, cen, pn, area, "cpu")
    v, f = _cube([0.1, 0.3, 1.2], 0.25)
    c = np.array([0.1, 0.3, 1.2])
    turn = np.array([[np.cos(0.5), 0.0, np.sin(0.5)], [0.0, 1.0, 0.0], [-np.sin(0.5), 0.0, np.cos(0.5)]])
    for verts in (v, (v - c) @ turn.T + c):
        occ = Occluder(verts, f, "cpu")
        sphere = (c, 0.25 * np.sqrt(3) + 1e-6)
        box = (verts.min(0) - 1e-3, verts.max(0) + 1e-3)
        for keep in (1.0, 0.99):
            monkeypatch.setattr(SO, "KEEP", keep)
            want = blocked_pass(dB, G_v, recv, rn, cen, pn, area, occ, sphere)
            assert want is not None and np.abs(want).max() > 1e-4
            for obb in (None, upright_box(verts)):
                got = kern(dB, occ, box, obb=obb)
                np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-9 * np.abs(want).max())
    v2, _ = _cube([0.0, 0.3, -1.0], 0.2)
    assert kern(dB, Occluder(v2, f, "cpu"), (v2.min(0), v2.max(0))) is None
    assert kern(np.zeros_like(dB), Occluder(v, f, "cpu"), (v.min(0), v.max(0))) is None
