"""The shading mesh cut along the contact lines between the object's own parts (issue 34: window_106's and sun_104's
seat in front of the chair's back).

A constructed chair (test_own_contacts' seat box, top at y = 0.46, and back box standing on its rear, the back's
front face at z = -0.19; four legs, so that it has roomgen's chair's 72 faces and is subdivided as that chair is).
The subdivided seat top has rows of vertices at z = -0.23 (under the back: buried, filled from its neighbours),
-0.115, 0, ...: the seat's visible strip in front of the back (z -0.19 .. -0.115) was a blend of the row 0.075 m
forward, flat, where the truth darkens towards the back. Under a uniform sky of radiance 1 (no bounce) a point of
the seat top s m in front of the back has irradiance / pi = 1 - F(s), F the form factor of the back's front face
(Lambert's polygon formula, exact): 0.517 at 0.01 m, 0.552 at 0.03 m, 0.602 at 0.06 m. Main gives 0.641 / 0.639 /
0.638 there (flat, 0.12 over at 0.01 m: fails); cut, the seat top has a row on the contact line, shaded 8.5 mm in
front of the back (own_contacts: 0.516 there against the exact 0.515), and the strip gives 0.534 / 0.566 / 0.616.
"""
import numpy as np
import pytest

from tests.app.test_own_contacts import BACK_FRONT, BACK_REAR, BACK_TOP, HALF, SEAT_Y, _box, _sky


def _back_form_factor(s: float) -> float:
    """Form factor from a point of the seat top (x = 0, s m in front of the back's front face, normal +y) to the
    back's front face above the seat (Lambert: (1 / 2 pi) sum over the polygon's edges of angle x normal cosine)."""
    p = np.array([0.0, SEAT_Y, BACK_FRONT + s])
    poly = np.array([[-HALF, SEAT_Y, BACK_FRONT], [HALF, SEAT_Y, BACK_FRONT], [HALF, BACK_TOP, BACK_FRONT],
                     [-HALF, BACK_TOP, BACK_FRONT]]) - p
    poly /= np.linalg.norm(poly, axis=1, keepdims=True)
    total = 0.0
    for i in range(4):
        a, b = poly[i], poly[(i + 1) % 4]
        c = np.cross(a, b)
        total += np.arccos(np.clip(a @ b, -1, 1)) * c[1] / np.linalg.norm(c)
    return abs(total) / (2 * np.pi)


def _parts() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seat, back and four legs 0.045 m square as one mesh (not subdivided): 72 faces, as roomgen's chair, so the
    shading mesh's budget (3000 faces) subdivides it as it does that chair (rows 0.115 m apart)."""
    leg = 0.045
    parts = [_box((-HALF, SEAT_Y - 0.05, -HALF), (HALF, SEAT_Y, HALF)),
             _box((-HALF, SEAT_Y, BACK_REAR), (HALF, BACK_TOP, BACK_FRONT))]
    parts += [_box((x0, 0.0, z0), (x0 + leg, SEAT_Y - 0.05, z0 + leg)) for x0 in (-HALF, HALF - leg)
              for z0 in (-HALF, HALF - leg)]
    offsets = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
    return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
            np.concatenate([p[2] + o for p, o in zip(parts, offsets)]))


def _seat_top(v, n, f, values, depths) -> np.ndarray:
    """Mean of the per-vertex values (V,) interpolated on the seat's top at each depth in front of the back."""
    out = []
    for s in depths:
        z = BACK_FRONT + s
        acc = []
        for face in f:
            c = v[face]
            if not (np.allclose(n[face], [0, 1, 0]) and np.allclose(c[:, 1], SEAT_Y)):
                continue
            for x in np.linspace(-0.15, 0.15, 21):  # away from the seat's side edges
                a, b, cc = c
                M = np.array([[b[0] - a[0], cc[0] - a[0]], [b[2] - a[2], cc[2] - a[2]]])
                if abs(np.linalg.det(M)) < 1e-12:
                    continue
                u, w = np.linalg.solve(M, [x - a[0], z - a[2]])
                if u >= -1e-9 and w >= -1e-9 and u + w <= 1 + 1e-9:
                    acc.append((1 - u - w) * values[face[0]] + u * values[face[1]] + w * values[face[2]])
        out.append(np.mean(acc))
    return np.array(out)


def test_seat_top_is_cut_along_the_back_and_nothing_else():
    from app.stages.object_shading import shading_mesh
    from app.stages.own_contacts import lift_off_own_contacts
    from recon.proxy import subdivide

    v, n, f, groups = shading_mesh(*_parts())
    top = (np.abs(v[:, 1] - SEAT_Y) < 1e-9) & (n[:, 1] > 0.99)
    rows = np.unique(np.round(v[top, 2], 9))
    np.testing.assert_allclose(rows, [-0.23, -0.19, -0.115, 0.0, 0.115, 0.23], atol=1e-9)
    # the same surface: area kept, every face of the cut seat top on one side of the back's front plane
    def area(v, f):
        return 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()
    np.testing.assert_allclose(area(v, f), area(*[subdivide(*_parts(), max_edge=0.08, max_faces=3000)[i]
                                                  for i in (0, 2)]), rtol=1e-12)
    ft = f[top[f].all(1)]
    s = v[ft, 2] - BACK_FRONT
    assert not ((s.max(1) > 1e-9) & (s.min(1) < -1e-9)).any()
    # the new row is lifted off the back (forward, 8.5 mm: a tenth of the back's faces' radius), within the seat
    lift = lift_off_own_contacts(v, n, f)
    crease = top & (np.abs(v[:, 2] - BACK_FRONT) < 1e-9)
    assert crease.sum() >= 8
    np.testing.assert_allclose(lift[crease][:, :2], 0.0, atol=1e-12)
    np.testing.assert_allclose(lift[crease][:, 2], 0.0085, atol=3e-4)
    # a lone box (no contact) comes back as it came: the same arrays
    box = subdivide(*_box((-HALF, 0.0, -HALF), (HALF, 0.05, HALF)), max_edge=0.08, max_faces=3000)
    out = shading_mesh(*_box((-HALF, 0.0, -HALF), (HALF, 0.05, HALF)))
    assert out[3] is None
    for a, b in zip(out[:3], box):
        np.testing.assert_array_equal(a, b)
    # each piece knows the face it was cut from: the faces before the cut, in order, each once or more
    assert groups is not None and len(groups) == len(f)
    n_before = len(subdivide(*_parts(), max_edge=0.08, max_faces=3000)[2])
    assert np.all(np.diff(groups) >= 0) and groups[-1] == n_before - 1


@pytest.fixture(scope="module")
def cut_shading():
    from app.config import ObjectConfig
    from app.stages.object_shading import ShapeShading, shading_mesh
    from kernels import runtime

    runtime.init()
    v, n, f, _ = shading_mesh(*_parts())
    oc = ObjectConfig()
    ss = ShapeShading(v - v.mean(0), n, f, oc.prt_dirs, oc.dB_samples, "cpu", oc.vis_stride, 0)
    return v, n, f, ss


def test_seat_darkens_towards_the_back_under_a_uniform_sky(cut_shading):
    from app.stages.object_shading import _fill_from_neighbours, vertex_light

    v, n, f, ss = cut_shading
    E = _sky(ss, v)
    albedo = np.array([0.5, 0.5, 0.5])
    L = vertex_light(albedo * E[ss.inv][:, None], None,
                     lambda x: _fill_from_neighbours(x, f, ss.buried), None, albedo)[:, 0] / 0.5
    depths = np.array([0.01, 0.03, 0.06])
    got = _seat_top(v, n, f, L, depths)
    want = 1 - np.array([_back_form_factor(s) for s in depths])  # 0.517, 0.552, 0.602
    assert np.all(np.diff(got) > 0.02), got
    np.testing.assert_allclose(got, want, atol=0.04)


def test_a_cut_face_gets_the_sun_per_hit_where_any_of_its_pieces_has_a_sunlit_corner():
    from lighting.sun import SunLight

    light = SunLight.__new__(SunLight)  # hit_codes reads nothing of the sun but its flat-face cache
    light._flat = None
    from app.stages.object_shading import shading_mesh

    v, n, f, groups = shading_mesh(*_parts())
    # the sun's edge crosses the seat in front of the back: the new row on the contact line and the rear row lie in
    # the back's shadow, the row 0.115 m forward is lit
    top = (np.abs(v[:, 1] - SEAT_Y) < 1e-9) & (n[:, 1] > 0.99)
    vis = np.where(top & (v[:, 2] > -0.12), 0.8, 0.0)
    strip = top[f].all(1) & (v[f][:, :, 2].max(1) < -0.11)  # the seat top's faces behind the lit row
    dark = strip & ~(vis[f] > 0).any(1)  # their pieces with no sunlit corner of their own
    assert dark.sum() >= 4
    lit_sibling = np.isin(groups, groups[(vis[f] > 0).any(1)])
    codes = light.hit_codes(n, f, vis, groups)
    np.testing.assert_array_equal(codes[dark & lit_sibling], 2)  # rays: the edge may cross them
    assert (dark & lit_sibling).sum() >= 4
    np.testing.assert_array_equal(light.hit_codes(n, f, vis)[dark], 0)  # without the groups: nothing there
    # a face not cut, with no sunlit corner, still gets nothing
    assert np.all(codes[~strip & ~(vis[f] > 0).any(1) & (np.bincount(groups)[groups] == 1)] == 0)


def test_two_bounces_between_the_object_s_own_parts():
    """seat -> back -> seat crease: vertex 0 (the sunlit seat) has sun L_sun and no room light; vertex 1 (the back)
    sees vertex 0 over half of its view (bounce 0.5), vertex 2 (the seat at the crease, in the back's shadow) sees
    vertex 1 over half (bounce 0.5) and not vertex 0. Exactly (Neumann series, albedo rho): L1 = rho (0.5 L0) + room,
    L2 = rho 0.5 L1 + room: vertex 2 gets rho^2 0.25 of the sun through the back. One bounce (main) gave it only the
    back's room light (rho 0.5 x 0.1 = 0.025 against 0.0875 here)."""
    import scipy.sparse as sp

    from app.stages.object_shading import vertex_light

    rho = np.array([0.5, 0.5, 0.5])
    L_room = np.array([[0.0] * 3, [0.1] * 3, [0.0] * 3])
    L_sun = np.array([[1.0] * 3, [0.0] * 3, [0.0] * 3])
    bounce = sp.csr_matrix(np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.5, 0.0]]))
    L = vertex_light(L_room, L_sun, lambda x: x, bounce, rho)[:, 0]
    L1 = 0.1 + 0.5 * 0.5 * 1.0
    np.testing.assert_allclose(L, [1.0, L1, 0.5 * 0.5 * L1], rtol=1e-12)
