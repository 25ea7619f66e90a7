"""nodes/common/raster.py against closed forms: coverage area, perspective-correct depth of a
plane, z-buffer order, shared-edge ownership, shadow maps."""
import numpy as np
import pytest

from graphkit import Camera, Light
from nodes.common import raster


def _cam(w=64, h=48, f=50.0):
    return Camera(width=w, height=h, fx=f, fy=f, cx=w / 2, cy=h / 2)


@pytest.mark.parametrize("tri", [
    [(3.2, 4.1), (57.7, 9.3), (20.4, 44.6)],
    [(10.0, 10.0), (50.0, 10.0), (10.0, 40.0)],
    [(0.3, 0.2), (63.9, 47.8), (2.0, 47.0)],
])
def test_coverage_area_of_known_triangles(tri):
    xy = np.array(tri, float)
    z = np.ones(3)
    r = raster.rasterize_screen(xy, z, [[0, 1, 2]], 64, 48)
    e1, e2 = xy[1] - xy[0], xy[2] - xy[0]
    area = 0.5 * abs(e1[0] * e2[1] - e1[1] * e2[0])
    perim = sum(np.linalg.norm(xy[i] - xy[(i + 1) % 3]) for i in range(3))
    # pixel-centre sampling: the count differs from the area by at most ~ perimeter / 2
    assert abs(r.coverage.sum() - area) <= 0.5 * perim
    # and every covered pixel centre is inside the triangle (closed form test)
    yy, xx = np.nonzero(r.coverage)
    pc = np.stack([xx + 0.5, yy + 0.5], 1)
    a, b, c = xy
    def s(p, q, x):
        return (q[0] - p[0]) * (x[:, 1] - p[1]) - (q[1] - p[1]) * (x[:, 0] - p[0])
    d = np.stack([s(a, b, pc), s(b, c, pc), s(c, a, pc)], 1)
    assert (np.all(d >= 0, 1) | np.all(d <= 0, 1)).all()


def test_area_converges_and_shared_edges_counted_once():
    # a 40×30 rectangle split along its diagonal, plus a fan of 7 triangles: pixel count exact
    xy = np.array([[10.0, 10.0], [50.0, 10.0], [50.0, 40.0], [10.0, 40.0]])
    r = raster.rasterize_screen(xy, np.ones(4), [[0, 1, 2], [0, 2, 3]], 64, 48)
    assert r.coverage.sum() == 40 * 30
    assert set(np.unique(r.tri[r.coverage])) == {0, 1}
    n = 7
    ang = np.linspace(0, 2 * np.pi, n + 1)[:-1]
    pts = np.vstack([[32.0, 24.0], np.stack([32 + 20 * np.cos(ang), 24 + 20 * np.sin(ang)], 1)])
    fan = [[0, 1 + i, 1 + (i + 1) % n] for i in range(n)]
    r2 = raster.rasterize_screen(pts, np.ones(n + 1), fan, 64, 48)
    single = sum(raster.rasterize_screen(pts, np.ones(n + 1), [f], 64, 48).coverage.sum()
                 for f in fan)
    assert r2.coverage.sum() == single  # no pixel is claimed twice or dropped
    poly_area = 0.5 * n * 20 * 20 * np.sin(2 * np.pi / n)
    assert abs(single - poly_area) < 0.5 * n * 2 * 20 * np.sin(np.pi / n)


def test_perspective_correct_depth_of_a_plane():
    cam = _cam(80, 60, 70.0)
    # a tilted plane z = 3 + 0.4 x + 0.2 y (camera = world), two big triangles
    def zf(x, y):
        return 3 + 0.4 * x + 0.2 * y
    xs = np.array([-1.5, 1.5, 1.5, -1.5])
    ys = np.array([-1.2, -1.2, 1.2, 1.2])
    V = np.stack([xs, ys, zf(xs, ys)], 1)
    r = raster.rasterize(V, [[0, 1, 2], [0, 2, 3]], cam)
    assert r.coverage.sum() > 1000
    yy, xx = np.nonzero(r.coverage)
    # ray through the pixel centre: (u, v, 1) t ; intersect with the plane
    u = (xx + 0.5 - cam.cx) / cam.fx
    v = (yy + 0.5 - cam.cy) / cam.fy
    t = 3 / (1 - 0.4 * u - 0.2 * v)
    np.testing.assert_allclose(r.depth[yy, xx], t, rtol=1e-9)
    # interpolated world x also exact (perspective-correct, not screen-linear)
    X = raster.interpolate(r, [[0, 1, 2], [0, 2, 3]], V[:, 0])
    np.testing.assert_allclose(X[yy, xx], u * t, rtol=1e-9, atol=1e-12)


def test_zbuffer_keeps_nearest_regardless_of_order():
    cam = _cam()
    near = np.array([[-1, -1, 2.0], [1, -1, 2.0], [0, 1, 2.0]])
    far = near * [3, 3, 1] + [0, 0, 2.0]
    for order in ([0, 1], [1, 0]):
        V = np.vstack([near, far])
        F = np.array([[0, 1, 2], [3, 4, 5]])[order]
        r = raster.rasterize(V, F, cam)
        centre = r.tri[24, 32]
        assert F[centre][0] == 0 and abs(r.depth[24, 32] - 2.0) < 1e-12
        # outside the near triangle the far one shows
        assert (r.depth[r.coverage] >= 2.0 - 1e-12).all() and (r.depth[r.coverage] > 3.9).any()


def test_backface_culling_and_empty():
    cam = _cam()
    V = np.array([[-1, -1, 2.0], [1, -1, 2.0], [0, 1, 2.0]])
    both = raster.rasterize(V, [[0, 1, 2]], cam).coverage.sum()
    back = raster.rasterize(V, [[0, 1, 2]], cam, cull="back").coverage.sum()
    front = raster.rasterize(V, [[0, 1, 2]], cam, cull="front").coverage.sum()
    assert both > 0 and {back, front} == {0, both}
    behind = raster.rasterize(V * [1, 1, -1], [[0, 1, 2]], cam)
    assert not behind.coverage.any()


def test_shadow_map_occluder_casts_exact_shadow():
    # a square occluder 1 unit above a ground plane, light straight above: shadow = square
    import trimesh

    ground = trimesh.creation.box(extents=[4, 0.01, 4])
    occ = trimesh.creation.box(extents=[1, 0.01, 1])
    occ.apply_translation([0, -1, 0])  # y down: "above" is -y
    m = trimesh.util.concatenate([ground, occ])
    light = Light(kind="directional", direction=(0, -1, 0))
    sm = raster.shadow_map(m.vertices, m.faces, light, size=256)
    g = np.linspace(-1.9, 1.9, 77)
    X, Z = np.meshgrid(g, g)
    pts = np.stack([X.ravel(), np.full(X.size, -0.005), Z.ravel()], 1)
    vis = sm.visibility(pts, pcf=0)
    inside = (np.abs(X.ravel()) < 0.45) & (np.abs(Z.ravel()) < 0.45)
    outside = (np.abs(X.ravel()) > 0.55) | (np.abs(Z.ravel()) > 0.55)
    assert (vis[inside] == 0).all() and (vis[outside] == 1).all()
    # point light at (0,-3,0): shadow grows by (3/2) → half-width 0.75
    pl = Light(kind="point", position=(0, -3, 0))
    smp = raster.shadow_map(m.vertices, m.faces, pl, size=256)
    vis = smp.visibility(pts, pcf=0)
    inside = (np.abs(X.ravel()) < 0.7) & (np.abs(Z.ravel()) < 0.7)
    outside = (np.abs(X.ravel()) > 0.8) | (np.abs(Z.ravel()) > 0.8)
    assert (vis[inside] == 0).all() and (vis[outside] == 1).all()


def test_pixel_centres_on_shared_edges_belong_to_one_triangle():
    """A grid of triangles whose edges (vertical, horizontal, both diagonals) run through pixel
    centres: each centre strictly inside the grid is covered by exactly one triangle (the tie
    rule), none by two."""
    xs, ys = 0.5 + 4.0 * np.arange(6), 0.5 + 3.0 * np.arange(6)
    X, Y = np.meshgrid(xs, ys)
    xy = np.stack([X.ravel(), Y.ravel()], 1)
    idx = np.arange(36).reshape(6, 6)
    faces = []
    for j in range(5):
        for i in range(5):
            a, b, c, d = idx[j, i], idx[j, i + 1], idx[j + 1, i + 1], idx[j + 1, i]
            faces += [[a, b, c], [a, c, d]] if (i + j) % 2 else [[a, b, d], [b, c, d]]
    count = sum(raster.rasterize_screen(xy, np.ones(36), [f], 24, 18).coverage.astype(int) for f in faces)
    yy, xx = np.mgrid[0:18, 0:24] + 0.5
    inside = (xx > xs[0]) & (xx < xs[-1]) & (yy > ys[0]) & (yy < ys[-1])
    assert count.max() == 1 and (count[inside] == 1).all()
    for f in faces:  # the same with the depth-only path (shadow maps)
        assert np.array_equal(np.isfinite(raster.rasterize_screen(xy, np.ones(36), [f], 24, 18, depth_only=True).depth),
                              raster.rasterize_screen(xy, np.ones(36), [f], 24, 18).coverage)


@pytest.mark.parametrize("perspective", [True, False])
def test_depth_only_zbuffer_equals_the_full_rasteriser(perspective):
    """Shadow maps' depth-only path (depth stepped along each row span) keeps the same pixels
    and depths as the full one: overlapping random triangles, some with horizontal edges."""
    rng = np.random.default_rng(11)
    W, H = 90, 70
    xy = rng.uniform([-15, -15], [W + 15, H + 15], (120, 2))
    xy[61:90:2, 1] = xy[60:90:2, 1]  # pairs of vertices on one row: horizontal edges
    faces = rng.integers(0, 120, (150, 3))
    faces[:15] = np.stack([rng.integers(0, 60, 15), np.arange(60, 90, 2), np.arange(61, 90, 2)], 1)
    z = rng.uniform(1.0, 5.0, 120)
    full = raster.rasterize_screen(xy, z, faces, W, H, perspective=perspective)
    fast = raster.rasterize_screen(xy, z, faces, W, H, perspective=perspective, depth_only=True)
    assert full.coverage.sum() > 0.8 * W * H
    assert np.array_equal(np.isfinite(fast.depth), full.coverage)
    assert np.allclose(fast.depth[full.coverage], full.depth[full.coverage], rtol=1e-12, atol=0)


def test_scanline_spans_equal_brute_force_inside_test():
    """Random triangles: the covered pixels are exactly those whose centre passes the three
    edge functions (brute force over every pixel)."""
    rng = np.random.default_rng(5)
    W, H = 70, 50
    yy, xx = np.mgrid[0:H, 0:W] + 0.5
    for _ in range(40):
        xy = rng.uniform([-10, -10], [W + 10, H + 10], (3, 2))
        r = raster.rasterize_screen(xy, np.ones(3), [[0, 1, 2]], W, H)
        a, b, c = xy
        def s(p, q):
            return (q[0] - p[0]) * (yy - p[1]) - (q[1] - p[1]) * (xx - p[0])
        d = np.stack([s(a, b), s(b, c), s(c, a)])
        inside = np.all(d > 0, 0) | np.all(d < 0, 0)
        assert np.array_equal(r.coverage, inside)


def test_orthographic_camera_depth_and_attributes_are_affine_and_exact():
    """Through an orthographic camera a tilted plane's depth and any attribute are linear in
    screen space: the rasteriser's affine barycentrics give them exactly (closed form), and the
    pixel footprint does not depend on depth."""
    cam = Camera(width=80, height=60, projection="orthographic", pixels_per_m=20.0, cx=40.0, cy=30.0)
    xs = np.array([-1.5, 1.5, 1.5, -1.5])
    ys = np.array([-1.2, -1.2, 1.2, 1.2])
    V = np.stack([xs, ys, 3 + 0.4 * xs + 0.2 * ys], 1)
    F = [[0, 1, 2], [0, 2, 3]]
    r = raster.rasterize(V, F, cam)
    yy, xx = np.nonzero(r.coverage)
    X = (xx + 0.5 - cam.cx) / cam.scale
    Y = (yy + 0.5 - cam.cy) / cam.scale
    np.testing.assert_allclose(r.depth[yy, xx], 3 + 0.4 * X + 0.2 * Y, rtol=1e-12)
    np.testing.assert_allclose(raster.interpolate(r, F, V[:, 0])[yy, xx], X, atol=1e-12)
    # the covered area is the projected area (3 × 2.4 units at 20 px/unit), up to the boundary
    assert abs(r.coverage.sum() - 60 * 48) <= 60 + 48
    # perspective interpolation of the same screen triangle would be wrong here
    xy, z = cam.project(V)
    wrong = raster.rasterize_screen(xy, z, F, 80, 60, perspective=True)
    assert np.abs(wrong.depth[yy, xx] - r.depth[yy, xx]).max() > 1e-3


def test_orthographic_units_and_rays():
    """pixels_per_m with a world in mm; rays start on the image plane and run along +z."""
    cam = Camera(width=64, height=64, projection="orthographic", pixels_per_m=200.0, cx=32.0, cy=32.0,
                 metres_per_unit=0.001)
    uv, z = cam.project(np.array([[50.0, -25.0, 700.0]]))
    np.testing.assert_allclose(uv[0], [32 + 0.2 * 50, 32 - 0.2 * 25])
    o, d = cam.rays(uv)
    np.testing.assert_allclose(o[0], [50.0, -25.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(d[0], [0, 0, 1.0])
    np.testing.assert_allclose(cam.units_per_pixel(np.array([1.0, 900.0])), [5.0, 5.0])


@pytest.mark.parametrize("light", [Light(kind="directional", direction=(0.3, -1.0, 0.2)),
                                   Light(kind="point", position=(0.5, -3.0, 0.4))])
@pytest.mark.parametrize("pcf", [1, 2])
def test_shadow_map_at_points_reads_the_full_maps_depths(light, pcf):
    """A shadow map made only for some points (``at``: the texels their taps read) gives them
    the whole map's visibility, bit for bit, and leaves most of the map undrawn."""
    import trimesh

    g = np.linspace(-2, 2, 121)
    X, Z = np.meshgrid(g, g)
    idx = np.arange(121 * 121).reshape(121, 121)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    ground = trimesh.Trimesh(np.stack([X.ravel(), np.zeros(X.size), Z.ravel()], 1),
                             np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]), process=False)
    occ = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    occ.apply_translation([0.2, -0.8, 0.1])
    m = trimesh.util.concatenate([ground, occ])
    rng = np.random.default_rng(3)
    pts = np.concatenate([np.stack([rng.uniform(-0.6, 1.0, 150), np.full(150, -0.005),
                                    rng.uniform(-0.7, 0.9, 150)], 1),
                          occ.sample(40, seed=4)])  # sparse: the taps' tiles are mostly their own
    nrm = np.tile([0.0, -1.0, 0.0], (len(pts), 1))
    full = raster.shadow_map(m.vertices, m.faces, light, size=300)
    part = raster.shadow_map(m.vertices, m.faces, light, size=300, at=pts, pcf=pcf)
    assert full.complete and not part.complete
    got, want = part.visibility(pts, nrm, pcf=pcf), full.visibility(pts, nrm, pcf=pcf)
    assert np.array_equal(got, want) and 0 < want.mean() < 1
    ix, iy = raster._tap_centres(full._project(pts)[0], 300, 300)  # every texel a tap reads
    d = np.arange(-pcf, pcf + 1)
    tx, ty = (ix[:, None, None] + d[None, None, :]).ravel(), (iy[:, None, None] + d[None, :, None]).ravel()
    on = (tx >= 0) & (tx < 300) & (ty >= 0) & (ty < 300)
    assert np.array_equal(part.depth[ty[on], tx[on]], full.depth[ty[on], tx[on]])
    assert np.isfinite(part.depth).sum() < 0.5 * np.isfinite(full.depth).sum()
