"""The Gaussian sphere of normals used by the reflectance map (Paris 2003 §3).

A reflectance map is stored as an ``Image`` in latitude–longitude form over unit normals
expressed in the **photo camera's frame** (OpenCV axes: x right, y down, z forward):

* row ``i`` ↔ polar angle θ between the normal and the direction towards the camera (−z),
  θ ∈ [0°, 180°); a normal facing the camera has θ = 0;
* column ``j`` ↔ azimuth φ ∈ [−180°, 180°), measured in the image plane from +x (right)
  towards −y (up): φ = atan2(−n_y, n_x);
* pixel centres sit at ``(i + 0.5)·res`` and ``−180° + (j + 0.5)·res``; the default
  resolution is 1° (180 × 360 pixels), the paper's "about 1°".

Normals visible from the camera have θ < 90°, so only the upper half of the map is ever
sampled by a photograph; the lower half is filled by extrapolation.
"""
from __future__ import annotations

import numpy as np

DEFAULT_RES_DEG = 1.0


def shape(res_deg: float = DEFAULT_RES_DEG) -> tuple[int, int]:
    """(rows, cols) of a map at ``res_deg`` degrees per pixel."""
    return int(round(180.0 / res_deg)), int(round(360.0 / res_deg))


def normals_to_angles(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (..., 3) in camera frame → (θ, φ) in radians."""
    n = np.asarray(n, dtype=np.float64)
    theta = np.arccos(np.clip(-n[..., 2], -1.0, 1.0))
    phi = np.arctan2(-n[..., 1], n[..., 0])
    return theta, phi


def angles_to_normals(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """(θ, φ) in radians → unit normals (..., 3) in camera frame."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, np.float64), np.asarray(phi, np.float64))
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), -st * np.sin(phi), -np.cos(theta)], axis=-1)


def normals_to_pixels(n: np.ndarray, res_deg: float = DEFAULT_RES_DEG) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals → continuous (row, col) map coordinates (pixel centres at +0.5)."""
    theta, phi = normals_to_angles(n)
    r = np.radians(res_deg)
    return theta / r, (phi + np.pi) / r


def pixel_normals(res_deg: float = DEFAULT_RES_DEG) -> np.ndarray:
    """Unit normal at the centre of every map pixel, shape (rows, cols, 3)."""
    rows, cols = shape(res_deg)
    r = np.radians(res_deg)
    theta = (np.arange(rows) + 0.5) * r
    phi = -np.pi + (np.arange(cols) + 0.5) * r
    return angles_to_normals(theta[:, None], phi[None, :])


def sample(rmap: np.ndarray, n: np.ndarray, res_deg: float = DEFAULT_RES_DEG) -> np.ndarray:
    """Bilinear lookup of map values (rows, cols, C) at unit normals (..., 3) → (..., C).

    φ wraps around; θ is clamped to the map.
    """
    rows, cols = rmap.shape[:2]
    fr, fc = normals_to_pixels(n, res_deg)
    fr = np.clip(fr - 0.5, 0, rows - 1)
    fc = fc - 0.5
    r0 = np.floor(fr).astype(np.int64)
    c0 = np.floor(fc).astype(np.int64)
    tr = (fr - r0)[..., None]
    tc = (fc - c0)[..., None]
    r1 = np.minimum(r0 + 1, rows - 1)
    c0w, c1w = c0 % cols, (c0 + 1) % cols
    top = rmap[r0, c0w] * (1 - tc) + rmap[r0, c1w] * tc
    bot = rmap[r1, c0w] * (1 - tc) + rmap[r1, c1w] * tc
    return top * (1 - tr) + bot * tr


def great_circle_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (radians) between unit vectors a and b (broadcasting over leading axes)."""
    d = np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)
    return np.arccos(d)
