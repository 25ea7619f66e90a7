"""ReflectanceMap — the skin reflectance map of Paris, Sillion, Quan 2003 §3."""
from __future__ import annotations

import numpy as np

from graphkit import BadInput, Camera, Field, Image, In, Light, Mask, Mesh, Node, Out


class ReflectanceMap(Node):
    """Skin reflectance on the Gaussian sphere from one photo (Paris 2003 §3, Fig. 5).

    1. *Samples by normal*: every skin pixel covered by the mesh gives a colour sample at its
       interpolated normal (photo camera frame, ``nodes.paris.sphere`` convention).
    2. *Clusters*: samples are grouped in cells of ``cluster_deg`` on the lat-long sphere.
    3. *Robust mean*: per cluster, only samples whose colour distance to the cluster mean is
       below the standard deviation (RMS distance) are averaged.
    4. *Interpolation / extrapolation*: at each map pixel P, clusters are grouped by their
       great-circle distance d to P (bins of ``res_deg``), averaged per distance to v(d), and
       the v(d) are combined with weights w(d) = exp(−d / ``falloff_deg``).
    Output: the map (rows θ 0…180°, columns φ −180…180°, ``res_deg`` per pixel, linear RGB) and
    the number of kept samples per map pixel (``samples``).  Units: degrees.
    """

    version = "1"
    inputs = {"image": In(Image, "the photo (linear RGB)"),
              "mesh": In(Mesh, "face mesh registered to the photo"),
              "camera": In(Camera, "the photo camera"),
              "skin": In(Mask, "skin pixels"),
              "light": In(Light, "the flash (world frame): samples are divided by its irradiance "
                                 "(a point flash's 1/d² fall-off), ShadeFace multiplies it back",
                          optional=True)}
    outputs = {"map": Out(Image, "reflectance map (lat-long, sphere.py convention)"),
               "samples": Out(Image, "kept samples per map pixel (1 channel)")}

    class Params(Node.Params):
        res_deg: float = Field(1.0, gt=0, le=10, description="map resolution (degrees/pixel); the paper's ~1°")
        cluster_deg: float = Field(2.0, gt=0, le=30, description="cluster cell size (degrees)")
        falloff_deg: float = Field(1.5, gt=0, description="w(d) = exp(-d / falloff) (degrees)")
        min_samples: int = Field(1, ge=1, description="clusters with fewer samples are dropped")
        neighbours: int = Field(96, ge=4, description="nearest clusters considered per map pixel")
        skin_threshold: float = Field(0.5, ge=0, le=1, description="mask value counted as skin")

    def compute(self, image: Image, mesh, camera: Camera, skin: Mask, light: Light | None = None):
        from .render import check_camera_matches, irradiance, surface, world_lights

        p = self.params
        check_camera_matches(camera, image)
        if skin.alpha.shape != image.pixels.shape[:2]:
            raise BadInput("skin", f"skin mask is {skin.width}×{skin.height}, the photo is "
                                   f"{image.width}×{image.height}")
        sk = skin.alpha >= p.skin_threshold
        if not sk.any():
            raise BadInput("skin", "the skin mask is empty (no pixel ≥ skin_threshold)")
        s = surface(mesh, camera, min_pixels=1)
        use = sk[s.coverage]
        if use.sum() < 10 * p.min_samples:
            raise BadInput("skin", f"only {int(use.sum())} skin pixels lie on the mesh: the skin "
                                   "mask and the mesh do not overlap")
        cols = image.pixels[s.coverage][use][:, :3].astype(np.float64)
        if light is not None:
            (lw,) = world_lights([light], camera, mesh, "light")
            e = irradiance(lw, s.points[use])
            if not (e > 0).all():
                raise BadInput("light", "the flash has intensity 0: it lights nothing")
            cols = cols / e[:, None]
        normals = camera.dir_to_camera(s.normals[use])
        rmap, count = build_map(normals, cols, p.res_deg, p.cluster_deg, p.falloff_deg,
                                p.min_samples, p.neighbours)
        return {"map": Image(rmap.astype(np.float32)),
                "samples": Image(count.astype(np.float32))}


def robust_clusters(normals: np.ndarray, colours: np.ndarray, cluster_deg: float, min_samples: int):
    """(cluster unit normals K×3, robust mean colours K×C, kept counts K) of samples binned in
    ``cluster_deg`` cells of the lat-long sphere (robust mean: distance to the mean < std)."""
    from . import sphere

    fr, fc = sphere.normals_to_pixels(normals, cluster_deg)
    rows, cols = sphere.shape(cluster_deg)
    cell = np.clip(fr.astype(np.int64), 0, rows - 1) * cols + np.clip(fc.astype(np.int64), 0, cols - 1)
    uniq, inv, cnt = np.unique(cell, return_inverse=True, return_counts=True)
    K, C = len(uniq), colours.shape[1]
    mean = np.stack([np.bincount(inv, colours[:, c], K) for c in range(C)], 1) / cnt[:, None]
    dist = np.linalg.norm(colours - mean[inv], axis=1)
    std = np.sqrt(np.bincount(inv, dist ** 2, K) / cnt)
    keep = dist <= std[inv] + 1e-12
    kc = np.bincount(inv[keep], minlength=K).astype(np.float64)
    rmean = np.stack([np.bincount(inv[keep], colours[keep, c], K) for c in range(C)], 1)
    rmean /= np.maximum(kc, 1)[:, None]
    nsum = np.stack([np.bincount(inv[keep], normals[keep, c], K) for c in range(3)], 1)
    ok = kc >= min_samples
    from .phong import unit

    return unit(nsum[ok]), rmean[ok], kc[ok]


def build_map(normals, colours, res_deg=1.0, cluster_deg=3.0, falloff_deg=2.0, min_samples=3,
              neighbours=96):
    """Dense lat-long map from samples (see ReflectanceMap)."""
    from scipy.spatial import cKDTree

    from . import sphere

    cn, cv, kc = robust_clusters(normals, colours, cluster_deg, min_samples)
    if len(cn) == 0:
        raise BadInput("skin", f"no cluster of ≥ {min_samples} skin samples: too few skin pixels")
    rows, cols = sphere.shape(res_deg)
    P = sphere.pixel_normals(res_deg).reshape(-1, 3)
    k = min(neighbours, len(cn))
    chord, idx = cKDTree(cn).query(P, k=k)
    chord = np.asarray(chord).reshape(len(P), k)
    idx = np.asarray(idx).reshape(len(P), k)
    d = np.degrees(2 * np.arcsin(np.clip(chord / 2, 0, 1)))  # great-circle distance
    # v(d): mean of the clusters in the same distance bin; w(d) = exp(-d / falloff)
    nb = int(np.ceil(180.0 / res_deg)) + 1
    b = np.minimum((d / res_deg).astype(np.int64), nb - 1)
    key = np.arange(len(P))[:, None] * nb + b
    per_bin = np.bincount(key.ravel(), minlength=len(P) * nb)[key]  # clusters sharing the bin
    dmin = d[:, :1]
    w = np.exp(-((b + 0.5) * res_deg - (dmin // res_deg + 0.5) * res_deg) / falloff_deg) / per_bin
    wsum = w.sum(1, keepdims=True)
    rmap = np.einsum("pk,pkc->pc", w, cv[idx]) / wsum
    # samples per map pixel (for display / confidence)
    fr, fc = sphere.normals_to_pixels(normals, res_deg)
    cell = np.clip(fr.astype(np.int64), 0, rows - 1) * cols + np.clip(fc.astype(np.int64), 0, cols - 1)
    count = np.bincount(cell, minlength=rows * cols).reshape(rows, cols)
    return rmap.reshape(rows, cols, -1), count
