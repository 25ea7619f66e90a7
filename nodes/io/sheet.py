"""ContactSheet — many images on one page, for a person to look at."""
from __future__ import annotations

import numpy as np

from graphkit import BadInput, Field, Image, In, Node


class ContactSheet(Node):
    """Lay images out on a grid with a label under each (for a PNG a person can look at).

    Every image is scaled to ``cell_width`` pixels wide (keeping its aspect ratio); one-channel
    images are shown as grey.  Values stay linear: save the sheet with SaveImage as PNG to get
    an sRGB-encoded picture.
    """

    version = "1"
    inputs = {"images": In(Image, "the images, in order", variadic=True, min_items=1)}
    outputs = {"image": Image}

    class Params(Node.Params):
        labels: list[str] = Field(default_factory=list, description="one caption per image (optional)")
        columns: int = Field(0, ge=0, description="images per row; 0 picks a near-square grid")
        cell_width: int = Field(256, ge=16, le=4096, description="width of each cell in pixels")
        gap: int = Field(6, ge=0, le=256, description="pixels between cells")
        background: float = Field(0.02, ge=0, description="linear grey of the page")

    def compute(self, images: list[Image]):
        import cv2

        p = self.params
        if p.labels and len(p.labels) != len(images):
            raise BadInput("labels", f"{len(p.labels)} labels for {len(images)} images")
        cols = p.columns or int(np.ceil(np.sqrt(len(images))))
        rows = int(np.ceil(len(images) / cols))
        tiles = []
        for im in images:
            px = im.pixels
            if px.shape[2] == 1:
                px = np.repeat(px, 3, axis=2)
            px = px[:, :, :3]
            h = max(1, round(px.shape[0] * p.cell_width / px.shape[1]))
            tiles.append(cv2.resize(np.ascontiguousarray(px), (p.cell_width, h), interpolation=cv2.INTER_AREA))
        label_h = 22 if p.labels else 0
        cell_h = max(t.shape[0] for t in tiles) + label_h
        H = rows * cell_h + (rows + 1) * p.gap
        W = cols * p.cell_width + (cols + 1) * p.gap
        sheet = np.full((H, W, 3), p.background, np.float32)
        for i, t in enumerate(tiles):
            r, c = divmod(i, cols)
            y = p.gap + r * (cell_h + p.gap)
            x = p.gap + c * (p.cell_width + p.gap)
            sheet[y:y + t.shape[0], x:x + t.shape[1]] = t
            if p.labels:  # OpenCV draws text on 8-bit images only: draw coverage, then blend
                strip = np.zeros((label_h, p.cell_width), np.uint8)
                cv2.putText(strip, p.labels[i][:40], (2, label_h - 6), cv2.FONT_HERSHEY_SIMPLEX,
                            0.45, 255, 1, cv2.LINE_AA)
                a = strip[:, :, None].astype(np.float32) / 255.0
                region = sheet[y + cell_h - label_h:y + cell_h, x:x + p.cell_width]
                region[:] = region * (1 - a) + 0.8 * a
        return Image(sheet)
