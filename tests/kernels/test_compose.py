"""The compose stage (app.stages.compose, kernels.pixel_compose) against the engine's numpy form it replaced,
on a synthetic frame with every case: shadows on listed and filled pixels, non-receiver pixels, the
object light in its three forms, the sun's loss, partial coverage, and clipping on either side."""
import numpy as np
import pytest
import warp as wp

from app.stages.compose import ComposeStage, compose_reference, nonzero_rows
from kernels.pixel_compose import GRID_CELLS, lookup, pack_response, rounding_table, to_pixel
from lighting.photolight import srgb_response

H, W, VR, P = 24, 32, 40, 12


def _fill(known, values, missing, out=None):
    """Any fill works for the comparison: the mean of the known values, scaled per pixel (given `out`,
    the compose stage's image-sized vec3d buffer: written there at the pixels, as WindowFill.fill)."""
    v = np.outer(1.0 + 0.01 * (missing % 7), values.mean(0)) if len(missing) else np.zeros((0, 3))
    if out is None:
        return v
    h = out.numpy()
    h[missing] = v
    out.assign(h)
    return None


def _reference(mode, scene, pix_sel, O_pix, fill_sel, R_pix, dE_v, cov, obj_rad, sun_pix, sun_loss):
    sc = scene
    out = compose_reference(mode, sc["L_b"], sc["L_b_levels"], sc["E_x"], sc["rho_x"], sc["recv_pix"], sc["pix_rows"],
                            sc["pix_bary"], sc["photo"], sc["response"], pix_sel, O_pix, fill_sel, _fill, R_pix, dE_v,
                            cov, obj_rad, sun_pix, sun_loss)
    return tuple(a.reshape(H, W, 3) for a in out)


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(7)
    resp = srgb_response(exposure_time=0.7)
    n = H * W
    photo = rng.integers(0, 256, (H, W, 3)).astype(np.uint8)
    photo.reshape(-1, 3)[rng.random(n) < 0.05] = 255  # clipped pixels
    L_b = resp.to_radiance(photo).reshape(-1, 3)
    recv_pix = rng.random(n) < 0.8
    pix_rows = rng.integers(0, VR, (n, 3))
    pix_rows[rng.random(n) < 0.05, 1] = -1  # no vertex there: never a receiver pixel
    recv_pix &= pix_rows.min(1) >= 0
    bary = rng.random((n, 3)).astype(np.float32)
    bary /= bary.sum(1, keepdims=True)
    E_x = np.where(recv_pix[:, None], rng.uniform(0.2, 2.0, (n, 3)), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho_x = np.where(E_x > 0, np.minimum(L_b / E_x, 1.0), 0.0)
    return dict(L_b=L_b, L_b_levels=resp.to_levels(L_b), E_x=E_x, rho_x=rho_x, recv_pix=recv_pix, pix_rows=pix_rows,
                pix_bary=bary, photo=photo, response=resp, G_v=rng.random((VR, P)).astype(np.float32) * 0.05,
                E_v=rng.random((VR, 3)), recv_vert=np.arange(VR))


def _frame_inputs(rng, scene, mode):
    n = H * W
    perm = rng.permutation(np.flatnonzero(scene["recv_pix"]))
    pix_sel, fill_sel = np.sort(perm[:300]), np.sort(perm[300:450])
    E = scene["E_x"][pix_sel]
    O_pix = rng.uniform(0, 1.3, (len(pix_sel), 3)) * (E if mode == "hdr" else 30.0)
    O_pix[:20] = 0.0  # listed but unshadowed
    R_idx = np.sort(rng.choice(np.flatnonzero(scene["recv_pix"]), 200, replace=False))
    R_vals = rng.uniform(0, 0.05, (200, 3))
    R_v = rng.uniform(0, 0.01, (VR, 3))
    dB = np.zeros((P, 3))
    dB[[1, 4, 7]] = rng.uniform(-0.3, 0.1, (3, 3))
    cov = np.zeros((H, W))
    cov[5:15, 8:20] = rng.choice([0.25, 0.5, 1.0], (10, 12))
    obj = np.zeros((H, W, 3))
    obj[5:15, 8:20] = rng.uniform(0, 1.6, (10, 12, 3))  # some clip
    sun_pix = np.sort(rng.choice(n, 100, replace=False))
    sun_loss = rng.uniform(0, 0.5, (100, 3))
    sun_loss[::4] = 0.0  # sun pixels the object takes no sun from: no row of their own
    sun_loss[1::9, 1] = 0.0  # a loss in some channels only
    return pix_sel, O_pix, fill_sel, (R_v, R_idx, R_vals), dB, cov, obj, sun_pix, sun_loss


def _dense(scene, R):
    R_v, idx, vals = R
    out = np.zeros((H * W, 3))
    rp = scene["recv_pix"]
    out[rp] = np.einsum("nk,nkc->nc", scene["pix_bary"][rp], R_v[scene["pix_rows"][rp]])
    out[idx] = vals
    return out


def _assert_same_levels(got: np.ndarray, want: np.ndarray, what) -> None:
    """8-bit frames from the kernels and from the numpy reference: equal (on this project's machine
    bit for bit), except that a value whose radiance lies within float32 rounding of a half level
    may round the other way on another CPU (the two sum in different orders, with or without
    fused multiply-adds): at most 1e-4 of the values, by one level."""
    d = np.abs(got.astype(np.int32) - want.astype(np.int32))
    assert d.max(initial=0) <= 1 and (d > 0).sum() <= max(1, 1e-4 * d.size), (what, d.max(), (d > 0).sum())


@pytest.mark.parametrize("mode", ["hdr", "ldr"])
def test_compose_matches_the_numpy_reference(scene, mode, device):
    stage = ComposeStage(**scene, patches=None, shape=(H, W), device=device)
    rng = np.random.default_rng(1 if mode == "hdr" else 2)
    for frame in range(4):  # the buffers are reset between frames: each frame alone must match
        pix_sel, O_pix, fill_sel, R, dB, cov, obj, sun_pix, sun_loss = _frame_inputs(rng, scene, mode)
        sun = frame % 2 == 1
        dE_v = stage.second_order(dB) if frame != 2 else None
        np.testing.assert_allclose(dE_v if dE_v is not None else 0.0,
                                   scene["G_v"].astype(np.float64) @ dB if dE_v is not None else 0.0, rtol=1e-12)
        dense = _dense(scene, R)
        forms = {"dense": dense, "sparse": (R[1], dense[R[1]]), "vertex": R}
        if frame == 2:  # the sparse form alone: no light elsewhere
            forms = {"sparse": (R[1], R[2])}
        for name, R_pix in forms.items():
            if name == "sparse":
                ref_R = np.zeros((H * W, 3))
                ref_R[R_pix[0]] = R_pix[1]
            else:
                ref_R = dense
            args = (pix_sel, O_pix, fill_sel)
            got = stage.frame(mode, *args, _fill, R_pix, dE_v, cov, obj, sun_pix if sun else None,
                              sun_loss if sun else None)
            want = _reference(mode, scene, *args, ref_R, dE_v, cov, obj, sun_pix if sun else None,
                              sun_loss if sun else None)
            # the same 8-bit frames; radiance to float32 rounding (sums may associate differently)
            _assert_same_levels(got[1], want[1], (mode, frame, name))
            for g, w in ((got[0], want[0]), (got[2], want[2])):
                np.testing.assert_allclose(g, w, rtol=2e-7, atol=1e-12)
            assert (got[1] != scene["photo"]).any()  # the frame did change something


def test_nonzero_rows_is_any_over_the_channels():
    """nonzero_rows(a) equals a.any(1) on zeros, signed zeros, negatives, NaN and infinities, alone and mixed."""
    vals = np.array([0.0, -0.0, 1e-300, -2.5, np.nan, np.inf, -np.inf])
    a = np.array(np.meshgrid(vals, vals, vals, indexing="ij")).reshape(3, -1).T.copy()  # every combination
    assert len(a) == len(vals) ** 3
    np.testing.assert_array_equal(nonzero_rows(a), a.any(1))
    assert not nonzero_rows(np.zeros((4, 3))).any() and nonzero_rows(np.zeros((0, 3))).shape == (0,)


@wp.kernel
def _lookup_kernel(x: wp.array(dtype=wp.float64), row: int, tab: wp.array2d(dtype=wp.float64),
                   grid: wp.array2d(dtype=wp.int32), out: wp.array(dtype=wp.float64)):
    i = wp.tid()
    out[i] = lookup(x[i], row, tab, grid)


@pytest.mark.parametrize("inverse", [False, True])
def test_response_lookup_is_np_interp_on_hard_values(inverse, device):
    """The kernel's table lookup equals np.interp bit for bit: at the breakpoints (ties included), one
    ulp either side of them and of the grid's cell starts, at 0 and 1, and outside the range."""
    from recon.response import CameraResponse

    g = np.linspace(0, 1, 256)
    # a response with a flat top (ties in ys) and a steep toe (crowded xs near 0)
    fwd = np.tile(np.minimum(g ** (1 / 2.6) * 1.05, 1.0), (3, 1))
    inv = np.tile(np.minimum(g, 0.95) ** 2.6, (3, 1))
    xs, ys = CameraResponse(fwd, inv).breakpoints()
    xp, fp = (ys, xs) if inverse else (xs, ys)
    tab, grid = pack_response(xs, ys)
    tab_wp = wp.array(tab, dtype=wp.float64, device=device)
    grid_wp = wp.array(grid, dtype=wp.int32, device=device)
    cells = np.arange(GRID_CELLS + 1) / GRID_CELLS
    for c in range(3):
        pts = np.concatenate([xp[c], np.nextafter(xp[c], 2), np.nextafter(xp[c], -1), cells,
                              np.nextafter(cells, -1), np.nextafter(cells, 2), [-0.5, 1.5],
                              np.random.default_rng(c).random(2000)])
        out = wp.zeros(len(pts), dtype=wp.float64, device=device)
        wp.launch(_lookup_kernel, dim=len(pts), device=device,
                  inputs=[wp.array(pts, dtype=wp.float64, device=device), 3 * inverse + c, tab_wp, grid_wp, out])
        assert np.array_equal(out.numpy(), np.interp(pts, xp[c], fp[c]))


@wp.kernel
def _pixel_kernel(L: wp.array(dtype=wp.float64), c: int, exposure: wp.float64, rtab: wp.array2d(dtype=wp.int16),
                  tab: wp.array2d(dtype=wp.float64), grid: wp.array2d(dtype=wp.int32), out: wp.array(dtype=wp.int32)):
    i = wp.tid()
    out[i] = to_pixel(L[i], c, exposure, rtab, tab, grid)


@pytest.mark.parametrize("cells", [64, 1 << 15])
def test_to_pixel_is_the_rounded_level_on_hard_values(cells, device):
    """to_pixel (the rounding table, T where a cell holds a half level) equals clip(rint(T(L)), 0, 255)
    exactly: at radiances whose level is a half level (and one ulp either side), at the breakpoints
    (a jump: tied xs; a dip), the cells' ends, 0, 1 and beyond; with a coarse table (most cells ambiguous)
    and the stage's own."""
    from recon.response import CameraResponse

    g = np.linspace(0, 1, 256)
    fwd = np.tile(np.minimum(g ** (1 / 2.6) * 1.05, 1.0), (3, 1))
    inv = np.tile(np.minimum(g, 0.95) ** 2.6, (3, 1))
    xs, ys = CameraResponse(fwd, inv).breakpoints()
    xs, ys = xs.copy(), ys.copy()
    xs[:, 300] = xs[:, 299]  # a jump: tied xs, two levels at one x
    for c in range(3):  # a dip in the flat top (not monotone): the bound must take the breakpoint's value
        ys[c, np.searchsorted(xs[c], 0.96)] -= 0.03  # its neighbours in the same cell of 64
    exposure = 0.37
    rtab = rounding_table(xs, ys, cells)
    assert (rtab >= 0).any() and (rtab < 0).any()
    tab, grid = pack_response(xs, ys)
    args = [wp.array(rtab, dtype=wp.int16, device=device), wp.array(tab, dtype=wp.float64, device=device),
            wp.array(grid, dtype=wp.int32, device=device)]
    edges = np.arange(cells + 1) / cells
    for c in range(3):
        half = (np.arange(255) + 0.5) / 255.0  # f(x) = a half level, on the segment that holds it
        j = np.clip(np.searchsorted(ys[c], half) - 1, 0, len(xs[c]) - 2)
        t = (half - ys[c, j]) / np.maximum(ys[c, j + 1] - ys[c, j], 1e-300)
        x_half = xs[c, j] + t * (xs[c, j + 1] - xs[c, j])
        x = np.concatenate([x_half, xs[c], edges, [0.0, 1.0, -0.2, 3.0], np.random.default_rng(c).random(3000) ** 3])
        x = np.concatenate([x, np.nextafter(x, 2), np.nextafter(x, -1)])
        L = x / exposure
        out = wp.zeros(len(L), dtype=wp.int32, device=device)
        wp.launch(_pixel_kernel, dim=len(L), device=device,
                  inputs=[wp.array(L, dtype=wp.float64, device=device), c, exposure, *args, out])
        want = np.clip(np.rint(255.0 * np.interp(np.clip(L * exposure, 0, 1), xs[c], ys[c])), 0, 255)
        assert np.array_equal(out.numpy(), want), np.flatnonzero(out.numpy() != want)[:5]


@pytest.mark.parametrize("n_vert", [1, 6, 41])
def test_second_order_sums_in_patch_order(n_vert, device):
    """Several vertices per thread, side by side: each vertex's sum is still G_v[v, p] dB[p] added in
    patch order in float64, bit for bit, for vertex counts that leave a partial group of rows, and
    over two launch ranges (as the two-core split cuts them)."""
    from kernels.pixel_compose import Compositor

    rng = np.random.default_rng(n_vert)
    G_v = (rng.random((n_vert, 30)) * 0.1).astype(np.float32)
    dB = np.zeros((30, 3))
    dB[rng.choice(30, 17, replace=False)] = rng.normal(size=(17, 3))
    n = 4
    k = Compositor(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)), np.full((n, 3), -1), np.zeros((n, 3)),
                   {"hdr": (np.zeros((n, 3)), np.zeros((n, 3))), "ldr": (np.zeros((n, 3)), np.zeros((n, 3)))},
                   np.tile(np.linspace(0, 1, 5), (3, 1)), np.tile(np.linspace(0, 1, 5), (3, 1)), 1.0, G_v, device)
    want = np.zeros((n_vert, 3))
    for p in np.flatnonzero(np.abs(dB).sum(1) > 0):  # sequential float64 sums in patch order
        want += G_v[:, p:p + 1].astype(np.float64) * dB[p]

    def halves(launch, m):
        launch(0, m // 2)
        launch(m // 2, m)

    for split in (lambda launch, m: launch(0, m), halves):
        k.dE_v[:] = np.nan
        k.second_order(dB, split)
        assert np.array_equal(k.dE_v[:n_vert], want) and np.array_equal(k.add_v[:n_vert], want)


def test_kept_frames_never_change_and_dropped_ones_are_reused(scene, device):
    """The output arrays come from a pool: a frame someone holds (its radiance, pixels or room, or a
    view of one) is never written by the frames after it, and the arrays of a frame no one holds any
    more are written again (no new allocation), each frame still equal to the reference."""
    stage = ComposeStage(**scene, patches=None, shape=(H, W), device=device)
    rng = np.random.default_rng(5)

    def frame():
        pix_sel, O_pix, fill_sel, R, dB, cov, obj, sun_pix, sun_loss = _frame_inputs(rng, scene, "hdr")
        dE_v = stage.second_order(dB)
        got = stage.frame("hdr", pix_sel, O_pix, fill_sel, _fill, R, dE_v, cov, obj)
        want = _reference("hdr", scene, pix_sel, O_pix, fill_sel, _dense(scene, R), dE_v, cov, obj, None, None)
        _assert_same_levels(got[1], want[1], "reused buffers")
        return got

    kept = frame()
    held_view = frame()[1][3:7, 2]  # only a view of one of the frame's arrays is held
    held_copy = [a.copy() for a in kept], held_view.copy()
    seen = set()
    for _ in range(6):
        out = frame()
        seen.add(out[0].__array_interface__["data"][0])
        for a in out:
            assert not np.shares_memory(a, kept[0]) and not np.shares_memory(a, kept[1])
            assert not np.shares_memory(a, kept[2]) and not np.shares_memory(a, held_view)
        del out, a
    assert all(np.array_equal(a, b) for a, b in zip(kept, held_copy[0]))
    assert np.array_equal(held_view, held_copy[1])
    assert len(seen) == 1  # frames dropped at once: one set, written again and again
