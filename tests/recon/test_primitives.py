"""Primitive modelling (recon/primitives.py): recovery of the benchmark scenes' true primitives from
their projected corners, the hierarchical constraints, drag updates, save/load, export to the
engine's quads, bad input."""
import json

import numpy as np
import pytest

from recon.camera import Camera
from recon.primitives import Primitive, PrimitiveModel, load_model, model_from_dict, save_model
from tests.conftest import shared_scene


def _scene(name):
    d = json.loads((shared_scene(name) / "scene.json").read_text())
    cam = Camera.from_json(d["main_camera"], "scene.json", "main_camera.")
    return d, cam


def constrain_to_truth(model, truth, cam, noise=0.0, rng=None):
    """Image constraints at the true projections of every vertex in front of the camera."""
    for p in truth.prims:
        uv, z = cam.project(p.vertices())
        for k in np.flatnonzero(z > 0.1):
            px = uv[k] + (rng.normal(0, noise, 2) if noise else 0)
            model.set_constraint(p.name, int(k), px)


def perturb(model, rng, dpos=0.1, dyaw_deg=5.0):
    """Every free parameter moved by 10 cm (offsets, sizes; sizes kept >= half) or 5 deg (yaw)."""
    for p in model.prims:
        x, lay = model.get_params([p.name])
        for j, (_, kind, k) in enumerate(lay):
            x[j] += (dpos if kind != "yaw" else np.radians(dyaw_deg)) * rng.choice([-1, 1])
            if kind == "size":
                x[j] = max(x[j], 0.5 * p.size[k])
        model.set_params(x, lay, [model.index[n] for n in [p.name] + model.descendants(p.name)])


def observable(model, cam, name):
    """Whether the image constraints on `name` determine all its free parameters (Jacobian rank)."""
    cons = [c for c in model.constraints if c.primitive == name]
    x0, lay = model.get_params([name])
    aff = [model.index[n] for n in [name] + model.descendants(name)]
    if not cons or 2 * len(cons) < len(x0):
        return False
    cols = []
    for j in range(len(x0)):
        r = []
        for s in (1, -1):
            x = x0.copy()
            x[j] += s * 1e-6
            model.set_params(x, lay, aff)
            r.append(model.residuals(cam, cons).ravel())
        cols.append((r[0] - r[1]) / 2e-6)
    model.set_params(x0, lay, aff)
    sv = np.linalg.svd(np.array(cols).T, compute_uv=False)
    return sv.min() > 1e-6 * sv.max()


@pytest.mark.parametrize("name", ["lamps_room", "window_room"])
def test_recover_perturbed_primitives(name):
    # true primitives perturbed by 10 cm / 5 deg, fitted to their projected corners: every primitive
    # whose corners determine it comes back within 1 cm / 0.5 deg (in practice to ~1e-6 m)
    d, cam = _scene(name)
    truth, model = model_from_dict(d), model_from_dict(d)
    constrain_to_truth(model, truth, cam)
    obs = {p.name: observable(model, cam, p.name) for p in model.prims}
    perturb(model, np.random.default_rng(3))
    info = model.fit(cam)
    assert info["rms_px"] < 1e-3
    worst_pos, worst_yaw, n = 0.0, 0.0, 0
    for p, q in zip(model.prims, truth.prims):
        if not obs[p.name]:
            continue
        n += 1
        worst_pos = max(worst_pos, np.abs(p.vertices() - q.vertices()).max())
        worst_yaw = max(worst_yaw, np.degrees(abs(p.yaw - q.yaw)))
    print(f"{name}: {n}/{len(model.prims)} primitives determined by their corners; worst corner error "
          f"{worst_pos * 100:.2g} cm, yaw {worst_yaw:.2g} deg; unobservable: {[k for k, v in obs.items() if not v]}")
    assert n >= len(model.prims) - 2
    assert worst_pos < 0.01 and worst_yaw < 0.5
    # every furniture box is determined
    assert all(obs[p.name] for p in model.prims if p.kind == "box")


def test_hierarchy_strict_and_drag():
    d, cam = _scene("window_room")
    model = model_from_dict(d)
    truth = model_from_dict(d)
    constrain_to_truth(model, truth, cam)
    top, leg = model["desk_top"], model["desk_leg0"]
    assert top.parent == "desk_leg0" and top.attach == "top"
    uv = cam.project(leg.vertices())[0]
    # the desk top and the leg's top are held by nothing but the dragged corner
    model.constraints = [c for c in model.constraints if c.primitive != "desk_top"
                         and not (c.primitive == "desk_leg0" and c.vertex & 2)]
    # drag the leg's top front corner 8 px up: the leg grows, the desk top follows it exactly
    info = model.drag(cam, "desk_leg0", 6, uv[6] + [0, -8])
    assert info["n_params"] == 6 + 6  # the leg and its child (desk top); up=True adds the parent
    lo_top = top.center[1] - top.half_extent()[1]
    hi_leg = leg.center[1] + leg.half_extent()[1]
    assert abs(lo_top - hi_leg) < 1e-12 and hi_leg > 0.71 + 1e-3
    assert abs(leg.center[1] - leg.half_extent()[1]) < 1e-12  # still on the floor
    assert np.linalg.norm(cam.project(leg.vertices()[6:7])[0][0] - (uv[6] + [0, -8])) < 0.5  # target is off the vertical line by ~0.3 px


def test_save_load_roundtrip_and_export(tmp_path):
    from recon.patches import build_patches
    from recon.scene import load_scene

    root = shared_scene("lamps_room")
    model = load_model(root / "scene.json")
    box = Primitive.box("crate", [1.0, 0, 2.5], [0.4, 0.3, 0.5], yaw_deg=20.0, parent="floor", albedo=[0.5] * 3)
    model = PrimitiveModel(model.prims + [box], model.constraints)
    model.set_constraint("crate", 7, [300.0, 200.0])
    assert abs(model["crate"].center[1] - 0.15) < 1e-12  # snapped onto the floor
    save_model(tmp_path / "m.json", model)
    back = load_model(tmp_path / "m.json")
    for p, q in zip(model.prims, back.prims):
        assert p.name == q.name and p.parent == q.parent and p.attach == q.attach
        assert np.abs(p.vertices() - q.vertices()).max() < 1e-9
    assert len(back.constraints) == 1 and back["crate"].yaw == pytest.approx(np.radians(20))
    scene = load_scene(root, load_textures=False)
    mesh = build_patches(model.to_scene(scene, root=root), patch_size=0.5)
    ref = build_patches(scene, patch_size=0.5)
    assert mesh.area.sum() == pytest.approx(ref.area.sum() + 2 * (0.4 * 0.3 + 0.3 * 0.5 + 0.4 * 0.5), rel=1e-9)  # rotated: 6 faces


def test_bad_model_input(tmp_path):
    base = {"name": "a", "type": "box", "center": [0, 0.5, 0], "size": [1, 1, 1]}
    cases = [
        ({"primitives": [dict(base, parent="nope")]}, "parent 'nope' does not exist"),
        ({"primitives": [dict(base, attach="sideways")]}, "attach"),
        ({"primitives": [dict(base, parent="b"), dict(base, name="b", parent="a")]}, "cycle"),
        ({"primitives": [dict(base, size=[1, 0, 1])]}, "size"),
        ({"primitives": [base], "image_constraints": [{"primitive": "a", "vertex": 9, "px": [0, 0]}]}, "vertex 9"),
        ({"primitives": []}, "non-empty"),
        # numbers must be JSON numbers (a string is never converted)
        ({"primitives": [dict(base, gap="0.1")]}, r"primitives\[0\]\.gap' must be a number, got \"0.1\""),
        ({"primitives": [base], "image_constraints": [{"primitive": "a", "vertex": "3", "px": [0, 0]}]},
         r"vertex' must be a number"),
        ({"primitives": [base], "image_constraints": [{"primitive": "a", "vertex": 2.5, "px": [0, 0]}]},
         "must be a whole number, got 2.5"),
        ({"primitives": [base], "image_constraints": [{"primitive": "a", "vertex": 1, "px": [0, 0],
                                                        "weight": float("nan")}]}, "weight' must be finite"),
    ]
    for k, (d, msg) in enumerate(cases):
        path = tmp_path / f"m{k}.json"
        path.write_text(json.dumps(d))
        with pytest.raises(ValueError, match=msg) as e:
            load_model(path)
        assert str(path) in str(e.value)


def test_model_cli(tmp_path):
    from app.cli import main

    root = shared_scene("window_room")
    d, cam = _scene("window_room")
    model = model_from_dict(d)
    constrain_to_truth(model, model_from_dict(d), cam)
    perturb(model, np.random.default_rng(5))
    save_model(tmp_path / "in.json", model)
    out = tmp_path / "fit"
    assert main(["-q", "model", str(tmp_path / "in.json"), "--image", str(root / "background.png"), "--camera",
                 str(root / "scene.json"), "--out", str(out)]) == 0
    fitted = load_model(out / "model.json")
    assert np.abs(fitted["desk_top"].vertices() - model_from_dict(d)["desk_top"].vertices()).max() < 0.01
    assert (out / "overlay.png").is_file()
    assert main(["-q", "model", str(tmp_path / "in.json"), "--image", str(root / "background.png"), "--camera",
                 str(tmp_path / "missing.json"), "--out", str(tmp_path / "f2")]) == 2
    assert not (tmp_path / "f2").exists()
