"""AnimatedPreview — frames (e.g. every instance of a sweep) as one animated GIF/WebP/PNG."""
from __future__ import annotations

import io
from pathlib import PurePosixPath

import numpy as np

from graphkit import BadInput, Field, File, Image, In, Node, OutputPath

FORMATS = {".gif": "GIF", ".webp": "WEBP", ".png": "PNG"}  # .png: animated PNG (APNG)


class AnimatedPreview(Node):
    """Images in order as an animation a person can look at (Pillow), written into ``--out``.

    Every frame is scaled to ``width`` pixels wide (keeping its aspect ratio; all frames must
    share one), exposed by ``exposure`` stops and encoded to 8-bit sRGB; one-channel images are
    grey.  GIF frames get a per-frame adaptive 256-colour palette.  ``fps`` in frames per second.
    """

    version = "1"
    inputs = {"frames": In(Image, "the frames, in order (e.g. relit[*].image)", variadic=True, min_items=1)}
    outputs = {"file": File}

    class Params(Node.Params):
        path: OutputPath = Field(description="file inside --out: .gif, .webp or .png (APNG)")
        fps: float = Field(10.0, gt=0, le=100, description="frames per second")
        width: int = Field(256, ge=16, le=2048, description="frame width in pixels")
        exposure: float = Field(0.0, ge=-20, le=20, description="stops added before encoding")
        loop: int = Field(0, ge=0, description="times to play; 0 = forever")

    def compute(self, frames: list[Image]):
        import cv2
        from PIL import Image as PILImage

        from nodes.common.color import linear_to_srgb

        p = self.params
        ext = PurePosixPath(p.path).suffix.lower()
        if ext not in FORMATS:
            raise BadInput("path", f"{p.path}: the extension must be one of {', '.join(FORMATS)}")
        pics, size = [], None
        for i, im in enumerate(frames):
            px = im.pixels
            px = np.repeat(px, 3, axis=2) if px.shape[2] == 1 else px[:, :, :3]
            h = max(1, round(px.shape[0] * p.width / px.shape[1]))
            if size is None:
                size = (p.width, h)
            elif size != (p.width, h):
                raise BadInput("frames", f"frame {i} is {im.width}×{im.height}, whose aspect ratio differs from "
                               f"frame 0's ({frames[0].width}×{frames[0].height})")
            px = cv2.resize(np.ascontiguousarray(px), size, interpolation=cv2.INTER_AREA)
            px = np.nan_to_num(px * np.float32(2.0 ** p.exposure), nan=0.0, posinf=1.0, neginf=0.0)
            srgb = linear_to_srgb(np.clip(px, 0, 1)) if im.colorspace.startswith("lin") else np.clip(px, 0, 1)
            pics.append(PILImage.fromarray(np.round(np.clip(srgb, 0, 1) * 255).astype(np.uint8), "RGB"))
        buf = io.BytesIO()
        kw = {"save_all": True, "append_images": pics[1:], "duration": round(1000 / p.fps), "loop": p.loop}
        if ext == ".gif":
            pics = [f.quantize(256, method=PILImage.Quantize.MEDIANCUT, dither=PILImage.Dither.NONE) for f in pics]
            kw.update(append_images=pics[1:], disposal=1, optimize=False)
        elif ext == ".webp":
            kw.update(lossless=False, quality=85, method=4)
        pics[0].save(buf, FORMATS[ext], **kw)
        return File(p.path, buf.getvalue())
