"""FitSkinPhong — the skin parameters of Paris, Sillion, Quan 2003 §4.2."""
from __future__ import annotations

from typing import Literal

import numpy as np

from graphkit import BadInput, Camera, Field, Image, In, Light, Mask, Mesh, Node, Out, Scalar

from .checks import check_lit
from .models import PhongMaterial


class FitSkinPhong(Node):
    """Skin colour (r, g, b) and specular intensity i_s, then the ambient intensity (§4.1–4.2).

    The mesh is rendered in the photo's pose with the Phong model of §4 (shininess s given,
    found separately by ShininessFromSaturation) under the flash ``light``; the parameters
    minimise the L2 distance in CIE L*u*v* (colour-science, D65) between the photo and the
    render over the skin pixels:  sqrt(Σ_skin ΔL² + Δu² + Δv²).

    The flash is in the world frame; a point flash falls off as I/d² (d in metres, through the
    camera's ``metres_per_unit``), always.

    Minimisation: a varying-step descent (Levenberg–Marquardt steps whose damping is divided on
    success and multiplied on failure), coarse to fine over growing subsets of the skin pixels
    (1/16, 1/4, all, up to ``max_pixels``), from ``starts`` random starting points drawn with
    ``seed``; the best end point is kept.

    Exponent: the given s (ShininessFromSaturation, §4.2) is refined unless
    ``shininess_search`` is off: the fit is repeated (warm-started, colour and i_s only) for s
    on a log grid 1…256 and the given value, then by a golden-section step in log s around
    the best, and the s of least Luv residual is kept.  §4.2 warns that optimising s *with* the
    other parameters by descent is unstable (s trades against ambient and i_s); a 1-D search
    with the ambient measured by the probe is not, and it guards against a saturation
    estimate thrown off by the map (clipped or blurred highlights).

    Ambient (``ambient``): "probe" takes the light's ambient as measured (ProbeLight gives it in
    flash units); "fit" then optimises its intensity relative to the flash with the skin
    parameters, as in §4.1 (the probe's ambient colour, or the flash colour when the light has
    none); "auto" (default) is "probe" when the light has an ambient and "fit" when it has
    none.  Outputs the material (with the residual), the light with its ambient, and the fitted
    render.  Units: linear RGB relative to the flash.
    """

    version = "3"
    inputs = {"image": In(Image, "the flash photo (linear RGB)"),
              "skin": In(Mask, "skin pixels", same_size_as="image"),
              "mesh": In(Mesh, "face mesh registered to the photo", finite=True),
              "camera": In(Camera, "the photo camera", same_size_as="image"),
              "light": In(Light, "the flash (ProbeLight.light)"),
              "shininess": In(Scalar, "Phong exponent s (ShininessFromSaturation); "
                                      "default: the `shininess` param", optional=True)}
    outputs = {"material": Out(PhongMaterial, "skin material and residual"),
               "light": Out(Light, "the flash with the fitted ambient"),
               "rendered": Out(Image, "the Phong render of the fitted parameters (photo pose)")}

    class Params(Node.Params):
        seed: int = Field(0, description="seed of the random starting points")
        starts: int = Field(4, ge=1, le=1000, description="random starting points")
        max_pixels: int = Field(4000, ge=100, description="skin pixels used at the finest level")
        ambient: Literal["auto", "probe", "fit"] = Field(
            "auto", description="probe: the light's ambient as measured; fit: optimise its intensity (§4.1); "
                                "auto: probe if the light has an ambient, else fit")
        iterations: int = Field(60, ge=1, description="descent iterations per level")
        skin_threshold: float = Field(0.5, ge=0, le=1, description="mask value counted as skin")
        shininess: float = Field(10.0, gt=0, description="Phong exponent used when the input is not connected")
        shininess_search: bool = Field(True, description="refine the exponent: the one (of the given one "
                                       "and a log grid 1…256, then a golden-section step) whose fit has the "
                                       "least Luv residual")

    def compute(self, image: Image, skin: Mask, mesh, camera: Camera, light: Light,
                shininess=None):
        from .render import light_vectors, skin_surface, world_lights
        from . import phong

        p = self.params
        if shininess is None:
            shininess = p.shininess
        if not (np.isfinite(shininess) and shininess > 0):
            raise BadInput("shininess", f"the Phong exponent must be > 0, got {shininess}")
        s, use = skin_surface(mesh, camera, skin, p.skin_threshold, fewest=20)
        (lw,) = world_lights([light], camera, mesh, "light")
        ldir, L = light_vectors(lw, s.points)
        diff, rv = phong.lobes(s.normals, ldir, s.view, 1.0)  # rv: max(r·v, 0) where lit
        with np.errstate(under="ignore"):
            spec = rv ** float(shininess)
        check_lit(diff[use], "light", f"the light (direction {light.direction})", "skin pixels")
        photo = image.pixels[s.coverage][:, :3].astype(np.float64)
        idx = np.nonzero(use)[0]
        if len(idx) > p.max_pixels:  # deterministic even subsample
            idx = idx[np.linspace(0, len(idx) - 1, p.max_pixels).round().astype(np.int64)]
        amb_base = np.asarray(light.ambient, np.float64)
        fit_ambient = p.ambient == "fit" or (p.ambient == "auto" and not amb_base.any())
        if not amb_base.any() and fit_ambient:
            # no probe ambient: fit a grey (flash-coloured) ambient, starting small
            amb_base = np.asarray(light.color, np.float64) * 0.01
        prob = _Problem(photo[idx], diff[idx], spec[idx], L[idx], amb_base)
        rng = np.random.default_rng(p.seed)
        best = None
        for i in range(p.starts):
            x0 = np.concatenate([rng.uniform(0.05, 1.0, 3), rng.uniform(0.0, 1.0, 1), [1.0]])
            x = prob.descend(x0, free=[0, 1, 2, 3], iters=p.iterations)
            e = prob.energy(x)
            if best is None or e < best[1]:
                best = (x, e)
            self.ctx.progress((i + 1) / p.starts, f"start {i + 1}/{p.starts}")
        x = best[0]
        if fit_ambient and amb_base.any():
            x = prob.descend(x, free=[4], iters=p.iterations)
            x = prob.descend(x, free=[0, 1, 2, 3, 4], iters=p.iterations)
        if p.shininess_search:
            shininess, x = _search_exponent(photo[idx], diff[idx], rv[idx], L[idx], amb_base, x,
                                            float(shininess), p.iterations)
            with np.errstate(under="ignore"):
                spec = rv ** shininess
            prob = _Problem(photo[idx], diff[idx], spec[idx], L[idx], amb_base)
            x = prob.descend(x, free=[0, 1, 2, 3, 4] if fit_ambient and amb_base.any() else [0, 1, 2, 3],
                             iters=p.iterations)
        amb_rgb = amb_base * x[4]
        # residual over all skin pixels
        full = _Problem(photo[use], diff[use], spec[use], L[use], amb_base)
        e_all = full.energy(x)
        n = int(use.sum())
        mat = PhongMaterial(diffuse=tuple(float(v) for v in x[:3]), specular=float(x[3]),
                            shininess=float(shininess), ambient_scale=1.0,
                            ambient=tuple(float(v) for v in amb_rgb),
                            residual=float(np.sqrt(e_all)), rms_luv=float(np.sqrt(e_all / n)),
                            pixels=n)
        out_light = light.model_copy(update={"ambient": tuple(float(v) for v in amb_rgb)})
        ren = np.zeros((camera.height, camera.width, 3), np.float32)
        ren[s.coverage] = phong.shade(x[:3], x[3], amb_rgb, L, diff, spec)
        return {"material": mat, "light": out_light, "rendered": Image(ren)}


def _search_exponent(photo, diff, rv, L, amb, x, s0, iters):
    """The Phong exponent whose fit (colour and i_s, warm-started from x) has the least Luv
    residual: the given s0 and a log grid 1…256 (√2 steps) on every 4th pixel, then a
    golden-section search in log s around the best → (s, x)."""
    sub = slice(0, len(diff), 4) if len(diff) >= 400 else slice(None)

    def fit(s, x0):
        with np.errstate(under="ignore"):
            sp = rv[sub] ** s
        prob = _Problem(photo[sub], diff[sub], sp, L[sub], amb)
        xs = prob.descend(x0, free=[0, 1, 2, 3], iters=max(10, iters // 3))
        return prob.energy(xs), xs

    grid = sorted(set(np.round(2.0 ** np.arange(0, 8.01, 0.5), 6)) | {round(s0, 6)})
    res = [fit(s, x) for s in grid]
    k = int(np.argmin([e for e, _ in res]))
    lo, hi = np.log(grid[max(k - 1, 0)]), np.log(grid[min(k + 1, len(grid) - 1)])
    g = (np.sqrt(5) - 1) / 2
    best = (res[k][0], grid[k], res[k][1])
    a, b = lo, hi
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = fit(np.exp(c), best[2]), fit(np.exp(d), best[2])
    for _ in range(6):
        if fc[0] < fd[0]:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = fit(np.exp(c), best[2])
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = fit(np.exp(d), best[2])
    for e, s, xs in ((fc[0], np.exp(c), fc[1]), (fd[0], np.exp(d), fd[1])):
        if e < best[0]:
            best = (e, s, xs)
    return float(best[1]), best[2]


class _Problem:
    """E(x) = Σ ||Luv(model(x)) − Luv(photo)||², x = (r, g, b, i_s, ambient scale)."""

    def __init__(self, photo, diff, spec, L, amb_base):
        from nodes.common.color import linear_srgb_to_luv

        self.luv = linear_srgb_to_luv
        self.photo = photo
        self.target = linear_srgb_to_luv(np.clip(photo, 0, None))
        self.diff, self.spec, self.L, self.amb = diff, spec, L, amb_base
        self.tol = 1e-6  # stop a level when the relative decrease of E falls below this
        self.evals = 0

    def model(self, x, sel=slice(None)):
        kd = x[:3]
        return (kd * (self.amb * x[4] + self.L[sel] * self.diff[sel, None])
                + x[3] * self.L[sel] * self.spec[sel, None])

    def dmodel(self, x, sel):
        """d model / d x: (n, 3, 5)."""
        n = len(self.diff[sel])
        J = np.zeros((n, 3, 5))
        base = self.amb * x[4] + self.L[sel] * self.diff[sel, None]
        for c in range(3):
            J[:, c, c] = base[:, c]
        J[:, :, 3] = self.L[sel] * self.spec[sel, None]
        J[:, :, 4] = x[:3] * self.amb
        return J

    def residual(self, x, sel=slice(None)):
        return self.luv(np.clip(self.model(x, sel), 1e-9, None)) - self.target[sel]

    def energy(self, x, sel=slice(None)):
        self.evals += 1
        r = self.residual(x, sel)
        return float(np.sum(r * r))

    def luv_and_jacobian(self, rgb):
        """Luv (n, 3) and d Luv / d rgb (n, 3, 3) by forward differences, in one colour-science
        call."""
        rgb = np.clip(rgb, 1e-9, None)
        n = len(rgb)
        h = np.maximum(rgb * 1e-4, 1e-7)
        stack = np.repeat(rgb[None], 4, axis=0)
        for c in range(3):
            stack[c + 1, :, c] += h[:, c]
        luv = self.luv(stack.reshape(-1, 3)).reshape(4, n, 3)
        J = np.stack([(luv[c + 1] - luv[0]) / h[:, c:c + 1] for c in range(3)], axis=2)
        return luv[0], J

    def descend(self, x, free, iters=60):
        """Varying-step descent, coarse to fine over pixel subsets (see FitSkinPhong)."""
        x = np.array(x, np.float64)
        n = len(self.diff)
        levels = [s for s in (16, 4, 1) if n // s >= 50] or [1]
        for step in levels:
            sel = slice(0, n, step)
            lam = 1e-3
            e = self.energy(x, sel)
            for _ in range(iters):
                luv, Jl = self.luv_and_jacobian(self.model(x, sel))
                r = (luv - self.target[sel]).reshape(-1)
                J = np.einsum("nij,njk->nik", Jl, self.dmodel(x, sel))[:, :, free].reshape(-1, len(free))
                g = J.T @ r
                A = J.T @ J
                improved = False
                for _try in range(12):
                    dx = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), -g)
                    xn = x.copy()
                    xn[free] = np.maximum(x[free] + dx, 0.0)
                    en = self.energy(xn, sel)
                    if en < e:
                        lam = max(lam / 4, 1e-9)
                        improved = True
                        break
                    lam *= 8
                if not improved:
                    break
                rel = (e - en) / max(e, 1e-300)
                x, e = xn, en
                if rel < self.tol:
                    break
        return x
