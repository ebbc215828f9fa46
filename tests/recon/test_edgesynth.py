"""recon/edgesynth.py: the profile detector's lean toward the bright side, predicted by synthesis.

Analytic: tests/recon/test_camrefine.py's room (a box room, a table, a window), each face a flat linear
level, box-filtered (3x3 supersampled ray casting), with pixel noise proportional to the level (a path
tracer's grain: the bright side's is larger), through gamma 2.2 to 8 bits. At the true camera the
profile detector's edges lean toward each edge's bright side; the synthetic photo rebuilt from the
photo's own per-face levels and noise predicts that lean, and subtracting it removes most of it."""
from __future__ import annotations

import numpy as np
import pytest

from recon.camrefine import _exclusive, _Occluder, _project, _sample_edges, room_edges, room_faces
from recon.edgesynth import EdgeSynth, edge_leans, face_coverage
from recon.edgesnap import EdgeImage
from recon.photoedges import PhotoEdges
from tests.recon.test_camrefine import PRIMS, _look_at

PHOTOS = 24  # photos of the room with independent noise: the detector's expected lean (its per-edge median
# over one photo scatters by ~0.1 px about it)
REL_NOISE = 0.6  # pixel noise, linear, as a fraction of the level: sun_101's floor-wall crease is ~0.7


@pytest.fixture(scope="module")
def room():
    cam = _look_at(np.array([3.2, 1.5, 4.4]), [1.0, 0.9, 0.5])
    faces = room_faces(PRIMS)
    occ = _Occluder(faces)
    lab = face_coverage(cam, occ, len(faces))
    rng = np.random.default_rng(3)
    level = rng.uniform(0.03, 0.25, len(faces))  # linear
    cov = np.stack([(lab == f).mean(axis=2) for f in range(len(faces))], -1)
    mean = cov @ level
    std = np.sqrt(cov @ (REL_NOISE * level) ** 2)
    lin = mean + std * rng.standard_normal(mean.shape)
    img = np.rint(255 * np.clip(lin, 0, 1) ** (1 / 2.2)).astype(np.uint8)
    return cam, faces, occ, level, lab, np.repeat(img[:, :, None], 3, axis=2)


def test_face_coverage_is_the_box_filter(room):
    """A pixel's sub-pixel rays: every pixel of the image sees a face (a closed room), and the
    pixels that mix faces lie along the projected edges (0.5-5 % of a 640x480 image)."""
    cam, faces, occ, level, lab, img = room
    assert np.all(lab >= 0)
    mixed = np.mean(np.any(lab != lab[:, :, :1], axis=2))
    assert 0.005 < mixed < 0.05


def test_synthetic_levels_and_noise_are_the_photos(room):
    """On pixels a face covers entirely, the synthetic's level is the face's (within 5 %, the mean of
    the gamma-decoded 8-bit noise) and its noise the photo's (within 15 %), on the faces of 2000+ pixels."""
    cam, faces, occ, level, lab, img = room
    syn = EdgeSynth(cam, occ, len(faces), img)
    for f in range(len(faces)):
        m = np.all(lab == f, axis=2)
        if m.sum() < 2000:
            continue
        assert abs(np.median(syn.mean[m]) / level[f] - 1) < 0.05, f
        assert abs(np.median(syn.std[m]) / (REL_NOISE * level[f]) - 1) < 0.15, f


def test_lean_toward_the_bright_side_is_predicted(room):
    """The detector's per-edge offsets at the true camera lean toward the bright side (noise grows with
    the level). The lean the synthetic photo (rebuilt from ONE photo's levels and noise) predicts is the
    detector's expected lean: the mean over the edges of the lean measured on PHOTOS photos of the room
    (independent noise) lies within 30 % of the predicted one (one photo's own lean scatters about it
    by its noise), and over 0.05 px."""
    cam, faces, occ, level, lab, img = room
    S = _sample_edges(cam, room_edges(faces), occ)
    uv, n = _project(cam, S)
    photo = PhotoEdges(img)
    E = photo.fine
    g = E._sample(E.gx, uv[None])[0] * n[:, 0] + E._sample(E.gy, uv[None])[0] * n[:, 1]
    lean = edge_leans(EdgeSynth(cam, occ, len(faces), img), E.near_clip, uv, n, S.edge)
    cov = np.stack([(lab == f).mean(axis=2) for f in range(len(faces))], -1)
    mean, std = cov @ level, np.sqrt(cov @ (REL_NOISE * level) ** 2)
    rng = np.random.default_rng(11)
    d_all, ok_all = [], []
    for _ in range(PHOTOS):
        lin = mean + std * rng.standard_normal(mean.shape)
        other = np.rint(255 * np.clip(lin, 0, 1) ** (1 / 2.2)).astype(np.uint8)
        pe = PhotoEdges.__new__(PhotoEdges)  # the profile detector needs only edgesnap's gradient image
        pe.fine = EdgeImage(np.repeat(other[:, :, None], 3, axis=2))
        q, ok = pe.subpixel(uv, n)
        ok &= _exclusive(uv, n, S.edge, q)
        d_all.append(np.sum((q - uv) * n, axis=1))
        ok_all.append(ok)
    meas, pred = [], []
    for e, p in lean.items():
        m = S.edge == e
        ds = np.concatenate([d[m & ok] for d, ok in zip(d_all, ok_all)])
        if len(ds) < 10 * PHOTOS:
            continue
        pol = np.sign(np.median(g[m]))
        meas.append(np.median(ds) * pol)
        pred.append(p * pol)
    assert len(meas) >= 6
    expected, predicted = float(np.mean(meas)), float(np.mean(pred))
    print(f"{len(meas)} edges: expected lean {expected:+.3f} px, predicted {predicted:+.3f} px")
    assert expected > 0.05
    assert abs(predicted - expected) < 0.3 * expected
