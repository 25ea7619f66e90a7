"""CosmeticShade — made-up skin: KM layers + skin SSS + per-layer specular (Huang et al. 2013 §3)."""
from __future__ import annotations

import threading
import weakref
from typing import NamedTuple

import numpy as np
import xxhash

from graphkit import BadInput, Camera, Field, Image, In, Light, Mask, Mesh, Node, Out
from graphkit.hashing import canonical
from graphkit.store import value_parts

from nodes.common.checks import connected_together, require_directional
from nodes.common.parallel import run_bands
from nodes.common.sss import Scatter, fold_faint, sss_blur

from . import km
from .layer import layer_thicknesses
from .library import KMLayerSpec, check_illuminant, layer_arrays, resolve_layers
from .stack import pixel_stack

#: the SSS profile of CosmeticShade: d'Eon 2007's with its faint channel weights folded
PROFILE = fold_faint()


class CosmeticShade(Node):
    """Skin under cosmetic layers: diffuse through the layers + SSS, plus layered specular (Huang 2013 §3, Fig. 1).

    Diffuse (§3.1–3.2): the irradiance E (``irradiance`` input; else from ``normals`` and a
    directional ``light``: colour·intensity·max(N·L, 0) + ambient; else 1) is partly reflected by
    the layers (Rt·E) and partly transmitted into the skin, with the inter-reflections between
    skin (albedo ρ) and layers: E_skin = T·E / (1 − Rb·ρ).  E_skin is scattered in the skin with
    the shared screen-space SSS (``nodes.common.sss.sss_blur``, d'Eon 2007 profile with its channel
    weights under 1 % folded onto nearby Gaussians (``fold_faint``: ≤ 0.21 % of a step) and its
    narrow passes as per-pixel tap maps (``Scatter``'s ``taps``), ``mm_per_pixel`` mm, optional
    ``depth`` in mm and ``skin`` mask), multiplied by ρ (post-scatter texturing) and leaves
    through the layers (RGB(T²)/RGB(T))::

        diffuse = Rt·E + (T²/T)·ρ·SSS(T·E / (1 − Rb·ρ))

    which equals KMStack over the background ρ times E where the lighting is uniform.
    Specular (§3.3, eq. 5): Kelemen/Szirmay-Kalos (Beckmann NDF, Schlick Fresnel;
    ``nodes.common.microfacet``) of the skin, then for each layer bottom to top: the specular so
    far is attenuated by the layer's transmittance T_i and the layer's own specular is added,
    weighted by its coverage min(1, d_i / ``cover_mm``).  Needs ``normals`` and a directional
    ``light`` (else zero).  ``view`` is the direction to the viewer in the normals' frame.
    Units: thickness mm, mm_per_pixel mm, depth mm, S/K mm⁻¹, wavelengths nm.
    """

    # 4: world-frame lights (turned into the camera frame), orthographic cameras
    # 5: the SSS runs on the skin's box grown by the widest kernel and the diffuse on the box of
    #    the layers and the skin (same formula; the filters' float rounding moves ≤ 1.2e-7)
    # 6: a per-pixel SSS kernel width as blurs at σ levels a factor 2 apart (nodes/common/sss.py);
    #    the layered specular in float32
    # 7: a pixel footprint within NEAR_UNIFORM (2 %) on both axes blurred at one σ (nodes/common/sss.py)
    # 8: the SSS's level blurs made on their weights' boxes and each channel's profile sum by
    #    cv2.scaleAdd (nodes/common/sss.py): outputs move in the last bits (≤ 1.2e-7)
    # 9: the SSS profile's channel weights under 1 % moved to that channel's nearest Gaussian
    #    (nodes.common.sss.fold_faint): three of eleven channel blurs fewer, ≤ 0.21 % of a step
    # 10: the SSS's narrow passes (reach ≤ 6 px) as per-pixel tap maps (nodes.common.sss.Scatter's
    #    taps): the same per-pixel kernels as the σ levels, outputs move by float rounding (≤ 1e-6)
    version = "10"
    studio_view = "nodes.huang.studio_view:MakeupView"  # graphkit serve: layer sliders
    inputs = {
        "albedo": In(Image, "skin diffuse reflectance ρ, linear RGB in [0, 1] (e.g. a photo)",
                     channels=3, finite=True, ge=0, le=1),
        "thickness": In(Image, "cosmetic map: H×W×n layer thicknesses in mm, bottom layer first",
                        same_size_as="albedo", finite=True, ge=0),
        "layers": In(KMLayerSpec, "layers, bottom first (else the 'cosmetics' param)", optional=True, variadic=True),
        "irradiance": In(Image, "diffuse irradiance, linear RGB (or 1 channel)", optional=True, channels=(1, 3),
                         same_size_as="albedo", finite=True, ge=0),
        "normals": In(Image, "unit surface normals (same frame as light and view)", optional=True, channels=3,
                      same_size_as="albedo"),
        "light": In(Light, "a directional light (for E and the specular)", optional=True),
        "depth": In(Image, "camera depth in mm (SSS kernel width)", optional=True, channels=1, same_size_as="albedo"),
        "skin": In(Mask, "where the skin is (SSS stays inside)", optional=True, same_size_as="albedo"),
        "mesh": In(Mesh, "face mesh (mm): normals, depth and view rays come from it with 'camera'", optional=True),
        "camera": In(Camera, "the photo camera of the mesh (OpenCV axes)", optional=True, same_size_as="albedo"),
    }
    outputs = {"image": Out(Image, "linear RGB radiance: diffuse + specular"),
               "diffuse": Out(Image, "diffuse part"), "specular": Out(Image, "specular part")}
    tolerance = {"rtol": 1e-4, "atol": 1e-5}
    # the per-pixel maths, hooks a backend replaces (plugins/graphkit-opencl)
    hooks = ("pixel_stack", "sss_blur")
    pixel_stack = staticmethod(pixel_stack)
    sss_blur = staticmethod(sss_blur)

    class Params(Node.Params):
        cosmetics: list[str] = Field(default_factory=list, description="library cosmetics, bottom layer first")
        illuminant: str = Field("D65", description="CIE illuminant for spectral → RGB (colour-science name)")
        lut_size: int = Field(25, ge=2, le=257, description="thickness grid nodes per layer (25: ΔE00 < 0.06 from the exact spectral result between nodes)")
        sss: bool = Field(True, description="scatter the transmitted light in the skin (nodes.common.sss)")
        mm_per_pixel: float = Field(0.5, gt=0, description="skin surface size of a pixel, mm")
        view: tuple[float, float, float] = Field((0.0, 0.0, -1.0), description="unit direction to the viewer (OpenCV camera: −z)")
        skin_m: float = Field(0.35, gt=0, description="skin Beckmann RMS slope (GPU Gems 3 ch. 14)")
        skin_rho_s: float = Field(0.18, ge=0, description="skin specular intensity")
        skin_f0: float = Field(0.028, ge=0, le=1, description="skin Fresnel reflectance at normal incidence")
        cover_mm: float = Field(0.005, gt=0, description="thickness (mm) at which a layer's own specular is fully on")
        relight: bool = Field(True, description="diffuse lit by 'light'; False: unit irradiance (the albedo is an "
                              "already-lit photo) and the light only makes the specular")

    def compute(self, albedo: Image, thickness: Image, layers=None, irradiance=None, normals=None,
                light: Light | None = None, depth=None, skin: Mask | None = None, mesh=None,
                camera: Camera | None = None):
        p = self.params
        check_illuminant(p.illuminant)
        specs = resolve_layers(layers, p.cosmetics)
        wl, S, K = layer_arrays(specs)
        rho = albedo.pixels  # float32 (Image), read only
        h, w = rho.shape[:2]
        t = layer_thicknesses(thickness, len(specs))
        if connected_together({"mesh": mesh, "camera": camera}) and (normals is not None or depth is not None):
            raise BadInput("mesh", "mesh + camera give the normals and depth: leave 'normals' and 'depth' unconnected")
        if light is not None:
            require_directional(light, "CosmeticShade")
        fixed = self._fixed(specs, (h, w), irradiance, normals, light, depth, skin, mesh, camera)
        layers = _layer_boxes(t)
        diffuse = self._diffuse(wl, S, K, t, rho, fixed, _support(layers[0]))
        spec, image = _with_specular(p, wl, S, K, fixed, layers, diffuse)
        return {"image": Image(image), "diffuse": Image(diffuse), "specular": Image(spec)}

    def _fixed(self, specs, hw, irradiance, normals, light, depth, skin, mesh, camera) -> _Fixed:
        """What does not depend on the cosmetic map or the albedo (surface, irradiance, the skin's
        SSS plan, the specular terms before the layers' transmittance): memoised on the inputs and
        params it comes from, so that a new thickness or cosmetic re-shades without it."""
        p = self.params
        given = {"irradiance": irradiance, "normals": normals, "light": light, "depth": depth, "skin": skin,
                 "mesh": mesh, "camera": camera}
        key = xxhash.xxh3_128(canonical([
            list(hw), {k: None if v is None else _digest(self.in_ports[k].type, v) for k, v in given.items()},
            p.mm_per_pixel, list(p.view), p.skin_m, p.skin_rho_s, p.skin_f0, p.relight, p.sss,
            self.sss_blur is sss_blur, [[L.m, L.rho_s, L.f0] for L in specs]])).hexdigest()
        got = _FIXED.get(key)
        if got is None:
            surf = _surface(p.mm_per_pixel, normals, depth, skin, mesh, camera)
            lcol, ldir, lt = _camera_frame_light(light, camera)
            E = _irradiance(hw, irradiance, lt, lcol, ldir, surf.normals, p.relight)
            scatter = None
            if p.sss and self.sss_blur is sss_blur:  # the reference: prepared once, on the skin's box
                scatter = Scatter(hw + (3,), surf.mm_per_pixel, surf.depth, PROFILE, mask=surf.mask, crop=True,
                                  taps=True)
            spec = None
            if surf.normals is not None and ldir is not None:
                spec = _specular(p, specs, surf, ldir, lcol)
            got = _Fixed(surf, E, scatter, spec, {})
            with _FIXED_LOCK:  # nodes may run on several threads (graphkit run --jobs)
                while len(_FIXED) >= 2:
                    _FIXED.pop(next(iter(_FIXED)))
                _FIXED[key] = got
        return got

    def _diffuse(self, wl, S, K, t, rho, fixed: _Fixed, support) -> np.ndarray:
        """§3.1: the stack's reflectance and transmittance per pixel (spectral, through the
        table); §3.2: the light entering the skin (with the skin ↔ layer inter-reflections),
        scattered in it, and leaving through the layers.  Through the backend hooks
        ``pixel_stack`` and ``sss_blur``.  With the reference SSS only the box around the layers
        and the skin is shaded (``support``: the layers' box): elsewhere no layer (Rt = Rb = 0,
        T = T² = 1) and no scattering leave ρ·E, which is what the formula gives there."""
        import cv2

        p, surf, E = self.params, fixed.surf, fixed.E
        box = None  # the whole frame (no skin mask: the SSS reaches every pixel)
        if fixed.scatter is not None and fixed.scatter.box is not None:
            box = _union(fixed.scatter.box, support)
        if box is not None:
            y0, y1, x0, x1 = box
            t, rho_b, E_b = t[y0:y1, x0:x1], rho[y0:y1, x0:x1], None if E is None else E[y0:y1, x0:x1]
        else:
            rho_b, E_b = rho, E
        q = self.pixel_stack(S, K, wl, t, p.illuminant, p.lut_size)
        Rt, Rb, T, T2 = q["Rt"], q["Rb"], q["T"], q["T2"]
        rows = _rows_per_band(T.shape[1])
        pre = np.empty(T.shape, np.result_type(T, Rb, rho_b, *([] if E_b is None else [E_b])))

        # (ρ, E and the output are boxes of frames: cv2 reads and writes them at the speed of
        # contiguous arrays, numpy 2–3× slower; the same float32 products and sums)
        def entering(r0, r1):  # T·E / (1 − Rb·ρ)
            den = cv2.multiply(Rb[r0:r1], rho_b[r0:r1])
            lit = T[r0:r1] if E_b is None else T[r0:r1] * E_b[r0:r1]
            np.divide(lit, np.subtract(1.0, den, out=den), out=pre[r0:r1])

        run_bands(entering, T.shape[0], rows)
        if fixed.scatter is not None and box is None:
            pre = fixed.scatter(pre)
        elif fixed.scatter is not None:  # the scatter's box lies in this box
            sy0, sy1, sx0, sx1 = fixed.scatter.box
            pre = np.asarray(pre, np.float32)
            if sy0 < sy1:
                here = (slice(sy0 - y0, sy1 - y0), slice(sx0 - x0, sx1 - x0))
                _scattered(fixed, pre[here])
        elif p.sss:
            pre = self.sss_blur(pre, surf.mm_per_pixel, surf.depth, profile=PROFILE, mask=surf.mask)
        out = np.empty(rho.shape, np.float32)
        if box is not None:  # ρ·E off the box (E None: ρ)
            def lit(r0, r1):
                for rows, cols in _off_box(box, r0, r1, out.shape[1]):
                    if E is None:
                        np.copyto(out[rows, cols], rho[rows, cols])
                    else:
                        np.multiply(rho[rows, cols], E[rows, cols], out=out[rows, cols])

            run_bands(lit, out.shape[0], _rows_per_band(out.shape[1]))
        inner = out if box is None else out[y0:y1, x0:x1]

        def leaving(r0, r1):  # Rt·E + (T²/T)·ρ·SSS(…)
            with np.errstate(divide="ignore", invalid="ignore"):
                t_exit = np.divide(T2[r0:r1], T[r0:r1])
            if not T[r0:r1].min() > 1e-12:  # (one pass where no T is that small)
                t_exit[~(T[r0:r1] > 1e-12)] = 0.0
            cv2.multiply(t_exit, rho_b[r0:r1], dst=t_exit)
            t_exit *= pre[r0:r1]
            if E_b is None:
                cv2.add(Rt[r0:r1], t_exit, dst=inner[r0:r1])
            else:
                np.multiply(Rt[r0:r1], E_b[r0:r1], out=inner[r0:r1])
                cv2.add(inner[r0:r1], t_exit, dst=inner[r0:r1])

        run_bands(leaving, T.shape[0], rows)
        return out

    @classmethod
    def examples(cls):
        h, w = 24, 32
        yy, xx = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
        t = np.stack([0.03 * (xx > 0.3), 0.05 * (yy > 0.5)], -1)
        nrm = np.stack([xx - 0.5, yy - 0.5, -np.ones_like(xx)], -1)
        nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
        rho = np.full((h, w, 3), [0.6, 0.4, 0.3])
        light = Light(direction=(0.3, -0.2, -1.0), intensity=2.0, ambient=(0.1, 0.1, 0.1))
        depth = Image((300.0 + 40.0 * (xx - 0.5) ** 2 + 2.0 * yy + 20.0 * (xx > 0.7))[..., None])
        skin = Mask((np.hypot(xx - 0.5, yy - 0.5) < 0.45).astype(np.float32))
        soft = np.stack([0.03 * xx, 0.05 * np.clip(2 * yy - 0.5, 0, 1)], -1)  # interpolated everywhere
        return [({"cosmetics": ["foundation_light", "lipstick_red"], "mm_per_pixel": 1.0},
                 {"albedo": Image(rho), "thickness": Image(t), "normals": Image(nrm), "light": light}),
                # σ per pixel from depth, SSS kept in the skin mask, thicknesses between grid nodes
                ({"cosmetics": ["foundation_light", "lipstick_red"], "mm_per_pixel": 0.3},
                 {"albedo": Image(rho), "thickness": Image(soft), "normals": Image(nrm), "light": light,
                  "depth": depth, "skin": skin})]


class _Surface(NamedTuple):
    """What CosmeticShade knows of the surface per pixel (None: not given)."""
    normals: np.ndarray | None  # unit, camera frame
    view: np.ndarray | None     # unit directions to the viewer (None: the 'view' param)
    mm_per_pixel: np.ndarray | float
    depth: np.ndarray | None    # mm
    mask: np.ndarray | None     # where the SSS stays


class _Specular(NamedTuple):
    """The specular terms before the layers' transmittance, in ``box`` (zero outside)."""
    skin: np.ndarray    # (h, w, 3) float32
    layers: list        # per layer (h, w, 1) float32
    box: tuple
    lcol: np.ndarray    # light colour × intensity
    seen: dict          # the last layers' (transmittance, own specular) by what they come from


class _Fixed(NamedTuple):
    """CosmeticShade's work that does not depend on the cosmetic map or the albedo."""
    surf: _Surface
    E: np.ndarray | None        # irradiance (H, W, 3) float32 (None: 1 everywhere)
    scatter: Scatter | None     # the reference SSS prepared for the surface (None: the hook, or no SSS)
    spec: _Specular | None      # None: no normals or no directional light
    last: dict                  # "sss": the last (light entering the skin, scattered) in the scatter's box


#: the last _Fixed values by the digest of what they come from (a live view's face, a benchmark's;
#: ~170 MB each for a 1280×720 face)
_FIXED: dict = {}
_FIXED_LOCK = threading.Lock()
_DIGESTS: dict = {}  # id(value): (weakref to it, its meta, weakrefs to its arrays, its digest)


def _digest(ptype, value) -> str:
    """``value_parts(ptype, value)``'s digest, remembered for a value whose arrays are all frozen
    (:func:`_frozen`: as the engine hands a node its inputs) and found again only for the same
    object with the same meta and the same array objects: a re-shade does not hash the same
    normals, depth and skin again (~0.7 ms a frame at 1280×720).  A writeable array is hashed
    every time (it may have been changed in place)."""
    meta, arrays = ptype.to_parts(value)
    if not arrays or not all(isinstance(a, np.ndarray) and _frozen(a) for a in arrays):
        return value_parts(ptype, value)[2]
    with _FIXED_LOCK:
        got = _DIGESTS.get(id(value))
    if got is not None and got[0]() is value and got[1] == meta and len(got[2]) == len(arrays) \
            and all(r() is a for r, a in zip(got[2], arrays)):
        return got[3]
    digest = value_parts(ptype, value)[2]
    with _FIXED_LOCK:
        while len(_DIGESTS) >= 16:
            _DIGESTS.pop(next(iter(_DIGESTS)))
        _DIGESTS[id(value)] = (weakref.ref(value), meta, [weakref.ref(a) for a in arrays], digest)
    return digest


def _frozen(a: np.ndarray) -> bool:
    """Whether ``a`` and every array it is a view of are read-only, down to one that owns its
    memory: nothing can change its values without first making one of them writeable again."""
    while isinstance(a, np.ndarray):
        if a.flags.writeable:
            return False
        a = a.base
    return a is None


def _surface(mm_per_pixel: float, normals, depth, skin, mesh, camera) -> _Surface:
    """The surface from mesh + camera (the skin mask cut to the mesh's coverage), else from the
    normals, depth and skin inputs."""
    smask = None if skin is None else skin.alpha
    if mesh is not None:
        n, dmap, mpp_map, view, cov = _mesh_geometry(mesh, camera)
        cover = cov.astype(np.float32)
        return _Surface(n, view, np.where(cov, mpp_map, mm_per_pixel), dmap,
                        cover if smask is None else np.minimum(smask, cover))
    n = None
    if normals is not None:
        n = np.asarray(normals.pixels, np.float64)
        n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    dmap = None if depth is None else np.asarray(depth.pixels, np.float64)[..., 0]
    return _Surface(n, None, mm_per_pixel, dmap, smask)


def _camera_frame_light(light: Light | None, camera: Camera | None):
    """(colour × intensity, unit direction, the light) in the camera frame of the normals
    (lights are world-frame); Nones without a light."""
    if light is None:
        return None, None, None
    lcol = np.asarray(light.color, np.float32) * np.float32(light.intensity)
    if camera is not None:
        light = camera.light_to_camera(light)
    ldir = np.asarray(light.direction, np.float64)
    return lcol, ldir / max(np.linalg.norm(ldir), 1e-12), light


def _irradiance(hw, irradiance, light, lcol, ldir, n, relight: bool) -> np.ndarray:
    """E (H×W×3): the irradiance input; else colour·intensity·max(N·L, 0) + ambient from a
    light (when ``relight``); else None (1 everywhere: nothing to multiply by)."""
    h, w = hw
    if irradiance is not None:
        return np.broadcast_to(np.asarray(irradiance.pixels, np.float32), (h, w, 3))
    if light is not None and relight:
        cos = 1.0 if n is None else np.maximum(n @ ldir, 0.0)[..., None]
        E = (np.asarray(cos, np.float32) * lcol + np.asarray(light.ambient, np.float32)).astype(np.float32)
        return np.broadcast_to(E, (h, w, 3))
    return None


def _specular(p, specs, surf: _Surface, ldir, lcol) -> _Specular:
    """§3.3, eq. 5: the Kelemen specular of the skin (H×W×3) and of each layer (H×W×1), and the
    box outside which they are all zero (no normals there)."""
    from nodes.common.microfacet import kelemen_specular

    n, v = surf.normals, surf.view
    if v is None:
        v = np.asarray(p.view, np.float64)
        v = v / max(np.linalg.norm(v), 1e-12)
    skin = (kelemen_specular(n, ldir, v, p.skin_m, p.skin_rho_s, p.skin_f0)[..., None] * np.ones(3)).astype(np.float32)
    layers = [kelemen_specular(n, ldir, v, L.m, L.rho_s, L.f0)[..., None].astype(np.float32) for L in specs]
    box = _nonzero_box(np.any(skin != 0, axis=2) | np.any([k[..., 0] != 0 for k in layers], axis=0))
    y0, y1, x0, x1 = box
    return _Specular(skin[y0:y1, x0:x1], [k[y0:y1, x0:x1] for k in layers], box, lcol, {})


def _with_specular(p, wl, S, K, fixed: _Fixed, layers, diffuse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(specular, image = diffuse + specular) over the frame, on bands of rows on the cores: the
    specular of §3.3 (:func:`_through_layers`) in its box, zero elsewhere (there the image is
    diffuse + 0: −0 + 0 is +0; the zeros are not written or read here).  The layers' terms are
    made (or found) first."""
    import cv2

    h, w = diffuse.shape[:2]
    spec = np.zeros((h, w, 3), np.float32)
    image = np.empty((h, w, 3), np.float32)
    sp = fixed.spec
    y0, y1, x0, x1 = box = (0, 0, 0, 0) if sp is None else sp.box
    terms = [] if sp is None else _terms_in_box(p, wl, S, K, sp, layers)

    def band(r0, r1):
        for rows, cols in _off_box(box, r0, r1, w):
            np.add(diffuse[rows, cols], np.float32(0), out=image[rows, cols])
        a, b = max(r0, y0), min(r1, y1)
        if a < b:
            _through_layers(sp, terms, (a, b), spec[a:b, x0:x1])
            cv2.add(diffuse[a:b, x0:x1], spec[a:b, x0:x1], dst=image[a:b, x0:x1])  # (boxes: see _diffuse)

    run_bands(band, h, _rows_per_band(w))
    return spec, image


def _terms_in_box(p, wl, S, K, sp: _Specular, layers) -> list:
    """Per layer present in the specular's box: (its part of the box (b0, b1, c0, c1), its RGB
    transmittance there, its own specular weighted by its coverage there), bottom first
    (:func:`_layer_terms`).  ``layers``: :func:`_layer_boxes`."""
    y0, y1, x0, x1 = sp.box
    terms = []
    for i, (box, top, crop) in enumerate(zip(*layers)):
        b0, b1, c0, c1 = max(box[0], y0), min(box[1], y1), max(box[2], x0), min(box[3], x1)
        if b0 < b1 and c0 < c1:
            part = (b0, b1, c0, c1)
            terms.append((part, *_layer_terms(p, wl, S[i], K[i], crop, box, top, part, i, sp)))
    return terms


def _through_layers(sp: _Specular, terms, rows: tuple[int, int], out: np.ndarray) -> None:
    """§3.3 on the rows a:b (``rows``, frame rows within the specular's box) into ``out`` (those
    rows of the box): the skin's specular, then for each layer bottom to top attenuated by the
    layer's transmittance and the layer's own specular added, weighted by its coverage (where
    any of them is not zero: zero elsewhere; a layer only where it is: off it T = 1 and the
    coverage 0 leave the specular as it is), times the light.  ``terms``: :func:`_terms_in_box`.
    Worked in a contiguous buffer of those rows (cache-sized; numpy writes a frame's box ~3×
    slower), the skin's specular read where it is kept: a first layer over all of the rows
    multiplies it into the buffer, else it is copied there first."""
    import cv2

    a, b = rows
    y0, x0, x1 = sp.box[0], sp.box[2], sp.box[3]
    skin = sp.skin[a - y0:b - y0]
    s = None  # the buffer once it holds the specular so far
    for (b0, b1, c0, c1), Ti, own in terms:
        r0, r1 = max(b0, a), min(b1, b)
        if r0 >= r1:
            continue
        Ti, own = Ti[r0 - b0:r1 - b0], own[r0 - b0:r1 - b0]
        if s is None and (r0, r1, c0, c1) == (a, b, x0, x1):
            here = s = np.multiply(skin, Ti)
        else:
            if s is None:
                s = skin.copy()
            here = s[r0 - a:r1 - a, c0 - x0:c1 - x0]
            cv2.multiply(here, Ti, dst=here)  # (a box of the buffer: see _diffuse)
        cv2.add(here, own, dst=here)
    src = skin if s is None else s
    # times the light's colour: rows by a tiled row (~10× faster than by a (3,) vector)
    np.multiply(src.reshape(b - a, -1), np.tile(sp.lcol, x1 - x0), out=out.reshape(b - a, -1))


def _layer_terms(p, wl, S, K, crop, lbox, top, box, i, sp: _Specular) -> tuple[np.ndarray, np.ndarray]:
    """Layer i's RGB transmittance (h, w, 3) and own specular weighted by its coverage (h, w, 3)
    in ``box`` (float32; inside the layer's box ``lbox``), from its thicknesses ``crop`` in
    ``lbox`` (0 outside it) of maximum ``top``: kept for the last layers seen on this surface (a
    re-shade after one layer changed does not redo the others; up to 8, ~6 MB each for a
    face-sized layer at 1280×720)."""
    import cv2

    key = xxhash.xxh3_128(canonical([i, list(box), list(lbox), top, p.lut_size, p.cover_mm, p.illuminant]))
    for a in (np.asarray(wl, np.float64), np.asarray(S, np.float64), np.asarray(K, np.float64), crop):
        key.update(np.ascontiguousarray(a))
    key = key.hexdigest()
    got = sp.seen.get(key)
    if got is None:
        b0, b1, c0, c1 = box
        y0, x0 = sp.box[0], sp.box[2]
        Wf = km.rgb_weights(wl, p.illuminant)
        Wf = Wf / Wf.sum(axis=0)  # T as an RGB filter (see stack.pixel_stack)
        grid = km.thickness_grid([top], p.lut_size)
        _, Tg = km.layer_R0_T(S, K, grid[0][:, None])
        ti = crop[b0 - lbox[0]:b1 - lbox[0], c0 - lbox[2]:c1 - lbox[2], None]
        Ti = np.asarray(km.lookup(Tg @ Wf, grid, ti), np.float32)
        cover = np.clip(ti[..., 0] / np.float32(p.cover_mm), 0.0, 1.0)
        own = np.multiply(cover, sp.layers[i][b0 - y0:b1 - y0, c0 - x0:c1 - x0, 0])
        got = (Ti, cv2.merge([own] * 3))  # (numpy's copy of a broadcast channel: ~13× slower)
        with _FIXED_LOCK:
            while len(sp.seen) >= 8:
                sp.seen.pop(next(iter(sp.seen)))
            sp.seen[key] = got
    return got


def _scattered(fixed: _Fixed, pre: np.ndarray) -> None:
    """``pre`` (float32, the scatter's box) replaced by ``fixed.scatter.on_box(pre)``, through the
    last light scattered on this surface when there is one (:meth:`Scatter.update`: a new
    thickness or colour of one layer blurs again only the rows around that layer; the same
    bytes).  ``pre`` is kept as the next call's result before: it must not change afterwards."""
    sub = pre.copy()  # kept as the next call's light before
    with _FIXED_LOCK:
        last = fixed.last.get("sss")
    if last is None:
        fixed.scatter.on_box(sub, out=pre)
    else:
        fixed.scatter.update(sub, *last, out=pre)
    with _FIXED_LOCK:
        fixed.last["sss"] = (sub, pre)


def _rows_per_band(w: int) -> int:
    """Rows per band of a frame w pixels wide whose per-pixel temporaries stay in the cache."""
    return max(1, km.LOOKUP_BLOCK // max(w, 1))


def _off_box(box, r0: int, r1: int, w: int) -> list[tuple[slice, slice]]:
    """The parts of rows r0:r1 (of a frame w pixels wide) off ``box`` (y0, y1, x0, x1; an empty
    box: all of them), as (rows, columns) slices."""
    y0, y1, x0, x1 = box
    a, b = max(r0, y0), min(r1, y1)
    if a >= b or x0 >= x1:
        return [(slice(r0, r1), slice(0, w))]
    parts = [(slice(r0, a), slice(0, w)), (slice(b, r1), slice(0, w)),
             (slice(a, b), slice(0, x0)), (slice(a, b), slice(x1, w))]
    return [(r, c) for r, c in parts if r.start < r.stop and c.start < c.stop]


def _nonzero_box(a: np.ndarray) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1): the bounding box of the true pixels of ``a`` (empty: (0, 0, 0, 0))."""
    rows, cols = np.flatnonzero(a.any(axis=1)), np.flatnonzero(a.any(axis=0))
    if rows.size == 0:
        return 0, 0, 0, 0
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def _layer_boxes(t: np.ndarray) -> tuple[list, list[float], list[np.ndarray]]:
    """Per layer, the box of the pixels where it is thicker than 0, its maximum and its
    thicknesses in that box (a contiguous copy).  The columns from one reduction over whole
    rows of (H, W·n) values, the rows from the layer's columns copied out (reductions over a
    strided channel are ~20× slower)."""
    h, w, n = t.shape
    if t.size == 0:
        return [(0, 0, 0, 0)] * n, [0.0] * n, [np.zeros((0, 0), t.dtype)] * n
    per_col = t.reshape(h, w * n).max(axis=0).reshape(w, n)
    boxes, tops, crops = [], [], []
    for i in range(n):
        cols = np.flatnonzero(per_col[:, i] > 0)
        tops.append(float(per_col[:, i].max()))
        if cols.size == 0:
            boxes.append((0, 0, 0, 0))
            crops.append(np.zeros((0, 0), t.dtype))
            continue
        c0, c1 = int(cols[0]), int(cols[-1]) + 1
        strip = np.ascontiguousarray(t[:, c0:c1, i])
        rows = np.flatnonzero(strip.max(axis=1) > 0)
        boxes.append((int(rows[0]), int(rows[-1]) + 1, c0, c1))
        crops.append(strip[rows[0]:rows[-1] + 1])
    return boxes, tops, crops


def _support(boxes) -> tuple[int, int, int, int]:
    """The box around the layers' boxes."""
    box = (0, 0, 0, 0)
    for b in boxes:
        box = _union(box, b)
    return box


def _union(a, b) -> tuple[int, int, int, int]:
    """The box around two boxes (an empty one, (0, 0, 0, 0) or y0 == y1, adds nothing)."""
    if a[0] == a[1]:
        return b
    if b[0] == b[1]:
        return a
    return min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3])


def _mesh_geometry(mesh, camera: Camera):
    """Rasterise ``mesh`` through ``camera`` (nodes.common.raster): per-pixel unit normals and
    view directions in the camera frame, depth (mesh units, mm), mm per pixel (depth / f) and
    coverage.  Uncovered pixels get zero normals (no specular) and the farthest covered depth."""
    from nodes.common.raster import interpolate, rasterize

    V = np.asarray(mesh.vertices, np.float64)
    F = np.asarray(mesh.faces, np.int64)
    r = rasterize(V, F, camera)
    cov = r.coverage
    R = camera.pose[:3, :3]
    vn = np.asarray(mesh.vertex_normals, np.float64) @ R.T
    n = interpolate(r, F, vn)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    n[~cov] = 0.0
    if cov.any():
        # normals facing away from the camera are flipped towards it (mesh winding varies)
        if np.mean(n[cov][:, 2]) > 0:
            n = -n
    h, w = cov.shape
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    if camera.orthographic:  # every ray runs along the camera's +z
        view = np.broadcast_to(np.array([0.0, 0.0, -1.0]), (h, w, 3))
    else:
        ray = np.stack([(xs - camera.cx) / camera.fx, (ys - camera.cy) / camera.fy, np.ones_like(xs)], -1)
        view = -ray / np.linalg.norm(ray, axis=-1, keepdims=True)
    far = float(r.depth[cov].max()) if cov.any() else 1.0
    depth = np.where(cov, r.depth, far)
    mpp = camera.units_per_pixel(depth)
    return n, depth, mpp, view, cov
