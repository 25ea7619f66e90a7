"""ScatterRelit — Jimenez et al. 2010 §6's subsurface scattering applied to a relit face.

Paris 2003 §7 notes that shadow boundaries on skin "are always soft": light entering the skin
leaves it a few millimetres away.  SkinShade scatters the irradiance *it* computes (N·L of a
directional light, no cast shadows); a face relit by Render carries its own light (area lights,
soft cast shadows, several lights).  This node scatters that light with SkinShade's scattering
(``nodes.common.sss.sss_blur``: d'Eon 2007 sum of Gaussians, kernel width from depth, the one
implementation) and keeps the texture sharp (post-scatter texturing, Jimenez §6):

    texture T = image / light,  out = image + T · (sss(light) − light)

where ``light`` is the same Render without the detail texture, eye highlights and clamp (the
material's colour × the light reaching the skin, × exposure): Render's image is T × that
light (plus the eye highlights), so ``out`` is T × sss(light) there.  The skin's specular is in
``light`` too and is scattered with it (a small lobe on skin; an approximation).  Pixels where
``light`` ≤ ``eps`` (no light and no ambient) or outside ``mask`` are left as they are.
Units: depth in the camera's world units (Render.depth), lengths on the skin in mm through the
camera's ``metres_per_unit``.
"""
from __future__ import annotations

import numpy as np

from graphkit import BadInput, Camera, Field, Image, In, Mask, Node, Out
from nodes.common.sss import sss_blur


class ScatterRelit(Node):
    """Subsurface scattering of the light on a relit face (Jimenez 2010 §6 on Render's light),
    texture kept sharp: image + (image / light) · (sss(light) − light).

    ``light`` is the same Render without the detail texture, eye highlights and clamp (so
    image = texture × light there); SkinShade's scattering (d'Eon's six Gaussians, in mm on the
    skin through the camera's ``metres_per_unit`` and Render's depth) softens its shadow edges
    and terminator.  The skin's specular, inside ``light``, is scattered with it (an
    approximation).  Pixels outside ``mask`` or where ``light`` ≤ ``eps`` are unchanged.
    """

    # 2: nodes.common.sss at σ levels a factor 2 apart (SkinShade 5)
    # 3: nodes.common.sss's level blurs on their weights' boxes, sums by cv2.scaleAdd (SkinShade 6)
    version = "3"
    inputs = {"image": In(Image, "the relit face (Render.image)", channels=3, finite=True),
              "light": In(Image, "the same Render without detail texture, eye highlights and clamp: "
                                 "the light on the skin × its colour", channels=3, finite=True, ge=0,
                          same_size_as="image"),
              "depth": In(Image, "Render.depth (camera world units, 0 where uncovered)", channels=1,
                          finite=True, ge=0, same_size_as="image"),
              "camera": In(Camera, "the camera Render rendered through", same_size_as="image"),
              "mask": In(Mask, "where light scatters (skin); default: wherever depth > 0", optional=True,
                         same_size_as="image")}
    outputs = {"image": Out(Image, "the relit face with scattered light")}

    class Params(Node.Params):
        eps: float = Field(1e-4, gt=0, description="light at or below this is no light (no texture to recover)")
        clamp: bool = Field(True, description="clamp to [0, 1] as Render does")

    def compute(self, image: Image, light: Image, depth: Image, camera: Camera, mask: Mask | None = None):
        z = depth.pixels[:, :, 0].astype(np.float64)
        covered = z > 0
        if not covered.any():
            raise BadInput("depth", "no pixel has a depth > 0: connect Render.depth of the relit face")
        skin = covered if mask is None else covered & (mask.alpha > 0.5)
        mm = 1000.0 * camera.metres_per_unit
        z_mm = np.where(covered, z, np.median(z[covered])) * mm  # (uncovered pixels are not skin)
        L = light.pixels.astype(np.float32)
        scattered = sss_blur(L, camera.units_per_pixel(z_mm / mm) * mm, z_mm, mask=skin.astype(np.float32))
        img = image.pixels.astype(np.float32)
        use = skin[:, :, None] & (L > self.params.eps)
        texture = img / np.maximum(L, np.float32(self.params.eps))
        out = np.where(use, img + texture * (scattered - L), img)
        if self.params.clamp:
            out = np.clip(out, 0.0, 1.0)
        return {"image": Image(out.astype(np.float32))}

    @classmethod
    def examples(cls):
        """A lit disc with a hard shadow edge across it, textured; an orthographic camera."""
        n = 48
        yy, xx = np.mgrid[0:n, 0:n]
        disc = (xx - n / 2) ** 2 + (yy - n / 2) ** 2 < (0.4 * n) ** 2
        light = np.where((xx < n / 2)[..., None], 0.8, 0.1) * np.array([0.9, 0.6, 0.5]) * disc[..., None]
        tex = np.random.default_rng(0).uniform(0.7, 1.3, (n, n, 3))
        cam = Camera(width=n, height=n, projection="orthographic", pixels_per_m=2000.0, cx=n / 2, cy=n / 2)
        depth = np.where(disc, 0.5, 0.0)[..., None]
        f32 = lambda a: Image(np.asarray(a, np.float32))  # noqa: E731
        return [({}, {"image": f32(np.clip(tex * light, 0, 1)), "light": f32(light), "depth": f32(depth),
                      "camera": cam})]
