"""Blur — a Gaussian-smoothed copy of an image, e.g. the smooth "shading" a ratio image
divides by."""
from __future__ import annotations

import numpy as np

from graphkit import Field, Image, In, Node


class Blur(Node):
    """Gaussian blur of each channel (borders mirrored; :func:`nodes.common.filters.gaussian_blur`,
    the same bytes on every CPU — version 1's OpenCV ``GaussianBlur`` rounded differently with
    and without AVX2).

    ``sigma_px`` is the standard deviation in pixels; the kernel spans ±3 σ.  Values stay linear.
    """

    version = "2"
    inputs = {"image": In(Image, "linear image")}
    outputs = {"image": Image}

    class Params(Node.Params):
        sigma_px: float = Field(8.0, gt=0, le=512, description="standard deviation of the Gaussian (pixels)")

    def compute(self, image: Image):
        from nodes.common.filters import gaussian_blur

        s = self.params.sigma_px
        truncate = np.ceil(3 * s) / s + 1e-9          # the kernel's half-width: ⌈3 σ⌉ px
        px = gaussian_blur(np.ascontiguousarray(image.pixels, np.float32), s, truncate=truncate)
        return Image(px.reshape(image.pixels.shape), image.colorspace)
