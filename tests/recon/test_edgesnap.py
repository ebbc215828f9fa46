"""Snapping clicked segments to image edges (recon/edgesnap.py): analytic anti-aliased edges with a
known sub-pixel line, and the cases where it must refuse (clipped side, two close edges, a click
too far off, an edge that is not there)."""
import numpy as np
import pytest

from recon.edgesnap import EdgeImage, snap_segments

SS = 16  # supersampling: each pixel is the box average of SS x SS sub-pixels (as a box-filter render)


def _render(inside, shape=(160, 200), dark=0.05, bright=0.6, noise=1.0, seed=0):
    """8-bit sRGB-like image (gamma 2.2) of a region `inside(x, y)` (pixel coordinates, pixel (0,0)
    centred at the origin), box-filtered over each pixel, with N(0, noise^2) levels of noise."""
    import cv2

    h, w = shape
    y, x = (np.mgrid[0:h * SS, 0:w * SS] + 0.5) / SS - 0.5
    lin = np.where(inside(x, y), bright, dark).astype(np.float32)
    lin = cv2.resize(lin, (w, h), interpolation=cv2.INTER_AREA)
    z = 255 * np.clip(lin, 0, 1) ** (1 / 2.2) + np.random.default_rng(seed).normal(0, noise, lin.shape)
    return np.repeat(np.clip(np.rint(z), 0, 255).astype(np.uint8)[:, :, None], 3, axis=2)


P0, D = np.array([61.3, 20.4]), np.array([np.sin(0.2), np.cos(0.2)])  # a line 11.5 deg off vertical
N = np.array([-D[1], D[0]])


def _side(x, y, offset=0.0):
    return (x - P0[0]) * N[0] + (y - P0[1]) * N[1] > offset


def _dist(seg):
    """Distances (px) of a segment's endpoints from the true line."""
    return np.array([(seg[:2] - P0) @ N, (seg[2:] - P0) @ N])


def _click(off0, off1, t0=5.0, t1=120.0):
    return np.concatenate([P0 + t0 * D + off0 * N, P0 + t1 * D + off1 * N])


def test_snap_recovers_a_subpixel_edge():
    img = _render(_side)
    for off in ((0.6, -0.4), (-1.0, 0.3), (0.2, 0.9)):
        r = snap_segments(img, _click(*off)[None])
        assert r.snapped[0], off
        assert np.all(np.abs(_dist(r.segments[0])) < 0.05), (off, _dist(r.segments[0]))
        assert r.sigma_px[0] == pytest.approx(0.1)  # the floor: the sample spread alone says less
    # the endpoints stay where they were clicked along the line
    seg = snap_segments(img, _click(0.6, -0.4)[None]).segments[0]
    assert abs((seg[:2] - P0) @ D - 5.0) < 0.5 and abs((seg[2:] - P0) @ D - 120.0) < 0.5


def test_snap_refuses_a_clipped_side():
    # the bright side saturates (an emitter): the apparent edge moves, so it is not snapped
    img = _render(_side, bright=3.0)
    r = snap_segments(img, _click(0.3, -0.3)[None])
    assert not r.snapped[0] and np.array_equal(r.segments[0], _click(0.3, -0.3))
    assert r.sigma_px[0] == 0.5


def test_snap_refuses_two_close_edges(monkeypatch):
    # a bar 1.5 px wide (a thin leg seen from afar): both sides lie in the search window. A loose
    # click noise (5 px) takes the click test out of play: the ambiguity rule alone refuses it ...
    img = _render(lambda x, y: _side(x, y) & ~_side(x, y, 1.5))
    assert not snap_segments(img, _click(0.5, 0.5)[None], click_sigma_px=5.0).snapped[0]
    # ... without which the far side would be taken, about 1.8 px off
    import recon.edgesnap

    monkeypatch.setattr(recon.edgesnap, "AMBIGUOUS", 99.0)
    r = snap_segments(img, _click(0.5, 0.5)[None], click_sigma_px=5.0)
    assert r.snapped[0] and np.all(_dist(r.segments[0]) > 1.5)
    monkeypatch.undo()
    # 6 px wide: the far side is out of the window, the near one is found
    img = _render(lambda x, y: _side(x, y) & ~_side(x, y, 6.0))
    r = snap_segments(img, _click(0.2, 0.1)[None])
    assert r.snapped[0] and np.all(np.abs(_dist(r.segments[0])) < 0.05)


def test_snap_refuses_far_clicks_and_missing_edges():
    img = _render(_side)
    # 2.5 px off: the edge is outside the +-1.75 px window
    assert not snap_segments(img, _click(2.5, 2.5)[None]).snapped[0]
    # a flat image: nothing to snap to
    flat = _render(lambda x, y: np.zeros_like(x, bool))
    assert not snap_segments(flat, _click(0.0, 0.0)[None]).snapped[0]
    # a click on the image border, half outside: no crash, not snapped or snapped inside
    r = snap_segments(img, np.array([[-20.0, -20.0, 3.0, 3.0]]))
    assert np.all(np.isfinite(r.segments))


def test_bad_image():
    with pytest.raises(ValueError, match="8-bit"):
        EdgeImage(np.zeros((10, 10, 3), np.float32))
