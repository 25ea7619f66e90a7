"""Blur — a Gaussian-smoothed copy of an image (OpenCV), e.g. the smooth "shading" a ratio
image divides by."""
from __future__ import annotations

import numpy as np

from graphkit import Field, Image, In, Node


class Blur(Node):
    """Gaussian blur of each channel (OpenCV ``GaussianBlur``, borders mirrored).

    ``sigma_px`` is the standard deviation in pixels; the kernel spans ±3 σ.  Values stay linear.
    """

    version = "1"
    inputs = {"image": In(Image, "linear image")}
    outputs = {"image": Image}

    class Params(Node.Params):
        sigma_px: float = Field(8.0, gt=0, le=512, description="standard deviation of the Gaussian (pixels)")

    def compute(self, image: Image):
        import cv2

        s = self.params.sigma_px
        k = 2 * int(np.ceil(3 * s)) + 1
        px = cv2.GaussianBlur(np.ascontiguousarray(image.pixels), (k, k), s, s, borderType=cv2.BORDER_REFLECT)
        return Image(px.reshape(image.pixels.shape), image.colorspace)
