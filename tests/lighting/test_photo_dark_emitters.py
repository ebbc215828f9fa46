"""Photo light: a modelled lamp the walls' fit leaves dark (lighting.photolight._dark_emitters, issue 34 item 4).

The walls see the lamps from afar and at grazing angles, so from them alone one lamp's light can go to
another; a lamp the model marks but the fit leaves at radiance 0 is that trade (lamps_104: the ceiling lamp
dark, a point lamp 2x, docs/unseen.md "photo34, tenth round"). Then the floor, the ceiling and the furniture
join the fit, each with its own albedo (surface_albedos). Analytic: test_photolight's box room.
"""
import numpy as np
import pytest

from lighting import photolight as PL
from lighting.radiosity import gather
from tests.lighting.test_photolight import WINDOW, _box_room


@pytest.fixture(scope="module")
def room_with_an_unlit_lamp():
    """The box room (albedo 0.5: a little darker than photo light's prior 0.55) with its window lit
    (radiance 8), and a 0.6 x 0.6 m lamp the model marks on the ceiling, out of view, that is off in the
    truth: (patches with the lamp marked as an emitter, G, the truth's converged radiance, the lamp's
    patches)."""
    from kernels.visibility import Occluder, transfer_matrix
    from recon.patches import build_patches
    from recon.scene import Quad
    from types import SimpleNamespace

    scene, _ = _box_room(floor=0.5, wall=0.5)
    y = 2.5 - 1e-3
    c = np.array([[1.2, y, 1.2], [1.8, y, 1.2], [1.8, y, 1.8], [1.2, y, 1.8]])
    lamp = Quad("lamp", c, np.array([0.0, -1.0, 0.0]), np.zeros(3), np.ones(3), "lamp")
    pm = build_patches(SimpleNamespace(quads=scene.quads + [lamp]), 0.5, 0.25)
    solid = ~pm.is_emitter[pm.tri_patch]
    occ = Occluder(pm.vert_pos, pm.tris[solid], "cpu")
    G = transfer_matrix(pm.centre, pm.normal, pm.corners, pm.normal, [occ], n_side=2, device="cpu")
    np.fill_diagonal(G, 0.0)
    off = pm.quad == len(scene.quads)  # the lamp: off in the truth
    B = gather(G, pm.albedo * ~pm.is_emitter[:, None], pm.emission * ~off[:, None], 60)[-1]
    return pm, G, B, off


def test_dark_lamp_brings_in_the_surfaces(room_with_an_unlit_lamp):
    # the walls need no light from the lamp (it is off): fitted at its lower bound 0, so the surfaces join the
    # fit (reported); the lamp stays dark (< 1 % of the window) and the window as the walls alone fit it
    # (within 2 %: the surfaces add the light's shape, not its scale; both 0.82x the truth, the prior 0.55 over
    # the truth's 0.5 walls)
    pm, G, B, off = room_with_an_unlit_lamp
    seen = np.flatnonzero((pm.quad != 1) & ~off)  # the floor (quad 1) and the lamp out of view
    pix_patch = np.repeat(seen, 10)
    resp = PL.srgb_response(0.4)
    photo = resp.to_pixels(B[pix_patch])
    roles = ["room"] * int(pm.quad.max()) + ["lamp"]
    names = [f"q{q}" for q in range(pm.quad.max())] + ["lamp"]
    fits = {}
    for rule in (None, False):
        fits[rule] = PL.fit_photo_light(pm, G, pix_patch, photo, resp, PL.PhotoPriors(surface_albedos=rule),
                                        where="test.png", quad_names=names, quad_roles=roles)
    rep = fits[None].report
    assert rep["surface_albedos_for"] == ["lamp"] and rep["surface_albedos"], rep
    em = {e["name"]: np.array(e["radiance"]) for e in rep["emitters"]}
    window = names[int(pm.quad[pm.is_emitter & ~off][0])]
    walls_only = np.array(fits[False].report["emitters"][0]["radiance"])
    print(em, walls_only)
    assert np.abs(em[window] / walls_only - 1).max() < 0.02, (em, walls_only)
    assert np.abs(em[window] / WINDOW - 1).max() < 0.25, em
    assert em["lamp"].max() < 0.01 * WINDOW, em
    assert fits[False].report["surface_albedos"] == {} and fits[False].report["surface_albedos_for"] == []


def test_dark_emitters_are_modelled_seen_and_at_a_zero_bound():
    at = np.array([[True] * 3, [True] * 3, [True] * 3, [False] * 3, [True] * 3])
    lower = np.array([[0.0] * 3, [0.0] * 3, [1.0] * 3, [0.0] * 3, [0.0] * 3])
    unresolved = np.array([False, True, False, False, False])
    modelled = [True, True, True, True, False]  # the last: a clipped region, not a modelled emitter
    assert PL._dark_emitters(at, lower, unresolved, modelled) == [0]
