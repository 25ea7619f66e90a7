"""Writes the example folder of photos that graphs/makeup_batch.yaml sweeps over.

All four are scikit-image's astronaut photograph (NASA, public domain; skimage.data.astronaut()),
cropped around the face (224 px, stored at 192 px) and varied so that the batch has different inputs: the crop itself, its
mirror image, a darker exposure (linear values × 0.45) and a crop rotated by 6 degrees.  Run:

    .venv/bin/python graphs/photos/make_photos.py
"""
from pathlib import Path

import numpy as np


def main() -> None:
    import colour
    import cv2
    import skimage.data

    here = Path(__file__).resolve().parent
    img = skimage.data.astronaut()  # 512x512 sRGB uint8
    crop = img[10:234, 130:354]  # 224x224 around the face
    rot = cv2.warpAffine(img, cv2.getRotationMatrix2D((242.0, 122.0), 6.0, 1.0), (512, 512),
                         flags=cv2.INTER_AREA, borderMode=cv2.BORDER_REFLECT)[10:234, 130:354]
    lin = colour.cctf_decoding(crop / 255.0, "sRGB") * 0.45
    dark = np.round(np.clip(colour.cctf_encoding(lin, "sRGB"), 0, 1) * 255).astype(np.uint8)
    for name, px in (("astronaut", crop), ("mirrored", crop[:, ::-1]), ("darker", dark), ("tilted", rot)):
        small = cv2.resize(np.ascontiguousarray(px), (192, 192), interpolation=cv2.INTER_AREA)
        cv2.imwrite(str(here / f"{name}.png"), small[:, :, ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 9])


if __name__ == "__main__":
    main()
