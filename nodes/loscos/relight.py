"""Unocclude and Relight (Loscos 2000 §4.2–4.4, §5, eqs. 5–9)."""
from __future__ import annotations

import numpy as np

from graphkit import BadInput, Field, Image, Node

from . import hierarchy as HR
from .ports import (PROJECTION, RADIOSITY, UNOCCLUDED, Projection, RadiositySolution,
                    Unoccluded)
from .radiosity import lab, leaf_neighbours, light_visibility

LUM = np.array([0.2126, 0.7152, 0.0722])


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
    inputs = {"solution": RADIOSITY, "unoccluded": UNOCCLUDED, "projection": PROJECTION,
              "photo": Image}
    outputs = {"image": Image}

    class Params(Node.Params):
        light_scale: dict[str, float] = Field(default_factory=dict,
                                              description="light name → emittance factor")
        emittance: dict[str, list[float]] = Field(default_factory=dict,
                                                  description="light name → RGB W/m²")

    def compute(self, solution: RadiositySolution, unoccluded: Unoccluded,
                projection: Projection, photo: Image):
        sol = solution
        if photo.pixels.shape[:2] != projection.pix_poly.shape:
            raise BadInput("photo", "photo size differs from the projection's camera")
        if len(unoccluded.modulation) != len(sol.leaves):
            raise BadInput("unoccluded", "computed for another solution")
        e = new_emittance(sol, self.params.light_scale, self.params.emittance)
        prep = prepare(sol, unoccluded, projection, photo.pixels[:, :, :3])
        return Image(relight_fast(prep, e))


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
