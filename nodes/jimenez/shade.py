"""SkinShade — real-time skin shading of Jimenez et al. 2010 §6.

albedo from the skin colour LUT (eq. 7) · screen-space subsurface-scattered diffuse light
(d'Eon 2007 sum of Gaussians, kernel width from depth; nodes/common/sss.py) + Kelemen /
Szirmay-Kalos specular (Beckmann + Schlick; nodes/common/microfacet.py).  Post-scatter
texturing: only the diffuse irradiance is blurred, the albedo multiplies afterwards, so the
chromophore maps (already blurred by acquisition, §3) are not blurred twice.
"""
from __future__ import annotations

import threading

import numpy as np

from graphkit import BadInput, Camera, Field, Image, In, Light, Mask, Node, Out
from graphkit.store import value_parts
from nodes.common.checks import require_directional
from nodes.common.parallel import run_bands
from nodes.common.sss import sss_blur, sss_blur_plane

BAND_ROWS = 48  # rows per band of the per-pixel terms (a band's temporaries stay in the cache)
#: the last albedos (LUT lookups) by the digest of the maps and LUT they come from (a live view's
#: face, a benchmark's; 11 MB each at 1280×720)
_ALBEDO: dict = {}
_ALBEDO_LOCK = threading.Lock()
#: the last unit normals by the digest of the normals they come from (11 MB at 1280×720)
_UNIT: dict = {}


class SkinShade(Node):
    """Shade skin from melanin/hemoglobin maps (Jimenez 2010 §6, eq. 7, figure 9).

    albedo = LUT(u = ∛C_m, v = ∛C_hd) (bilinear); diffuse = sss_blur(E) with
    E = light·max(N·L, 0) + ambient (GPU Gems convention: a white Lambertian surface returns
    N·L); specular = ρ_s·π·f_r·N·L with f_r the Kelemen/Szirmay-Kalos BRDF (Beckmann RMS slope
    ``roughness``, Schlick F₀ = ``f0``); image = albedo·diffuse + specular·light.
    Normals are camera-space unit vectors (OpenCV axes; default facing the camera), the viewer
    is along −z (orthographic view).  ``depth`` is in mm, ``mm_per_pixel`` the pixel footprint
    on the skin in mm (with a ``camera`` and ``depth`` it is the camera's pixel footprint at that depth instead: depth/√(fx·fy), or 1/scale for an orthographic camera); a ``camera`` also turns the world-frame light into the camera frame of the maps.
    Maps are volume fractions (table 1 ranges).
    """

    # 3: world-frame lights (turned into the camera frame); pixel footprint z/sqrt(fx·fy)
    # 4: a per-pixel SSS kernel width as blurs at σ levels a factor 2 apart (nodes/common/sss.py)
    # 5: a pixel footprint within NEAR_UNIFORM (2 %) on both axes blurred at one σ (its geometric mean)
    # 6: the SSS's level blurs made on their weights' boxes and each channel's profile sum by
    #    cv2.scaleAdd (nodes/common/sss.py): outputs move in the last bits (≤ 2.4e-7)
    # 7: the reference SSS scatters N·L once per Gaussian, diffuse = light · sss(N·L) + ambient
    #    (nodes.common.sss.sss_blur_plane; the scatter is linear): outputs move by float rounding
    version = "7"
    inputs = {"melanin": In(Image, "C_m map (volume fraction)", channels=1, finite=True, ge=0),
              "hemoglobin": In(Image, "C_hd map (volume fraction)", channels=1, same_size_as="melanin",
                               finite=True, ge=0),
              "lut": In(Image, "SkinColorLUT table", channels=3),
              "light": In(Light, "directional light"),
              "normals": In(Image, "camera-space unit normals", optional=True, channels=3, same_size_as="melanin"),
              "depth": In(Image, "camera depth in mm", optional=True, channels=1, same_size_as="melanin"),
              "mask": In(Mask, "skin: where light scatters", optional=True, same_size_as="melanin"),
              "camera": In(Camera, "camera of the maps: with depth, the pixel footprint (mm); turns the world-frame light into its frame", optional=True)}
    outputs = {"image": Out(Image, "shaded skin, linear RGB"),
               "albedo": Out(Image, "LUT albedo"),
               "diffuse": Out(Image, "scattered diffuse irradiance (before the albedo)"),
               "specular": Out(Image, "specular term (before the light colour)")}
    tolerance = {"rtol": 1e-4, "atol": 1e-5}
    # the screen-space SSS, a hook a backend replaces (plugins/graphkit-opencl)
    hooks = ("sss_blur",)
    sss_blur = staticmethod(sss_blur)

    class Params(Node.Params):
        mm_per_pixel: float = Field(0.25, gt=0, description="pixel footprint on the skin (mm)")
        roughness: float = Field(0.35, gt=0, le=1, description="Beckmann RMS slope m (skin: 0.3–0.35)")
        specular: float = Field(0.18, ge=0, description="ρ_s, specular intensity (skin ≈ 0.18)")
        f0: float = Field(0.028, ge=0, le=1, description="Fresnel reflectance at normal incidence")
        scatter: bool = Field(True, description="apply subsurface scattering to the diffuse term")

    def compute(self, melanin: Image, hemoglobin: Image, lut: Image, light: Light,
                normals: Image | None = None, depth: Image | None = None, mask: Mask | None = None,
                camera: Camera | None = None):
        import cv2

        from nodes.common.microfacet import kelemen_specular

        from .skinlut import lut_corners, lut_lookup

        p = self.params
        shp = melanin.pixels.shape[:2]
        maps = {"melanin": melanin.pixels[:, :, 0], "hemoglobin": hemoglobin.pixels[:, :, 0]}  # float32
        if min(lut.height, lut.width) < 2:
            raise BadInput("lut", f"expected an RGB table of at least 2×2 entries, got {lut.size_str()}")
        require_directional(light, "SkinShade")
        mpp = p.mm_per_pixel
        if camera is not None and depth is not None:
            if (camera.height, camera.width) != shp:
                raise BadInput("camera", f"camera is {camera.width}×{camera.height}, maps are {shp[1]}×{shp[0]}")
            z = depth.pixels[:, :, 0].astype(np.float64)
            if not np.all(z > 0):
                raise BadInput("depth", "depth must be > 0 mm everywhere when a camera gives the pixel footprint")
            mpp = camera.units_per_pixel(z)

        if camera is not None:
            light = camera.light_to_camera(light)  # lights are world-frame; the maps are camera-frame
        # directional light, orthographic viewer along −z: L and V are the same at every pixel
        ldir = np.asarray(light.direction, np.float64)
        ldir = ldir / max(np.linalg.norm(ldir), 1e-12)
        vdir = np.array([0.0, 0.0, -1.0])
        col = (np.asarray(light.color, np.float64) * light.intensity).astype(np.float32)
        amb = np.asarray(light.ambient, np.float32)
        if normals is None:  # facing the camera everywhere: N·L and the specular are constants
            n0 = np.array([0.0, 0.0, -1.0])
            ndotl_0 = np.float32(max(float(n0 @ ldir), 0.0))
            spec_0 = np.float32(kelemen_specular(n0, ldir, vdir, p.roughness, p.specular, p.f0))
        l32, v32 = ldir.astype(np.float32), vdir.astype(np.float32)
        H, W = shp
        key = self._albedo_key(melanin, hemoglobin, lut)
        albedo = _ALBEDO.get(key)  # a new light on the same face: the LUT lookup is not redone
        looked_up = albedo is None
        if looked_up:
            albedo = np.empty((H, W, 3), np.float32)
            lut32 = np.ascontiguousarray(lut.pixels, np.float32)
            corners = lut_corners(lut32)
        # the reference SSS scatters N·L once per Gaussian: E = col·N·L + ambient in every
        # channel, the scatter is linear and the profile's weights sum to one per channel
        # (energy conserving), so sss(E) = col·sss(N·L) + ambient (to float rounding)
        one_plane = p.scatter and self.sss_blur is sss_blur
        ndl = np.empty((H, W), np.float32) if one_plane else None
        irr = None if one_plane else np.empty((H, W, 3), np.float32)
        spec = np.empty((H, W), np.float32)
        unit = None if normals is None else self._unit_normals(normals)

        # Per-pixel work in float32 on bands of rows, on contiguous arrays: numpy is several
        # times slower on (…, 3) arrays broadcast against (…, 1) ones than on flat arrays, so
        # 3-channel results are assembled from planes by cv2.merge.
        def per_pixel(y0, y1):  # the pixel-local terms of one band of rows (cache-sized)
            if looked_up:
                albedo[y0:y1] = lut_lookup(lut32, maps["melanin"][y0:y1], maps["hemoglobin"][y0:y1], corners)
            if normals is None:
                ndotl = np.full((y1 - y0, W), ndotl_0, np.float32)
                spec[y0:y1] = spec_0
            else:
                nb = unit[y0:y1]
                ndotl = np.maximum(nb @ l32, np.float32(0))
                spec[y0:y1] = kelemen_specular(nb, l32, v32, p.roughness, p.specular, p.f0, dtype=np.float32)
            if one_plane:
                ndl[y0:y1] = ndotl
            else:
                cv2.merge([ndotl * col[c] + amb[c] for c in range(3)], dst=irr[y0:y1])

        run_bands(per_pixel, H, BAND_ROWS)
        if looked_up:
            with _ALBEDO_LOCK:  # nodes may run on several threads (graphkit run --jobs)
                while len(_ALBEDO) >= 2:
                    _ALBEDO.pop(next(iter(_ALBEDO)))
                _ALBEDO[key] = albedo
        if p.scatter:
            self.ctx.progress(0.2, "subsurface scattering")
            z, skin = None if depth is None else depth.pixels[:, :, 0], None if mask is None else mask.alpha  # (mm)
            if one_plane:  # sss(N·L) in every channel (the light and ambient are applied in combine)
                irr = sss_blur_plane(ndl, mpp, z, mask=skin)
            else:
                irr = np.ascontiguousarray(self.sss_blur(irr, mpp, z, mask=skin), np.float32)
        img, albedo_out = np.empty((H, W, 3), np.float32), np.empty((H, W, 3), np.float32)
        col4, amb4 = tuple(map(float, col)) + (0.0,), tuple(map(float, amb)) + (0.0,)

        def combine(y0, y1):  # (diffuse = col · sss(N·L) + ambient;) image = albedo · diffuse + specular · light
            if one_plane:
                d = irr[y0:y1]
                cv2.add(cv2.multiply(d, col4, dst=d), amb4, dst=d)
            cv2.merge([spec[y0:y1] * col[c] for c in range(3)], dst=img[y0:y1])
            img[y0:y1] += albedo[y0:y1] * irr[y0:y1]
            albedo_out[y0:y1] = albedo[y0:y1]  # (the kept albedo is not handed out)

        run_bands(combine, H, BAND_ROWS)
        return {"image": Image(img), "albedo": Image(albedo_out), "diffuse": Image(irr), "specular": Image(spec)}

    def _unit_normals(self, normals: Image) -> np.ndarray:
        """The unit normals (H, W, 3) float32, kept for the last faces (a new light on the same
        face does not normalise them again)."""
        import cv2

        key = value_parts(self.in_ports["normals"].type, normals)[2]
        got = _UNIT.get(key)
        if got is None:
            n = normals.pixels
            got = np.empty(n.shape, np.float32)

            def band(y0, y1):
                nb = n[y0:y1]
                inv = np.sqrt((nb * nb) @ np.ones(3, np.float32))  # |n|
                np.maximum(inv, np.float32(1e-12), out=inv)
                np.divide(np.float32(1), inv, out=inv)
                np.multiply(nb, cv2.merge([inv] * 3), out=got[y0:y1])

            run_bands(band, n.shape[0], BAND_ROWS)
            with _ALBEDO_LOCK:
                while len(_UNIT) >= 2:
                    _UNIT.pop(next(iter(_UNIT)))
                _UNIT[key] = got
        return got

    def _albedo_key(self, melanin: Image, hemoglobin: Image, lut: Image) -> str:
        """The digest of what the albedo comes from (the two maps and the LUT)."""
        parts = [value_parts(self.in_ports[k].type, v)[2] for k, v in
                 (("melanin", melanin), ("hemoglobin", hemoglobin), ("lut", lut))]
        return "/".join(parts)

    @classmethod
    def examples(cls):
        from .skinlut import SkinColorLUT

        rng = np.random.default_rng(7)
        lut = SkinColorLUT(SkinColorLUT.Params(size=8)).compute()["lut"]
        m = Image(rng.random((24, 32, 1), dtype=np.float32) * 0.2)
        h = Image(rng.random((24, 32, 1), dtype=np.float32) * 0.1)
        yy, xx = np.mgrid[0:24, 0:32] / 32.0
        nrm = np.dstack([xx - 0.5, yy - 0.4, -np.ones_like(xx)]).astype(np.float32)
        depth = Image((400.0 + 60.0 * (xx - 0.5) ** 2 + 3.0 * xx + 25.0 * (yy > 0.6))[..., None].astype(np.float32))
        skin = Mask((np.hypot(xx - 0.5, yy - 0.4) < 0.4).astype(np.float32))
        cam = Camera(width=32, height=24, fx=900.0, fy=900.0, cx=16.0, cy=12.0)
        light = Light(direction=(0.3, -0.2, -1.0), ambient=(0.05, 0.05, 0.05))
        return [({"mm_per_pixel": 0.5}, {"melanin": m, "hemoglobin": h, "lut": lut,
                                         "light": Light(direction=(0.3, -0.2, -1.0))}),
                # σ per pixel from the depth gradient, light kept in the skin mask
                ({"mm_per_pixel": 0.25}, {"melanin": m, "hemoglobin": h, "lut": lut, "light": light,
                                          "normals": Image(nrm), "depth": depth, "mask": skin}),
                # footprint depth / fx per pixel (camera)
                ({}, {"melanin": m, "hemoglobin": h, "lut": lut, "light": light, "depth": depth, "camera": cam})]
