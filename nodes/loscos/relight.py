"""Unocclude and Relight (Loscos 2000 §4.2–4.4, §5, eqs. 5–9)."""
from __future__ import annotations

import functools

import numpy as np

from pydantic import BaseModel, ConfigDict

from graphkit import BadInput, Camera, Field, Image, In, Node

from . import hierarchy as HR
from .ports import (PROJECTION, RADIOSITY, UNOCCLUDED, Projection, RadiositySolution,
                    Unoccluded)
from .radiosity import lab, leaf_neighbours, light_visibility

LUM = np.array([0.2126, 0.7152, 0.0722])


class VirtualLight(BaseModel):
    """A virtual rectangular area light (metres, W/m²)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    name: str = "virtual"
    center: tuple[float, float, float]
    size: tuple[float, float] = (0.3, 0.3)
    normal: tuple[float, float, float] = (0.0, -1.0, 0.0)
    emittance: tuple[float, float, float]


class VirtualBox(BaseModel):
    """A virtual diffuse box (metres; rotation about +y in degrees)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    name: str = "box"
    center: tuple[float, float, float]
    size: tuple[float, float, float]
    rotation_deg: float = 0.0
    reflectance: tuple[float, float, float] = (0.8, 0.45, 0.1)


def pixel_leaves(sol: RadiositySolution, proj: Projection):
    """Position (into sol.leaves) of the leaf seen at each pixel (-1: none)."""
    h = sol.hierarchy()
    lv = sol.leaves
    pos = np.full(h.n_elems, -1)
    pos[lv] = np.arange(len(lv))
    pp = proj.pix_poly
    m = pp >= 0
    out = np.full(pp.shape, -1)
    out[m] = pos[h.locate(pp[m], proj.pix_st[m][:, 0], proj.pix_st[m][:, 1])]
    return out


def _emit_mask(sol):
    # a leaf emits when its unit response to some light contains the unit emission itself
    return (sol.resp - sol.rho[:, None, :] * sol.resp_H > 0.5).any(axis=(1, 2)).astype(float)


def render(photo: np.ndarray, pix_leaf: np.ndarray, modulation: np.ndarray, B: np.ndarray,
           D: np.ndarray, emits: np.ndarray) -> np.ndarray:
    """image = T_final × B / D per pixel (eq. 3 with §4.4's unoccluded texture), where
    T_final = photo × modulation; emitter pixels show B / π (radiance)."""
    out = photo.astype(np.float64).copy()
    m = pix_leaf >= 0
    k = pix_leaf[m]
    ratio = np.where(D > 1e-12, B / np.maximum(D, 1e-12), 0.0)
    val = out[m] * modulation[k] * ratio[k]
    em = emits[k] > 0
    val[em] = B[k][em] / np.pi
    out[m] = val
    return out.astype(np.float32)


class Unocclude(Node):
    """Unoccluded illumination textures (Loscos 2000 §4.2–4.3, eqs. 5–9, Figs. 15–16).

    Step 1 (eqs. 5–6): the blocked irradiance Ē_i = Σ_s F_is (1 − V_is) B_s (direct and
    indirect, from the links) is added: T_inter = (ρE + ρĒ)/D_orig · T_orig, i.e.
    T_orig × H_unoccluded / H.  Step 2 (eqs. 7–9): for each leaf occluded from a real light
    (attenuation < 1 − ``visibility_threshold``) the closest camera-visible frontier leaf
    (unoccluded, next to an occluded one) on the same polygon whose colour (CIELAB of the
    reflectance πT/H_u) is within ``color_threshold`` is its reference r, and
    T_final = T_inter · ρ_corr/ρ_inter with ρ_corr = ρ_r · S_i/S_r (eq. 8), S the unoccluded
    irradiance from all primary and secondary sources; with no such leaf the polygon's
    default reference (its largest unoccluded visible leaf) is used.  Outputs the
    per-leaf modulation T_final/T_orig, D_final = ρ (E + Ē) responses, and the image of the
    unoccluded textures from the camera (real shadows removed).
    """

    version = "1"
    inputs = {"solution": RADIOSITY, "projection": PROJECTION, "photo": Image}
    outputs = {"unoccluded": UNOCCLUDED, "image": Image}

    class Params(Node.Params):
        color_threshold: float = Field(10.0, gt=0, description="ΔE*ab for similar colours")
        visibility_threshold: float = Field(0.05, gt=0, lt=1, description="occluded if V < 1 − this")
        correction: float = Field(1.0, ge=0, le=1, description="weight of step 2 (0: step 1 only)")

    def compute(self, solution: RadiositySolution, projection: Projection, photo: Image):
        sol = solution
        if photo.pixels.shape[:2] != projection.pix_poly.shape:
            raise BadInput("photo", "photo size differs from the projection's camera")
        h = sol.hierarchy()
        lv = sol.leaves
        H = sol.H()
        Hu = sol.H(unoccluded=True)
        emits = _emit_mask(sol)
        # step 1, eq. (6)
        m1 = np.where(H > 1e-12, Hu / np.maximum(H, 1e-12), 1.0)
        m1[emits > 0] = 1.0
        T = sol.T
        seen = np.all(np.isfinite(T), 1) & (emits == 0)
        T_inter = np.where(seen[:, None], np.nan_to_num(T) * m1, 0.0)
        # step 2, eqs. (7)-(9)
        lights = sol.lights
        lp = []
        for s in range(len(lights)):
            on = (sol.resp[:, s, :] - sol.rho * sol.resp_H[:, s, :] > 0.5).any(1)
            lp.append(np.unique(h.poly[lv[on]]))
        Vis = np.nan_to_num(light_visibility(h, lv, lp), nan=1.0) if lp else \
            np.ones((len(lv), 1))
        occl = (Vis < 1 - self.params.visibility_threshold).any(1) & seen
        a, b = leaf_neighbours(h, lv)
        front = np.zeros(len(lv), bool)
        front[a[occl[b] & ~occl[a]]] = True
        front[b[occl[a] & ~occl[b]]] = True
        front &= seen
        rho_n = np.where(seen[:, None], np.pi * T_inter / np.maximum(Hu, 1e-12), 0.0)
        C = lab(rho_n)
        o, u, v, _, area = h.geom(lv)
        cen = o + 0.5 * (u + v)
        poly = h.poly[lv]
        ref = np.full(len(lv), -1)
        for p in np.unique(poly[occl]):
            oi = np.flatnonzero(occl & (poly == p))
            fr = np.flatnonzero(front & (poly == p))
            cand_def = np.flatnonzero(seen & ~occl & (poly == p))
            if len(fr):
                d = np.linalg.norm(cen[oi][:, None] - cen[fr][None], axis=2)
                dc = np.linalg.norm(C[oi][:, None] - C[fr][None], axis=2)
                d = np.where(dc < self.params.color_threshold, d, np.inf)
                k = np.argmin(d, 1)
                ok = np.isfinite(d[np.arange(len(oi)), k])
                ref[oi[ok]] = fr[k[ok]]
            if len(cand_def):
                dflt = cand_def[np.argmax(area[cand_def])]
                ref[oi[ref[oi] < 0]] = dflt
        c2 = np.ones((len(lv), 3))
        has = occl & (ref >= 0)
        i, r = np.flatnonzero(has), ref[has]
        rho_corr = rho_n[r] * 1.0  # eq. 8 with S = H_u cancels into ρ_r in these units
        c2[i] = np.where(rho_n[i] > 1e-12, rho_corr / np.maximum(rho_n[i], 1e-12), 1.0)
        c2 = 1.0 + self.params.correction * (c2 - 1.0)
        modulation = m1 * c2
        # D_final = ρ_final (E + Ē) = ρ_final H_u (+ E for emitters), per unit emittance
        rho_f = sol.rho.copy()
        rho_f[i] = np.clip(sol.rho[i] * c2[i], 0, 0.95)
        resp_D = rho_f[:, None, :] * sol.resp_Hu + (sol.resp - sol.rho[:, None, :] * sol.resp_H)
        un = Unoccluded(modulation=modulation, resp_D=resp_D, occluded=occl.astype(np.int64),
                        reference=ref)
        pix = pixel_leaves(sol, projection)
        img = render(photo.pixels[:, :, :3], pix, modulation, np.ones((len(lv), 3)),
                     np.ones((len(lv), 3)), np.zeros(len(lv)))
        return {"unoccluded": un, "image": Image(img)}


class Relight(Node):
    """Relight the real scene (Loscos 2000 §4.4, §5): image = T_final × B / D per pixel.

    ``light_scale`` multiplies the emittance of named real lights (0 switches a light off);
    ``emittance`` sets a light's RGB emittance in W/m².  The refinement, form factors and
    visibility are not redone (§5); going further than the paper, the solution holds one
    radiosity response per light, so B for new emittances is a weighted sum of responses
    (radiosity is linear in the emittances) — no gathering at all.  D stays the display
    correction of the original lighting.  Values are linear radiance.
    """

    version = "1"
    studio_view = "nodes.loscos.studio_view:RoomView"  # graphkit serve: light sliders on the fast path
    inputs = {"solution": RADIOSITY, "unoccluded": UNOCCLUDED, "projection": PROJECTION,
              "photo": Image,
              "camera": In(Camera, "needed when inserting virtual lights or boxes", optional=True)}
    outputs = {"image": Image}

    @staticmethod
    def relight_fast(prep, e):
        """The per-pixel modulation (module function :func:`relight_fast`), a hook a backend
        replaces (plugins/graphkit-opencl)."""
        return relight_fast(prep, e)

    class Params(Node.Params):
        light_scale: dict[str, float] = Field(default_factory=dict,
                                              description="light name → emittance factor")
        emittance: dict[str, list[float]] = Field(default_factory=dict,
                                                  description="light name → RGB W/m²")
        virtual_lights: list[VirtualLight] = Field(default_factory=list,
                                                   description="area lights to insert (§4.5)")
        virtual_boxes: list[VirtualBox] = Field(default_factory=list,
                                                description="diffuse boxes to insert ([8])")
        force_level: int = Field(3, ge=0, le=8, description="§4.5 forced refinement depth")
        eps_bf: float = Field(0.1, gt=0, description="refinement of new links (as RadiositySolve)")
        eps_bfv: float = Field(0.01, gt=0, description="BFV threshold of new links")
        min_area: float = Field(2e-3, gt=0, description="smallest new element (m²)")
        max_level: int = Field(6, ge=0, le=10, description="deepest level of new elements")
        rays: int = Field(4, ge=1, le=16, description="rays² per new link")
        seed: int = Field(0, description="seed of the visibility jitter")

    def compute(self, solution: RadiositySolution, unoccluded: Unoccluded,
                projection: Projection, photo: Image, camera=None):
        sol = solution
        if photo.pixels.shape[:2] != projection.pix_poly.shape:
            raise BadInput("photo", "photo size differs from the projection's camera")
        if len(unoccluded.modulation) != len(sol.leaves):
            raise BadInput("unoccluded", "computed for another solution")
        p = self.params
        e = new_emittance(sol, p.light_scale, p.emittance)
        if p.virtual_lights or p.virtual_boxes:
            if camera is None:
                raise BadInput("camera", "inserting virtual lights or boxes needs the camera")
            prm = HR.RefineParams(p.eps_bf, p.eps_bfv, p.min_area, p.max_level, p.rays, 3, p.seed)
            img, _ = relight_virtual(sol, unoccluded, projection, photo.pixels[:, :, :3], camera,
                                     e, [x.model_dump() for x in p.virtual_lights],
                                     [x.model_dump() for x in p.virtual_boxes], prm,
                                     p.force_level, 1e-6)
            return Image(img)
        prep = prepare(sol, unoccluded, projection, photo.pixels[:, :, :3])
        return Image(self.relight_fast(prep, e))

    @classmethod
    def examples(cls):
        """A small room (3 walls, 2 lights, 40×32 px) solved coarsely: lights switched off,
        scaled and recoloured (the backend conformance cases; solved once per process)."""
        return _relight_examples()


@functools.lru_cache(maxsize=1)
def _relight_examples():
    """Relight.examples(): solved once per process."""
    from graphkit import Context

    from .radiosity import RadiositySolve
    from .scene import parse_scene
    from .textures import ProjectTextures

    q = [[-.3, .99, -.6], [.3, .99, -.6], [.3, .99, -.2], [-.3, .99, -.2]]  # facing down
    doc = {"loscos_scene": 1, "camera": {"width": 40, "height": 32, "fov_deg": 60,
                                         "position": [0, 0, 2.5], "look_at": [0, 0, 0]},
           "materials": {"w": [0.7, 0.6, 0.5], "r": [0.6, 0.1, 0.1]},
           "polygons": [{"name": "back", "material": "w", "vertices": [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1]]},
                        {"name": "floor", "material": "w", "vertices": [[-1, -1, 1], [1, -1, 1], [1, -1, -1], [-1, -1, -1]]},
                        {"name": "left", "material": "r", "vertices": [[-1, -1, 1], [-1, -1, -1], [-1, 1, -1], [-1, 1, 1]]}],
           "lights": [{"name": "A", "material": "w", "emittance": [20, 20, 16], "vertices": q},
                      {"name": "B", "material": "w", "emittance": [8, 12, 16],
                       "vertices": [[.5, .99, .1], [.8, .99, .1], [.8, .99, .4], [.5, .99, .4]]}]}
    sc, cam, _ = parse_scene(doc)
    yy, xx = np.mgrid[0:32, 0:40] / 40.0
    photo = Image((0.3 + 0.4 * np.dstack([xx, yy, xx * yy])).astype(np.float32))

    def run(node, params, **kw):
        return node(node.Params(**params), Context()).compute(**kw)

    pr = run(ProjectTextures, {"resolution": 8}, scene=sc, camera=cam, photo=photo)
    sol = run(RadiositySolve, {"eps_bf": 0.5, "eps_bfv": 0.05, "min_area": 0.05, "max_level": 3},
              scene=sc, projection=pr)
    un = run(Unocclude, {}, solution=sol, projection=pr, photo=photo)["unoccluded"]
    inputs = {"solution": sol, "unoccluded": un, "projection": pr, "photo": photo}
    return [({"light_scale": {"A": 0.0}}, inputs),
            ({"light_scale": {"A": 1.5}, "emittance": {"B": [1.0, 6.0, 2.0]}}, inputs),
            ({}, inputs)]


def new_emittance(sol, scale: dict, emit: dict) -> np.ndarray:
    e = sol.emit.copy()
    for name in list(scale) + list(emit):
        if name not in sol.lights:
            raise BadInput("light_scale" if name in scale else "emittance",
                           f"unknown light '{name}' (lights: {', '.join(sol.lights)})")
    for k, n in enumerate(sol.lights):
        if n in emit:
            v = np.asarray(emit[n], float)
            if v.shape != (3,) or np.any(v < 0):
                raise BadInput("emittance", f"light '{n}': 3 values ≥ 0 (W/m²)")
            e[k] = v
        if n in scale:
            if scale[n] < 0:
                raise BadInput("light_scale", f"light '{n}': factor must be ≥ 0")
            e[k] = e[k] * scale[n]
    return e


def prepare(sol, un, proj, photo):
    """Everything that does not depend on the emittances (done once per preprocess)."""
    pix = pixel_leaves(sol, proj)
    m = pix >= 0
    k = pix[m]
    D = np.einsum("lsc,sc->lc", un.resp_D, sol.emit)
    emits = _emit_mask(sol) > 0
    # per seen pixel: base = photo × modulation / D (non-emitters), 1/π for emitters
    base = np.where(emits[k][:, None], 1.0 / np.pi,
                    photo[m] * un.modulation[k] / np.maximum(D[k], 1e-12)
                    * (D[k] > 1e-12))
    return {"shape": photo.shape, "photo": photo.astype(np.float32), "mask": m, "k": k,
            "base": base.astype(np.float32),
            "resp": np.ascontiguousarray(sol.resp.transpose(2, 0, 1)).astype(np.float32)}


def relight_fast(prep, e: np.ndarray) -> np.ndarray:
    """B = Σ_s resp_s · e_s (per channel), image = base × B at the pixels' leaves."""
    resp = prep["resp"]  # (3, L, S)
    B = np.einsum("cls,sc->lc", resp, e.astype(np.float32))
    out = prep["photo"].copy()
    out[prep["mask"]] = prep["base"] * B[prep["k"]]
    return out


# ------------------------------------------------------------------------------------------
# §4.5 / [8]: inserting virtual lights and objects


def quad_from(center, size, normal, up_hint=(0.0, 0.0, 1.0)):
    """Parallelogram (4,3) centred at ``center`` with side lengths size=(a, b), facing normal."""
    n = np.asarray(normal, float)
    n /= np.linalg.norm(n)
    t = np.asarray(up_hint, float)
    if abs(np.dot(t, n)) > 0.9:
        t = np.array([1.0, 0.0, 0.0])
    e1 = np.cross(t, n)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    a, b = size
    c = np.asarray(center, float)
    o = c - 0.5 * a * e1 - 0.5 * b * e2
    return np.array([o, o + a * e1, o + a * e1 + b * e2, o + b * e2])


def box_quads(center, size, rotation_deg):
    """The 6 outward faces of an axis-aligned box (metres) rotated about +y by rotation_deg."""
    from .scene import box_faces

    c = np.radians(rotation_deg)
    R = np.array([[np.cos(c), 0, np.sin(c)], [0, 1, 0], [-np.sin(c), 0, np.cos(c)]])
    M = np.eye(4)
    M[:3, :3] = R @ np.diag(np.asarray(size, float) / 2)
    M[:3, 3] = center
    return box_faces(M)


def shaft_hits(h: HR.Hierarchy, r, s, lo, hi):
    """Links whose bounding box (of both elements) overlaps the AABB [lo, hi]."""
    o1, u1, v1, _, _ = h.geom(r)
    o2, u2, v2, _, _ = h.geom(s)
    pts = np.concatenate([G_corners(o1, u1, v1), G_corners(o2, u2, v2)], axis=1)
    mn, mx = pts.min(1), pts.max(1)
    return np.all((mn <= hi) & (mx >= lo), axis=1)


def G_corners(o, u, v):
    from .geometry import corners

    return corners(o, u, v)


def relight_virtual(sol: RadiositySolution, un: Unoccluded, proj: Projection, photo, camera,
                    e_real, vlights, vboxes, prm: HR.RefineParams, force_level: int, tol):
    """Insert virtual emitters / boxes into the preprocessed hierarchy and relight (§4.5)."""
    from .geometry import frame
    from .textures import pixel_map

    h = sol.hierarchy().copy()
    lv0 = sol.leaves
    N0, P0 = h.n_elems, len(h.P_o)
    quads, refl, emit, kind = [], [], [], []
    for L in vlights:
        q = quad_from(L["center"], L.get("size", [0.3, 0.3]), L.get("normal", [0, -1, 0]))
        quads.append(q); refl.append(np.zeros(3)); emit.append(np.asarray(L["emittance"], float))
        kind.append("light")
    for bx in vboxes:
        for q in box_quads(bx["center"], bx["size"], bx.get("rotation_deg", 0.0)):
            quads.append(q); refl.append(np.asarray(bx.get("reflectance", [0.5] * 3), float))
            emit.append(np.zeros(3)); kind.append("box")
    Q = np.array(quads)
    o, u, v, n, a = frame(Q)
    if np.any(a <= 1e-10):
        raise BadInput("virtual_lights", "a virtual light or box has zero area")
    K = len(Q)
    h.P_o = np.concatenate([h.P_o, o]); h.P_u = np.concatenate([h.P_u, u])
    h.P_v = np.concatenate([h.P_v, v])
    h.poly = np.concatenate([h.poly, P0 + np.arange(K)])
    h.level = np.concatenate([h.level, np.zeros(K, np.int64)])
    h.ij = np.concatenate([h.ij, np.zeros((K, 2), np.int64)])
    h.parent = np.concatenate([h.parent, np.full(K, -1)])
    h.child0 = np.concatenate([h.child0, np.full(K, -1)])
    refl, emit = np.array(refl), np.array(emit)
    # element radiosity estimate for the refinement oracle
    B_old = sol.B(e_real)
    ops0 = HR.operators(sol.hierarchy())
    B_el = np.concatenate([(ops0.pull @ B_old) @ LUM, (emit + refl * np.median(B_old, 0)) @ LUM])
    rng = np.random.default_rng(prm.seed + 7)
    # 1. existing links whose shaft meets a virtual box are re-evaluated (and re-refined)
    # (virtual lights occlude too: their back faces are black)
    redo = np.zeros(len(h.recv), bool)
    for q in Q:
        redo |= shaft_hits(h, h.recv, h.send, q.min(0) - 1e-6, q.max(0) + 1e-6)
    cand_r = [h.recv[redo]]
    cand_s = [h.send[redo]]
    keep = ~redo
    kr, ks, kF, kV, kC = h.recv[keep], h.send[keep], h.F[keep], h.V[keep], h.C[keep]
    # 2. new links between virtual polygons and every polygon
    roots = np.flatnonzero(h.parent == -1)
    new = N0 + np.arange(K)
    R1, S1 = np.meshgrid(roots, new, indexing="ij")
    cand_r += [R1.ravel(), S1.ravel()]
    cand_s += [S1.ravel(), R1.ravel()]
    r = np.concatenate(cand_r); s = np.concatenate(cand_s)
    m = r != s
    r, s = r[m], s[m]
    seen_poly = np.zeros(len(h.P_o), bool)
    seen_poly[np.unique(proj.pix_poly[proj.pix_poly >= 0])] = True
    vl_polys = P0 + np.array([i for i, k in enumerate(kind) if k == "light"], dtype=int)

    def force(rr, ss):  # §4.5: links from virtual lights go down to visible polygons
        return (np.isin(h.poly[ss], vl_polys) & seen_poly[h.poly[rr]]
                & (h.level[rr] < force_level))

    nr, ns, nF, nV, nC = HR.refine(h, r, s, B_el, prm, rng, force=force)
    h.recv = np.concatenate([kr, nr]); h.send = np.concatenate([ks, ns])
    h.F = np.concatenate([kF, nF]); h.V = np.concatenate([kV, nV])
    h.C = np.concatenate([kC, nC])
    # 3. solve on the new leaves; new leaves inherit ρ, T_final/T and D of their old leaf
    ops = HR.operators(h)
    lv = ops.leaves
    pos0 = np.full(N0, -1)
    pos0[lv0] = np.arange(len(lv0))
    virt = h.poly[lv] >= P0
    anc = lv.copy()
    while True:  # elements made after the preprocess have ids ≥ N0: climb to the old leaf
        up = (anc >= N0) & ~virt
        if not up.any():
            break
        anc[up] = h.parent[anc[up]]
    old = np.where(virt, -1, pos0[np.minimum(anc, N0 - 1)])
    rho = np.zeros((len(lv), 3))
    rho[~virt] = sol.rho[old[~virt]]
    rho[virt] = refl[h.poly[lv][virt] - P0]
    E = np.zeros((len(lv), 3))
    emits0 = _emit_mask(sol) > 0
    # real emitters: their emittance under the new setting
    Ereal = np.einsum("lsc,sc->lc", sol.resp - sol.rho[:, None, :] * sol.resp_H, e_real)
    E[~virt] = Ereal[old[~virt]]
    E[virt] = emit[h.poly[lv][virt] - P0]
    B, _ = HR.solve(ops, E, rho, tol=tol)
    # consistent reference (Loscos §2.4: only *changes* of B matter): the same new mesh and
    # links, real-real visibility recomputed without the virtual polygons, no virtual
    # polygons, original emittances.  Real pixels are then scaled by B / B_ref.
    rr = (h.poly[nr] < P0) & (h.poly[ns] < P0)
    occ = (h.P_o[:P0], h.P_u[:P0], h.P_v[:P0], h.P_n[:P0])
    V_wo, C_wo = HR.link_visibility(h, nr[rr], ns[rr], prm.n_rays,
                                    np.random.default_rng(prm.seed + 9), occ=occ, centroid=True)
    h_ref = h.copy()
    h_ref.recv = np.concatenate([kr, nr[rr]]); h_ref.send = np.concatenate([ks, ns[rr]])
    h_ref.F = np.concatenate([kF, nF[rr]]); h_ref.V = np.concatenate([kV, V_wo])
    h_ref.C = np.concatenate([kC, C_wo])
    ops_ref = HR.operators(h_ref)
    E_ref = np.zeros((len(lv), 3))
    E_ref[~virt] = np.einsum("lsc,sc->lc", sol.resp - sol.rho[:, None, :] * sol.resp_H,
                             sol.emit)[old[~virt]]
    rho_ref = np.where(virt[:, None], 0.0, rho)
    B_ref, _ = HR.solve(ops_ref, E_ref, rho_ref, tol=tol)
    D0 = np.einsum("lsc,sc->lc", un.resp_D, sol.emit)
    B0 = sol.B()
    # 4. render: the camera sees either a virtual polygon or the real scene
    allv = np.concatenate([np.stack([h.P_o[:P0], h.P_o[:P0] + h.P_u[:P0],
                                     h.P_o[:P0] + h.P_u[:P0] + h.P_v[:P0],
                                     h.P_o[:P0] + h.P_v[:P0]], 1), Q])
    pp, pst = pixel_map(allv, camera)
    grid = h.leaf_grid()
    posn = np.full(h.n_elems, -1)
    posn[lv] = np.arange(len(lv))
    out = photo.astype(np.float64).copy()
    pix_old = pixel_leaves(sol, proj)
    msk = pp >= 0
    kn = posn[h.locate(pp[msk], pst[msk][:, 0], pst[msk][:, 1], grid)]
    ko = pix_old[msk]
    val = out[msk]
    isv = h.poly[lv][kn] >= P0
    em = (E[kn].max(1) > 0) | isv | (ko < 0)
    real = ~em & (ko >= 0)
    ratio = (B[kn[real]] / np.maximum(B_ref[kn[real]], 1e-12)
             * B0[ko[real]] / np.maximum(D0[ko[real]], 1e-12))
    val[real] = val[real] * un.modulation[ko[real]] * ratio
    val[em] = B[kn[em]] / np.pi
    emitter_old = np.zeros(len(kn), bool)
    emitter_old[ko >= 0] = emits0[ko[ko >= 0]]
    val[emitter_old & ~isv] = B[kn[emitter_old & ~isv]] / np.pi
    out[msk] = val
    return out.astype(np.float32), {"leaves": int(len(lv)), "links": int(len(h.recv))}
