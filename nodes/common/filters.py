"""Image filters that give the same bytes on every CPU.

OpenCV picks a kernel for the CPU it runs on (SSE, AVX2 with fused multiply-add, AVX-512), and
its floating-point filters round differently in each: ``cv2.GaussianBlur`` of a float32 image,
``cv2.Sobel``, ``cv2.remap`` (bilinear), ``cv2.scaleAdd`` and ``cv2.addWeighted`` change their last
bits when its AVX2/FMA3 kernels are turned off (``OPENCV_CPU_DISABLE=AVX2,FMA3``), and the
portraits blended through ``cv2.GaussianBlur`` (CompositeFace) came out with other bytes on an
AVX2 machine than on the AVX-512 one their digests were recorded on.  SciPy's ``ndimage`` runs one
compiled loop everywhere, so a node whose output is cached and compared by its bytes filters
through these (tests/test_same_bytes_cpus.py runs them with OpenCV's kernels turned off).
"""
from __future__ import annotations

import numpy as np


def gaussian_blur(x: np.ndarray, sigma: float, truncate: float = 4.0) -> np.ndarray:
    """Gaussian blur of an H×W or H×W×C float image along its two image axes (standard deviation
    ``sigma`` px, the kernel cut at ``truncate`` σ, borders mirrored as OpenCV's
    ``BORDER_REFLECT``: …cba|abc…), in the image's own float type."""
    from scipy.ndimage import gaussian_filter1d

    x = np.asarray(x)
    dt = x.dtype if x.dtype in (np.float32, np.float64) else np.float32
    out = gaussian_filter1d(x.astype(dt, copy=False), sigma, axis=0, mode="reflect", truncate=truncate)
    return gaussian_filter1d(out, sigma, axis=1, mode="reflect", truncate=truncate, output=out)
