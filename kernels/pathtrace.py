"""Monte-Carlo differential renderer: the ray-traced reference of seed sec. 7 (fig. 17, 18).

Debevec (SIGGRAPH 98, "Rendering synthetic objects into real scenes"): render the local scene
model twice, without the object (I_noobj) and with it (I_obj), and add their difference to the
photo, L_final = L_b - (I_noobj - I_obj) outside the object and I_obj on it.

Each pixel sample traces one unidirectional path (Kajiya 1986) through a model made of the
scene's patches (recon.patches.PatchMesh: Lambertian, per-patch albedo or the quad's albedo
texture, one-sided Lambertian emitter patches) and, in the object pass, the object's triangle
mesh (Lambertian, the scene's object albedo, smooth shading normals):
  * the camera ray sees emission directly (emitters do not reflect);
  * at each of up to `bounces` surface vertices, next-event estimation: one emitter patch
    chosen in proportion to its power (area x luminance of emission), a uniform point on it,
    one shadow ray (contribution albedo/pi * L_e * cos_x cos_y / d^2 / pdf);
  * then a cosine-weighted direction to the next vertex (throughput *= albedo).
  * with a sun (recon.scene.Sun: a far disk of angular radius a, radiance L_s = E_perp / (pi sin^2 a)),
    a second next-event estimate at each vertex: a direction uniform in the disk's cone (solid angle
    Omega = 2 pi (1 - cos a)), contribution albedo/pi * L_s * cos_x * Omega, with a shadow ray whose
    first hit in the model must be the front of an opening quad's patch (the sun is seen only
    through openings; the object between is tested as for the other shadow rays). Bounce rays that
    leave through an opening meet its sky patch and end there, so the sun is never counted twice.
    Rays are parallel (the disk's 2000 m distance moves its direction by < 0.1 deg in a room);
    the two extra random numbers are drawn only when there is a sun (scenes without one trace the
    same paths as before);
`bounces` = 4 reproduces Mitsuba's `max_depth` 5 used for the benchmark truth.

Correlated sampling: the object-free path is traced first while testing every ray segment
(bounce rays and shadow rays) against the object's BVH as well. A path the object never
touches is the same path in both renders, so I_obj = I_noobj for that sample and the
difference is exactly zero; only touched paths are traced again, with the same random numbers,
in the scene with the object. The difference is therefore far less noisy than either image.

Samples: pixel (col, row) covers [col-0.5, col+0.5] x [row-0.5, row+0.5] (pixel centres at
integers, FORMAT.md); sample j of a batch of spp samples is jittered inside stratum j mod n^2 of
an n x n grid, n = floor(sqrt(spp)) (stratified box filter). Each batch is stratified on its own,
so it is an unbiased estimate by itself and the spread of batch means is an honest variance.
Random numbers come from Warp's PCG seeded with (seed, sample number, pixel): a render is
reproducible and two seeds give independent estimates.

The same kernel runs on the CPU and on CUDA (no host callbacks, no recursion, fixed loops).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from kernels import runtime
from kernels.luma import LUMA

EMITTER_LIFT = 1.0e-3  # m: emitter patches are lifted off the wall they sit on (as the engine's camera mesh)
RAY_EPS = 1.0e-4  # m: ray origins pushed off their surface along the geometric normal


@wp.func
def _frame_dir(n: wp.vec3, r1: float, r2: float) -> wp.vec3:
    """Cosine-weighted direction about unit n (Malley's method, pdf cos/pi)."""
    phi = 2.0 * wp.pi * r1
    s = wp.sqrt(r2)
    lx = s * wp.cos(phi)
    ly = s * wp.sin(phi)
    lz = wp.sqrt(wp.max(0.0, 1.0 - r2))
    a = wp.vec3(1.0, 0.0, 0.0)
    if wp.abs(n[0]) > 0.9:
        a = wp.vec3(0.0, 1.0, 0.0)
    t = wp.normalize(wp.cross(a, n))
    b = wp.cross(n, t)
    return t * lx + b * ly + n * lz


@wp.func
def _cone_dir(axis: wp.vec3, one_minus_cos: float, r1: float, r2: float) -> wp.vec3:
    """Direction uniform in solid angle within the cone of half-angle acos(1 - one_minus_cos) about unit
    axis (1 - cos passed as such: float32 cannot hold the cosine of a 0.27 deg angle to better than 1 %
    of 1 - cos)."""
    ct = 1.0 - r1 * one_minus_cos
    st = wp.sqrt(wp.max(0.0, 1.0 - ct * ct))
    phi = 2.0 * wp.pi * r2
    a = wp.vec3(1.0, 0.0, 0.0)
    if wp.abs(axis[0]) > 0.9:
        a = wp.vec3(0.0, 1.0, 0.0)
    t = wp.normalize(wp.cross(a, axis))
    b = wp.cross(axis, t)
    return t * (st * wp.cos(phi)) + b * (st * wp.sin(phi)) + axis * ct


@wp.func
def _texel(texels: wp.array(dtype=wp.vec3), off: int, w: int, h: int, x: int, y: int) -> wp.vec3:
    xi = wp.clamp(x, 0, w - 1)
    yi = wp.clamp(y, 0, h - 1)
    return texels[off + yi * w + xi]


@wp.func
def _albedo(p: wp.vec3, patch: int, patch_albedo: wp.array(dtype=wp.vec3), patch_quad: wp.array(dtype=wp.int32),
            quad_c0: wp.array(dtype=wp.vec3), quad_du: wp.array(dtype=wp.vec3), quad_dv: wp.array(dtype=wp.vec3),
            quad_tex: wp.array(dtype=wp.vec3i), texels: wp.array(dtype=wp.vec3)) -> wp.vec3:
    """Albedo at point p of a patch: the quad's texture (bilinear, clamped), else the patch mean."""
    q = patch_quad[patch]
    info = quad_tex[q]  # (offset, width, height); offset < 0: no texture
    if info[0] < 0:
        return patch_albedo[patch]
    d = p - quad_c0[q]
    x = wp.dot(d, quad_du[q]) * float(info[1]) - 0.5
    y = wp.dot(d, quad_dv[q]) * float(info[2]) - 0.5
    x0 = int(wp.floor(x))
    y0 = int(wp.floor(y))
    fx = x - float(x0)
    fy = y - float(y0)
    a = _texel(texels, info[0], info[1], info[2], x0, y0)
    b = _texel(texels, info[0], info[1], info[2], x0 + 1, y0)
    c = _texel(texels, info[0], info[1], info[2], x0, y0 + 1)
    e = _texel(texels, info[0], info[1], info[2], x0 + 1, y0 + 1)
    return (a * (1.0 - fx) + b * fx) * (1.0 - fy) + (c * (1.0 - fx) + e * fx) * fy


@wp.func
def _pick_emitter(cdf: wp.array(dtype=wp.float32), r: float) -> int:
    """Index k with cdf[k-1] <= r < cdf[k] (binary search; cdf ends at 1)."""
    lo = int(0)
    hi = cdf.shape[0] - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if cdf[mid] <= r:
            lo = mid + 1
        else:
            hi = mid
    return lo


@wp.struct
class Model:
    """The scene model and the object, as device arrays (see PathTracer for shapes)."""

    scene: wp.uint64
    tri_patch: wp.array(dtype=wp.int32)
    patch_normal: wp.array(dtype=wp.vec3)
    patch_albedo: wp.array(dtype=wp.vec3)
    patch_emit: wp.array(dtype=wp.vec3)
    patch_quad: wp.array(dtype=wp.int32)
    quad_c0: wp.array(dtype=wp.vec3)
    quad_du: wp.array(dtype=wp.vec3)
    quad_dv: wp.array(dtype=wp.vec3)
    quad_tex: wp.array(dtype=wp.vec3i)
    texels: wp.array(dtype=wp.vec3)
    em_cdf: wp.array(dtype=wp.float32)
    em_prob: wp.array(dtype=wp.float32)
    em_c0: wp.array(dtype=wp.vec3)
    em_eu: wp.array(dtype=wp.vec3)
    em_ev: wp.array(dtype=wp.vec3)
    em_normal: wp.array(dtype=wp.vec3)
    em_emit: wp.array(dtype=wp.vec3)
    em_area: wp.array(dtype=wp.float32)
    obj: wp.uint64
    obj_idx: wp.array(dtype=wp.int32)
    obj_pts: wp.array(dtype=wp.vec3)
    obj_vnormal: wp.array(dtype=wp.vec3)
    obj_albedo: wp.vec3
    patch_open: wp.array(dtype=wp.int32)  # 1: the patch belongs to an opening quad (the sun passes it)
    sun_on: int  # 0: no sun
    sun_dir: wp.vec3  # unit direction to the sun's centre
    sun_1mcos: float  # 1 - cosine of the disk's angular radius
    sun_omega: float  # the disk's solid angle, sr
    sun_L: wp.vec3  # the disk's radiance


@wp.func
def _past_object(m: Model, use_obj: int, a: wp.vec3, d: wp.vec3, t_max: float) -> wp.vec2i:
    """(visible, touched) of a ray from a along d that the scene lets through up to t_max: the object
    blocks it there (touched), which hides what lies beyond when use_obj is set."""
    if m.obj != wp.uint64(0):
        qo = wp.mesh_query_ray(m.obj, a, d, t_max)
        if qo.result:
            if use_obj != 0:
                return wp.vec2i(0, 1)
            return wp.vec2i(1, 1)
    return wp.vec2i(1, 0)


@wp.func
def _shadow(m: Model, use_obj: int, a: wp.vec3, b: wp.vec3) -> wp.vec2i:
    """(visible, touched) for the segment a->b: touched = only the object blocks it."""
    d = b - a
    dist = wp.length(d)
    if dist <= 1.0e-7:
        return wp.vec2i(1, 0)
    d = d / dist
    qs = wp.mesh_query_ray(m.scene, a, d, dist * 0.9999)
    if qs.result:
        return wp.vec2i(0, 0)
    return _past_object(m, use_obj, a, d, dist * 0.9999)


@wp.func
def _sun_shadow(m: Model, use_obj: int, a: wp.vec3, d: wp.vec3) -> wp.vec2i:
    """(visible, touched) for the ray from a toward the sun along d: visible when the first thing it
    meets in the model is the front of an opening's patch (it leaves the room there) and, with use_obj,
    the object is not in between; touched = only the object blocks it."""
    qs = wp.mesh_query_ray(m.scene, a, d, 1.0e6)
    if not qs.result:
        return wp.vec2i(0, 0)  # no opening on the way: the model is not closed there
    patch = m.tri_patch[qs.face]
    if m.patch_open[patch] == 0 or wp.dot(d, m.patch_normal[patch]) >= 0.0:
        return wp.vec2i(0, 0)
    return _past_object(m, use_obj, a, d, qs.t)


@wp.func
def _trace(m: Model, use_obj: int, origin: wp.vec3, direction: wp.vec3, bounces: int, state: wp.uint32) -> wp.vec4:
    """Radiance along one camera path. Returns (r, g, b, flags): flags bit 0 = the object touched
    any segment of this path (for use_obj = 0), bit 1 = the camera ray's first hit is the object."""
    L = wp.vec3(0.0, 0.0, 0.0)
    thr = wp.vec3(1.0, 1.0, 1.0)
    touched = int(0)
    cam_obj = int(0)
    o = origin
    d = direction
    for depth in range(bounces + 1):
        # ---- closest hit: scene model, then the object in front of it
        qs = wp.mesh_query_ray(m.scene, o, d, 1.0e6)
        t_hit = 1.0e6
        if qs.result:
            t_hit = qs.t
        hit_obj = int(0)
        face = int(-1)
        qu = float(0.0)
        qv = float(0.0)
        if m.obj != wp.uint64(0):
            qo = wp.mesh_query_ray(m.obj, o, d, t_hit)
            if qo.result:
                touched = 1
                if use_obj != 0:
                    hit_obj = 1
                    t_hit = qo.t
                    face = qo.face
                    qu = qo.u
                    qv = qo.v
        if hit_obj == 0 and not qs.result:
            break
        p = o + d * t_hit
        ng = wp.vec3(0.0, 0.0, 0.0)
        ns = wp.vec3(0.0, 0.0, 0.0)
        alb = wp.vec3(0.0, 0.0, 0.0)
        if hit_obj != 0:
            if depth == 0:
                cam_obj = 1
            i0 = m.obj_idx[face * 3 + 0]
            i1 = m.obj_idx[face * 3 + 1]
            i2 = m.obj_idx[face * 3 + 2]
            p0 = m.obj_pts[i0]
            p1 = m.obj_pts[i1]
            p2 = m.obj_pts[i2]
            ns = wp.normalize(m.obj_vnormal[i0] * qu + m.obj_vnormal[i1] * qv + m.obj_vnormal[i2] * (1.0 - qu - qv))
            ng = wp.normalize(wp.cross(p1 - p0, p2 - p0))
            if wp.dot(ng, ns) < 0.0:
                ng = -ng
            alb = m.obj_albedo
        else:
            patch = m.tri_patch[qs.face]
            ng = m.patch_normal[patch]
            ns = ng
            e = m.patch_emit[patch]
            if e[0] + e[1] + e[2] > 0.0:
                if depth == 0 and wp.dot(d, ng) < 0.0:
                    L = L + e  # emitters are seen by the camera; bounce rays get them by NEE
                break  # emitters do not reflect
            alb = _albedo(p, patch, m.patch_albedo, m.patch_quad, m.quad_c0, m.quad_du, m.quad_dv, m.quad_tex,
                          m.texels)
        if wp.dot(d, ng) >= 0.0:
            break  # back side of a one-sided surface: black
        if depth == bounces:
            break
        # ---- next-event estimation towards one emitter patch (3 random numbers, always drawn)
        r0 = wp.randf(state)
        r1 = wp.randf(state)
        r2 = wp.randf(state)
        k = _pick_emitter(m.em_cdf, r0)
        en = m.em_normal[k]
        y = m.em_c0[k] + m.em_eu[k] * r1 + m.em_ev[k] * r2 + en * (2.0 * EMITTER_LIFT)
        w = y - p
        dist2 = wp.dot(w, w)
        w = w / wp.sqrt(dist2)
        cos_x = wp.dot(ns, w)
        cos_y = -wp.dot(en, w)
        if cos_x > 0.0 and cos_y > 0.0 and wp.dot(ng, w) > 0.0:
            vis = _shadow(m, use_obj, p + ng * RAY_EPS, y)
            if vis[1] != 0:
                touched = 1
            if vis[0] != 0:
                g = cos_x * cos_y / dist2 * m.em_area[k] / m.em_prob[k]
                L = L + wp.cw_mul(thr, wp.cw_mul(alb, m.em_emit[k])) * (g / wp.pi)
        # ---- the sun: next-event estimation toward a point of its disk (2 random numbers, only with a sun)
        if m.sun_on != 0:
            r5 = wp.randf(state)
            r6 = wp.randf(state)
            ws = _cone_dir(m.sun_dir, m.sun_1mcos, r5, r6)
            cs = wp.dot(ns, ws)
            if cs > 0.0 and wp.dot(ng, ws) > 0.0:
                vs = _sun_shadow(m, use_obj, p + ng * RAY_EPS, ws)
                if vs[1] != 0:
                    touched = 1
                if vs[0] != 0:
                    L = L + wp.cw_mul(thr, wp.cw_mul(alb, m.sun_L)) * (cs * m.sun_omega / wp.pi)
        # ---- continue the path: cosine-weighted bounce (2 random numbers)
        r3 = wp.randf(state)
        r4 = wp.randf(state)
        nd = _frame_dir(ns, r3, r4)
        if wp.dot(nd, ng) <= 0.0:
            break
        thr = wp.cw_mul(thr, alb)
        o = p + ng * RAY_EPS
        d = nd
    return wp.vec4(L[0], L[1], L[2], float(touched + 2 * cam_obj))


@wp.kernel
def _render_kernel(m: Model, pixels: wp.array(dtype=wp.int32), width: int, k_inv: wp.mat33, r_t: wp.mat33,
                   centre: wp.vec3, spp: int, first_sample: int, strata: int, seed: int, bounces: int,
                   noobj: wp.array(dtype=wp.vec3), obj: wp.array(dtype=wp.vec3), diff: wp.array(dtype=wp.vec3),
                   obj_hit: wp.array(dtype=wp.vec3), obj_count: wp.array(dtype=wp.float32)):
    i = wp.tid()
    pix = pixels[i]
    col = pix % width
    row = pix // width
    s_noobj = wp.vec3(0.0, 0.0, 0.0)
    s_obj = wp.vec3(0.0, 0.0, 0.0)
    s_diff = wp.vec3(0.0, 0.0, 0.0)
    s_hit = wp.vec3(0.0, 0.0, 0.0)
    n_hit = float(0.0)
    n2 = strata * strata
    n_strat = (spp // n2) * n2  # whole strata passes; any rest is jittered over the whole pixel
    for j in range(spp):
        s = first_sample + j
        state0 = wp.rand_init(seed * 7919 + s, pix)
        state = state0
        cell = j % n2  # stratified within the batch: every batch is an unbiased estimate on its own
        fx = (float(cell % strata) + wp.randf(state)) / float(strata)
        fy = (float(cell // strata) + wp.randf(state)) / float(strata)
        if j >= n_strat:
            fx = wp.randf(state)
            fy = wp.randf(state)
        uv = wp.vec3(float(col) - 0.5 + fx, float(row) - 0.5 + fy, 1.0)
        d = wp.normalize(r_t * (k_inv * uv))
        state_path = state
        a = _trace(m, 0, centre, d, bounces, state)
        ln = wp.vec3(a[0], a[1], a[2])
        lo = ln
        cam_obj = int(0)
        if int(a[3]) % 2 == 1:
            b = _trace(m, 1, centre, d, bounces, state_path)  # same random numbers: correlated
            lo = wp.vec3(b[0], b[1], b[2])
            cam_obj = int(b[3]) // 2
        s_noobj = s_noobj + ln
        s_obj = s_obj + lo
        if cam_obj != 0:
            s_hit = s_hit + lo
            n_hit = n_hit + 1.0
        else:
            s_diff = s_diff + (ln - lo)
    noobj[i] = s_noobj
    obj[i] = s_obj
    diff[i] = s_diff
    obj_hit[i] = s_hit
    obj_count[i] = n_hit


@dataclass
class PassSums:
    """Per-pixel sums over one batch of samples (N = len(pixels); radiance in scene units).

    noobj, obj (N,3): sum of I_noobj and I_obj samples; diff (N,3): sum of I_noobj - I_obj over the
    samples whose camera ray does not hit the object; obj_hit (N,3): sum of I_obj over the samples
    that do; obj_count (N,): how many do; spp: samples per pixel in the batch.
    """

    noobj: np.ndarray
    obj: np.ndarray
    diff: np.ndarray
    obj_hit: np.ndarray
    obj_count: np.ndarray
    spp: int


class PathTracer:
    """The scene model on the device, ready to render batches of samples for a pixel list.

    patches: recon.patches.PatchMesh (its albedo and emission are used as they are);
    textures: per quad of the model (list aligned with patches.quad indices) an (Ht,Wt,3) linear
      albedo texture or None; quad_corners (Q,4,3) the quads' corners (c0->c1 texture columns,
      c0->c3 rows). Without textures every patch uses its mean albedo.
    sun: recon.scene.Sun or None; quad_opening (Q,) bool per quad: the openings the sun shines
      through (without any, a sun lights nothing).
    camera: recon.camera.Camera; obj_vertices (V,3) / obj_normals (V,3) / obj_faces (F,3) in world
      metres, obj_albedo (3,), or None for an empty scene.
    """

    def __init__(self, patches, camera, obj_vertices=None, obj_normals=None, obj_faces=None, obj_albedo=None,
                 textures: list | None = None, quad_corners: np.ndarray | None = None, device: str | None = None,
                 sun=None, quad_opening: np.ndarray | None = None):
        self.device = dev = runtime.device(device)
        pm = patches
        emit = pm.is_emitter
        if not emit.any():
            raise ValueError("path tracer: the scene model has no emitter patch (nothing lights the room)")
        self.camera = camera
        # scene mesh: every patch; emitters lifted off their wall so rays meet them first
        lift = np.zeros_like(pm.vert_pos)
        ev = pm.tris[emit[pm.tri_patch]].ravel()
        lift[ev] = pm.vert_normal[ev] * EMITTER_LIFT
        self._pts = wp.array((pm.vert_pos + lift).astype(np.float32), dtype=wp.vec3, device=dev)
        self._idx = wp.array(pm.tris.astype(np.int32).reshape(-1), dtype=wp.int32, device=dev)
        self._mesh = wp.Mesh(points=self._pts, indices=self._idx)
        m = Model()
        m.scene = self._mesh.id
        f32 = lambda a: wp.array(np.asarray(a, np.float32), dtype=wp.vec3, device=dev)
        m.tri_patch = wp.array(pm.tri_patch.astype(np.int32), dtype=wp.int32, device=dev)
        m.patch_normal = f32(pm.normal)
        m.patch_albedo = f32(pm.albedo)
        m.patch_emit = f32(np.where(emit[:, None], pm.emission, 0.0))
        m.patch_quad = wp.array(pm.quad.astype(np.int32), dtype=wp.int32, device=dev)
        # quad textures: one flat texel array, (offset, width, height) per quad
        n_q = int(pm.quad.max()) + 1
        info = np.full((n_q, 3), -1, np.int32)
        c0 = np.zeros((n_q, 3))
        du = np.zeros((n_q, 3))
        dv = np.zeros((n_q, 3))
        chunks, off = [np.zeros((1, 3), np.float32)], 1
        if textures is not None and quad_corners is not None:
            for q in range(n_q):
                tex = textures[q] if q < len(textures) else None
                if tex is None:
                    continue
                c = np.asarray(quad_corners[q], np.float64)
                U, V = c[1] - c[0], c[3] - c[0]
                c0[q], du[q], dv[q] = c[0], U / (U @ U), V / (V @ V)
                h, w = tex.shape[:2]
                info[q] = (off, w, h)
                chunks.append(np.asarray(tex, np.float32).reshape(-1, 3))
                off += h * w
        m.quad_c0, m.quad_du, m.quad_dv = f32(c0), f32(du), f32(dv)
        m.quad_tex = wp.array(info, dtype=wp.vec3i, device=dev)
        m.texels = f32(np.concatenate(chunks))
        self.textured = bool((info[:, 0] >= 0).any())
        # emitter patches, chosen in proportion to power (area x luminance of emitted radiance)
        ei = np.flatnonzero(emit)
        lum = pm.emission[ei] @ LUMA
        power = pm.area[ei] * np.maximum(lum, 1e-12)
        prob = power / power.sum()
        cdf = np.cumsum(prob)
        cdf[-1] = 1.0
        cor = pm.corners[ei]
        m.em_cdf = wp.array(cdf.astype(np.float32), dtype=wp.float32, device=dev)
        m.em_prob = wp.array(prob.astype(np.float32), dtype=wp.float32, device=dev)
        m.em_c0, m.em_eu, m.em_ev = f32(cor[:, 0]), f32(cor[:, 1] - cor[:, 0]), f32(cor[:, 3] - cor[:, 0])
        m.em_normal = f32(pm.normal[ei])
        m.em_emit = f32(pm.emission[ei])
        m.em_area = wp.array(pm.area[ei].astype(np.float32), dtype=wp.float32, device=dev)
        # the object
        m.obj = wp.uint64(0)
        m.obj_albedo = wp.vec3(0.0, 0.0, 0.0)
        self._obj_mesh = None
        if obj_vertices is not None and obj_faces is not None and len(obj_faces):
            self._opts = wp.array(np.asarray(obj_vertices, np.float32), dtype=wp.vec3, device=dev)
            self._oidx = wp.array(np.asarray(obj_faces, np.int32).reshape(-1), dtype=wp.int32, device=dev)
            self._obj_mesh = wp.Mesh(points=self._opts, indices=self._oidx)
            m.obj = self._obj_mesh.id
            m.obj_idx = self._oidx
            m.obj_pts = self._opts
            nrm = np.asarray(obj_normals, np.float64)
            nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
            m.obj_vnormal = f32(nrm)
            m.obj_albedo = wp.vec3(*np.asarray(obj_albedo, np.float32).tolist())
        else:
            m.obj_idx = wp.zeros(3, dtype=wp.int32, device=dev)
            m.obj_pts = f32(np.zeros((1, 3)))
            m.obj_vnormal = f32(np.zeros((1, 3)))
        # the sun and the openings it shines through
        opening = np.zeros(n_q, bool) if quad_opening is None else np.asarray(quad_opening, bool)
        if len(opening) < n_q:
            raise ValueError(f"path tracer: {len(opening)} opening flags for {n_q} quads")
        m.patch_open = wp.array(opening[pm.quad].astype(np.int32), dtype=wp.int32, device=dev)
        self.sun = sun if sun is not None and opening.any() else None
        m.sun_on, m.sun_dir, m.sun_1mcos, m.sun_omega, m.sun_L = 0, wp.vec3(0.0, 1.0, 0.0), 0.0, 0.0, wp.vec3(0.0, 0.0, 0.0)
        if self.sun is not None:
            d = np.asarray(sun.direction, np.float64)
            a = float(np.radians(0.5 * sun.angular_diameter_deg))
            if not (np.all(np.isfinite(d)) and np.linalg.norm(d) > 0 and 0 < a < np.pi / 2
                    and np.all(np.isfinite(sun.irradiance)) and np.all(np.asarray(sun.irradiance) >= 0)):
                raise ValueError(f"path tracer: bad sun (direction {d}, angular diameter {sun.angular_diameter_deg} "
                                 f"deg, irradiance {sun.irradiance})")
            L_s = np.asarray(sun.irradiance, np.float64) / (np.pi * np.sin(a) ** 2)  # E_perp = pi L sin^2 a
            m.sun_on = 1
            m.sun_dir = wp.vec3(*(d / np.linalg.norm(d)).astype(np.float32).tolist())
            m.sun_1mcos = float(2.0 * np.sin(0.5 * a) ** 2)  # 1 - cos a, without cancellation
            m.sun_omega = float(2.0 * np.pi * m.sun_1mcos)
            m.sun_L = wp.vec3(*L_s.astype(np.float32).tolist())
        self.model = m
        self.k_inv = wp.mat33(*np.linalg.inv(camera.K).astype(np.float32).ravel().tolist())
        self.r_t = wp.mat33(*camera.R.T.astype(np.float32).ravel().tolist())
        self.centre = wp.vec3(*camera.centre.astype(np.float32).tolist())

    def render(self, pixels: np.ndarray, spp: int, first_sample: int = 0, seed: int = 0, bounces: int = 4,
               strata: int | None = None, chunks: int | None = None) -> PassSums:
        """Samples first_sample .. first_sample+spp-1 of each flat pixel index (row * width + col).

        `strata`: n of the n x n jitter grid (the batch's j-th sample uses cell j mod n^2; default
        floor(sqrt(spp)); samples past the last whole pass of n^2 are jittered over the whole pixel). `chunks`: launches
        run concurrently (default 2 on the CPU, one per core; 1 on CUDA).
        """
        pixels = np.asarray(pixels, np.int32).reshape(-1)
        n = len(pixels)
        if strata is None:
            strata = max(1, int(np.sqrt(spp)))
        if spp < 1 or bounces < 0 or strata < 1:
            raise ValueError(f"path tracer: spp ({spp}) and strata ({strata}) must be >= 1, bounces ({bounces}) >= 0")
        if n and (pixels.min() < 0 or pixels.max() >= self.camera.width * self.camera.height):
            raise ValueError("path tracer: pixel index outside the image")
        dev = self.device
        if chunks is None:
            chunks = 1 if str(dev).startswith("cuda") else 2
        out = {k: np.zeros((n, 3), np.float64) for k in ("noobj", "obj", "diff", "obj_hit")}
        count = np.zeros(n, np.float64)

        def run(sel: np.ndarray) -> None:
            if len(sel) == 0:
                return
            k = len(sel)
            bufs = [wp.zeros(k, dtype=wp.vec3, device=dev) for _ in range(4)]
            cnt = wp.zeros(k, dtype=wp.float32, device=dev)
            wp.launch(_render_kernel, dim=k,
                      inputs=[self.model, wp.array(pixels[sel], dtype=wp.int32, device=dev), int(self.camera.width),
                              self.k_inv, self.r_t, self.centre, int(spp), int(first_sample), int(strata), int(seed),
                              int(bounces)],
                      outputs=[*bufs, cnt], device=dev)
            for name, b in zip(("noobj", "obj", "diff", "obj_hit"), bufs):
                out[name][sel] = b.numpy()
            count[sel] = cnt.numpy()

        parts = np.array_split(np.arange(n), max(1, chunks))
        runtime.run_parallel([lambda s=s: run(s) for s in parts])
        return PassSums(out["noobj"], out["obj"], out["diff"], out["obj_hit"], count, int(spp))
