"""RadiositySolve and TextureRefine (Loscos 2000 §2.3–2.4, §4, §4.1)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import numpy as np

from graphkit import BadInput, Field, Json, Node

from . import geometry as G
from . import hierarchy as HR
from .ports import (PROJECTION, RADIOSITY, ROOM_SCENE, Projection, RadiositySolution,
                    RoomScene)

LUM = np.array([0.2126, 0.7152, 0.0722])


# ------------------------------------------------------------------------------------------
# shared steps


def light_matrix(scene: RoomScene, h: HR.Hierarchy, leaves: np.ndarray, lights: list[str]):
    """(L,S) 1 where leaf l lies on a polygon of light s."""
    name = np.array(scene.light + [""] * (len(h.P_o) - len(scene.light)), dtype=object)
    ln = name[h.poly[leaves]]
    return np.stack([(ln == s).astype(float) for s in lights], 1) if lights else \
        np.zeros((len(leaves), 0))


def light_emittance(scene: RoomScene, lights: list[str]) -> np.ndarray:
    """(S,3) emittance per light (the first polygon of each light), W/m²."""
    out = []
    for s in lights:
        p = scene.light.index(s)
        out.append(scene.emittance[p])
    return np.array(out).reshape(-1, 3)


def responses(h: HR.Hierarchy, ops: HR.Operators, Lm: np.ndarray, rho: np.ndarray, tol):
    """Per-light unit-emittance responses: radiosity, irradiance, unoccluded irradiance.

    Radiosity is linear in the emittances (B = (I − ρK)⁻¹ E), so one solve per light and
    channel gives every later relighting as a weighted sum (§5, "going further").
    Returns three (L,S,3) arrays (W/m² per W/m² of emittance) and the iteration count.
    """
    L, S = Lm.shape
    if S == 0:
        z = np.zeros((L, 0, 3))
        return z, z, z, 0
    E = np.repeat(Lm[:, :, None], 3, axis=2).reshape(L, S * 3)
    R = np.repeat(rho[:, None, :], S, axis=1).reshape(L, S * 3)
    B, it = HR.solve(ops, E, R, tol=tol)
    H = ops.gather(B)
    Hu = ops.gather(B, unoccluded=True)
    return B.reshape(L, S, 3), H.reshape(L, S, 3), Hu.reshape(L, S, 3), it


def leaf_textures(h: HR.Hierarchy, leaves: np.ndarray, proj: Projection, seen_area=False):
    """Mean texture (linear radiance) over the covered texels of each leaf; NaN if unseen.

    With ``seen_area``, also the area (m²) of each leaf that the camera sees."""
    P, R = proj.coverage.shape[:2]
    st = (np.arange(R) + 0.5) / R
    S, T = np.meshgrid(st, st, indexing="ij")
    grid = h.leaf_grid()
    pid = np.repeat(np.arange(P), R * R)
    leaf = h.locate(pid, np.tile(S.ravel(), P), np.tile(T.ravel(), P), grid)
    pos = np.full(h.n_elems, -1)
    pos[leaves] = np.arange(len(leaves))
    k = np.where(leaf >= 0, pos[leaf], -1)  # -1: past a triangle's diagonal
    w = proj.coverage.reshape(-1).astype(float)
    m = (k >= 0) & (w > 0)
    cnt = np.bincount(k[m], w[m], minlength=len(leaves))
    out = np.full((len(leaves), 3), np.nan)
    tex = proj.textures.reshape(-1, 3).astype(float)
    for c in range(3):
        s = np.bincount(k[m], w[m] * tex[m, c], minlength=len(leaves))
        out[:, c] = np.where(cnt > 0, s / np.maximum(cnt, 1e-300), np.nan)
    if seen_area:
        return out, cnt * h.P_jac[h.poly[leaves]] / (R * R)
    return out


def fournier_reflectance(h, leaves, T, seen, rho_hat, rho_scene):
    """Eq. (1): ρ_i = T_i / T_A · ρ̂ on the seen leaves (T_A the mean texture luminance,
    area-weighted); the scene file's albedos elsewhere."""
    a = h.area(leaves)
    TA = np.sum(a[seen] * (T[seen] @ LUM)) / a[seen].sum()
    rho = rho_scene.copy()
    rho[seen] = np.clip(T[seen] / max(TA, 1e-12) * rho_hat, 0.0, 0.95)
    return rho


def fill_unseen(h, leaves, rho, seen, emitting):
    """Leaves the camera does not see take their polygon's area-weighted average of the
    computed reflectances (§4, "the average of the computed reflectances"); unseen polygons
    and emitters keep the scene file's value (the approximate textures of §3)."""
    a = h.area(leaves)
    poly = h.poly[leaves]
    for p in np.unique(poly[~seen]):
        on = (poly == p) & seen
        if on.any() and not emitting[poly == p].any():
            rho[(poly == p) & ~seen] = (a[on, None] * rho[on]).sum(0) / a[on].sum()
    return rho


def implied_reflectance(rho, T, H, seen, h, leaves, emitting):
    """§4 refinement step: ρ_i = π T_i / H_i, the reflectance the irradiance implies."""
    rho = rho.copy()
    rho[seen] = np.clip(np.pi * T[seen] / np.maximum(H[seen], 1e-12), 0.0, 0.95)
    return fill_unseen(h, leaves, rho, seen, emitting)


def estimate_reflectance(scene, h, ops, leaves, T, emit_leaf, mode, rho_hat, n_iter, tol):
    """Leaf reflectances (L,3) — Fournier et al. eq. (1), refined (§4).

    mode "scene": the scene file's albedos.  mode "photo": start from eq. (1), then
    ``n_iter`` times solve and set ρ_i = π T_i / H_i (:func:`implied_reflectance`).
    """
    rho_scene = scene_reflectance(scene, h, leaves)
    if mode == "scene":
        return rho_scene
    emitting = emit_leaf.max(1) > 0
    seen = np.all(np.isfinite(T), 1) & ~emitting
    if not seen.any():
        return rho_scene
    rho = fill_unseen(h, leaves, fournier_reflectance(h, leaves, T, seen, rho_hat, rho_scene),
                      seen, emitting)
    B = None
    for _ in range(n_iter):  # each solve starts from the last (ρ changes a little)
        B, _ = HR.solve(ops, emit_leaf, rho, tol=tol, B0=B)
        rho = implied_reflectance(rho, T, ops.gather(B), seen, h, leaves, emitting)
    return rho


def scene_reflectance(scene, h, leaves):
    refl = scene.reflectance
    return refl[h.poly[leaves]].astype(float)


# ------------------------------------------------------------------------------------------
# emittances from the photograph (§2.4 eq. 2 as the start; §4: "a system of equations could
# be solved for non-homogeneous intensities")


def fournier_emittance(scene: RoomScene, proj: Projection, lights, known, emit, rho_hat):
    """Eq. (2) with equal unknown lights: Σ E_i A_i = (1 − ρ̂) B_A Σ A_i, B_A = π × the mean
    texture radiance (per channel), less what the known lights emit.  (S,3) W/m²."""
    from .geometry import frame

    A = frame(scene.verts)[4]
    cov = proj.coverage > 0
    TA = proj.textures[cov].mean(0) if cov.any() else np.zeros(3)
    area = np.array([A[[p for p, n in enumerate(scene.light) if n == s]].sum() for s in lights])
    total = (1 - rho_hat) * np.pi * TA * A.sum()
    rest = total - (area[known, None] * emit[known]).sum(0)
    out = np.asarray(emit, float).copy()
    if (~known).any():
        unknown_area = max(area[~known].sum(), 1e-12)
        out[~known] = np.maximum(rest, 0.05 * total) / unknown_area
    return out


@dataclass
class EmittanceFit:
    """Result of :func:`fit_emittance`."""

    emit: np.ndarray  # (S,3) W/m²
    rho_poly: np.ndarray  # (P,3) reflectance per polygon the fit used
    seen: np.ndarray  # (S,) bool: the photograph shows the light itself
    share: np.ndarray  # (S,) largest share of a seen leaf's irradiance from each light
    residual: float  # weighted rms of the fit relative to the rms of πT


def fit_emittance(RH, T, seen_area, leaf_poly, P, light_of, emit, known, rho_leaf,
                  rho_fixed=None, rho_hat=0.5, light_obs=None, light_weight=None,
                  max_iter=200, tol=1e-7) -> EmittanceFit:
    """Emittances of the unknown lights from the photograph (radiosity is linear in them).

    For each seen surface leaf l (weight: its seen area, m²) and channel:
    π T_l = ρ_p Σ_s H_ls e_s, with H_ls the irradiance per unit emittance of light s (the
    responses, interreflections included) and ρ_p one reflectance per polygon — a leaf's own
    reflectance would explain any pixel.  For each light s the photograph shows (its
    radiance ``light_obs`` (S,3), NaN if unseen; weight ``light_weight`` (S,) m²):
    π L_s = e_s + ρ̄_s Σ_s' H̄_ss' e_s', H̄ and ρ̄ the mean over the light's own leaves.
    Alternating least squares: ρ_p in closed form, then the unknown e by non-negative least
    squares (scipy.optimize.nnls), from the given start, until e settles.  ``rho_fixed``
    (P,3): known reflectances (no ρ step).  When no light is seen or known, the level and
    colour of the lights are not in the photograph: they are set so that the mean seen
    reflectance is ρ̂ per channel (Fournier's assumption).
    """
    from scipy.optimize import nnls

    L, S, _ = RH.shape
    em = light_of >= 0
    surf = np.all(np.isfinite(T), 1) & (seen_area > 0) & ~em
    rows = np.flatnonzero(surf)
    w = np.sqrt(seen_area)
    piT = np.pi * np.nan_to_num(T)
    unknown = ~known
    obs = np.full((S, 3), np.nan) if light_obs is None else np.asarray(light_obs, float)
    lw2 = np.zeros(S) if light_weight is None else np.asarray(light_weight, float)
    seen = np.all(np.isfinite(obs), 1) & (lw2 > 0)
    lw = np.sqrt(np.where(seen, lw2, 0.0))
    # mean irradiance response and reflectance over each light's own leaves
    Hbar = np.zeros((S, S, 3))
    rbar = np.zeros((S, 3))
    for s in range(S):
        m = light_of == s
        if m.any():
            Hbar[s] = RH[m].mean(0)
            rbar[s] = rho_leaf[m].mean(0)
    anchored = known.any() or seen[unknown].any() or rho_fixed is not None
    out = np.asarray(emit, float).copy()
    rho_poly = np.zeros((P, 3)) if rho_fixed is None else np.asarray(rho_fixed, float).copy()
    num_res = den_res = 0.0
    ls = np.flatnonzero(seen)
    for c in range(3):
        e = out[:, c].copy()
        Hc = RH[:, :, c]
        Al = rbar[ls, c][:, None] * Hbar[ls, :, c]
        Al[np.arange(len(ls)), ls] += 1.0
        bl = np.pi * np.nan_to_num(obs[ls, c])
        for _ in range(max_iter if unknown.any() else 1):
            if rho_fixed is None:
                Htot = Hc @ e
                num = np.bincount(leaf_poly[surf], seen_area[surf] * Htot[surf] * piT[surf, c],
                                  minlength=P)
                den = np.bincount(leaf_poly[surf], seen_area[surf] * Htot[surf] ** 2,
                                  minlength=P)
                rho_poly[:, c] = np.where(den > 0, num / np.maximum(den, 1e-300), 0.0)
            if not unknown.any():
                break
            A = np.concatenate([(rho_poly[leaf_poly[rows], c][:, None] * Hc[rows])
                                * w[rows, None], Al * lw[ls, None]])
            b = np.concatenate([piT[rows, c] * w[rows], bl * lw[ls]])
            x, _ = nnls(A[:, unknown], b - A[:, known] @ e[known], maxiter=50 * S)
            new = e.copy()
            new[unknown] = x
            done = np.abs(new - e).max() <= tol * max(np.abs(new).max(), 1e-300)
            e = new
            if done:
                break
        if not anchored:
            # the overall level per channel: mean seen reflectance ρ̂ (ρ × k, e / k)
            sa = seen_area[surf]
            mean_rho = (sa * rho_poly[leaf_poly[surf], c]).sum() / max(sa.sum(), 1e-300)
            k = mean_rho / rho_hat if mean_rho > 0 else 1.0
            e[unknown] *= k
            rho_poly[:, c] /= k
        out[:, c] = e
        model = rho_poly[leaf_poly[rows], c] * (Hc[rows] @ e)
        num_res += np.sum(((model - piT[rows, c]) * w[rows]) ** 2)
        num_res += np.sum(((Al @ e - bl) * lw[ls]) ** 2)
        den_res += np.sum((piT[rows, c] * w[rows]) ** 2) + np.sum((bl * lw[ls]) ** 2)
    share = np.zeros(S)
    if S and surf.any():
        H = np.einsum("lsc,sc->ls", RH * LUM[None, None, :], out)
        share = (H[surf] / np.maximum(H[surf].sum(1, keepdims=True), 1e-300)).max(0)
    return EmittanceFit(out, rho_poly, seen, share,
                        float(np.sqrt(num_res / max(den_res, 1e-300))))


def light_observations(scene: RoomScene, proj: Projection, lights):
    """(S,3) each light's radiance in the photograph (Projection.em_radiance, over its
    polygons by covered pixels; NaN if unseen) and (S,) its polygons' area, m² (0: unseen)."""
    from .geometry import frame

    A = frame(scene.verts)[4]
    obs = np.full((len(lights), 3), np.nan)
    weight = np.zeros(len(lights))
    rad = getattr(proj, "em_radiance", np.zeros((0, 3)))
    if len(rad) != len(scene.verts):
        return obs, weight
    for k, s in enumerate(lights):
        ps = [p for p, n in enumerate(scene.light) if n == s and np.all(np.isfinite(rad[p]))
              and proj.em_seen[p] > 0]
        if ps:
            px = proj.em_seen[ps]
            obs[k] = (px[:, None] * rad[ps]).sum(0) / px.sum()
            weight[k] = A[[p for p, n in enumerate(scene.light) if n == s]].sum()
    return obs, weight


def estimate_emittance(scene, h, ops, leaves, Lm, T, seen_area, emit, known, rho_mode,
                       rho_hat, n_iter, tol, lights, observed=(None, None), min_share=0.01):
    """Reflectances and emittances refined together (§4 with per-light emittances).

    Starting from eq. (1) reflectances and the given (or eq. 2) emittances, each pass solves
    the unit responses for the current reflectances, fits the unknown emittances
    (:func:`fit_emittance`; ``observed``: the lights' radiance in the photo and weights,
    :func:`light_observations`) and, in photo mode, sets ρ_i = π T_i / H_i (§4); a last pass
    solves the responses for the final reflectances and fits once more.  Refuses (BadInput)
    a light that the camera does not see and that gives under ``min_share`` of the
    irradiance of every seen surface leaf: nothing in the photograph says how bright it is.
    Returns (emit, rho, responses, fit).
    """
    emitting = Lm.any(1) if len(lights) else np.zeros(len(leaves), bool)
    light_of = np.where(emitting, Lm.argmax(1), -1) if len(lights) else \
        np.full(len(leaves), -1)
    rho_scene = scene_reflectance(scene, h, leaves)
    seen = np.all(np.isfinite(T), 1) & ~emitting
    rho = rho_scene
    if rho_mode == "photo" and seen.any():
        rho = fill_unseen(h, leaves, fournier_reflectance(h, leaves, T, seen, rho_hat,
                                                          rho_scene), seen, emitting)
    rho_fixed = scene.reflectance if rho_mode == "scene" else None
    leaf_poly = h.poly[leaves]
    P = len(scene.verts)
    passes = max(n_iter, 1) if rho_mode == "photo" else 0
    for k in range(passes + 1):
        resp = responses(h, ops, Lm, rho, tol)
        fit = fit_emittance(resp[1], T, seen_area, leaf_poly, P, light_of, emit, known, rho,
                            rho_fixed, rho_hat, *observed)
        if k == 0:
            check_estimable(fit, known, lights, min_share)
        emit = fit.emit
        if k == passes:
            break
        H = np.einsum("lsc,sc->lc", resp[1], emit)
        rho = implied_reflectance(rho, T, H, seen, h, leaves, emitting)
    return emit, rho, resp, fit


def check_estimable(fit: EmittanceFit, known, lights, min_share):
    """BadInput naming the lights that neither the camera sees nor anything they light."""
    bad = [s for s in range(len(lights)) if not known[s] and not fit.seen[s]
           and fit.share[s] < min_share]
    if bad:
        names = ", ".join(f"'{lights[s]}'" for s in bad)
        raise BadInput("scene", f"the emittance of light {names} cannot be estimated: the camera "
                       f"does not see it and it gives under {min_share:.0%} of the light on "
                       "every surface the camera sees; give its emittance in the scene file")


def finish_solution(scene, h: HR.Hierarchy, proj, rho_mode, rho_hat, n_iter, tol, info,
                    emit=None, estimate=None):
    """Reflectances, emittances and the per-light responses on the final mesh.

    emit (S,3): the emittances to keep (default: the scene file's); estimate (S,) bool: the
    lights whose emittance is fitted to the photograph (:func:`estimate_emittance`), with
    ``emit`` as the start.
    """
    lights = scene.light_names
    ops = HR.operators(h)
    leaves = ops.leaves
    Lm = light_matrix(scene, h, leaves, lights)
    emit = light_emittance(scene, lights) if emit is None else np.asarray(emit, float)
    if proj is not None:
        T, seen_area = leaf_textures(h, leaves, proj, seen_area=True)
    else:
        T, seen_area = np.full((len(leaves), 3), np.nan), np.zeros(len(leaves))
    if estimate is not None and np.any(estimate):
        emit, rho, (R, RH, RHu, it), fit = estimate_emittance(
            scene, h, ops, leaves, Lm, T, seen_area, emit, ~np.asarray(estimate), rho_mode,
            rho_hat, n_iter, tol, lights, light_observations(scene, proj, lights))
        info = dict(info, fit_residual=round(fit.residual, 5))
    else:
        emit_leaf = Lm @ emit if len(lights) else np.zeros((len(leaves), 3))
        rho = estimate_reflectance(scene, h, ops, leaves, T, emit_leaf, rho_mode, rho_hat,
                                   n_iter, tol)
        R, RH, RHu, it = responses(h, ops, Lm, rho, tol)
    info = dict(info, leaves=int(len(leaves)), links=int(len(h.recv)), elements=int(h.n_elems),
                iterations=int(it))
    return RadiositySolution(**{k: getattr(h, k) for k in HR.Hierarchy.ARRAYS}, rho=rho, T=T,
                             resp=R, resp_H=RH, resp_Hu=RHu, emit=emit, lights=lights, info=info,
                             **h.tri_arrays(), **h.cluster_arrays())


def initial_radiosity(scene: RoomScene, h: HR.Hierarchy) -> np.ndarray:
    """Per-element luminance guess for the first refinement: E + ρ·B_ambient (§2.4, eq. 2)."""
    A = h.P_area
    e = scene.emittance @ LUM
    rho = scene.reflectance @ LUM
    rho_bar = np.sum(rho * A) / A.sum()
    amb = np.sum(e * A) / A.sum() / max(1 - rho_bar, 1e-3)
    Bp = e + rho * amb
    return Bp[h.poly]


#: scenes of more polygons than this start their links from a cluster hierarchy
#: (:mod:`clusters`); fewer, from every pair of polygons
CLUSTER_ABOVE = 512
#: a clustered scene's polygon links are refined this many at a time (:func:`HR.refine_links`)
FRONTIER = 1 << 17


def start_links(scene: RoomScene, h: HR.Hierarchy, B: np.ndarray, prm: HR.RefineParams, rng):
    """The candidate polygon links (r, s) the refinement starts from: every ordered pair of
    distinct polygons, or above ``CLUSTER_ABOVE`` polygons the pairs the cluster refinement
    leaves (:mod:`clusters`), its cluster links set in h."""
    P = len(scene.verts)
    if P <= CLUSTER_ABOVE:
        r, s = np.meshgrid(np.arange(P), np.arange(P), indexing="ij")
        r, s = r.ravel(), s.ravel()
        return r[r != s], s[r != s]
    from . import clusters as CL

    tri = h.tri_poly
    corners = G.corners(h.P_o, h.P_u, h.P_v, tri)
    light = np.array(scene.light + [""] * (P - len(scene.light)), dtype=object) != ""
    light |= scene.emittance.max(1) > 0
    t = CL.build_tree(corners, h.P_area, B[:P], light)
    (r, s), (R, S) = CL.refine_clusters(t, prm.eps_bf, max(float(np.median(B[:P])), 1e-12))
    cl = CL.link_weights(t, R, S, h.centre(np.arange(P)), h.P_n, h.P_area)
    scale, cl.V = CL.cluster_transport(cl, h.occluders(), prm.n_rays, rng)
    cl.sw *= scale[cl.s[:, 0]]
    h.cl_V, h.cl_r, h.cl_rw, h.cl_s, h.cl_sw = cl.V, cl.r, cl.rw, cl.s, cl.sw
    return r, s


def hierarchical_solve(scene: RoomScene, prm: HR.RefineParams, rounds: int, tol: float,
                       progress=None) -> HR.Hierarchy:
    """BF(V) refinement from polygon–polygon links (or cluster links, :func:`start_links`),
    alternating with solves (§2.3)."""
    h = HR.Hierarchy.roots(scene.verts)
    rng = np.random.default_rng(prm.seed)
    B = initial_radiosity(scene, h)
    r, s = start_links(scene, h, B, prm, rng)
    frontier = FRONTIER if len(h.cl_V) else None
    if len(scene.verts) > CLUSTER_ABOVE:  # a mesh's small polygons: BF alone splits their partners
        prm = dataclasses.replace(prm, small_end=prm.min_area)
    links = None
    for k in range(rounds):
        # a later round refines the last round's links with the new B: what they carry
        # (F, its spread, V, C) depends only on the two elements, so it is not computed again
        links = HR.refine_links(h, r, s, B, prm, rng, known=links, frontier=frontier)
        h.recv, h.send, h.F, h.V, h.C = links.astuple()
        if progress:
            progress((k + 1) / (rounds + 1), f"refinement round {k + 1}: {len(h.recv)} links")
        if k == rounds - 1:
            break  # the last round's B would refine nothing (finish_solution solves again)
        ops = HR.operators(h)
        emit_leaf = scene.emittance[h.poly[ops.leaves]]
        Bl, _ = HR.solve(ops, emit_leaf, scene.reflectance[h.poly[ops.leaves]], tol=tol)
        B = (ops.pull @ Bl) @ LUM
    return h


class RefineParamsMixin(Node.Params):
    eps_bf: float = Field(0.1, gt=0, description="BF threshold on F·B / median polygon B")
    eps_bfv: float = Field(0.01, gt=0, description="BFV threshold for PARTIAL links (same)")
    min_area: float = Field(4e-4, gt=0, description="smallest element area (m²)")
    max_level: int = Field(7, ge=0, le=10, description="deepest quadtree level")
    rays: int = Field(4, ge=1, le=16, description="rays² per link for the attenuation factor")
    ff_points: int = Field(3, ge=1, le=8, description="points² per receiver for form factors")
    seed: int = Field(0, description="seed of the visibility ray jitter")
    tol: float = Field(1e-6, gt=0, description="relative convergence threshold of gathering")
    max_link_area: float = Field(0.5, gt=0, description="m²: larger elements are split before "
                                 "they carry a link (BF misses how B curves over them)")


class RadiositySolve(Node):
    """Hierarchical radiosity of the real scene (Loscos 2000 §2.3–2.4, §4).

    Quadtree patches over each polygon, links with form factors (contour integral, exact per
    receiver point) and attenuation factors from ray casting (VISIBLE / PARTIAL / INVISIBLE),
    BF refinement with a BFV term for partial links, then gather + push-pull until the
    largest change is below ``tol`` (relative).  Reflectances come from the photograph:
    Fournier's eq. (1) with the average reflectance ``rho_hat``, refined from the computed
    reflectances (§4).  Emittances (W/m²): the scene file's, and for every light the file
    leaves out (or all of them, ``emittance: estimate``) a per-light fit to the photograph —
    radiosity is linear in the emittances, so the photo's seen texels against the unit
    responses give a non-negative least-squares problem, solved together with the
    reflectances (§4; §2.4's "system of equations … for non-homogeneous intensities"), from
    Fournier's eq. (2) with equal lights as the start (``emittance: homogeneous`` stops there).
    The solution keeps one response per light; output ``lights`` records each light's
    emittance and where it came from (also in the solution's info).
    A scene of more than ``CLUSTER_ABOVE`` (512) polygons (a triangle mesh of a room) starts
    its links from a cluster hierarchy of the polygons instead of every pair of them
    (clusters.py: Smits, Arvo & Greenberg 1994; Sillion 1995): clusters far enough apart
    exchange light through one link (each member's own cosine towards the other end, Embree
    visibility), links from lights always reach the polygons, and a link whose smaller end is
    at most ``min_area`` (a mesh's small triangle) is split on its other end by BF alone, not
    down to ``max_link_area``; its preprocess grows about linearly with the polygons, not with
    their square.  Fewer polygons: as before.
    """

    version = "5"
    inputs = {"scene": ROOM_SCENE, "projection": PROJECTION}
    outputs = {"solution": RADIOSITY, "lights": Json}
    tolerance = {"rtol": 1e-4, "atol": 1e-6}

    @classmethod
    def examples(cls):
        """The ray-casting backends' conformance case: a small room with a box (embree.py)."""
        from .embree import RAY_PARAMS, ray_examples

        e = ray_examples()
        return [(RAY_PARAMS["RadiositySolve"], {"scene": e["scene"], "projection": e["projection"]})]

    class Params(RefineParamsMixin):
        rounds: int = Field(2, ge=1, le=5, description="refine/solve rounds (BF uses the last B)")
        reflectance: Literal["photo", "scene"] = Field(
            "photo", description="photo: Fournier eq. 1 + §4 refinement; scene: file albedos")
        emittance: Literal["scene", "estimate", "homogeneous"] = Field(
            "scene", description="scene: the file's W/m², the lights it leaves out estimated; "
            "estimate: every light estimated from the photo; homogeneous: Fournier eq. 2 alone "
            "(all estimated lights equal)")
        rho_hat: float = Field(0.5, gt=0, lt=1, description="user average reflectance ρ̂ (eq. 1)")
        reflectance_iterations: int = Field(3, ge=0, le=20, description="§4 refinement passes")

    def refine_params(self):
        p = self.params
        return HR.RefineParams(p.eps_bf, p.eps_bfv, p.min_area, p.max_level, p.rays,
                               p.ff_points, p.seed, p.max_link_area)

    def compute(self, scene: RoomScene, projection: Projection):
        p = self.params
        if projection.textures.shape[0] != len(scene.verts):
            raise BadInput("projection", f"projection has {projection.textures.shape[0]} "
                           f"polygons, the scene {len(scene.verts)}")
        lights = scene.light_names
        known = scene.light_given() if p.emittance == "scene" else np.zeros(len(lights), bool)
        start = fournier_emittance(scene, projection, lights, known,
                                   light_emittance(scene, lights), p.rho_hat)
        scene = with_light_emittance(scene, lights, start)
        h = hierarchical_solve(scene, self.refine_params(), p.rounds, p.tol, self.ctx.progress)
        sol = finish_solution(scene, h, projection, p.reflectance, p.rho_hat,
                              p.reflectance_iterations, p.tol, {"step": "RadiositySolve"},
                              emit=start, estimate=None if p.emittance == "homogeneous"
                              else ~known)
        source = np.where(known, "scene", "homogeneous" if p.emittance == "homogeneous"
                          else "estimated")
        r6 = lambda v: [round(float(x), 6) for x in v]  # noqa: E731
        sol.info["lights"] = {
            s: {"emittance": r6(sol.emit[k]), "source": str(source[k]),
                **({} if known[k] else {"fournier_eq2": r6(start[k])})}
            for k, s in enumerate(lights)}
        return {"solution": sol, "lights": {"unit": "W/m² (π × radiance)",
                                            "lights": sol.info["lights"],
                                            "fit_residual": sol.info.get("fit_residual")}}


def with_light_emittance(scene: RoomScene, lights, emit) -> RoomScene:
    """The scene with each light's polygons emitting ``emit`` (S,3) W/m²."""
    em = scene.emittance.copy()
    for k, s in enumerate(lights):
        em[[i for i, n in enumerate(scene.light) if n == s]] = emit[k]
    return RoomScene(scene.names, scene.verts, scene.reflectance, em, scene.light,
                     scene.virtual, scene.emit_given)


# ------------------------------------------------------------------------------------------
# §4.1 texture-based refinement


def light_visibility(h: HR.Hierarchy, leaves, light_polys: list[np.ndarray]) -> np.ndarray:
    """(L,S) attenuation of each leaf w.r.t. each light: Σ F·V / Σ F over the light's links
    to the leaf or its ancestors (NaN when no link)."""
    pos = np.full(h.n_elems, -1)
    pos[leaves] = np.arange(len(leaves))
    rows, cols = h.ancestors_pairs(leaves)
    import scipy.sparse as sp

    A = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(leaves), h.n_elems))
    out = np.full((len(leaves), len(light_polys)), np.nan)
    for k, lp in enumerate(light_polys):
        m = np.isin(h.poly[h.send], lp)
        fv = np.bincount(h.recv[m], h.F[m] * h.V[m], minlength=h.n_elems)
        f = np.bincount(h.recv[m], h.F[m], minlength=h.n_elems)
        a, b = A @ fv, A @ f
        out[:, k] = np.where(b > 0, a / np.maximum(b, 1e-300), np.nan)
    return out


def push_links_down(h: HR.Hierarchy, mask: np.ndarray, prm: HR.RefineParams, rng):
    """Replace links `mask` (receiver not a leaf) by links from each receiver leaf."""
    r, s = h.recv[mask], h.send[mask]
    keep = ~mask
    nr, ns = [], []
    while len(r):
        leaf = h.child0[r] < 0
        nr.append(r[leaf]); ns.append(s[leaf])
        r, s = r[~leaf], s[~leaf]
        c = h.children(r)
        r, s = c.ravel(), np.repeat(s, 4)
    r, s = np.concatenate(nr), np.concatenate(ns)
    g = HR.LinkGeom.of(h, r, s)
    f = HR.facing(h, r, s, g)
    r, s, g = r[f], s[f], g.select(f)
    F = HR.element_links_ff(h, r, s, prm.n_ff, g=g)
    V, C = HR.link_visibility(h, r, s, prm.n_rays, rng, centroid=True, g=g)
    m = F > 0
    h.recv = np.concatenate([h.recv[keep], r[m]])
    h.send = np.concatenate([h.send[keep], s[m]])
    h.F = np.concatenate([h.F[keep], F[m]])
    h.V = np.concatenate([h.V[keep], V[m]])
    h.C = np.concatenate([h.C[keep], C[m]])


def lab(rgb: np.ndarray) -> np.ndarray:
    from nodes.common.color import linear_srgb_to_lab

    x = np.nan_to_num(np.asarray(rgb, float))
    scale = max(np.percentile(x, 99), 1e-12)  # normalise: the photo's scale is arbitrary
    return np.asarray(linear_srgb_to_lab(np.clip(x / scale, 0, None)), float)


def leaf_neighbours(h: HR.Hierarchy, leaves) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of positions (into leaves) of edge-adjacent leaves on the same polygon."""
    grid = h.leaf_grid()
    pos = np.full(h.n_elems, -1)
    pos[leaves] = np.arange(len(leaves))
    g = np.where(grid >= 0, pos[grid], -1)
    # across cell edges (a cell's lower half meets the left/below neighbours' upper halves),
    # and between a cell's two halves (the same leaf on a parallelogram)
    a = np.concatenate([g[:, :-1, :, 1].ravel(), g[:, :, :-1, 1].ravel(), g[..., 0].ravel()])
    b = np.concatenate([g[:, 1:, :, 0].ravel(), g[:, :, 1:, 0].ravel(), g[..., 1].ravel()])
    m = (a != b) & (a >= 0) & (b >= 0)
    pr = np.unique(np.stack([a[m], b[m]], 1), axis=0)
    return pr[:, 0], pr[:, 1]


def texture_refine(scene, h: HR.Hierarchy, proj, prm: HR.RefineParams, color_thr, vis_thr,
                   max_rounds, rng, progress=None):
    """§4.1: links from real lights to leaves, then Fig. 12's texture-based subdivision."""
    lights = scene.light_names
    lp = [np.array([p for p, n in enumerate(scene.light) if n == s]) for s in lights]
    allp = np.concatenate(lp) if lp else np.zeros(0, int)
    from_light = lambda: np.isin(h.poly[h.send], allp) & (h.child0[h.recv] >= 0)  # noqa: E731
    push_links_down(h, from_light(), prm, rng)
    stats = {"subdivided": 0, "undone": 0}
    for rnd in range(max_rounds):
        leaves = h.leaves
        T = leaf_textures(h, leaves, proj)
        seen = np.all(np.isfinite(T), 1)
        C = lab(T)
        Vis = np.nan_to_num(light_visibility(h, leaves, lp), nan=1.0)
        a, b = leaf_neighbours(h, leaves)
        ok = seen[a] & seen[b]
        a, b = a[ok], b[ok]
        dc = np.linalg.norm(C[a] - C[b], axis=1)
        dv = np.abs(Vis[a] - Vis[b]).max(1) if Vis.shape[1] else np.zeros(len(a))
        similar_c = dc < color_thr
        similar_v = dv < vis_thr
        bad = (similar_c & ~similar_v) | (~similar_c & similar_v)
        want = np.zeros(len(leaves), bool)
        want[a[bad]] = True
        want[b[bad]] = True
        partial = ((Vis > vis_thr) & (Vis < 1 - vis_thr)).any(1) if Vis.shape[1] else \
            np.zeros(len(leaves), bool)
        want |= partial & seen
        e = leaves[want & (h.level[leaves] < prm.max_level)
                   & (h.area(leaves) > prm.min_area)]
        if not len(e):
            break
        h.subdivide(e)
        push_links_down(h, np.isin(h.recv, e) & np.isin(h.poly[h.send], allp), prm, rng)
        # undo subdivisions whose children show no visibility change (Fig. 12)
        leaves2 = h.leaves
        Vis2 = np.nan_to_num(light_visibility(h, leaves2, lp), nan=1.0)
        pos = np.full(h.n_elems, -1)
        pos[leaves2] = np.arange(len(leaves2))
        ch = h.children(e)
        vc = Vis2[pos[ch]]  # (k,4,S)
        same = (np.ptp(vc, axis=1) < vis_thr).all(1) & \
            ~((vc > vis_thr) & (vc < 1 - vis_thr)).any((1, 2))
        undo = e[same]
        if len(undo):
            gone = np.isin(h.recv, h.children(undo).ravel())
            back = gone & np.isin(h.poly[h.send], allp)
            # restore one link per (parent, light element) by pushing children links up
            pr, ps = h.parent[h.recv[back]], h.send[back]
            key = np.unique(np.stack([pr, ps], 1), axis=0)
            h.recv, h.send, h.F, h.V, h.C = (x[~gone] for x in (h.recv, h.send, h.F, h.V, h.C))
            h.unsubdivide(undo)
            F = HR.element_links_ff(h, key[:, 0], key[:, 1], prm.n_ff)
            V, C = HR.link_visibility(h, key[:, 0], key[:, 1], prm.n_rays, rng, centroid=True)
            h.recv = np.concatenate([h.recv, key[:, 0]])
            h.send = np.concatenate([h.send, key[:, 1]])
            h.F = np.concatenate([h.F, F]); h.V = np.concatenate([h.V, V])
            h.C = np.concatenate([h.C, C])
        stats["subdivided"] += int(len(e) - len(undo))
        stats["undone"] += int(len(undo))
        if progress:
            progress((rnd + 1) / max_rounds, f"texture refinement round {rnd + 1}")
        if len(undo) == len(e):
            break
    return stats


class TextureRefine(Node):
    """Texture-based refinement of shadow boundaries (Loscos 2000 §4.1, Fig. 12, eq. 4).

    All links from real lights are first moved to the leaves (Fig. 10b).  Then, for each
    visible leaf and each neighbour: similar colour (CIELAB distance, eq. 4, below
    ``color_threshold``) but different visibility (attenuation differs by ≥
    ``visibility_threshold``) → subdivide; different colour but similar visibility →
    subdivide; PARTIAL → subdivide.  A subdivision whose children show no visibility change
    is undone.  Ends with a radiosity step on the new mesh and re-estimated reflectances.
    Colours are of the leaf's mean texture, normalised by the photo's 99th percentile.
    The emittances are the solution's (the scene file's or those RadiositySolve estimated).
    """

    version = "4"
    inputs = {"scene": ROOM_SCENE, "solution": RADIOSITY, "projection": PROJECTION}
    outputs = {"solution": RADIOSITY}
    tolerance = {"rtol": 1e-4, "atol": 1e-6}

    @classmethod
    def examples(cls):
        """The ray-casting backends' conformance case: a small room with a box (embree.py)."""
        from .embree import RAY_PARAMS, ray_examples

        e = ray_examples()
        return [(RAY_PARAMS["TextureRefine"], {"scene": e["scene"], "solution": e["solution"],
                                               "projection": e["projection"]})]

    class Params(RefineParamsMixin):
        rays: int = Field(6, ge=1, le=16, description="rays² per light link at the leaves")
        color_threshold: float = Field(6.0, gt=0, description="ΔE*ab below which colours match")
        visibility_threshold: float = Field(0.1, gt=0, lt=1, description="attenuation difference")
        max_rounds: int = Field(4, ge=0, le=10, description="refinement passes")
        reflectance: Literal["photo", "scene"] = Field("photo", description="as RadiositySolve")
        rho_hat: float = Field(0.5, gt=0, lt=1, description="user average reflectance ρ̂ (eq. 1)")
        reflectance_iterations: int = Field(3, ge=0, le=20, description="§4 refinement passes")

    def compute(self, scene: RoomScene, solution: RadiositySolution, projection: Projection):
        if len(solution.P_o) != len(scene.verts):
            raise BadInput("solution", "the solution was computed for another scene")
        p = self.params
        h = solution.hierarchy().copy()
        prm = HR.RefineParams(p.eps_bf, p.eps_bfv, p.min_area, p.max_level, p.rays,
                              p.ff_points, p.seed, p.max_link_area)
        rng = np.random.default_rng(p.seed + 1)
        stats = texture_refine(scene, h, projection, prm, p.color_threshold,
                               p.visibility_threshold, p.max_rounds, rng, self.ctx.progress)
        if list(solution.lights) != scene.light_names:
            raise BadInput("solution", f"the solution's lights {solution.lights} are not the "
                           f"scene's {scene.light_names}")
        scene = with_light_emittance(scene, solution.lights, solution.emit)
        return finish_solution(scene, h, projection, p.reflectance, p.rho_hat,
                               p.reflectance_iterations, p.tol,
                               dict(solution.info, step="TextureRefine", **stats),
                               emit=solution.emit)
