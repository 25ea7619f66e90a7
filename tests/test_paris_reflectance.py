"""ReflectanceMap (Paris 2003 §3) on photos whose reflectance is a known function of the normal."""
import functools

import numpy as np
import pytest
import trimesh

from graphkit import BadInput, Camera, Image, Mask
from graphkit.contract import compute_checked
from nodes.paris import sphere
from nodes.paris.reflectance import ReflectanceMap, robust_clusters

CAM = Camera(width=160, height=160, fx=260, fy=260, cx=80, cy=80)


def _f(n):
    """A smooth reflectance of the camera-frame normal: diffuse-like + a highlight at θ = 0."""
    c = np.clip(-n[..., 2], 0, 1)
    return np.stack([0.5 * c + 0.3 * c ** 20, 0.35 * c + 0.3 * c ** 20, 0.25 * c + 0.3 * c ** 20
                     + 0.05 * n[..., 0]], -1)


def _photo(outliers=0.0, seed=0):
    from nodes.paris.render import surface

    m = trimesh.creation.icosphere(subdivisions=5)
    m.apply_translation([0, 0, 4.0])
    s = surface(m, CAM)
    img = np.zeros((160, 160, 3))
    img[s.coverage] = _f(s.normals)
    skin = s.coverage.copy()
    if outliers:
        rng = np.random.default_rng(seed)
        yy, xx = np.nonzero(skin)
        k = rng.random(len(yy)) < outliers
        img[yy[k], xx[k]] = rng.uniform(0, 1, (k.sum(), 3))  # e.g. hair, segmentation errors
    return m, Image(img.astype(np.float32)), Mask(skin.astype(np.float32))


def test_map_reproduces_the_reflectance_function():
    m, photo, skin = _photo()
    out = ReflectanceMap().compute(image=photo, mesh=m, camera=CAM, skin=skin)
    rmap = out["map"].pixels
    assert rmap.shape == (180, 360, 3)
    assert np.isfinite(rmap).all()
    pn = sphere.pixel_normals(1.0)
    theta = np.degrees(np.arccos(-pn[..., 2]))
    ref = _f(pn)
    seen = theta < 75
    err = np.abs(rmap - ref)[seen]
    assert np.median(err) < 0.004 and np.percentile(err, 99) < 0.03
    # extrapolation beyond the sampled hemisphere stays within the sampled values' range
    assert rmap[theta > 100].min() >= photo.pixels.min() - 1e-6
    assert rmap[theta > 100].max() <= photo.pixels.max() + 1e-6
    assert out["samples"].pixels.sum() == (skin.alpha > 0).sum()


def test_robust_mean_discards_outliers():
    m, clean, skin = _photo()
    _, dirty, _ = _photo(outliers=0.15, seed=3)
    pn = sphere.pixel_normals(1.0)
    seen = np.degrees(np.arccos(-pn[..., 2])) < 70
    ref = _f(pn)[seen]
    robust = ReflectanceMap(ReflectanceMap.Params(cluster_deg=4.0)).compute(
        image=dirty, mesh=m, camera=CAM, skin=skin)["map"].pixels[seen]
    # a plain mean of the same clusters, for comparison
    from nodes.paris.render import surface

    s = surface(m, CAM)
    n = s.normals @ CAM.pose[:3, :3].T
    cols = dirty.pixels[s.coverage].astype(float)
    fr, fc = sphere.normals_to_pixels(n, 4.0)
    cell = fr.astype(int) * 90 + fc.astype(int)
    u, inv = np.unique(cell, return_inverse=True)
    plain = np.stack([np.bincount(inv, cols[:, c]) for c in range(3)], 1) / np.bincount(inv)[:, None]
    plain_err = np.abs(plain[inv] - _f(n)).mean()
    robust_err = np.abs(robust - ref).mean()
    print(f"\nmean abs error with 15% outliers: robust map {robust_err:.4f}, plain cluster mean {plain_err:.4f}")
    assert robust_err < 0.5 * plain_err
    # robust_clusters itself: a cluster of 9 equal samples and one outlier keeps the 9
    nn = np.tile([[0.0, 0.0, -1.0]], (10, 1))
    cc = np.full((10, 3), 0.4)
    cc[0] = 5.0
    _, mean, kept = robust_clusters(nn, cc, 2.0, 1)
    np.testing.assert_allclose(mean, [[0.4, 0.4, 0.4]])
    assert kept[0] == 9


def test_bad_inputs():
    m, photo, skin = _photo()
    node = ReflectanceMap()
    run = functools.partial(compute_checked, node)  # as the engine runs it: declared constraints first
    with pytest.raises(BadInput, match="empty") as e:
        run(image=photo, mesh=m, camera=CAM, skin=Mask(np.zeros((160, 160))))
    assert e.value.port == "skin"
    with pytest.raises(BadInput) as e:  # declared: same_size_as="image"
        run(image=photo, mesh=m, camera=CAM.model_copy(update={"width": 200}), skin=skin)
    assert e.value.port == "camera" and e.value.message == "sizes differ: image is 160×160×3, camera is 200×160"
    far = m.copy()
    far.apply_translation([50, 0, 0])  # the mesh misses the photo entirely
    with pytest.raises(BadInput, match="beside the camera") as e:
        run(image=photo, mesh=far, camera=CAM, skin=skin)
    assert e.value.port == "mesh"
    with pytest.raises(BadInput) as e:
        run(image=photo, mesh=m, camera=CAM, skin=Mask(np.ones((10, 10))))
    assert e.value.port == "skin" and e.value.message == "sizes differ: image is 160×160×3, skin is 10×10"
    bad = m.copy()
    bad.vertices[0, 0] = np.nan
    with pytest.raises(BadInput, match="holds 1 NaN") as e:  # declared: finite=True
        run(image=photo, mesh=bad, camera=CAM, skin=skin)
    assert e.value.port == "mesh"
