"""ReflectanceMap — the skin reflectance map of Paris, Sillion, Quan 2003 §3."""
from __future__ import annotations

from typing import Literal, Optional

import numpy as np

from graphkit import BadInput, Camera, Field, Image, In, Light, Mask, Mesh, Node, Out, Scalar

#: cluster sizes (degrees) tried when ``cluster_deg`` is chosen from the data
CANDIDATES_DEG = (2.0, 3.0, 4.0, 6.0, 8.0, 11.0, 15.0)
#: samples used to choose the cluster size (an even subsample of the skin pixels beyond that)
CV_SAMPLES = 12000


class ReflectanceMap(Node):
    """Skin reflectance on the Gaussian sphere from one photo (Paris 2003 §3, Fig. 5).

    1. *Samples by normal*: every skin pixel covered by the mesh gives a colour sample at its
       interpolated normal (photo camera frame, ``nodes.paris.sphere`` convention).  With the
       flash ``light``, each sample is divided by the flash's irradiance there (I/d² for a
       point flash, d in metres), so the map holds the reflectance per unit irradiance and the
       flash's fall-off across the face is not taken for reflectance (ShadeFace multiplies it
       back).
    2. *Symmetry* (``symmetry``, with the light): skin is taken as an isotropic material, whose
       radiance for a fixed light l and view v depends on the normal only through n·l and n·v,
       i.e. is the same at a normal and at its mirror image across the plane holding l and v;
       each sample is also entered at its mirror normal.  Albedo that differs between the two
       sides of that plane (a texture lit from one side, one cheek redder) is then left to the
       detail texture instead of being taken for shading.  (With l = v the plane is undefined
       and nothing is mirrored.)
    3. *Clusters*: samples are grouped by the nearest point of an equal-area (Fibonacci) grid
       of spacing ``cluster_deg`` on the sphere of normals.
    4. *Robust mean*: per cluster, only samples whose colour distance to the cluster mean is
       below the standard deviation (RMS distance) are averaged.
    5. *Interpolation / extrapolation*: at each map pixel P, clusters are grouped by their
       great-circle distance d to P (bins of ``res_deg``), averaged per distance to v(d), and
       the v(d) are combined with weights w(d) = exp(−d / falloff), falloff = ``falloff_deg``
       (default 0.75 × the cluster size, the paper's 1.5° for 2°).

    The smoothing is chosen from the data (``cluster_deg`` unset), by held-out pixels: for
    each candidate size (``CANDIDATES_DEG``), each side of the mirror plane is predicted by the
    map built from the other side's samples entered at their mirror normals — the same shading,
    by isotropy, seen at other places of the face with their own albedo — and the size whose
    map predicts best is used.  The error is the squared log-ratio of sample to prediction less
    its smooth trend over the image (a quadratic in x, y: a slow albedo drift such as a tan or
    a texture lit from one side is no map's to predict), the worst 5 % left out.  A map that
    follows one place's albedo (too fine) or blurs the shading (too coarse) predicts the other
    side badly.  Without a mirror plane (no light, or the flash on the lens axis) ``folds``
    sets of image blocks (``block_frac`` of the skin region's size, assigned with ``seed``)
    are the held-out sets.  At most ``CV_SAMPLES`` samples (an even subsample) take part.

    Output: the map (rows θ 0…180°, columns φ −180…180°, ``res_deg`` per pixel, linear RGB),
    the number of kept samples per map pixel (``samples``) and the cluster size used
    (``cluster_deg``).  Units: degrees.
    """

    version = "2"
    inputs = {"image": In(Image, "the photo (linear RGB)"),
              "mesh": In(Mesh, "face mesh registered to the photo", finite=True),
              "camera": In(Camera, "the photo camera", same_size_as="image"),
              "skin": In(Mask, "skin pixels", same_size_as="image"),
              "light": In(Light, "the flash (world frame): samples are divided by its irradiance "
                                 "(a point flash's 1/d² fall-off), ShadeFace multiplies it back; "
                                 "it also sets the mirror plane", optional=True)}
    outputs = {"map": Out(Image, "reflectance map (lat-long, sphere.py convention)"),
               "samples": Out(Image, "kept samples per map pixel (1 channel)"),
               "cluster_deg": Out(Scalar, "the cluster size used (degrees)")}

    class Params(Node.Params):
        res_deg: float = Field(1.0, gt=0, le=10, description="map resolution (degrees/pixel); the paper's ~1°")
        cluster_deg: Optional[float] = Field(None, gt=0, le=30, description="cluster size (degrees); "
                                             "default: chosen by held-out pixels")
        falloff_deg: Optional[float] = Field(None, gt=0, description="w(d) = exp(-d / falloff) (degrees); "
                                             "default 0.75 × cluster_deg")
        symmetry: Literal["mirror", "none"] = Field("mirror", description="mirror samples across the "
                                                    "light–view plane (needs the light)")
        min_samples: int = Field(1, ge=1, description="clusters with fewer samples are dropped")
        neighbours: int = Field(96, ge=4, description="nearest clusters considered per map pixel")
        skin_threshold: float = Field(0.5, ge=0, le=1, description="mask value counted as skin")
        folds: int = Field(4, ge=2, le=20, description="held-out folds when choosing cluster_deg")
        block_frac: float = Field(0.125, gt=0, le=1, description="held-out block size, fraction of the "
                                  "skin region's larger side")
        seed: int = Field(0, description="seed of the block → fold assignment")

    def compute(self, image: Image, mesh, camera: Camera, skin: Mask, light: Light | None = None):
        from .render import irradiance, skin_surface, world_lights

        p = self.params
        s, use = skin_surface(mesh, camera, skin, p.skin_threshold, fewest=10 * p.min_samples)
        cols = image.pixels[s.coverage][use][:, :3].astype(np.float64)
        mirror = None
        if light is not None:
            (lw,) = world_lights([light], camera, mesh, "light")
            e = irradiance(lw, s.points[use])
            if not (e > 0).all():
                raise BadInput("light", "the flash has intensity 0: it lights nothing")
            cols = cols / e[:, None]
            if p.symmetry == "mirror":
                mirror = mirror_plane(camera.dir_to_camera(np.asarray(light.direction, np.float64)))
        normals = camera.dir_to_camera(s.normals[use])
        cluster = p.cluster_deg
        if cluster is None:
            yy, xx = np.nonzero(s.coverage)
            xy = np.stack([xx[use], yy[use]], 1)
            cluster, _ = choose_cluster(normals, cols, xy, mirror, p)
            self.ctx.progress(0.8, f"cluster size {cluster:g}°")
        falloff = p.falloff_deg if p.falloff_deg is not None else 0.75 * cluster
        n2, c2 = with_mirror(normals, cols, mirror)
        rmap, _ = build_map(n2, c2, p.res_deg, cluster, falloff, p.min_samples, p.neighbours)
        count = sample_counts(normals, p.res_deg)
        return {"map": Image(rmap.astype(np.float32)),
                "samples": Image(count.astype(np.float32)),
                "cluster_deg": float(cluster)}


def mirror_plane(l_cam: np.ndarray, min_sin: float = 1e-3) -> np.ndarray | None:
    """Unit normal of the plane holding the light direction and the view direction (camera
    frame, the camera at −z), or None when they coincide."""
    l = np.asarray(l_cam, np.float64)
    l = l / np.linalg.norm(l)
    m = np.cross(l, [0.0, 0.0, -1.0])
    nm = np.linalg.norm(m)
    return None if nm < min_sin else m / nm


def with_mirror(normals, colours, m):
    """Samples plus their mirror images across the plane of unit normal ``m`` (if any)."""
    if m is None:
        return normals, colours
    mir = normals - 2 * (normals @ m)[:, None] * m
    return np.concatenate([normals, mir]), np.concatenate([colours, colours])


def fibonacci_normals(spacing_deg: float) -> np.ndarray:
    """An equal-area grid of unit vectors with neighbours about ``spacing_deg`` apart."""
    r = np.radians(spacing_deg)
    n = max(12, int(round(4 * np.pi / (r * r))))
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5 ** 0.5) * i
    rho = np.sqrt(1 - z * z)
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], 1)


def robust_clusters(normals: np.ndarray, colours: np.ndarray, cluster_deg: float, min_samples: int):
    """(cluster unit normals K×3, robust mean colours K×C, kept counts K) of samples grouped by
    the nearest point of an equal-area grid of spacing ``cluster_deg`` (robust mean: samples
    whose distance to the mean is below the standard deviation)."""
    from scipy.spatial import cKDTree

    from .phong import unit

    grid = fibonacci_normals(cluster_deg)
    _, cell = cKDTree(grid).query(normals)
    uniq, inv, cnt = np.unique(cell, return_inverse=True, return_counts=True)
    inv = inv.ravel()
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
    return unit(nsum[ok]), rmean[ok], kc[ok]


def predict(cn, cv, Q, res_deg, falloff_deg, neighbours) -> np.ndarray:
    """Map values at unit normals Q (N×3) from clusters (normals cn, values cv): §3's
    distance-binned v(d) with weights exp(−d / falloff)."""
    from scipy.spatial import cKDTree

    k = min(neighbours, len(cn))
    chord, idx = cKDTree(cn).query(Q, k=k)
    chord = np.asarray(chord).reshape(len(Q), k)
    idx = np.asarray(idx).reshape(len(Q), k)
    d = np.degrees(2 * np.arcsin(np.clip(chord / 2, 0, 1)))  # great-circle distance
    # v(d): mean of the clusters in the same distance bin; w(d) = exp(-d / falloff)
    nb = int(np.ceil(180.0 / res_deg)) + 1
    b = np.minimum((d / res_deg).astype(np.int64), nb - 1)
    # clusters sharing each one's bin: the neighbours come sorted by distance, so equal bins
    # are runs along each row (run lengths, O(N·k))
    key = (np.arange(len(Q), dtype=np.int64)[:, None] * nb + b).ravel()
    step = np.diff(key)
    if (step < 0).any():  # pragma: no cover - cKDTree sorts by distance
        per_bin = np.bincount(key)[key].reshape(b.shape)
    else:
        starts = np.concatenate([[0], np.flatnonzero(step) + 1])
        runs = np.diff(np.concatenate([starts, [key.size]]))
        per_bin = np.repeat(runs, runs).reshape(b.shape)
    dmin = d[:, :1]
    w = np.exp(-((b + 0.5) * res_deg - (dmin // res_deg + 0.5) * res_deg) / falloff_deg) / per_bin
    return np.einsum("pk,pkc->pc", w, cv[idx]) / w.sum(1, keepdims=True)


def build_map(normals, colours, res_deg=1.0, cluster_deg=3.0, falloff_deg=2.0, min_samples=3,
              neighbours=96):
    """Dense lat-long map from samples (see ReflectanceMap) → (map, samples per map pixel)."""
    from . import sphere

    cn, cv, kc = robust_clusters(normals, colours, cluster_deg, min_samples)
    if len(cn) == 0:
        raise BadInput("skin", f"no cluster of ≥ {min_samples} skin samples: too few skin pixels")
    rows, cols = sphere.shape(res_deg)
    P = sphere.pixel_normals(res_deg).reshape(-1, 3)
    rmap = predict(cn, cv, P, res_deg, falloff_deg, neighbours)
    return rmap.reshape(rows, cols, -1), sample_counts(normals, res_deg)


def sample_counts(normals, res_deg) -> np.ndarray:
    """Samples per map pixel (display / confidence)."""
    from . import sphere

    rows, cols = sphere.shape(res_deg)
    fr, fc = sphere.normals_to_pixels(normals, res_deg)
    cell = np.clip(fr.astype(np.int64), 0, rows - 1) * cols + np.clip(fc.astype(np.int64), 0, cols - 1)
    return np.bincount(cell, minlength=rows * cols).reshape(rows, cols)


def choose_cluster(normals, colours, xy, mirror, p, candidates=CANDIDATES_DEG):
    """The cluster size (degrees) whose map best predicts held-out skin pixels (see
    ReflectanceMap) → (size, {size: error}).

    With a mirror plane the two sides of the face are the folds: each side is predicted by the
    map of the other side's samples entered at their mirror normals — the same shading seen at
    other places of the face, with their own albedo.  Without one, image blocks are the folds.
    At most ``CV_SAMPLES`` samples (an even subsample) take part."""
    if len(normals) > CV_SAMPLES:
        keep = np.linspace(0, len(normals) - 1, CV_SAMPLES).round().astype(np.int64)
        normals, colours, xy = normals[keep], colours[keep], xy[keep]
    if mirror is not None:
        side = (normals @ mirror) >= 0
        folds = [side, ~side]
        if min(side.sum(), (~side).sum()) < 0.1 * len(side):
            mirror = None
    if mirror is None:
        lo, hi = xy.min(0), xy.max(0)
        block = max(2.0, p.block_frac * float(max(hi - lo) + 1))
        bx = ((xy - lo) // block).astype(np.int64)
        tile = bx[:, 0] * 100003 + bx[:, 1]
        tiles, tinv = np.unique(tile, return_inverse=True)
        rng = np.random.default_rng(p.seed)
        fold = (rng.permutation(len(tiles)) % p.folds)[tinv.ravel()]
        folds = [fold == k for k in range(p.folds)]
    errors = {}
    for c in candidates:
        falloff = p.falloff_deg if p.falloff_deg is not None else 0.75 * c
        e = np.full(len(colours), np.nan)
        for test in folds:
            if not test.any():
                continue
            if mirror is not None:  # the other side, mirrored onto this one
                tr = normals[~test]
                n2, c2 = tr - 2 * (tr @ mirror)[:, None] * mirror, colours[~test]
            else:
                n2, c2 = normals[~test], colours[~test]
            cn, cv, _ = robust_clusters(n2, c2, c, p.min_samples)
            if len(cn) == 0:
                e[test] = np.inf
                continue
            pred = predict(cn, cv, normals[test], p.res_deg, falloff, p.neighbours)
            e[test] = _detrended_error(colours[test], pred, xy[test])
        e = np.sort(e[np.isfinite(e)])
        errors[c] = float(e[: max(1, int(0.95 * len(e)))].mean()) if len(e) else np.inf
    best = min(errors, key=errors.get)
    return best, errors


def _detrended_error(obs, pred, xy) -> np.ndarray:
    """Per-sample squared log-ratio error, less its smooth trend over the image (a quadratic in
    x, y per channel, least squares): albedo that drifts slowly across the face (a tan, a
    texture lit from one side) is no map's to predict, and is not counted."""
    r = np.log(np.maximum(obs, 1e-6) / np.maximum(pred, 1e-6))
    x, y = (xy - xy.mean(0)).T / max(float(np.ptp(xy)), 1.0)
    A = np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y])
    coef, *_ = np.linalg.lstsq(A, r, rcond=None)
    return np.sum((r - A @ coef) ** 2, 1)
