"""RatioImage — the detail texture of Paris, Sillion, Quan 2003, §3."""
from __future__ import annotations

import numpy as np

from graphkit import Field, Image, In, Node


class RatioImage(Node):
    """Per-channel ratio a / max(b, eps) (Paris 2003 §3, the detail texture).

    Dividing the photograph by the face rendered with its smooth reflectance ("shaded face")
    leaves the detail texture T that the renderer multiplies back in.  ``b`` may have one
    channel (it is then used for every channel of ``a``).  Both images must have the same
    height and width.
    """

    version = "1"
    inputs = {"a": In(Image, "numerator (e.g. the photograph)"),
              "b": In(Image, "denominator (e.g. the shaded face)", same_size_as="a")}
    outputs = {"ratio": Image}
    tolerance = {"rtol": 1e-5, "atol": 1e-6}

    class Params(Node.Params):
        eps: float = Field(1e-4, gt=0, description="floor of the denominator (linear units)")

    def compute(self, a: Image, b: Image):
        check_ratio_inputs(a, b)
        return Image(ratio(a.pixels, b.pixels, self.params.eps), a.colorspace)

    @classmethod
    def examples(cls):
        rng = np.random.default_rng(3)
        a = Image(rng.random((37, 53, 3), dtype=np.float32))
        b = rng.random((37, 53, 3), dtype=np.float32)
        b[::7, ::5] = 0.0  # exercise the floor
        c = Image(rng.random((64, 48, 1), dtype=np.float32) * 2)
        return [({}, {"a": a, "b": Image(b)}),
                ({"eps": 0.25}, {"a": a, "b": Image(b)}),
                ({}, {"a": Image(rng.random((64, 48, 3), dtype=np.float32)), "b": c})]


def check_ratio_inputs(a: Image, b: Image) -> None:
    """Raise BadInput unless a and b (of the same size: declared) can be divided channel by
    channel."""
    from graphkit import BadInput

    if b.channels not in (1, a.channels):
        raise BadInput("b", f"b has {b.channels} channels; it needs 1 or {a.channels} (as a)")


def ratio(a: np.ndarray, b: np.ndarray, eps: float) -> np.ndarray:
    """a / max(b, eps) in float32 (the reference for every backend)."""
    return (a / np.maximum(b, np.float32(eps))).astype(np.float32, copy=False)
