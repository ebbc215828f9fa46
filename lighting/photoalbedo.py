"""The walls' albedo read off the photo's interreflections (photo light, issue 34).

Photo light (lighting.photolight) explains each photo-seen patch i as L_i = rho_q E_i, E_i = a0_i +
A1_i e: a0 the irradiance/pi from what the photo measures (the seen surfaces' radiance, and the
unseen patches gathered from it), A1 e the unknown emitters' share (directly, and through the unseen
patches). One photo fixes rho x light wherever a patch is lit by the emitters alone, but not where it
is lit by the room: a0 is measured, in the photo's own units, and does not scale with the emitters.
So (e x k, rho / k) fits the photo only when a0 = 0; in a closed room the share of the light that
comes from the other surfaces differs from patch to patch (the floor under a table, the corners,
the wall facing the window), and the albedo that explains them all is determined.

The fit: every seen quad q has its own RGB albedo rho_q (the walls, the vertical room quads, share
one: they are usually one paint, and together they see the emitters from many sides); the emitters
e >= their lower bounds. Alternating least squares: e by bounded least squares over every seen
patch at the current albedos, then each albedo in closed form (sum w^2 L E / sum w^2 E^2 over its
patches), until they settle. Residuals are relative (weights w = 1 / L), as in the walls' fit.

The unseen patches gather with the albedo of their own surface where the photo shows part of it
(one material per quad), the walls' where a wall is not seen at all, `ceiling_albedo` on an unseen
ceiling (ceiling paint: the lighting handbooks' recommended ceiling reflectance is 0.7-0.9, walls
0.5-0.7, floors 0.2-0.4; the ceiling gets its own prior because it is the largest surface out of
view and the brightest), and `unseen_reflectivity` elsewhere (unseen furniture faces). They change
a0 and A1, so the whole is repeated (a few outer rounds) until the unseen reflectivities settle.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import lsq_linear

from lighting.sources import luminance

ALBEDO_RANGE = (0.02, 0.95)  # physical albedos of painted / furnished surfaces (nothing is blacker or whiter)


@dataclass
class AlbedoFit:
    """The fitted albedos: the walls' (3,), every seen quad's {quad: (3,)}, each patch's reflectivity
    when unseen (P,), the transfers at it (seen_transfers: a0, A1, Z0, Z1), the emitters (G,3)
    of the joint fit and the rounds it took."""

    wall: np.ndarray
    surface: dict
    r_patch: np.ndarray
    a0: np.ndarray
    A1: np.ndarray
    Z0: np.ndarray
    Z1: np.ndarray
    e: np.ndarray
    rounds: int
    ss: np.ndarray | None = None  # (3,) the weighted squared residual of every seen patch at the fit, per channel
    n: int = 0  # the seen patches it sums over

    def report(self, names: list[str] | None) -> dict:
        """{quad name: RGB albedo} of the seen surfaces and the rounds, for report.json."""
        return {"surfaces": {(names[q] if names else f"quad {q}"): [round(float(v), 3) for v in a]
                             for q, a in self.surface.items()}, "rounds": self.rounds}


def seen_transfers(G: np.ndarray, S: np.ndarray, U: np.ndarray, r_patch: np.ndarray, known: np.ndarray,
                   M: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(a0 (|S|,3), A1 (|S|,G), Z0 (|U|,3), Z1 (|U|,G)): irradiance/pi at the seen patches S from the
    known radiance (P,3) and per unit radiance of each unknown group (M (P,G) its patches), the unseen
    patches U gathering
    with reflectivity r_patch[U], solved exactly: (I - r G_UU) B_U = r (G_U. known + G_U. M e);
    B_U = Z0 + Z1 e."""
    ng = M.shape[1]
    if len(U):
        r = r_patch[U, None]
        A_uu = np.eye(len(U)) - r * G[np.ix_(U, U)]
        rhs = np.concatenate([r * (G[U] @ known), r * (G[U] @ M)], axis=1)
        Z = np.linalg.solve(A_uu, rhs)
        Z0, Z1 = Z[:, :3], Z[:, 3:]
    else:
        Z0, Z1 = np.zeros((0, 3)), np.zeros((0, ng))
    a0 = G[S] @ known + G[np.ix_(S, U)] @ Z0
    A1 = G[S] @ M + G[np.ix_(S, U)] @ Z1
    return a0, A1, Z0, Z1


def fit_albedo_scale(G: np.ndarray, S: np.ndarray, U: np.ndarray, known: np.ndarray, M: np.ndarray,
                     qS: np.ndarray, wall: np.ndarray, w: np.ndarray, L_S: np.ndarray, lower: np.ndarray,
                     quad: np.ndarray, vertical: np.ndarray, ceiling_q: np.ndarray, priors,
                     fit_walls: bool = True, outer: int = 4, inner: int = 40, levels: int = 0,
                     reflected: np.ndarray | None = None) -> AlbedoFit:
    """The albedos and the emitters that best explain every seen patch (module docstring).

    G (P,P) transfers; S seen patches (their radiance L_S (|S|,3) in `known`), U unseen ones, M (P,G)
    the unknown groups' patches; qS the quad of each seen patch, wall (|S|,) its being a wall, w (|S|,)
    the relative weights; lower (G,3) the emitters' lower bounds; quad (P,) each patch's quad,
    vertical (P,) a wall patch, ceiling_q (Q,) a ceiling quad; priors: lighting.photolight.PhotoPriors
    (wall_albedo the start, ceiling_albedo, unseen_reflectivity); fit_walls False: the walls keep
    wall_albedo, the other seen surfaces and the unseen patches are fitted around it.

    levels > 0: the photo holds at most `levels` light bounces, the camera hit one of them (a path tracer's
    cap), so a seen patch gathers its neighbours at level levels - 1, not at the level the photo shows them:
    from the second round on each source patch j is weighted by f_j = B^(levels-1) / B^(levels) of the
    previous round's model (bounce_weights; `reflected` (G,) marks the clipped regions). 0: every bounce."""
    nq = len(ceiling_q)
    vertical_q = np.bincount(quad, vertical, nq) > 0
    seen_q = np.unique(qS)
    groups = [wall] if wall.any() and fit_walls else []
    groups += [(qS == q) & ~wall for q in seen_q if ((qS == q) & ~wall).any()]
    rho = np.full((len(S), 3), priors.wall_albedo)
    r_q = np.where(ceiling_q, priors.ceiling_albedo, priors.unseen_reflectivity)
    a0 = A1 = Z0 = Z1 = e = None
    rounds = 0
    Gf = G
    for rounds in range(1, outer + 1):
        a0, A1, Z0, Z1 = seen_transfers(Gf, S, U, r_q[quad], known, M)
        reach = np.abs(w[:, None] * A1).sum(0)
        unresolved = reach <= 1e-9 * max(reach.max(initial=0.0), 1e-300)
        for _ in range(inner):
            e = solve_emitters(w[:, None] * A1, w, L_S, a0, rho, lower, unresolved)[0]
            E = a0 + A1 @ e
            new = rho.copy()
            for m in groups:
                den = np.sum(w[m, None] ** 2 * E[m] ** 2, axis=0)
                new[m] = np.where(den > 0, np.sum(w[m, None] ** 2 * L_S[m] * E[m], axis=0) / np.maximum(den, 1e-300),
                                  rho[m][0])
            new = np.clip(new, *ALBEDO_RANGE)
            done = np.allclose(new, rho, rtol=1e-4)
            rho = new
            if done:
                break
        wall_rho = rho[wall][0] if wall.any() else np.full(3, priors.wall_albedo)
        new_q = np.where(ceiling_q, priors.ceiling_albedo, priors.unseen_reflectivity)
        new_q[vertical_q] = luminance(wall_rho)
        for q in seen_q:
            new_q[q] = luminance(rho[qS == q][0])
        if levels > 0 and rounds < outer:
            f = bounce_weights(G, S, U, known, M, e, rho, new_q[quad], levels, reflected)
            Gf = G * f[None, :]
        elif np.allclose(new_q, r_q, atol=1e-3) or rounds == outer:
            break  # (r_q stays the one a0, A1 were solved with)
        r_q = new_q
    surface = {int(q): rho[qS == q][0] for q in seen_q}
    wall_rho = rho[wall][0] if wall.any() else np.full(3, priors.wall_albedo)
    on = w > 0
    ss = np.sum((w[on, None] * (rho[on] * (a0[on] + A1[on] @ e) - L_S[on])) ** 2, axis=0)
    return AlbedoFit(wall_rho, surface, r_q[quad].astype(np.float64), a0, A1, Z0, Z1, e, rounds, ss, int(on.sum()))


def walls_test(free: AlbedoFit, held: AlbedoFit, level: float = 0.95) -> tuple[float, float]:
    """(statistic, threshold): the likelihood-ratio test of the walls' albedo prior (`held`: the fit with the walls
    at the prior, fit_walls False) against the walls' albedo fitted to the interreflections (`free`, one more
    albedo per channel). Residuals taken as independent and normal, one variance per channel: statistic
    n sum_c ln(ss_held,c / ss_free,c), threshold the chi-square quantile at `level` with 3 degrees of freedom.
    Above it the interreflections tell the walls' albedo; at or below it they do not, and the prior stands (a
    flat residual over the walls' albedo: the light and the albedos trade, lamps_110's walls 0.73 for 0.53,
    docs/unseen.md "photolamp111")."""
    from scipy.stats import chi2

    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.log(np.maximum(held.ss, 1e-300) / np.maximum(free.ss, 1e-300))
    stat = float(free.n * np.sum(r)) if free.ss is not None and held.ss is not None else float("inf")
    return stat, float(chi2.ppf(level, 3))


def bounce_weights(G: np.ndarray, S: np.ndarray, U: np.ndarray, known: np.ndarray, M: np.ndarray, e: np.ndarray,
                   rho_S: np.ndarray, r_patch: np.ndarray, levels: int, reflected: np.ndarray | None = None
                   ) -> np.ndarray:
    """(P,) f_j = B_(levels-1) / B_(levels) (luminance, in [0, 1]) of the fitted model: the emitters (the
    known patches outside S, and M e) gathered with reflectivity rho_S on S, r_patch on U. A group marked
    `reflected` (G,) (a clipped region: a surface lit by the sun or a lamp, not a source) is itself one
    bounce, so its light gathers one level less. Emitters get 1 (their radiance does not build up)."""
    from lighting.radiosity import gather

    refl = np.zeros(M.shape[1], bool) if reflected is None else np.asarray(reflected, bool)
    other = np.ones(len(known), bool)
    other[S] = False
    kn = other & known.any(1)  # measured emitters (known, not a seen reflector)
    src = M[:, ~refl] @ e[~refl]
    src[kn] = known[kn]
    clip = M[:, refl] @ e[refl]
    emitting = M.any(1) | kn
    albedo = np.zeros_like(known)
    albedo[S] = rho_S
    albedo[U] = r_patch[U, None]
    A = gather(G, albedo, src, levels)
    C = gather(G, albedo, clip, max(levels - 1, 0))
    hi = luminance(A[levels] + C[-1])
    lo = luminance(A[levels - 1] + (C[-2] if levels >= 2 else 0 * C[-1]))
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(hi > 0, lo / hi, 1.0)
    f = np.clip(np.nan_to_num(f, nan=1.0), 0.0, 1.0)
    f[emitting] = 1.0
    return f


def solve_emitters(J1: np.ndarray, w: np.ndarray, L_S: np.ndarray, a0: np.ndarray, rho: float | np.ndarray,
                   lower: np.ndarray, unresolved: np.ndarray):
    """Bounded least squares of rho (a0 + A1 e) = L_S per channel, rows weighted by w (J1 = w A1);
    rho one albedo for every row, or one per row (|S|,) or per row and channel (|S|,3).
    Returns e (G,3), its 1-sigma std (G,3) (NaN where at a bound or not seen), at_bound (G,3) and
    the RMS weighted residual per channel (3,)."""
    ng, fit_on = J1.shape[1], w > 0
    e, std = np.zeros((ng, 3)), np.full((ng, 3), np.nan)
    at_bound, resid = np.zeros((ng, 3), bool), np.zeros(3)
    if ng == 0:
        return e, std, at_bound, resid
    rho = np.broadcast_to(np.asarray(rho, np.float64).reshape(-1, 1) if np.ndim(rho) < 2 else rho, (len(w), 3))
    for c in range(3):
        J = rho[:, c, None] * J1
        b = w * (L_S[:, c] - rho[:, c] * a0[:, c])
        sol = lsq_linear(J, b, bounds=(lower[:, c], np.inf), method="bvls")
        e[:, c] = sol.x
        res = J @ sol.x - b
        resid[c] = float(np.sqrt(np.mean(res[fit_on] ** 2)))
        at_bound[:, c] = sol.x <= lower[:, c] * (1 + 1e-9) + 1e-300
        free = ~at_bound[:, c] & ~unresolved
        dof = max(int(fit_on.sum()) - int(free.sum()), 1)
        if free.any():
            cov = np.sum(res ** 2) / dof * np.linalg.pinv(J[:, free].T @ J[:, free])
            std[free, c] = np.sqrt(np.clip(np.diag(cov), 0, None))
    return e, std, at_bound, resid


