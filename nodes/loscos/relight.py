"""Unocclude and Relight (Loscos 2000 §4.2–4.4, §5, eqs. 5–9)."""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict

from graphkit import BadInput, Camera, Field, Image, In, Node

from . import checks
from . import hierarchy as HR
from .display import modulate_pixels, polygon_groups
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


def emitter_leaves(sol: RadiositySolution) -> np.ndarray:
    """(L,) bool: leaves whose unit response to some light holds the unit emission itself."""
    return (unit_emission(sol) > 0.5).any(axis=(1, 2))


def unit_emission(sol: RadiositySolution) -> np.ndarray:
    """(L,S,3) emittance of each leaf per unit emittance of each light (1 on its polygons)."""
    return sol.resp - sol.rho[:, None, :] * sol.resp_H


def emitter_polygons(h: HR.Hierarchy, leaves: np.ndarray, emits: np.ndarray) -> np.ndarray:
    """(P,) bool: polygons that carry an emitting leaf."""
    out = np.zeros(len(h.P_o), bool)
    out[np.unique(h.poly[leaves[emits]])] = True
    return out


def photo_emitter_radiance(sol: RadiositySolution, proj: Projection, emit_poly: np.ndarray):
    """(P,3) each emitter's radiance in the photograph (ProjectTextures measures it from the
    pixels it covers); B/π of the solution where the photo does not show it."""
    h = sol.hierarchy()
    B = sol.B()
    poly = h.poly[sol.leaves]
    a = h.area(sol.leaves)
    out = np.zeros((len(h.P_o), 3))
    rad = proj.em_radiance if len(proj.em_radiance) == len(h.P_o) else \
        np.full((len(h.P_o), 3), np.nan)
    for p in np.flatnonzero(emit_poly):
        if np.all(np.isfinite(rad[p])):
            out[p] = rad[p]
        else:
            m = poly == p
            out[p] = (a[m, None] * B[m]).sum(0) / a[m].sum() / np.pi
    return out


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
    unoccluded textures from the camera (real shadows removed; the modulation interpolated
    per vertex, emitters as photographed).
    """

    version = "2"
    inputs = {"solution": RADIOSITY, "projection": PROJECTION, "photo": Image}
    outputs = {"unoccluded": UNOCCLUDED, "image": Image}

    class Params(Node.Params):
        color_threshold: float = Field(10.0, gt=0, description="ΔE*ab for similar colours")
        visibility_threshold: float = Field(0.05, gt=0, lt=1, description="occluded if V < 1 − this")
        correction: float = Field(1.0, ge=0, le=1, description="weight of step 2 (0: step 1 only)")

    def compute(self, solution: RadiositySolution, projection: Projection, photo: Image):
        sol = solution
        checks.photo_fits(photo, projection)
        h = sol.hierarchy()
        lv = sol.leaves
        H = sol.H()
        Hu = sol.H(unoccluded=True)
        emits = emitter_leaves(sol).astype(float)
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
        area = h.area(lv)
        cen = h.centre(lv)
        poly = h.poly[lv]
        ref = np.full(len(lv), -1)
        for idx in polygon_groups(poly):
            oi = idx[occl[idx]]
            if not len(oi):
                continue
            fr = idx[front[idx]]
            cand_def = idx[seen[idx] & ~occl[idx]]
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
        return {"unoccluded": un, "image": Image(unoccluded_image(sol, un, projection,
                                                                 photo.pixels[:, :, :3]))}


class Relight(Node):
    """Relight the real scene (Loscos 2000 §4.4, §5): image = T_final × B / D per pixel.

    ``light_scale`` multiplies the emittance of named real lights (0 switches a light off);
    ``emittance`` sets a light's RGB emittance in W/m² (both start from the solution's
    emittances: the scene file's, or those RadiositySolve estimated).  The refinement, form
    factors and visibility are not redone (§5); going further than the paper, the solution
    holds one radiosity response per light, so B for new emittances is a weighted sum of
    responses (radiosity is linear in the emittances) — no gathering at all.  D stays the
    display correction of the original lighting.  B/D (times the texture modulation) is
    interpolated per vertex over each leaf (the paper's Gouraud display), pixels on the rim of
    an emitter are drawn by coverage (display.py), and a light's fixture shows
    (E + ρ_fixture·H)/π with ``fixture_reflectance`` — what a switched-off lamp looks like.
    Values are linear radiance.
    """

    version = "4"  # 4: in a clustered room virtual boxes block cluster links
    studio_view = "nodes.loscos.studio_view:RoomView"  # graphkit serve: light sliders on the fast path
    inputs = {"solution": RADIOSITY, "unoccluded": UNOCCLUDED, "projection": PROJECTION,
              "photo": Image,
              "camera": In(Camera, "needed when inserting virtual lights or boxes", optional=True)}
    outputs = {"image": Image}
    hooks = ("modulate_pixels",)

    @staticmethod
    def modulate_pixels(px, e):
        """The per-pixel maths (:func:`display.modulate_pixels`: per pixel base·Σ R·e + Σ G·e),
        a hook a backend replaces (plugins/graphkit-opencl)."""
        return modulate_pixels(px, e)

    class Params(Node.Params):
        light_scale: dict[str, float] = Field(default_factory=dict,
                                              description="light name → emittance factor")
        emittance: dict[str, list[float]] = Field(default_factory=dict,
                                                  description="light name → RGB W/m²")
        fixture_reflectance: tuple[float, float, float] = Field(
            (0.5, 0.5, 0.5), description="diffuse albedo (linear RGB, in [0, 1)) of the lights' "
            "fixtures: a switched-off light shows ρ·H/π")
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
        checks.photo_fits(photo, projection)
        if len(unoccluded.modulation) != len(sol.leaves):
            raise BadInput("unoccluded", "computed for another solution")
        p = self.params
        rho_fix = checks.reflectance(p.fixture_reflectance, "fixture_reflectance")
        e = new_emittance(sol, p.light_scale, p.emittance)
        px = photo.pixels[:, :, :3]
        if p.virtual_lights or p.virtual_boxes:
            if camera is None:
                raise BadInput("camera", "inserting virtual lights or boxes needs the camera")
            checks.pinhole(camera, "camera", "inserting virtual lights or boxes needs")
            from .virtual import check_params_placement

            check_params_placement(sol.hierarchy(), p.virtual_lights, p.virtual_boxes)
            prm = HR.RefineParams(p.eps_bf, p.eps_bfv, p.min_area, p.max_level, p.rays, 3, p.seed)
            img, _ = relight_virtual(sol, unoccluded, projection, px, camera, e,
                                     virtual_polygons(p.virtual_lights, p.virtual_boxes), prm,
                                     p.force_level, 1e-6, rho_fix)
            return Image(img)
        return Image(self.modulate_pixels(relight_plan(sol, unoccluded, projection, px, rho_fix),
                                          e))

    @classmethod
    def examples(cls):
        """A small room (3 walls, 2 lights, 40×32 px) solved coarsely: lights switched off,
        scaled and recoloured (the backend conformance cases; solved once per process); and a
        virtual box in a room with a real box, whose links are re-evaluated (§4.5)."""
        from graphkit import Context

        from .embree import ray_examples

        e = ray_examples()
        un = Unocclude(Unocclude.Params(), Context()).compute(
            solution=e["refined"], projection=e["projection"], photo=e["photo"])["unoccluded"]
        box = {"name": "v", "center": [0.4, -0.85, 0.2], "size": [0.3, 0.3, 0.3],
               "rotation_deg": 20, "reflectance": [0.8, 0.4, 0.1]}
        return _relight_examples() + [({"virtual_boxes": [box]}, {
            "solution": e["refined"], "unoccluded": un, "projection": e["projection"],
            "photo": e["photo"], "camera": e["camera"]})]


@functools.lru_cache(maxsize=1)
def _relight_examples():
    """Relight.examples(): solved once per process."""
    from graphkit import Context

    from .radiosity import RadiositySolve
    from .scene import example_room
    from .textures import ProjectTextures

    sc, cam, photo = example_room()

    def run(node, params, **kw):
        return node(node.Params(**params), Context()).compute(**kw)

    pr = run(ProjectTextures, {"resolution": 8}, scene=sc, camera=cam, photo=photo)
    sol = run(RadiositySolve, {"eps_bf": 0.5, "eps_bfv": 0.05, "min_area": 0.05, "max_level": 3},
              scene=sc, projection=pr)["solution"]
    un = run(Unocclude, {}, solution=sol, projection=pr, photo=photo)["unoccluded"]
    inputs = {"solution": sol, "unoccluded": un, "projection": pr, "photo": photo}
    return [({"light_scale": {"A": 0.0}}, inputs),
            ({"light_scale": {"A": 1.5}, "emittance": {"B": [1.0, 6.0, 2.0]}}, inputs),
            ({}, inputs)]


def new_emittance(sol, scale: dict, emit: dict) -> np.ndarray:
    """(S,3) emittances in W/m²: the solution's, set by ``emit`` then scaled by ``scale``."""
    e = sol.emit.copy()
    for name in list(scale) + list(emit):
        if name not in sol.lights:
            raise BadInput("light_scale" if name in scale else "emittance",
                           f"unknown light '{name}' (lights: {', '.join(sol.lights)})")
    for k, n in enumerate(sol.lights):
        if n in emit:
            e[k] = checks.emittance(emit[n], "emittance", f"light '{n}'")
        if n in scale:
            if not np.isfinite(scale[n]) or scale[n] < 0:
                raise BadInput("light_scale", f"light '{n}': factor must be finite and ≥ 0, "
                                              f"got {scale[n]}")
            e[k] = e[k] * scale[n]
    return e


def leaf_multiplier(sol: RadiositySolution, un: Unoccluded) -> np.ndarray:
    """(L,S,3) T_final/T × B/D per unit emittance of each light (§4.4): B from the responses,
    D_final at the solution's emittances."""
    D = np.einsum("lsc,sc->lc", un.resp_D, sol.emit)
    inv = np.where(D > 1e-12, 1.0 / np.maximum(D, 1e-12), 0.0)
    return un.modulation[:, None, :] * sol.resp * inv[:, None, :]


def fixture_glow(sol: RadiositySolution, rho_fix: np.ndarray) -> np.ndarray:
    """(L,S,3) radiance of the emitters per unit emittance: (E + ρ_fixture·H)/π."""
    return (unit_emission(sol) + rho_fix[None, None, :] * sol.resp_H) / np.pi


def relight_plan(sol: RadiositySolution, un: Unoccluded, proj: Projection, photo,
                 rho_fix=(0.5, 0.5, 0.5)):
    """Everything that does not depend on the emittances (once per preprocess): per drawn
    pixel its modulation and emitted radiance per unit emittance (display.PixelResponses)."""
    from .display import nearest_seen, pixel_plan, pixel_responses

    h = sol.hierarchy()
    emit_poly = emitter_polygons(h, sol.leaves, emitter_leaves(sol))
    plan = pixel_plan(h, proj, photo, emit_poly, photo_emitter_radiance(sol, proj, emit_poly),
                      leaf_radiance=sol.T @ LUM)
    near = nearest_seen(h, np.all(np.isfinite(sol.T), 1))
    return pixel_responses(plan, leaf_multiplier(sol, un)[near],
                           fixture_glow(sol, np.asarray(rho_fix, float)))


def unoccluded_image(sol: RadiositySolution, un: Unoccluded, proj: Projection, photo):
    """The photograph with the real shadows removed: photo × T_final/T per vertex, emitters
    as photographed."""
    from .display import nearest_seen, pixel_plan, pixel_responses

    h = sol.hierarchy()
    emit_poly = emitter_polygons(h, sol.leaves, emitter_leaves(sol))
    L_em = photo_emitter_radiance(sol, proj, emit_poly)
    plan = pixel_plan(h, proj, photo, emit_poly, L_em, leaf_radiance=sol.T @ LUM)
    glow = L_em[h.poly[sol.leaves]][:, None, :]
    near = nearest_seen(h, np.all(np.isfinite(sol.T), 1))
    px = pixel_responses(plan, un.modulation[near][:, None, :], glow)
    return modulate_pixels(px, np.ones((1, 3)))


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


@dataclass(eq=False)
class VirtualPolygons:
    """Polygons to insert: quads (K,4,3) metres, reflectance (K,3), emittance (K,3) W/m²,
    light (K,) bool — a virtual light's face (black, emitting) or a box face."""

    quads: np.ndarray
    reflectance: np.ndarray
    emittance: np.ndarray
    light: np.ndarray


def virtual_polygons(vlights, vboxes) -> VirtualPolygons:
    """VirtualLight / VirtualBox params → polygons; BadInput on bad values."""
    quads, refl, emit, light = [], [], [], []
    for L in vlights:
        e = checks.emittance(L.emittance, "virtual_lights", f"light '{L.name}'")
        quads.append(quad_from(L.center, L.size, L.normal))
        refl.append(np.zeros(3)); emit.append(e); light.append(True)
    for bx in vboxes:
        r = checks.reflectance(bx.reflectance, "virtual_boxes", f"box '{bx.name}'")
        for q in box_quads(bx.center, bx.size, bx.rotation_deg):
            quads.append(q); refl.append(r); emit.append(np.zeros(3)); light.append(False)
    Q = np.array(quads)
    if not np.all(np.isfinite(Q)):
        raise BadInput("virtual_lights" if vlights else "virtual_boxes",
                       "a virtual light or box has non-finite coordinates")
    from .geometry import frame

    if np.any(frame(Q)[4] <= 1e-10):
        raise BadInput("virtual_lights" if vlights else "virtual_boxes",
                       "a virtual light or box has zero area")
    return VirtualPolygons(Q, np.array(refl), np.array(emit), np.array(light))


def add_roots(h: HR.Hierarchy, quads: np.ndarray) -> None:
    """Append the quads to h as new polygons, each one root element (no links yet)."""
    from .geometry import frame

    o, u, v, _, _ = frame(quads)
    K = len(quads)
    P0 = len(h.P_o)
    h.P_o = np.concatenate([h.P_o, o])
    h.P_u = np.concatenate([h.P_u, u])
    h.P_v = np.concatenate([h.P_v, v])
    h.poly = np.concatenate([h.poly, P0 + np.arange(K)])
    h.level = np.concatenate([h.level, np.zeros(K, np.int64)])
    h.ij = np.concatenate([h.ij, np.zeros((K, 2), np.int64)])
    h.parent = np.concatenate([h.parent, np.full(K, -1)])
    h.child0 = np.concatenate([h.child0, np.full(K, -1)])


def shaft_hits(h: HR.Hierarchy, r, s, lo, hi):
    """Links whose bounding box (of both elements) overlaps the AABB [lo, hi]."""
    from .geometry import corners

    o1, u1, v1, _, _ = h.geom(r)
    o2, u2, v2, _, _ = h.geom(s)
    pts = np.concatenate([corners(o1, u1, v1), corners(o2, u2, v2)], axis=1)
    mn, mx = pts.min(1), pts.max(1)
    return np.all((mn <= hi) & (mx >= lo), axis=1)


@dataclass(eq=False)
class Links:
    recv: np.ndarray
    send: np.ndarray
    F: np.ndarray
    V: np.ndarray
    C: np.ndarray

    def __add__(self, o: "Links") -> "Links":
        return Links(*(np.concatenate([a, b]) for a, b in zip(self.astuple(), o.astuple())))

    def astuple(self):
        return self.recv, self.send, self.F, self.V, self.C

    def select(self, m) -> "Links":
        return Links(*(x[m] for x in self.astuple()))


def relink(h: HR.Hierarchy, vp: VirtualPolygons, B_elem: np.ndarray, seen_poly: np.ndarray,
           prm: HR.RefineParams, force_level: int, rng) -> tuple[Links, Links]:
    """§4.5 on a hierarchy whose last len(vp.quads) polygons are virtual (roots only).

    Links whose bounding box meets a virtual polygon are refined again (the polygons may
    block them; a virtual light's back is black), every root is linked both ways with every
    virtual polygon, and links from virtual lights are forced down to ``force_level`` on
    the polygons the camera sees.  Returns (kept links, new links); sets h's links.
    """
    P0 = len(h.P_o) - len(vp.quads)
    N0 = h.n_elems - len(vp.quads)
    old = Links(h.recv, h.send, h.F, h.V, h.C)
    redo = np.zeros(len(h.recv), bool)
    for q in vp.quads:
        redo |= shaft_hits(h, h.recv, h.send, q.min(0) - 1e-6, q.max(0) + 1e-6)
    roots = np.flatnonzero(h.parent == -1)
    new = N0 + np.arange(len(vp.quads))
    R1, S1 = np.meshgrid(roots, new, indexing="ij")
    r = np.concatenate([h.recv[redo], R1.ravel(), S1.ravel()])
    s = np.concatenate([h.send[redo], S1.ravel(), R1.ravel()])
    m = r != s
    vl_polys = P0 + np.flatnonzero(vp.light)

    def force(rr, ss):
        return (np.isin(h.poly[ss], vl_polys) & seen_poly[h.poly[rr]]
                & (h.level[rr] < force_level))

    kept = old.select(~redo)
    added = Links(*HR.refine(h, r[m], s[m], B_elem, prm, rng, force=force))
    h.recv, h.send, h.F, h.V, h.C = (kept + added).astuple()
    return kept, added


def old_leaf(h: HR.Hierarchy, N0: int, P0: int, old_leaves: np.ndarray) -> np.ndarray:
    """For each leaf of h: its position among the preprocessed leaves (elements made after
    the preprocess have ids ≥ N0: climb to the old leaf); -1 on virtual polygons."""
    lv = h.leaves
    pos0 = np.full(N0, -1)
    pos0[old_leaves] = np.arange(len(old_leaves))
    virt = h.poly[lv] >= P0
    anc = lv.copy()
    while True:
        up = (anc >= N0) & ~virt
        if not up.any():
            break
        anc[up] = h.parent[anc[up]]
    return np.where(virt, -1, pos0[np.minimum(anc, N0 - 1)])


def real_reference(h: HR.Hierarchy, kept: Links, added: Links, P0: int, n_rays: int, seed: int):
    """The same mesh and links without the virtual polygons (real–real links' visibility
    recomputed without them): Loscos §2.4, only *changes* of B matter, so the real pixels
    are scaled by B / B_ref computed on one mesh."""
    rr = (h.poly[added.recv] < P0) & (h.poly[added.send] < P0)
    occ = h.occluders(P0)
    V, C = HR.link_visibility(h, added.recv[rr], added.send[rr], n_rays,
                              np.random.default_rng(seed), occ=occ, centroid=True)
    ref = h.copy()
    a = added.select(rr)
    ref.recv, ref.send, ref.F, ref.V, ref.C = (kept + Links(a.recv, a.send, a.F, V, C)).astuple()
    return ref


def relight_virtual(sol: RadiositySolution, un: Unoccluded, proj: Projection, photo, camera,
                    e_real, vp: VirtualPolygons, prm: HR.RefineParams, force_level: int, tol,
                    rho_fix=(0.5, 0.5, 0.5)):
    """Insert virtual emitters / boxes into the preprocessed hierarchy and relight (§4.5).

    1. the virtual polygons become new roots; 2. links are re-evaluated and added (relink);
    3. B is solved on the new mesh with the new real emittances, and B_ref on the same mesh
    without the virtual polygons at the original emittances; 4. each leaf's multiplier is
    T_final/T × B₀/D₀ (its preprocessed leaf) × B/B_ref, drawn per vertex; pixels whose
    centre sees a virtual polygon show its B/π, fixtures (E + ρ_fixture·H)/π.
    """
    from .display import nearest_seen, pixel_plan, pixel_responses
    from .geometry import corners
    from .textures import edge_subsamples, emitter_coverage, pixel_map

    rho_fix = np.asarray(rho_fix, float)
    lv0 = sol.leaves
    h = sol.hierarchy().copy()
    N0, P0 = h.n_elems, len(h.P_o)
    add_roots(h, vp.quads)
    # 1-2. links; the refinement oracle needs each element's radiosity (luminance)
    B_old = sol.B(e_real)
    pull0 = HR.operators(sol.hierarchy()).pull
    B_elem = np.concatenate([(pull0 @ B_old) @ LUM,
                             (vp.emittance + vp.reflectance * np.median(B_old, 0)) @ LUM])
    seen_poly = np.zeros(len(h.P_o), bool)
    seen_poly[np.unique(proj.pix_poly[proj.pix_poly >= 0])] = True
    kept, added = relink(h, vp, B_elem, seen_poly, prm, force_level,
                         np.random.default_rng(prm.seed + 7))
    # 3. leaves inherit ρ, E, T_final/T and D of their preprocessed leaf
    ops = HR.operators(h)
    if ops.Kc is not None and not vp.light.all():  # a clustered room: boxes block cluster links
        from .virtual import blocked_cluster_matrices, quad_triangles

        ops.Kc = blocked_cluster_matrices(h, quad_triangles(vp.quads[~vp.light]),
                                          np.random.default_rng(prm.seed + 11))
    lv = ops.leaves
    old = old_leaf(h, N0, P0, lv0)
    virt = old < 0
    vpoly = h.poly[lv][virt] - P0
    unit = unit_emission(sol)
    rho = np.zeros((len(lv), 3))
    rho[~virt] = sol.rho[old[~virt]]
    rho[virt] = vp.reflectance[vpoly]
    E = np.zeros((len(lv), 3))
    E[~virt] = np.einsum("lsc,sc->lc", unit, e_real)[old[~virt]]
    E[virt] = vp.emittance[vpoly]
    B, _ = HR.solve(ops, E, rho, tol=tol)
    H = ops.gather(B)
    ops_ref = HR.operators(real_reference(h, kept, added, P0, prm.n_rays, prm.seed + 9))
    E_ref = np.zeros((len(lv), 3))
    E_ref[~virt] = np.einsum("lsc,sc->lc", unit, sol.emit)[old[~virt]]
    B_ref, _ = HR.solve(ops_ref, E_ref, np.where(virt[:, None], 0.0, rho), tol=tol)
    # 4. per-leaf multiplier of the photograph, and the radiance of emitters and virtual faces
    D0 = np.einsum("lsc,sc->lc", un.resp_D, sol.emit)
    f0 = un.modulation * sol.B() * np.where(D0 > 1e-12, 1.0 / np.maximum(D0, 1e-12), 0.0)
    f = np.zeros((len(lv), 3))
    f[~virt] = f0[old[~virt]] * B[~virt] / np.maximum(B_ref[~virt], 1e-12)
    emits0 = emitter_leaves(sol)
    real_emit = np.zeros(len(lv), bool)
    real_emit[~virt] = emits0[old[~virt]]
    glow = np.where(virt[:, None], B, 0.0) / np.pi
    glow[real_emit] = (E[real_emit] + rho_fix * H[real_emit]) / np.pi
    emit_poly = np.zeros(len(h.P_o), bool)
    emit_poly[:P0] = emitter_polygons(sol.hierarchy(), lv0, emits0)
    allv = np.concatenate([corners(h.P_o[:P0], h.P_u[:P0], h.P_v[:P0], h.tri_poly[:P0]),
                           vp.quads])
    pp, _ = pixel_map(allv, camera)
    sub = edge_subsamples(allv, camera, pp)
    inserted = emitter_coverage(allv, range(P0, len(allv)), camera, pp, *sub[:2])
    L_em = np.zeros((len(h.P_o), 3))
    L_em[:P0] = photo_emitter_radiance(sol, proj, emit_poly[:P0])
    lum = np.full(len(lv), np.nan)
    lum[~virt] = (sol.T @ LUM)[old[~virt]]
    plan = pixel_plan(h, proj, photo, emit_poly, L_em, virtual=inserted, leaf_radiance=lum)
    near = nearest_seen(h, virt | np.isfinite(lum))
    px = pixel_responses(plan, f[near][:, None, :], glow[:, None, :])
    return modulate_pixels(px, np.ones((1, 3))), {"leaves": int(len(lv)),
                                                  "links": int(len(h.recv))}

