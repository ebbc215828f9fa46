"""recon/clickmodel: the room from clicks on a calibrated photo, against the shared scenes' truth.

The clicks are the true corners of window_room, lamps_room and sun_room projected with the true
camera (bench/clicks_truth.py), exactly or with 1 px of seeded Gaussian noise. Without noise the
model is the truth to a millimetre (the geometry is exact); with 1 px noise each wall, furniture
piece and window quad is within 3 cm plus what 3 px of click move the point there (far from the
camera a pixel spans several centimetres of floor: a bound in metres alone would test the noise;
a quad on a wall carries that wall's error too).
"""
import json
import logging

import numpy as np
import pytest

from recon.camera import Camera
from recon.clickmodel import ClickError, hit_plane, model_from_clicks
from bench.clicks_truth import furniture_groups, true_clicks
from tests.conftest import shared_scene

SCENES = ["window_room", "lamps_room", "sun_room"]
FACE_AXIS = {"left": (0, 0), "right": (0, 1), "back": (2, 0), "front": (2, 1)}


def _scene(name):
    sc = json.loads((shared_scene(name) / "scene.json").read_text())
    return sc, Camera.from_json(sc["main_camera"], name, "main_camera.")


def _px_m(cam, uvs, normal, offset):
    """Largest metres-per-pixel on the plane normal . x = offset at the clicks uvs (m,2)."""
    out = 0.0
    for uv in np.atleast_2d(np.asarray([q for q in uvs if q is not None], float)):
        p = hit_plane(cam, uv, normal, offset)
        for d in ((1.0, 0.0), (0.0, 1.0)):
            q = hit_plane(cam, uv + d, normal, offset)
            out = max(out, float(np.linalg.norm(q - p)))
    return out


def _errors(sc, cam, clicks, done, model):
    """{item: (error m, allowance m for 2 px of click noise)} of every clicked wall, the ceiling,
    furniture piece and window/lamp quad."""
    lo0, hi0 = np.array(sc["world"]["room_min"]), np.array(sc["world"]["room_max"])
    by = {p["name"]: p for p in model.primitives}
    byclick = {c.get("name", "ceiling"): c for c in clicks["clicks"]}
    out = {}
    for face in done["walls"]:
        ax, side = FACE_AXIS[face]
        err = abs((model.lo, model.hi)[side][ax] - (lo0, hi0)[side][ax])
        out[f"wall {face}"] = (err, _px_m(cam, byclick[face]["floor_line"], [0, 1, 0], 0.0))
    if done["ceiling"]:
        c = byclick["ceiling"]
        ax, side = FACE_AXIS[c["wall"]]
        out["ceiling"] = (abs(model.hi[1] - hi0[1]), _px_m(cam, [c["edge"]], np.eye(3)[ax], (lo0, hi0)[side][ax]))
    for g in furniture_groups(sc):
        if g["name"] not in done["furniture"]:
            continue
        p = by.get(g["name"]) or by[g["name"] + "_top"]
        c, s = np.array(p["center"]), np.array(p["size"])
        e = np.r_[np.array(g["x"]) - [c[0] - s[0] / 2, c[0] + s[0] / 2],
                  np.array(g["z"]) - [c[2] - s[2] / 2, c[2] + s[2] / 2], g["top"] - (c[1] + s[1] / 2)]
        out[g["name"]] = (float(np.abs(e).max()), _px_m(cam, byclick[g["name"]]["floor"], [0, 1, 0], 0.0))
    for q in sc["primitives"]:
        if q["name"] in done["quads"]:
            T, O = np.array(q["corners"]), np.array(by[q["name"]]["corners"])
            n = np.abs(np.array(q["normal"]))
            err = float(np.linalg.norm(T[:, None] - O[None], axis=-1).min(1).max())
            px = _px_m(cam, byclick[q["name"]]["corners"], n, float(T[0] @ n))
            on = byclick[q["name"]]["on"]  # the quad lies on that clicked plane: its error carries over
            px = max(px, out.get(f"wall {on}", out.get(on, (0, 0)))[1])
            out[q["name"]] = (err, px)
    return out


@pytest.mark.parametrize("name", SCENES)
def test_exact_clicks_give_the_true_room(name):
    sc, cam = _scene(name)
    clicks, done = true_clicks(sc, sigma_px=0.0)
    assert len(done["walls"]) >= 2 and done["furniture"], done
    model = model_from_clicks(clicks, cam, name, ceiling_height=None if done["ceiling"] else 2.6)
    errs = _errors(sc, cam, clicks, done, model)
    print(name, {k: round(v[0], 4) for k, v in errs.items()}, "skipped (out of the photo):", done["skipped"])
    for k, (e, _) in errs.items():
        assert e <= 0.005, (k, e)
    # the walls not clicked are guessed, beyond the camera
    room = model.primitives[0]
    guessed = {w["name"] for w in room["walls"] if w["guessed"] and w["name"] != "ceiling"}
    assert guessed == set(FACE_AXIS) - set(done["walls"])
    assert np.all(cam.centre > model.lo) and np.all(cam.centre < model.hi)


@pytest.mark.parametrize("name", SCENES)
def test_clicks_with_one_pixel_noise(name):
    """Ten seeds of 1 px noise: every item within 3 cm + 3 px (3 sigma); the median within 3 cm + 1 px."""
    sc, cam = _scene(name)
    logging.disable(logging.WARNING)
    try:
        runs = []
        for seed in range(10):
            clicks, done = true_clicks(sc, sigma_px=1.0, seed=seed)
            runs.append(_errors(sc, cam, clicks, done, model_from_clicks(clicks, cam, name, 2.6)))
    finally:
        logging.disable(logging.NOTSET)
    for k in runs[0]:
        errs = np.array([r[k][0] for r in runs])
        px = runs[0][k][1]
        print(f"{name} {k}: median {np.median(errs) * 100:.1f} cm, max {errs.max() * 100:.1f} cm, 1 px = "
              f"{px * 100:.1f} cm")
        assert errs.max() <= 0.03 + 3 * px, k
        assert np.median(errs) <= 0.03 + px, k


def test_window_room_model_is_a_valid_primitives_input(tmp_path):
    """The model goes through `photoar scene`'s parser: one room box, the desk's top and four legs,
    the window quad facing into the room, 2 mm in front of its wall."""
    from recon.assemble import parse_primitives

    sc, cam = _scene("window_room")
    clicks, _ = true_clicks(sc, sigma_px=0.0)
    d = model_from_clicks(clicks, cam, "window_room").to_json()
    prims, lo, hi = parse_primitives(json.loads(json.dumps(d)), "primitives.json")
    names = [p["name"] for p in prims]
    assert {"desk_top", "desk_leg0", "desk_leg3", "window", "floor", "front"} <= set(names)
    top = next(p for p in prims if p["name"] == "desk_top")
    assert abs(top["size"][1] - 0.04) < 1e-9
    leg = next(p for p in prims if p["name"] == "desk_leg0")
    assert abs(leg["size"][0] - 0.05) < 1e-9 and abs(leg["center"][1] * 2 + 0.04 - 0.75) < 0.005
    win = next(p for p in prims if p["name"] == "window")
    assert win["role"] == "window" and win["normal"] == [1.0, 0.0, 0.0]
    np.testing.assert_allclose(np.array(win["corners"])[:, 0], lo[0] + 0.002, atol=1e-9)


def test_more_points_on_a_walls_foot():
    """A wall's foot clicked at six points: exact clicks give the exact wall, and with 1 px noise the
    walls are on average nearer the truth than from two points (20 seeds)."""
    sc, cam = _scene("lamps_room")
    clicks, done = true_clicks(sc, sigma_px=0.0, wall_points=6)
    errs = _errors(sc, cam, clicks, done, model_from_clicks(clicks, cam, "lamps_room", 2.7))
    assert all(errs[f"wall {f}"][0] < 1e-3 for f in done["walls"]), errs
    logging.disable(logging.WARNING)
    try:
        mean = {}
        for n in (2, 6):
            e = []
            for seed in range(20):
                clicks, done = true_clicks(sc, sigma_px=1.0, seed=seed, wall_points=n)
                errs = _errors(sc, cam, clicks, done, model_from_clicks(clicks, cam, "lamps_room", 2.7))
                e += [errs[f"wall {f}"][0] for f in done["walls"]]
            mean[n] = float(np.mean(e))
    finally:
        logging.disable(logging.NOTSET)
    print(f"lamps_room walls, mean error: two points {mean[2] * 100:.2f} cm, six {mean[6] * 100:.2f} cm")
    assert mean[6] < 0.8 * mean[2], mean


def test_two_floor_corners_and_the_wall_it_stands_against():
    """window_room's desk from its two front corners and "against": the back wall (its back corner
    unclicked); without the wall or a size the missing side is refused."""
    sc, cam = _scene("window_room")
    clicks, _ = true_clicks(sc, sigma_px=0.0)
    g = next(g for g in furniture_groups(sc) if g["name"] == "desk")
    (x0, x1), (z0, z1) = g["x"], g["z"]
    f = np.array([[x1, 0, z1], [x0, 0, z1], [x0, 0, z0]])
    uv, _ = cam.project(np.vstack([f, f[:1] + [0, g["top"], 0]]))
    d = _edited(clicks, "desk", floor=[uv[0].tolist(), uv[1].tolist(), None], top=uv[3].tolist(), against="back")
    by = {p["name"]: p for p in model_from_clicks(d, cam, "clicks.json", 2.6).primitives}
    c, s = np.array(by["desk_top"]["center"]), np.array(by["desk_top"]["size"])
    np.testing.assert_allclose([c[0] - s[0] / 2, c[0] + s[0] / 2, c[2] - s[2] / 2, c[2] + s[2] / 2, c[1] + s[1] / 2],
                               [x0, x1, z0, z1, g["top"]], atol=0.002)
    del d["clicks"][[c.get("name") for c in d["clicks"]].index("desk")]["against"]
    _refused(cam, d, "furniture 'desk'", "size_m", "against")


# ----------------------------------------------------------------------------------------------
# Errors: one line naming the click

@pytest.fixture(scope="module")
def window_room():
    sc, cam = _scene("window_room")
    clicks, _ = true_clicks(sc, sigma_px=0.0)
    return sc, cam, clicks


def _edited(clicks, name, **changes):
    d = json.loads(json.dumps(clicks))
    c = next(c for c in d["clicks"] if c.get("name") == name)
    c.update(changes)
    return d


def _refused(cam, d, *words):
    with pytest.raises(ClickError) as e:
        model_from_clicks(d, cam, "clicks.json", 2.6)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("clicks.json: "), msg
    for w in words:
        assert w in msg, msg
    return msg


def test_floor_click_above_the_horizon(window_room):
    sc, cam, clicks = window_room
    desk = next(c for c in clicks["clicks"] if c.get("name") == "desk")
    floor = [list(q) for q in desk["floor"]]
    floor[1] = [floor[1][0], 2.0]  # near the top of the photo, above the horizon of a camera looking down
    _refused(cam, _edited(clicks, "desk", floor=floor), "furniture 'desk'", "floor[1]", "above the horizon")
    wall = next(c for c in clicks["clicks"] if c.get("label") == "wall")
    line = [list(wall["floor_line"][0]), [wall["floor_line"][1][0], 1.0]]
    _refused(cam, _edited(clicks, wall["name"], floor_line=line), f"wall '{wall['name']}'", "floor_line[1]",
             "above the horizon")


def test_click_outside_the_photo(window_room):
    sc, cam, clicks = window_room
    desk = next(c for c in clicks["clicks"] if c.get("name") == "desk")
    _refused(cam, _edited(clicks, "desk", top=[desk["top"][0], -3.0]), "furniture 'desk'", "top", "outside the photo")
    _refused(cam, _edited(clicks, "window", corners=[[700.0, 10.0]] * 4), "window 'window'", "corners[0]",
             "outside the photo")


def test_footprint_crossing_a_wall(window_room):
    """The desk moved 0.5 m through the back wall (its true corners at z - 0.5, projected)."""
    sc, cam, clicks = window_room
    g = next(g for g in furniture_groups(sc) if g["name"] == "desk")
    (x0, x1), (z0, z1) = g["x"], g["z"]
    ring = np.array([[x0, 0, z1 - 0.5], [x0, 0, z0 - 0.5], [x1, 0, z0 - 0.5]])
    uv, _ = cam.project(ring)
    top, _ = cam.project((ring[0] + [0, g["top"], 0])[None])
    _refused(cam, _edited(clicks, "desk", floor=uv.tolist(), top=top[0].tolist()), "furniture 'desk'",
             "crosses the back wall")


def test_quad_off_its_wall(window_room):
    """A window's corners clicked on the back wall but said to be on the left one."""
    sc, cam, clicks = window_room
    P = np.array([[1.0, 2.0, 0.0], [2.0, 2.0, 0.0], [2.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
    uv, _ = cam.project(P)
    _refused(cam, _edited(clicks, "window", corners=uv.tolist()), "window 'window'", "off its left")


def test_unknown_wall_and_bad_fields(window_room):
    sc, cam, clicks = window_room
    _refused(cam, _edited(clicks, "window", on="north"), "window 'window'", "'on' must be")
    _refused(cam, _edited(clicks, "desk", kind="table"), "furniture 'desk'", "kind")
    _refused(cam, {"clicks": [{"label": "door", "name": "d"}]}, "clicks[0].label")
    d = json.loads(json.dumps(clicks))
    d["clicks"] = [c for c in d["clicks"] if c["label"] != "wall"]
    _refused(cam, d, "no wall")


def test_wall_off_the_axes_and_top_not_above(window_room):
    sc, cam, clicks = window_room
    # a floor line running 30 deg off the room's x axis
    P = np.array([[1.0, 0.0, 0.5], [1.0 + np.cos(np.radians(30)), 0.0, 0.5 + np.sin(np.radians(30))]])
    uv, _ = cam.project(P)
    wall = next(c for c in clicks["clicks"] if c.get("label") == "wall")
    _refused(cam, _edited(clicks, wall["name"], floor_line=uv.tolist()), f"wall '{wall['name']}'", "30 deg off")
    # the top click 60 px beside the vertical line over floor[0]
    desk = next(c for c in clicks["clicks"] if c.get("name") == "desk")
    _refused(cam, _edited(clicks, "desk", top=[desk["top"][0] - 60.0, desk["top"][1]]), "furniture 'desk'",
             "not straight above floor[0]")


# ----------------------------------------------------------------------------------------------
# Refined against the photo (recon/clickedges.py)

def runs_refined(item, snapped):
    n = sum(item in s for s in snapped)
    return f"foot snapped in {n} of {len(snapped)}" if item.startswith("wall ") else ""


def _photo_edges(name):
    from recon.edgesnap import EdgeImage
    from recon.io import read_image_rgb

    return EdgeImage(read_image_rgb(shared_scene(name) / "background.png"))


def _synthetic_feet(cam, lo, ss=4):
    """An 8-bit photo of the room's floor (dark) against its walls (light) through `cam`: each
    pixel the mean of ss x ss rays, floor where the ray meets y = 0 inside x > lo[0], z > lo[2]."""
    h, w = cam.height, cam.width
    off = (np.arange(ss) + 0.5) / ss - 0.5
    u = (np.arange(w)[None, :, None, None] + off[None, None, None, :]) + 0 * off[None, None, :, None]
    v = (np.arange(h)[:, None, None, None] + off[None, None, :, None]) + 0 * off[None, None, None, :]
    u, v = np.broadcast_arrays(u, v)
    d = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(cam.K).T @ cam.R  # world directions
    C = cam.centre
    s = -C[1] / np.where(d[..., 1] < 0, d[..., 1], -1e-12)
    floor = (d[..., 1] < 0) & (C[0] + s * d[..., 0] > lo[0]) & (C[2] + s * d[..., 2] > lo[2])
    val = np.where(floor, 60.0, 180.0).mean(axis=(2, 3))
    return np.repeat(np.round(val).astype(np.uint8)[..., None], 3, axis=2)


def test_walls_snap_to_an_analytic_edge():
    """window_room's camera over a synthetic photo whose only edges are the true wall-floor lines
    (anti-aliased, 4x4 rays a pixel): with 1 px click noise the snapped walls are within 0.2 px of
    floor there (under 8 mm; measured 0.03-0.11 px), against ~1 cm as clicked. The clicks keep their
    weight in the fit (1 px against a line's noise floor of 0.25 px: 1/17 of a click's error stays,
    3 sigma 0.18 px); without the photo nothing is refined."""
    sc, cam = _scene("window_room")
    photo = _synthetic_feet(cam, np.array(sc["world"]["room_min"], float))
    logging.disable(logging.WARNING)
    try:
        for seed in range(5):
            clicks, done = true_clicks(sc, sigma_px=1.0, seed=seed)
            clicks["clicks"] = [c for c in clicks["clicks"] if c["label"] == "wall"]
            m = model_from_clicks(clicks, cam, "window_room", 2.6, photo=photo)
            m0 = model_from_clicks(clicks, cam, "window_room", 2.6)
            for face in done["walls"]:
                ax, side = FACE_AXIS[face]
                err = abs((m.lo, m.hi)[side][ax] - (sc["world"]["room_min"], sc["world"]["room_max"])[side][ax])
                px = _px_m(cam, next(c for c in clicks["clicks"] if c["name"] == face)["floor_line"], [0, 1, 0], 0.0)
                assert m.refined[face] != "as clicked", (seed, m.refined)
                assert err <= 0.2 * px, (seed, face, err, px)
            assert "refined_from_photo" not in m0.to_json()["model"]
    finally:
        logging.disable(logging.NOTSET)


def test_box_blocker():
    """A unit box 2 m in front of a camera at the origin looking down +Z hides what is behind it, not
    what is in front of it or beside it, nor a point inside it (pieces that touch)."""
    from recon.clickedges import box_blocker

    cam = Camera(np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]), np.eye(3), np.zeros(3), 640, 480)
    blocked = box_blocker(cam, [{"center": [0.0, 0.0, 2.0], "size": [1.0, 1.0, 1.0]}])
    got = blocked(np.array([[0.0, 0.0, 4.0], [0.0, 0.0, 1.0], [2.0, 0.0, 4.0], [0.0, 0.0, 2.2], [0.1, 0.1, 2.6]]))
    assert got.tolist() == [True, False, False, False, True]


def test_corners_the_photo_shows():
    """recon/clickfurniture._shown on a camera at the origin looking down +Z: a solid unit cube 3 m
    ahead shows its four near corners and hides its four far ones (its own box); a small piece in the
    sight line to one near corner hides it, and so does a piece touching another near corner (1 cm
    off it: within the 2 cm of click noise the other pieces are grown by); a desk's own top slab
    hides a floor point behind it, not one beside it, and shows its own near top corner."""
    from recon.clickbase import _Clicks
    from recon.clickfurniture import _shown

    cam = Camera(np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]), np.eye(3), np.zeros(3), 640, 480)
    own = {"name": "cube", "center": [0.0, 0.0, 3.0], "size": [1.0, 1.0, 1.0]}
    X = np.array([[a, b, c] for c in (2.5, 3.5) for a in (-0.5, 0.5) for b in (-0.5, 0.5)])
    alone = _Clicks(cam, "t", None, [own])
    assert _shown(alone, "cube", X, own).tolist() == [True] * 4 + [False] * 4
    others = [own, {"name": "blocker", "center": [0.4, 0.4, 2.0], "size": [0.2, 0.2, 0.2]},
              {"name": "touching", "center": [-0.61, -0.5, 2.5], "size": [0.2, 0.2, 0.2]}]
    got = _shown(_Clicks(cam, "t", None, others), "cube", X, own)
    assert got.tolist() == [False, True, True, False] + [False] * 4
    # hidden by another piece (by_others): the two near corners above, and the far corner behind the
    # blocker (its sight line passes (0.29, 0.29) at z = 2, inside the blocker grown by 2 cm); the
    # other far corners only the cube itself hides (a far side a wall hold may judge)
    got = _shown(_Clicks(cam, "t", None, others), "cube", X, own, by_others=True)
    assert got.tolist() == [False, True, True, False, True, True, True, False]
    slab = {"name": "desk_top", "center": [0.0, -0.45, 3.0], "size": [1.0, 0.1, 1.0]}  # a desk's top, not solid
    desk = _Clicks(cam, "t", None, [slab])
    assert _shown(desk, "desk", np.array([[0.5, 0.5, 2.5], [0.0, -0.9, 5.0], [0.5, -0.4, 2.5]]), slab).tolist() == \
        [True, False, True]


# the pieces a draw of test_clicks_refined_against_the_photo puts beyond a flat 3 cm (each reported
# ill-determined there): measured worst 5.7 and 3.2 cm. Both rest on clicks of corners the photo does
# not show (behind the seat, under the back), which no edge in the photo can correct: from those clicks
# alone, every other side given, the seat's back side is 5.3 cm off at worst and the back's front side
# 3.6 cm on the same seeds (bench/bench_clicks_hidden_limit.py).
BEYOND_3CM = {"lamps_room": ("sofa_seat", "sofa_back")}


@pytest.mark.parametrize("name", SCENES)
def test_clicks_refined_against_the_photo(name):
    """Ten seeds of 1 px noise, the clicks refined against the photo: every wall, the ceiling, every
    window quad and every piece of furniture within the issue's flat 3 cm on every seed, except a
    piece the model itself reports ill-determined (`model.ill_determined`: a side the clicks and the
    photo pin less well than 3 cm at 99 %; no wall here is), which keeps the bound of clicks, 3 cm + 3 px:
    lamps_room's sofa seat (its back side hidden under the sofa's back: no edge of it in the photo,
    its place from the clicks on its hidden back corners alone, 1 px = 2.7 cm of floor there; the
    truth's seat runs 5 cm short of the wall, so no wall holds it) and the sofa's back (its top face
    3.5 px deep: its two long edges too near to tell apart, so its depth rests on floor clicks hidden
    behind the seat). Every other piece is within the flat 3 cm on every seed, reported or not
    (BEYOND_3CM): the desks of window_room and sun_room, each standing against the back wall (worst
    0.8 and 1.2 cm: a side is held on a wall when the two are one plane within both their noises,
    the wall's at least its crease's noise floor in metres, 0.8 cm at sun_room's back wall, and
    then lies between the two by their variances). With exact clicks every item is within
    3 cm (the refinement does not lock onto a wrong edge; an ill-determined one is allowed 1 px
    more), and over all items and seeds the mean error is lower than as clicked."""
    sc, cam = _scene(name)
    edges = _photo_edges(name)
    logging.disable(logging.WARNING)
    try:
        clicks, done = true_clicks(sc, sigma_px=0.0)
        m = model_from_clicks(clicks, cam, name, 2.6, photo=edges)
        exact, exact_loose = _errors(sc, cam, clicks, done, m), set(m.to_json()["model"]["ill_determined"])
        runs, runs0, loose = [], [], []
        for seed in range(10):
            clicks, done = true_clicks(sc, sigma_px=1.0, seed=seed)
            m = model_from_clicks(clicks, cam, name, 2.6, photo=edges)
            runs.append(_errors(sc, cam, clicks, done, m))
            runs0.append(_errors(sc, cam, clicks, done, model_from_clicks(clicks, cam, name, 2.6)))
            loose.append(set(m.to_json()["model"]["ill_determined"]))
    finally:
        logging.disable(logging.NOTSET)
    print(name, "exact clicks, refined:", {k: round(v[0] * 100, 1) for k, v in exact.items()})
    for k, (e, px) in exact.items():
        assert e <= 0.03 + (px if k in exact_loose else 0.0), (k, e)
    for k in runs[0]:
        errs = np.array([r[k][0] for r in runs])
        errs0 = np.array([r[k][0] for r in runs0])
        px = runs[0][k][1]
        flat = np.array([k not in s for s in loose])
        print(f"{name} {k}: median {np.median(errs0) * 100:.1f} -> {np.median(errs) * 100:.1f} cm, max "
              f"{errs0.max() * 100:.1f} -> {errs.max() * 100:.1f} cm, 1 px = {px * 100:.1f} cm; reported "
              f"ill-determined in {int((~flat).sum())} of 10")
        if k.startswith("wall ") or k == "ceiling" or k in done["quads"]:
            assert flat.all(), k  # every wall snapped here; the ceiling and quads are not judged
        assert np.all(errs[flat] <= 0.03), (k, errs)
        assert np.all(errs <= 0.03 + 3 * px), k
        if k not in BEYOND_3CM.get(name, ()):  # the desks too, reported or not
            assert np.all(errs <= 0.03), (k, errs)
    mean = np.mean([v[0] for r in runs for v in r.values()])
    mean0 = np.mean([v[0] for r in runs0 for v in r.values()])
    print(f"{name}: mean error {mean0 * 100:.2f} -> {mean * 100:.2f} cm")
    assert mean < mean0


def test_faint_edge_with_swapping_polarity():
    """recon/clickedges.PhotoEdges.snap_faint on a synthetic photo: a straight edge between a wall of
    one tone and planks 120 px long alternately 8 levels darker and lighter than it (the polarity
    swaps along the edge), anti-aliased (4x4 samples a pixel), under Gaussian noise of 4 levels a
    pixel: edgesnap's sample-by-sample snap finds nothing; from a model line 1.5 px off, the averaged
    pieces find the edge on each of eight noise draws, its ends within 0.5 px (twice the 0.25 px
    noise floor a snapped line gets in the fit) and 0.2 px on average (measured 0.28 and 0.11); a
    model line 6 px off (beyond the search) is refused."""
    from recon.clickedges import PhotoEdges
    from recon.edgesnap import EdgeImage

    h, w, ss = 240, 320, 4
    a, b = np.array([20.0, 80.0]), np.array([300.0, 150.0])  # the true edge, pixels
    d = (b - a) / np.linalg.norm(b - a)
    n = np.array([-d[1], d[0]])
    off = (np.arange(ss) + 0.5) / ss - 0.5
    v, u = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    P = np.stack(np.broadcast_arrays(u[..., None, None] + off[None, None, None, :],
                                     v[..., None, None] + off[None, None, :, None]), -1)
    across = (P - a) @ n
    along = (P - a) @ d
    plank = np.where((along // 120) % 2 == 0, 112.0, 128.0)
    val = np.where(across > 0, plank, 120.0).mean(axis=(2, 3))
    cam = Camera(np.array([[300.0, 0, w / 2 - 0.5], [0, 300, h / 2 - 0.5], [0, 0, 1]]), np.eye(3), np.zeros(3), w, h)
    errs = []
    for seed in range(8):
        rng = np.random.default_rng(seed)
        img = np.clip(np.round(val + rng.normal(0.0, 4.0, val.shape)), 0, 255).astype(np.uint8)
        photo = EdgeImage(np.repeat(img[..., None], 3, axis=2))
        pe = PhotoEdges(photo, cam, 1.0)
        model = np.r_[a + 1.5 * n, b + 1.5 * n]
        assert photo.snap(model, 1.0, pe.search, False, 2.0) is None
        r = pe.snap_faint(model)
        assert r is not None, seed
        seg = r[0]
        for end, true in ((seg[:2], a), (seg[2:], b)):
            errs.append(abs(float((end - true) @ n)))
        assert pe.snap_faint(np.r_[a + 6.0 * n, b + 6.0 * n]) is None
    print(f"faint edge: ends off by {np.mean(errs):.3f} px on average, {max(errs):.3f} px at worst (8 draws)")
    assert max(errs) <= 0.5 and np.mean(errs) <= 0.2, errs


def _seam_photo(seam_at: float, seam_step: bool, seed: int, h: int = 240, w: int = 320):
    """A synthetic photo: a piece (tone 100) above a floor (tone 140) along the straight line a -> b
    (a piece's foot), and `seam_at` px below it a floor feature parallel to it: a dark seam 1 px
    wide (50 levels darker), or with `seam_step` a second step (the floor 40 levels brighter beyond
    it), anti-aliased (4x4 samples a pixel), under Gaussian noise of 3 levels. Returns (EdgeImage,
    camera, a, b, n the unit normal towards the floor)."""
    from recon.edgesnap import EdgeImage

    ss = 4
    a, b = np.array([20.0, 100.0]), np.array([300.0, 112.0])
    d = (b - a) / np.linalg.norm(b - a)
    n = np.array([-d[1], d[0]])
    n = n if n[1] > 0 else -n
    off = (np.arange(ss) + 0.5) / ss - 0.5
    v, u = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    P = np.stack(np.broadcast_arrays(u[..., None, None] + off[None, None, None, :],
                                     v[..., None, None] + off[None, None, :, None]), -1)
    across = (P - a) @ n
    floor = np.where(across > seam_at, 180.0, 140.0) if seam_step else \
        np.where(np.abs(across - seam_at) < 0.5, 90.0, 140.0)
    val = np.where(across > 0, floor, 100.0).mean(axis=(2, 3))
    rng = np.random.default_rng(seed)
    img = np.clip(np.round(val + rng.normal(0.0, 3.0, val.shape)), 0, 255).astype(np.uint8)
    cam = Camera(np.array([[300.0, 0, w / 2 - 0.5], [0, 300, h / 2 - 0.5], [0, 0, 1]]), np.eye(3), np.zeros(3), w, h)
    return EdgeImage(np.repeat(img[..., None], 3, axis=2)), cam, a, b, n


def test_edge_beside_a_floor_seam_is_scanned():
    """recon/clickedges.PhotoEdges.snap_scan on a synthetic photo: a piece's foot with a floor seam
    3.5 px below it, inside the 3.5 px search a fit gives (a seat's foot over planks). edgesnap over
    the whole search finds it ambiguous (the seam's side is a second peak); the narrow windows
    across the search find the foot alone, from a model line on it or 1 px off towards the seam,
    its ends within
    0.2 px on each of six noise draws (the snapped line's noise floor is 0.25 px). Where the floor
    feature is a second step as strong as the foot (two lines), the scan refuses, and an edge
    shorter than SCAN_MIN_PX is not scanned."""
    from recon.clickedges import OPPOSITE_PX, SCAN_MIN_PX, PhotoEdges

    errs = []
    for seed in range(6):
        photo, cam, a, b, n = _seam_photo(3.5, False, seed)
        pe = PhotoEdges(photo, cam, 1.0)
        for shift in (0.0, 1.0):  # the seam inside the model's search
            model = np.r_[a + shift * n, b + shift * n]
            assert photo.snap(model, 1.0, 3.5, False, OPPOSITE_PX) is None
            r = pe.snap_scan(model, 3.5, 1.0)
            assert r is not None, (seed, shift)
            errs += [abs(float((r[0][:2] - a) @ n)), abs(float((r[0][2:] - b) @ n))]
        short = np.r_[a + 2.0 * n, a + 2.0 * n + (SCAN_MIN_PX - 5.0) * (b - a) / np.linalg.norm(b - a)]
        assert pe.snap_scan(short, 3.5, 1.0) is None
        photo, cam, a, b, n = _seam_photo(3.0, True, seed)
        assert PhotoEdges(photo, cam, 1.0).snap_scan(np.r_[a + 1.5 * n, b + 1.5 * n], 3.5, 1.0) is None
    print(f"foot beside a seam: ends off by {np.mean(errs):.3f} px on average, {max(errs):.3f} px at worst")
    assert max(errs) <= 0.2


def test_clicking_only_what_the_photo_shows():
    """lamps_room's sofa seat clicked as a user who sees it: its two back corners are hidden (under
    the sofa's back, behind the seat itself), so its front corners and the top corner above one are
    clicked, the hidden one is null and the footprint's sizes are measured (size_m; the sofa's back,
    whose floor corners the seat hides, cannot be clicked so and is left out). A null corner that
    lies in the photo is behind what is seen: exact clicks give the seat within 5 mm. With 1 px of
    noise (10 seeds, refined against the photo) its worst error is lower than when its hidden
    corners are clicked (5.7 cm there; measured 0.2 cm here, median 0.1 cm: its foot, beside the
    floor's plank seams, snaps on every seed) and it is within the issue's flat 3 cm on every seed."""
    sc, cam = _scene("lamps_room")
    edges = _photo_edges("lamps_room")
    clicks, done = true_clicks(sc, sigma_px=0.0, seen_only=True)
    seat = next(c for c in clicks["clicks"] if c.get("name") == "sofa_seat")
    assert seat["floor"][2] is None and "size_m" in seat and "sofa_back" in done["skipped"], seat
    errs = _errors(sc, cam, clicks, done, model_from_clicks(clicks, cam, "lamps_room", 2.7))
    assert errs["sofa_seat"][0] <= 0.005, errs
    logging.disable(logging.WARNING)
    try:
        seen, hidden = [], []
        for seed in range(10):
            for out, only in ((seen, True), (hidden, False)):
                clicks, done = true_clicks(sc, sigma_px=1.0, seed=seed, seen_only=only)
                m = model_from_clicks(clicks, cam, "lamps_room", 2.6, photo=edges)
                out.append(_errors(sc, cam, clicks, done, m)["sofa_seat"][0])
    finally:
        logging.disable(logging.NOTSET)
    print(f"sofa seat, worst / median cm: hidden corners clicked {max(hidden) * 100:.1f} / "
          f"{np.median(hidden) * 100:.1f}, only what is seen {max(seen) * 100:.1f} / {np.median(seen) * 100:.1f}")
    assert max(seen) < max(hidden)
    assert max(seen) <= 0.03


def test_measured_sizes_hold_clicked_sides():
    """A footprint's sizes measured with a tape (size_m, the truth's here) hold it even where both
    ends of a side are clicked: the end further from the camera follows the nearer one. window_room's
    desk, all three floor corners clicked with 1 px of noise (10 seeds, clicks only): exact with
    exact clicks; with the sizes its mean error is lower and its worst no higher (measured 2.0 -> 1.9
    cm mean, 5.0 cm worst both: in the worst draw the desk's back side goes against the back wall,
    clicks only, and that wall is 5 cm off as clicked)."""
    sc, cam = _scene("window_room")
    g = next(g for g in furniture_groups(sc) if g["name"] == "desk")
    size = [g["x"][1] - g["x"][0], g["z"][1] - g["z"][0]]

    def desk_error(sigma, seed, sized):
        clicks, done = true_clicks(sc, sigma_px=sigma, seed=seed)
        c = next(c for c in clicks["clicks"] if c.get("name") == "desk")
        assert all(q is not None for q in c["floor"])
        if sized:  # size_m pairs floor[0]-floor[1] and floor[1]-floor[2]
            f = np.array([hit_plane(cam, q, [0, 1, 0], 0.0) for q in c["floor"]])
            c["size_m"] = [min(size, key=lambda v: abs(v - np.linalg.norm(f[i] - f[i + 1]))) for i in (0, 1)]
        return _errors(sc, cam, clicks, done, model_from_clicks(clicks, cam, "window_room", 2.6))["desk"][0]

    assert desk_error(0.0, 0, True) < 1e-3
    logging.disable(logging.WARNING)
    try:
        plain = np.array([desk_error(1.0, seed, False) for seed in range(10)])
        sized = np.array([desk_error(1.0, seed, True) for seed in range(10)])
    finally:
        logging.disable(logging.NOTSET)
    print(f"window_room desk, clicks only, worst / mean cm: {plain.max() * 100:.1f} / {plain.mean() * 100:.1f} -> "
          f"with sizes {sized.max() * 100:.1f} / {sized.mean() * 100:.1f}")
    assert sized.max() <= plain.max() and sized.mean() < plain.mean()


def test_a_piece_standing_on_another():
    """lamps_room's sofa back stands on its seat (its bottom at the seat's top, 0.42 m): clicked with
    `"on": "sofa_seat"`, its corners where it meets the seat's top (bench/clicks_truth.py, stacked).
    Exact clicks give the back to a millimetre with its bottom on the modelled seat's top (refined
    against the photo: within 3 cm, as every piece there). With 1 px of noise (10 seeds, refined)
    the back keeps the clicks' bound, 3 cm + 3 px (a pixel spans 3-4 cm on the seat's top, seen more
    grazing than the floor: measured worst 3.7 cm, median 2.4), lies on the seat on every seed and is reported ill-determined whenever it is beyond
    3 cm; its x min side is held on the seat's (one plane within both their noises, as a side on a
    wall: `model.refined_from_photo` says so) on most seeds."""
    sc, cam = _scene("lamps_room")
    edges = _photo_edges("lamps_room")
    clicks, done = true_clicks(sc, sigma_px=0.0, stacked=True)
    back = next(c for c in clicks["clicks"] if c.get("name") == "sofa_back")
    assert back["on"] == "sofa_seat" and "on" not in next(c for c in clicks["clicks"] if c.get("name") == "sofa_seat")
    for photo in (None, edges):
        m = model_from_clicks(clicks, cam, "lamps_room", 2.7, photo=photo)
        by = {p["name"]: p for p in m.primitives}
        errs = _errors(sc, cam, clicks, done, m)
        tol = 0.001 if photo is None else 0.03  # refined: the edges found move it (measured 1.0 cm)
        assert errs["sofa_back"][0] <= tol and errs["sofa_seat"][0] <= tol, errs
        b, s = by["sofa_back"], by["sofa_seat"]
        assert b["center"][1] - b["size"][1] / 2 == pytest.approx(s["center"][1] + s["size"][1] / 2, abs=1e-9)
        assert b["center"][1] - b["size"][1] / 2 == pytest.approx(0.42, abs=0.001)
    logging.disable(logging.WARNING)
    try:
        errs, held = [], 0
        for seed in range(10):
            clicks, done = true_clicks(sc, sigma_px=1.0, seed=seed, stacked=True)
            m = model_from_clicks(clicks, cam, "lamps_room", 2.7, photo=edges)
            by = {p["name"]: p for p in m.primitives}
            b, s = by["sofa_back"], by["sofa_seat"]
            assert b["center"][1] - b["size"][1] / 2 == pytest.approx(s["center"][1] + s["size"][1] / 2, abs=1e-9)
            e = _errors(sc, cam, clicks, done, m)["sofa_back"][0]
            errs.append(e)
            assert e <= 0.03 or "sofa_back" in m.uncertain, (seed, e)
            held += "x min side against 'sofa_seat'" in m.refined["sofa_back"]
    finally:
        logging.disable(logging.NOTSET)
    px = _px_m(cam, back["floor"], [0, 1, 0], 0.42)
    print(f"sofa back on the seat: worst {max(errs) * 100:.1f} cm, median {np.median(errs) * 100:.1f} cm, 1 px = "
          f"{px * 100:.1f} cm; x min held on the seat's in {held} of 10")
    assert max(errs) <= 0.03 + 3 * px and np.median(errs) <= 0.03 + px
    assert held >= 5


def test_on_names_a_piece_it_can_stand_on():
    """`on` must name a furniture piece of the file (in any order: the support is modelled first), and
    the piece's footprint must lie over that piece's top; refused with one line otherwise."""
    sc, cam = _scene("lamps_room")
    clicks, _ = true_clicks(sc, sigma_px=0.0, stacked=True)
    # the support after the piece in the file: modelled first all the same
    d = json.loads(json.dumps(clicks))
    d["clicks"].sort(key=lambda c: c.get("name") != "sofa_back")
    by = {p["name"]: p for p in model_from_clicks(d, cam, "clicks.json", 2.7).primitives}
    assert by["sofa_back"]["center"][1] == pytest.approx(0.6, abs=0.001)
    _refused(cam, _edited(clicks, "sofa_back", on="armchair"), "furniture 'sofa_back'", "'on' must name")
    _refused(cam, _edited(clicks, "sofa_back", on="window"), "furniture 'sofa_back'", "'on' must name")
    # its corners clicked 1.5 m in front of the seat (z 1.5-1.7; the seat's top ends at z 0.95)
    f = np.array([[1.0, 0.42, 1.5], [1.0, 0.42, 1.7], [3.0, 0.42, 1.7]])
    uv, _ = cam.project(np.vstack([f, f[:1] + [0, 0.36, 0]]))
    _refused(cam, _edited(clicks, "sofa_back", floor=uv[:3].tolist(), top=uv[3].tolist()), "furniture 'sofa_back'",
             "beyond the top of 'sofa_seat'")
    # two pieces standing on each other
    d = _edited(clicks, "sofa_seat", on="sofa_back")
    _refused(cam, d, "'on' must name")


def test_predicted_edge_noise_is_the_fits():
    """recon/clickedges.PhotoEdges.predicted_sd, analytic: a horizontal segment 5 m ahead of a camera
    (f = 500 px) at height x, clicked at its two ends with 1 px of noise: the fit's x has sd
    1 px / (100 px/m sqrt 2), so the edge's place across itself in the photo has sd 1/sqrt 2 px; with a
    snapped line of 0.25 px on it as well (its two ends, 16 clicks' weight each), 1/sqrt(2 + 32) px.
    lines() then searches that edge 3.5 sigma + 1 px either side (at least 2 px), not the clicks'
    3.5 px."""
    from recon.clickedges import EdgeLine, PhotoEdges

    cam = Camera(np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]), np.eye(3), np.zeros(3), 640, 480)
    pe = PhotoEdges(np.zeros((480, 640, 3), np.uint8), cam, 1.0)

    def corners(x):
        return np.array([[-1.0, x[0], 5.0], [1.0, x[0], 5.0]])

    sd = pe.predicted_sd(np.array([0.2]), corners, corners, [], [(0, 1)])
    assert sd[(0, 1)] == pytest.approx(1 / np.sqrt(2), rel=1e-3)
    line = EdgeLine(0, 1, 0.0, 1.0, np.array([220.0, 260.0]), np.array([0.0, 1.0]), 0.25)
    sd = pe.predicted_sd(np.array([0.2]), corners, corners, [line], [(0, 1)])
    assert sd[(0, 1)] == pytest.approx(1 / np.sqrt(34), rel=1e-3)


def test_turn_within_the_clicks_noise_is_no_turn():
    """recon/clickfurniture._footprint: two floor corners 0.31 m apart whose edge runs 11.3 deg off the
    room's x axis (the third corner null, the sizes measured). Where one click sigma spans 4 cm of
    floor at each (far off), the edge's direction is known to 10.6 deg (atan of 5.7 cm across 0.31 m),
    so 11.3 deg is within Z99 sigma of none: the footprint is axis-aligned. Where a sigma spans 5 mm
    (1.3 deg) the turn is real and, with two corners only, refused as before."""
    from recon.clickbase import _Clicks
    from recon.clickfurniture import _footprint

    sc, cam = _scene("window_room")
    P = _Clicks(cam, "clicks.json")
    f = np.array([[1.0, 0.0, 1.0], [1.3, 0.0, 1.06], [np.nan] * 3])
    yaw, xr, zr = _footprint(P, f, "clicks[3] (furniture 'shelf')", np.array([0.306, 0.5]),
                             noise_m=np.array([0.04, 0.04, np.nan]))
    assert yaw == 0.0
    np.testing.assert_allclose(xr, [1.0, 1.3], atol=1e-9)
    with pytest.raises(ClickError, match="turned -11 deg"):
        _footprint(P, f, "clicks[3] (furniture 'shelf')", np.array([0.306, 0.5]),
                   noise_m=np.array([0.005, 0.005, np.nan]))


def test_a_piece_against_its_wall_held_on_every_seed():
    """window_101 (rendered by roomgen, not tuned on): bench_2 stands against the left wall, its wall
    side pinned only by one grazing floor click (1 px = 3.1 cm of floor there) and the top click over
    it. Ten seeds of 1 px noise, refined against the photo: that side is held on the wall on every
    seed and lies within the issue's 3 cm of it, within 1 cm on the median seed (measured on the room
    rendered at 2 x 20 spp: within 1 cm on every seed; rendered again at the bench's 2 x 12: worst 1.56,
    median 0.38 cm: the wall it is held on moves with the photo's noise). The hold test is 1 % for the piece's four sides (CHI2_HOLD,
    3.02 sigma); at 1 % a side (2.58 sigma) seed 9's fit, 8.0 cm off at 2.8 of its sigmas, was
    refused and the bench left 7.9 cm off."""
    import os
    from pathlib import Path

    from recon.edgesnap import EdgeImage
    from recon.io import read_image_rgb

    root = Path(os.environ.get("PHOTOAR_ROOMS", Path.home() / ".cache" / "photoar" / "rooms")) / "window_101"
    if not (root / "scene.json").is_file():
        pytest.skip(f"unseen room {root} not rendered (bench/bench_unseen.py --render)")
    sc = json.loads((root / "scene.json").read_text())
    cam = Camera.from_json(sc["main_camera"], str(root), "main_camera.")
    edges = EdgeImage(read_image_rgb(root / "background.png"))
    g = next(q for q in furniture_groups(sc) if q["name"] == "bench_2")
    assert g["x"][0] == 0.0  # it stands against the left wall
    logging.disable(logging.WARNING)
    errs = []
    try:
        for seed in range(10):
            clicks, done = true_clicks(sc, sigma_px=1.0, seed=seed)
            m = model_from_clicks(clicks, cam, "window_101", None if done["ceiling"] else sc["world"]["room_max"][1],
                                  photo=edges)
            p = next(q for q in m.primitives if q["name"] == "bench_2")
            x_min = p["center"][0] - p["size"][0] / 2
            assert "x min side against the wall" in m.refined["bench_2"], (seed, m.refined["bench_2"])
            errs.append(abs(x_min - g["x"][0]))
    finally:
        logging.disable(logging.NOTSET)
    print(f"window_101 bench_2's wall side: worst {max(errs) * 100:.2f} cm, median {np.median(errs) * 100:.2f} cm")
    assert max(errs) <= 0.03, errs  # the flat 3 cm
    assert np.median(errs) <= 0.01, errs


def test_the_one_size_to_tape(caplog):
    """A side the clicks and the photo pin worse than 3 cm whose opposite side is sure is named with
    the one size a tape gives (`model.measure`, and a warning line saying which: its length along x or z,
    between which floor clicks, as which size_m entry); given it (size_m with the other entry null),
    the loose side follows the sure one. lamps_room with its hidden corners clicked (BEYOND_3CM: no
    edge of the seat's back side or of the back's front side shows, and from their hidden clicks
    alone they are 5.3 and 3.6 cm off at worst, bench/bench_clicks_hidden_limit.py): on every seed
    the model asks for the seat's depth and the back's depth (along z) and nothing else; with those two
    lengths taped (the truth's, off by -1 or +1 cm of tape error) every item is within the issue's
    flat 3 cm on every seed and none is reported ill-determined (measured: seat 5.7 -> 1.1 cm worst,
    1.8 -> 0.2 median; back 3.2 -> 2.8 worst, 2.0 -> 1.2 median, exact tape). A size_m with both
    entries null is refused."""
    from bench.clicks_truth import tape_asked

    sc, cam = _scene("lamps_room")
    edges = _photo_edges("lamps_room")
    worst = {n: [0.0, 0.0] for n in BEYOND_3CM["lamps_room"]}
    logging.disable(logging.WARNING)
    try:
        for seed in range(10):
            clicks, done = true_clicks(sc, sigma_px=1.0, seed=seed)
            m = model_from_clicks(clicks, cam, "lamps_room", 2.6, photo=edges)
            asked = m.to_json()["model"]["measure"]
            assert set(asked) == set(BEYOND_3CM["lamps_room"]), (seed, asked)
            for n, asks in asked.items():
                assert len(asks) == 1 and asks[0]["along"] == "z" and asks[0]["loose"] in m.uncertain[n], (seed, asks)
                worst[n][0] = max(worst[n][0], _errors(sc, cam, clicks, done, m)[n][0])
            for tape_error in (-0.01, 0.01):
                m2 = model_from_clicks(tape_asked(sc, clicks, asked, tape_error), cam, "lamps_room", 2.6, photo=edges)
                assert not m2.uncertain and not m2.measure, (seed, m2.uncertain)
                errs = _errors(sc, cam, clicks, done, m2)
                for k, (e, _) in errs.items():
                    assert e <= 0.03, (seed, tape_error, k, e)
                for n in worst:
                    worst[n][1] = max(worst[n][1], errs[n][0])
    finally:
        logging.disable(logging.NOTSET)
    print("worst over 10 seeds, clicks -> with the asked size taped (+-1 cm):",
          {n: f"{a * 100:.1f} -> {b * 100:.1f} cm" for n, (a, b) in worst.items()})
    # the warning names the size plainly, on one line
    clicks, _ = true_clicks(sc, sigma_px=1.0, seed=9)
    with caplog.at_level(logging.WARNING, logger="photoar"):
        model_from_clicks(clicks, cam, "clicks.json", 2.6, photo=edges)
    lines = [r.getMessage() for r in caplog.records if "tape its length" in r.getMessage()]
    assert len(lines) == 2 and all("\n" not in s for s in lines), lines
    seat = next(s for s in lines if "sofa_seat: z min pinned only to" in s)
    assert "along z from floor[0] to floor[1]" in seat and '"size_m": [L, null]' in seat, seat
    from recon.io import SceneError

    with pytest.raises(SceneError, match=r"furniture 'sofa_seat'\)\.size_m' must be 2 numbers"):
        model_from_clicks(_edited(clicks, "sofa_seat", size_m=[None, None]), cam, "clicks.json", 2.6)
    with pytest.raises(ClickError, match="size_m must be positive"):
        model_from_clicks(_edited(clicks, "sofa_seat", size_m=[-0.9, None]), cam, "clicks.json", 2.6)


def test_a_null_corner_marked_hidden():
    """A box against the back wall near the left wall of lamps_room (x 0.05-1.25 m, z 0-1 m, 0.45 m
    high; its front-left floor corner 60 px inside the photo's left edge), clicked as a user
    who sees it: its two front corners and the top above the front-right one; its back-left corner
    lies in the photo behind the box itself, so it is null. A null corner is first taken as out of
    the photo, and the box 1 m deep towards the camera puts it there too (1 m off: what
    bench_clickmodel_unseen --seen-only found on lamps_106's sofa seat, 91.9 cm on every draw).
    Marked `"hidden": [2]` (the user saw it is behind the box) the side that keeps it in the photo is
    taken: the exact clicks give the box within 5 mm. 'hidden' naming a clicked corner is refused."""
    sc, cam = _scene("lamps_room")
    clicks, _ = true_clicks(sc, sigma_px=0.0)
    walls = [c for c in clicks["clicks"] if c["label"] in ("wall", "ceiling")]
    x0, x1, depth, h = 0.05, 1.25, 1.0, 0.45
    P = np.array([[x1, 0, depth], [x0, 0, depth], [x1, h, depth], [x0, 0, 0.0], [x0, 0, 2 * depth]])
    uv, _ = cam.project(P)
    inside = [bool(0 <= q[0] <= cam.width - 1 and 0 <= q[1] <= cam.height - 1) for q in uv]
    assert inside == [True, True, True, True, False], uv  # the back-left corner in the photo, its mirror out of it
    box = {"label": "furniture", "name": "chest", "kind": "box", "floor": [uv[0].tolist(), uv[1].tolist(), None],
           "top": uv[2].tolist(), "size_m": [1.2, depth]}

    def z_range(extra):
        m = model_from_clicks({"clicks": walls + [{**box, **extra}]}, cam, "clicks.json", 2.7)
        p = next(p for p in m.primitives if p["name"] == "chest")
        return p["center"][2] - p["size"][2] / 2, p["center"][2] + p["size"][2] / 2

    assert z_range({}) == pytest.approx((depth, 2 * depth), abs=0.005)  # null alone: out of the photo
    assert z_range({"hidden": [2]}) == pytest.approx((0.0, depth), abs=0.005)
    for bad in ([0], [3], "2", [True]):
        with pytest.raises(ClickError, match="'hidden' must list null floor corners"):
            z_range({"hidden": bad})


def test_box_edges_px_and_a_neighbouring_outline():
    """box_edges_px: a unit box 2 m in front of a camera at the origin gives its 12 edges, each the
    projection of two corners one index bit apart. PhotoEdges.lines searches a model edge at most half
    way to such an outline: a synthetic step edge (a vertical line at u = 320.5) snaps without one
    (within 0.1 px) and not with another piece's edge 3 px beside it (nearer than 2 MIN_SEARCH_PX)."""
    from recon.clickedges import PhotoEdges, box_edges_px
    from recon.view import box_corners

    cam = Camera(np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]), np.eye(3), np.zeros(3), 640, 480)
    box = {"center": [0.0, 0.0, 2.0], "size": [1.0, 1.0, 1.0]}
    e = box_edges_px(cam, [box])
    uv, _ = cam.project(box_corners(box["center"], box["size"]))
    assert e.shape == (12, 2, 2)
    assert all(min(np.abs(s - uv[[a, a ^ b]]).max() for a in range(8) for b in (1, 2, 4)) < 1e-9 for s in e)
    photo = np.full((480, 640, 3), 50, np.uint8)
    photo[:, 321:] = 200  # a step between pixel columns 320 and 321
    pe = PhotoEdges(photo, cam)
    X = np.array([[0.001, -0.3, 2.0], [0.001, 0.3, 2.0]])  # model edge about 0.25 px off the step
    never = lambda P: np.zeros(len(P), bool)  # noqa: E731
    found = pe.lines(X, [(0, 1)], never)
    assert len(found) == 1 and abs(float((np.array([320.5, 240.0]) - found[0].p0) @ found[0].n)) < 0.1
    beside = np.array([[[323.5, 100.0], [323.5, 380.0]]])
    assert pe.lines(X, [(0, 1)], never, others=beside) == []


def test_a_room_corner_beside_a_shelf():
    """sun_107 (roomgen, clean render; skipped where ~/.cache/photoar/rooms_full lacks it): the back
    wall's corner line with the left wall shows only near the floor (40 px), and there shelf_2's side
    stands 2-5 px beside it; snapped in the corner's place it pulled the back wall 3.5-3.9 cm off on 5 of
    10 draws (1 px noise), unreported. Searched only half way to the shelf's outline, the corner is
    not snapped: the back wall stays within 3 cm of the truth on every draw (measured 2.6 worst) and
    is reported ill-determined where its clicks pin it worse than 3 cm (99 %)."""
    import os
    from pathlib import Path

    from recon.edgesnap import EdgeImage
    from recon.io import read_image_rgb

    root = Path(os.environ.get("PHOTOAR_ROOMS_FULL", Path.home() / ".cache" / "photoar" / "rooms_full")) / "sun_107"
    if not (root / "background.png").exists():
        pytest.skip(f"{root} not rendered")
    sc = json.loads((root / "scene.json").read_text())
    cam = Camera.from_json(sc["main_camera"], str(root), "main_camera.")
    edges = EdgeImage(read_image_rgb(root / "background.png"))
    logging.disable(logging.WARNING)
    try:
        for seed in range(10):
            clicks, done = true_clicks(sc, sigma_px=1.0, seed=seed)
            ch = None if done["ceiling"] else sc["world"]["room_max"][1]
            m = model_from_clicks(clicks, cam, "sun_107", ch, photo=edges)
            err = _errors(sc, cam, clicks, done, m)["wall back"][0]
            assert err <= 0.03, (seed, err, m.refined)
    finally:
        logging.disable(logging.NOTSET)
