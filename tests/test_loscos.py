"""Loscos 2000 radiosity kernels against closed forms, and bad inputs (no Mitsuba needed)."""
import numpy as np
import pytest

from graphkit import BadInput
from nodes.loscos import geometry as G
from nodes.loscos import hierarchy as HR
from nodes.loscos import radiosity as RS
from nodes.loscos.ports import RoomScene
from nodes.loscos.scene import box_faces, check_polygons, parse_scene


def rect(o, u, v):
    o, u, v = (np.asarray(x, float) for x in (o, u, v))
    return np.array([o, o + u, o + u + v, o + v])


def F_pair(ri, rj, n=24):
    o1, u1, v1, n1, _ = G.frame(ri[None])
    o2, u2, v2, n2, _ = G.frame(rj[None])
    return G.element_form_factors(o1, u1, v1, n1, o2, u2, v2, n2, n)[0]


def howell_parallel(a, b, c):
    """Howell C-11: identical parallel directly opposed rectangles a×b at distance c."""
    X, Y = a / c, b / c
    x1, y1 = np.sqrt(1 + X * X), np.sqrt(1 + Y * Y)
    return 2 / (np.pi * X * Y) * (np.log(np.sqrt((1 + X * X) * (1 + Y * Y) / (1 + X * X + Y * Y)))
                                  + X * y1 * np.arctan(X / y1) + Y * x1 * np.arctan(Y / x1)
                                  - X * np.arctan(X) - Y * np.arctan(Y))


def howell_perpendicular(l, w, h):
    """Howell C-14: from a w×l rectangle to a h×l rectangle sharing the edge l, at 90°."""
    H, W = h / l, w / l
    A = (1 + W * W) * (1 + H * H) / (1 + W * W + H * H)
    B = W * W * (1 + W * W + H * H) / ((1 + W * W) * (W * W + H * H))
    C = H * H * (1 + H * H + W * W) / ((1 + H * H) * (H * H + W * W))
    return 1 / (np.pi * W) * (W * np.arctan(1 / W) + H * np.arctan(1 / H)
                              - np.sqrt(H * H + W * W) * np.arctan(1 / np.sqrt(H * H + W * W))
                              + 0.25 * np.log(A * B ** (W * W) * C ** (H * H)))


@pytest.mark.parametrize("a,b,c", [(1, 1, 1), (2, 1, 0.5), (1, 3, 2)])
def test_parallel_rectangles(a, b, c):
    lo = rect([0, 0, 0], [a, 0, 0], [0, b, 0])  # normal +z
    hi = rect([0, 0, c], [0, b, 0], [a, 0, 0])  # normal −z
    assert F_pair(lo, hi) == pytest.approx(howell_parallel(a, b, c), rel=2e-3)


@pytest.mark.parametrize("l,w,h", [(1, 1, 1), (2, 1, 0.5), (1, 0.3, 2)])
def test_perpendicular_rectangles(l, w, h):
    base = rect([0, 0, 0], [0, l, 0], [w, 0, 0])  # in z=0 plane, normal −z? fix orientation
    if G.frame(base[None])[3][0][2] < 0:
        base = base[[0, 3, 2, 1]]
    wall = rect([0, 0, 0], [0, 0, h], [0, l, 0])  # x=0 plane
    if G.frame(wall[None])[3][0][0] < 0:
        wall = wall[[0, 3, 2, 1]]
    assert F_pair(base, wall, 48) == pytest.approx(howell_perpendicular(l, w, h), rel=1e-2)


def test_reciprocity():
    rng = np.random.default_rng(1)
    a = rect([0, 0, 0], [1, 0, 0], [0, 0.7, 0])
    for _ in range(4):
        o = rng.uniform(-1, 1, 3) + [0, 0, 1.5]
        b = rect(o, [0.4, 0.2, 0], [0, 0.5, 0.1])
        if G.frame(b[None])[3][0][2] > 0:
            b = b[[0, 3, 2, 1]]
        Ai, Aj = G.frame(a[None])[4][0], G.frame(b[None])[4][0]
        assert Ai * F_pair(a, b) == pytest.approx(Aj * F_pair(b, a), rel=1e-2)


def closed_box(rho=0.5, E=1.0):
    f = box_faces(np.diag([1.0, 0.5, 0.8, 1.0]))[:, ::-1]  # inward
    P = len(f)
    return RoomScene([f"f{i}" for i in range(P)], f, np.full((P, 3), rho), np.full((P, 3), E),
                     [""] * P)


def test_rows_sum_to_one_in_closed_box():
    sc = closed_box()
    prm = HR.RefineParams(eps_bf=0.05, eps_bfv=0.01, min_area=5e-3, max_level=4, n_rays=1)
    h = RS.hierarchical_solve(sc, prm, 1, 1e-8)
    ops = HR.operators(h)
    row = ops.push @ (ops.Ku @ np.ones(h.n_elems))
    a = h.area(ops.leaves)
    assert np.sum(a * row) / a.sum() == pytest.approx(1.0, abs=2e-3)
    assert np.abs(row - 1).max() < 0.05  # per leaf: the push step spreads link averages


def test_refinement_in_blocks_of_candidates_gives_the_same_links(monkeypatch):
    # a closed box casts no ray (nothing but the two polygons of a link lies in its box), so
    # the refinement is deterministic: blocks of candidates may only change the order
    sc = closed_box()
    prm = HR.RefineParams(eps_bf=0.05, eps_bfv=0.01, min_area=5e-3, max_level=4, n_rays=1)
    one = RS.hierarchical_solve(sc, prm, 2, 1e-8)
    monkeypatch.setattr(HR, "LINKS_AT_ONCE", 7)
    blocks = RS.hierarchical_solve(sc, prm, 2, 1e-8)

    def links(h):
        key = lambda e: np.column_stack([h.poly[e], h.level[e], h.ij[e]])  # noqa: E731
        k = np.column_stack([key(h.recv), key(h.send)])
        order = np.lexsort(k.T[::-1])
        return k[order], h.F[order]

    assert len(one.recv) > 7 * 10
    (k1, f1), (k2, f2) = links(one), links(blocks)
    assert np.array_equal(k1, k2) and np.allclose(f1, f2, rtol=0, atol=1e-15)


def test_furnace_closed_box():
    sc = closed_box(rho=0.6, E=1.0)
    # 2×2 rays: a link's sender centroid (where the receiver looks, hierarchy.link_matrix)
    # comes from its visibility rays, and one ray gives one random point
    prm = HR.RefineParams(eps_bf=0.1, eps_bfv=0.01, min_area=1e-2, max_level=4, n_rays=2)
    h = RS.hierarchical_solve(sc, prm, 1, 1e-9)
    ops = HR.operators(h)
    L = len(ops.leaves)
    B, _ = HR.solve(ops, np.ones((L, 1)), np.full((L, 1), 0.6), tol=1e-10, max_iter=2000)
    a = h.area(ops.leaves)
    assert np.sum(a * B[:, 0]) / a.sum() == pytest.approx(1 / (1 - 0.6), rel=1e-2)
    assert np.abs(B[:, 0] * (1 - 0.6) - 1).max() < 0.08


def test_bad_polygons():
    good = rect([0, 0, 0], [1, 0, 0], [0, 1, 0])
    with pytest.raises(BadInput, match="degenerate"):
        check_polygons(np.array([[good[0], good[0], good[0], good[0]]]), ["p"], "path")
    bent = good.copy()
    bent[2, 2] = 0.3
    with pytest.raises(BadInput, match="not planar"):
        check_polygons(bent[None], ["p"], "path")


def test_check_polygons_names_the_first_bad_polygon_as_the_loop_did():
    """The vectorised pre-test never lets a bad polygon through: polygons just past each limit
    (and just inside it) among 2,000 good ones, the first bad one named, with the message
    check_polygon gives alone."""
    from nodes.loscos.scene import check_polygon

    rng = np.random.default_rng(1)
    good = [rect(rng.normal(size=3), *rng.normal(size=(2, 3))) for _ in range(2000)]
    tri = good[5].copy()
    tri[3] = tri[2]
    good[5] = tri  # a triangle (a, b, c, c) passes

    def bent(k, by):  # v2 off the plane by ``by`` times the limit
        v = good[k].copy()
        u, w = v[1] - v[0], v[3] - v[0]
        n = np.cross(u, w) / np.linalg.norm(np.cross(u, w))
        v[2] = v[2] + by * 1e-5 * max(np.linalg.norm(u), np.linalg.norm(w)) * n
        return v

    def skewed(k, by):  # v2 off v1 + v3 − v0 within the plane by ``by`` times the limit
        v = good[k].copy()
        u = v[1] - v[0]
        size = max(np.linalg.norm(u), np.linalg.norm(v[3] - v[0]))
        v[2] = v[2] + by * 1e-4 * size * u / np.linalg.norm(u)
        return v

    names = [f"p{k}" for k in range(len(good))]
    ok = np.array(good)
    ok[10], ok[11] = bent(10, 0.9), skewed(11, 0.9)
    check_polygons(ok, names, "path")
    for k, v in [(700, bent(700, 1.1)), (900, skewed(900, 1.1)), (300, np.zeros((4, 3))),
                 (400, np.where(np.eye(4, 3, dtype=bool), np.nan, good[400]))]:
        bad = ok.copy()
        bad[k] = v
        bad[1500] = bent(1500, 5)
        with pytest.raises(BadInput) as alone:
            check_polygon(v, names[k], "path")
        with pytest.raises(BadInput, match=f"'p{k}'") as got:
            check_polygons(bad, names, "path")
        assert str(got.value) == str(alone.value)


def doc(**kw):
    d = {"loscos_scene": 1, "camera": {"width": 32, "height": 32, "fov_deg": 40,
                                       "position": [0, 0, 3], "look_at": [0, 0, 0]},
         "materials": {"w": [0.5, 0.5, 0.5]},
         "polygons": [{"name": "wall", "material": "w",
                       "vertices": [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]}],
         "lights": [{"name": "L", "material": "w", "emittance": [1, 1, 1],
                     "vertices": [[-.1, .9, 1], [.1, .9, 1], [.1, .9, .8], [-.1, .9, .8]]}]}
    d.update(kw)
    return d


def test_zero_area_emitter():
    d = doc()
    d["lights"][0]["vertices"] = [[0, .9, 1]] * 4
    with pytest.raises(BadInput, match="degenerate|zero area"):
        parse_scene(d)


def test_camera_sees_nothing_and_photo_size():
    from graphkit import Image
    from graphkit.contract import compute_checked
    from nodes.loscos.scene import check_camera_sees
    from nodes.loscos.textures import ProjectTextures

    sc, cam, _ = parse_scene(doc())
    _, cam_away, _ = parse_scene(doc(camera={"width": 32, "height": 32, "fov_deg": 40,
                                             "position": [0, 0, 3], "look_at": [0, 0, 6]}))
    with pytest.raises(BadInput, match="sees no polygon"):
        check_camera_sees(sc, cam_away, "path")
    # declared on the port (same_size_as="camera"), checked before compute as the engine does
    with pytest.raises(BadInput, match="sizes differ: camera is 32×32, photo is 16×16×3") as e:
        compute_checked(ProjectTextures(), scene=sc, camera=cam, photo=Image(np.zeros((16, 16, 3))))
    assert e.value.port == "photo"
    with pytest.raises(BadInput, match="needs 3 or 4 channels, got 1") as e:
        compute_checked(ProjectTextures(), scene=sc, camera=cam, photo=Image(np.zeros((32, 32, 1))))
    assert e.value.port == "photo"



def test_shared_checks():
    """The checks several Loscos nodes share (nodes/loscos/checks.py), one wording each: the
    photo of Unocclude and Relight against the projection's camera, an RGB reflectance (scene
    files, Relight's fixtures and boxes), a perspective camera."""
    from graphkit import Camera, Context, Image
    from nodes.loscos import checks
    from nodes.loscos.relight import Relight, Unocclude

    inputs = dict(Relight.examples()[0][1])
    inputs["photo"] = Image(np.zeros((32, 20, 3), np.float32))
    for node, names in ((Unocclude, ("solution", "projection", "photo")), (Relight, inputs)):
        with pytest.raises(BadInput, match="photo is 20×32 but the projection's camera is 40×32") as e:
            node(node.Params(), Context()).compute(**{k: inputs[k] for k in names})
        assert e.value.port == "photo"
    for bad in ([0.5, float("nan"), 0.5], [0.5, 1.0, 0.5], [0.5, 0.5]):
        d = doc(materials={"w": bad})
        with pytest.raises(BadInput, match=r"'wall': reflectance must be 3 finite values in \[0, 1\)"):
            parse_scene(d)
    with pytest.raises(BadInput, match="needs the photograph's perspective") as e:
        checks.pinhole(Camera(width=8, height=6, projection="orthographic", pixels_per_m=10.0,
                              cx=4.0, cy=3.0), "camera", "this needs")
    assert e.value.port == "camera"

def test_files_named_by_an_input_file_are_in_the_key(tmp_path, write, engine_registry):
    """A scene file's photograph (Node.referenced_files) changes the key when its bytes change."""
    import shutil

    from graphkit.graphfile import load_graph
    from graphkit.runner import Session
    from graphkit.store import Store
    from nodes.loscos import scene

    data = tmp_path / "scene"
    shutil.copytree(scene.DATA, data)
    g = write("g.yaml", f"graphkit: 1\nnodes:\n  s: {{type: LoadScene, params: {{path: {data}/cornell2.yaml}}}}\n")

    def key():
        graph = load_graph(g, engine_registry, {})
        return Session(graph, engine_registry, Store(tmp_path / "c")).key(graph.nodes["s"], {})[0]

    k1 = key()
    assert k1 == key()
    photo = data / "cornell2.exr"
    photo.write_bytes(photo.read_bytes() + b"\0")
    assert key() != k1


# ------------------------------------------------------------------------------------------
# display: per-vertex interpolation and emitter coverage (closed forms)


def uniform_hierarchy(verts, levels):
    h = HR.Hierarchy.roots(np.asarray(verts, float)[None])
    for _ in range(levels):
        h.subdivide(h.leaves)
    return h


def test_vertex_interpolation_reproduces_linear_fields():
    """Leaf means of a linear field, averaged at the vertices and interpolated bilinearly,
    give the field back inside the polygon (exact on a uniform mesh); a constant survives
    T-junctions (the weights are a partition of unity)."""
    from nodes.loscos.display import interpolation

    h = uniform_hierarchy(rect([0, 0, 0], [2, 0, 0], [0, 1, 0]), 3)
    o, u, v, _, _ = h.geom(h.leaves)
    c = o + 0.5 * (u + v)
    f = 3 + 2 * c[:, 0] - 5 * c[:, 1]
    it = interpolation(h)
    rng = np.random.default_rng(3)
    s, t = rng.uniform(0.125, 0.875, 300), rng.uniform(0.125, 0.875, 300)  # off the border leaves
    vid, w = it.weights(h, np.zeros(300, np.int64), s, t)
    got = (w * (it.average @ f)[vid]).sum(1)
    assert np.allclose(got, 3 + 2 * (2 * s) - 5 * t, atol=1e-12)
    h.subdivide(h.leaves[[9, 10, 27]])  # mixed levels
    it = interpolation(h)
    vid, w = it.weights(h, np.zeros(300, np.int64), rng.random(300), rng.random(300))
    assert np.allclose((w * (it.average @ np.full(len(h.leaves), 7.0))[vid]).sum(1), 7.0)


def square_emitter_scene():
    """A grey wall at z = −0.5 and a square emitter at z = 0 facing a camera at z = 2."""
    from nodes.loscos.scene import camera_from_lookat

    wall = rect([-2, -2, -0.5], [4, 0, 0], [0, 4, 0])
    lamp = rect([0.13 - 0.31, -0.07 - 0.31, 0], [0.62, 0, 0], [0, 0.62, 0])
    sc = RoomScene(["wall", "lamp"], np.array([wall, lamp]), np.full((2, 3), 0.5),
                   np.array([[0, 0, 0], [30.0, 20, 10]]), ["", "lamp"])
    cam = camera_from_lookat(16, 16, 60.0, [0, 0, 2], [0, 0, 0], [0, 1, 0])
    # closed form: the camera looks straight at the square, so its image is the rectangle
    # u = f·x/2 + 8, v = −f·y/2 + 8 (depth 2), and a pixel's share is the overlap product
    f = cam.fx
    u0, u1 = f * (0.13 - 0.31) / 2 + 8, f * (0.13 + 0.31) / 2 + 8
    v0, v1 = -f * (-0.07 + 0.31) / 2 + 8, -f * (-0.07 - 0.31) / 2 + 8
    j, i = np.meshgrid(np.arange(16), np.arange(16))
    ov = lambda a0, a1, b: np.clip(np.minimum(a1, b + 1) - np.maximum(a0, b), 0, 1)  # noqa: E731
    return sc, cam, ov(u0, u1, j) * ov(v0, v1, i)


def test_emitter_coverage_and_mixed_pixels():
    """Exact pixel coverage of an emitter; the share recovered from a photograph that mixes
    it with the wall; switched off, a rim pixel keeps only the wall's part."""
    from graphkit import Image
    from nodes.loscos.display import modulate_pixels, pixel_plan, pixel_responses
    from nodes.loscos.textures import ProjectTextures

    sc, cam, cover = square_emitter_scene()
    L, S = np.array([9.0, 6.0, 3.0]), np.array([0.4, 0.5, 0.6])
    photo = cover[..., None] * L + (1 - cover[..., None]) * S
    pr = ProjectTextures(ProjectTextures.Params(resolution=16)).compute(
        scene=sc, camera=cam, photo=Image(photo))
    got = np.zeros(256)
    np.add.at(got, pr.em_pix, pr.em_cover)
    assert np.allclose(got.reshape(16, 16), cover, atol=1e-9)
    # texels next to the rim are not used (their pixels mix two polygons); the lamp's
    # radiance is measured from every pixel it covers
    assert np.allclose(pr.textures[1][pr.coverage[1] > 0], L, atol=1e-5)
    assert np.allclose(pr.em_radiance[1], L, rtol=1e-6) and pr.em_seen[1] == pytest.approx(
        cover.sum())
    h = HR.Hierarchy.roots(sc.verts)
    plan = pixel_plan(h, pr, photo, np.array([False, True]), np.array([[0, 0, 0], L]))
    c = np.zeros(256)
    c[plan.index] = plan.coverage
    assert np.allclose(c.reshape(16, 16), cover, atol=1e-5)
    # lamp off (glow 0), wall unchanged (ratio 1): each pixel keeps (1 − c)·S
    px = pixel_responses(plan, np.ones((2, 1, 3)), np.zeros((2, 1, 3)))
    out = modulate_pixels(px, np.ones((1, 3)))
    assert np.allclose(out, (1 - cover[..., None]) * S, atol=1e-5)


# ------------------------------------------------------------------------------------------
# emittances from the photograph


def synthetic_fit_problem(seed=0):
    """Leaves on 5 polygons lit by 3 lights (unit irradiance responses RH), reflectance per
    polygon; the photograph shows lights 0 and 1 (their radiance), not light 2."""
    rng = np.random.default_rng(seed)
    L, P, S = 400, 5, 3
    poly = rng.integers(0, P, L)
    x = rng.random(L)
    RH = np.stack([np.exp(-3 * x), 0.3 + x, 1 + np.sin(4 * x + poly)], 1)[:, :, None] \
        * rng.uniform(0.8, 1.2, (1, 1, 3)) * 0.05
    light_of = np.full(L, -1)
    light_of[:10], light_of[10:20], light_of[20:30] = 0, 1, 2
    rho_p = rng.uniform(0.2, 0.8, (P, 3))
    rho_leaf = np.where(light_of[:, None] >= 0, 0.5, rho_p[poly])
    e = np.array([[40.0, 30, 20], [10, 20, 30], [25, 25, 25]])
    H = np.einsum("lsc,sc->lc", RH, e)
    T = np.where(light_of[:, None] >= 0, np.nan, rho_leaf * H / np.pi)
    obs = np.array([(e[s] + (0.5 * H[light_of == s]).mean(0)) / np.pi for s in range(S)])
    obs[2] = np.nan
    return RH, T, poly, P, light_of, rho_leaf, rho_p, e, obs


def test_fit_emittance_recovers_each_light():
    RH, T, poly, P, light_of, rho_leaf, rho_p, e, obs = synthetic_fit_problem()
    area = np.ones(len(T))
    known = np.zeros(3, bool)
    fit = RS.fit_emittance(RH, T, area, poly, P, light_of, np.full((3, 3), 100.0), known,
                           rho_leaf, light_obs=obs, light_weight=np.array([0.2, 0.2, 0.2]),
                           max_iter=2000, tol=1e-12)
    assert np.allclose(fit.emit, e, rtol=1e-4)  # light 2 from the light it casts alone
    assert np.allclose(fit.rho_poly, rho_p, rtol=1e-4)
    assert list(fit.seen) == [True, True, False] and fit.residual < 1e-5
    # nothing seen, nothing known: the level per channel is Fournier's ρ̂ assumption, the
    # ratios between lights still come from the photograph
    fit = RS.fit_emittance(RH, T, area, poly, P, light_of, np.full((3, 3), 100.0), known,
                           rho_leaf, rho_hat=0.4, max_iter=3000, tol=1e-13)
    surf = np.isfinite(T[:, 0])
    assert np.allclose(fit.rho_poly[poly[surf]].mean(0), 0.4, rtol=1e-6)
    assert np.allclose(fit.emit / fit.emit[0], e / e[0], rtol=1e-3)


def test_unestimable_light_is_named():
    fit = RS.EmittanceFit(np.ones((2, 3)), np.zeros((1, 3)), np.array([True, False]),
                          np.array([0.9, 0.001]), 0.0)
    with pytest.raises(BadInput, match="light 'C' cannot be estimated") as e:
        RS.check_estimable(fit, np.zeros(2, bool), ["A", "C"], 0.01)
    assert e.value.port == "scene"
    RS.check_estimable(fit, np.array([False, True]), ["A", "C"], 0.01)  # given: fine


@pytest.mark.parametrize("value,ok", [(None, True), ("estimate", True), ([1, 2, 3], True),
                                      ([1, float("nan"), 3], False), ([1, -2, 3], False),
                                      ("bright", False), ([1, 2], False)])
def test_light_emittance_values(value, ok):
    d = doc()
    if value is None:
        d["lights"][0].pop("emittance")
    else:
        d["lights"][0]["emittance"] = value
    if ok:
        sc, _, _ = parse_scene(d)
        assert list(sc.light_given()) == [isinstance(value, list)]
    else:
        with pytest.raises(BadInput, match="light 'L': emittance must be 3"):
            parse_scene(d)


def test_relight_refuses_bad_emittances():
    from nodes.loscos.relight import new_emittance

    class Sol:
        emit = np.ones((1, 3))
        lights = ["A"]

    for prm, port in (({}, {"A": [1, float("nan"), 1]}), ({"A": float("nan")}, {}),
                      ({"A": -1.0}, {}), ({}, {"A": [1, -1, 1]})):
        with pytest.raises(BadInput) as e:
            new_emittance(Sol, prm, port)
        assert e.value.port == ("light_scale" if prm else "emittance")


def test_project_textures_refuses_an_orthographic_camera():
    """The projection maths here is the photograph's pinhole: an orthographic camera is refused
    at the camera port, not a TypeError on its missing focal length."""
    from graphkit import Camera, Context, Image
    from nodes.loscos.textures import ProjectTextures

    cam = Camera(width=8, height=6, projection="orthographic", pixels_per_m=10.0, cx=4.0, cy=3.0)
    node = ProjectTextures(ProjectTextures.Params(), Context())
    with pytest.raises(BadInput) as e:
        node.compute(scene=None, camera=cam, photo=Image(np.zeros((6, 8, 3), np.float32)))
    assert e.value.port == "camera" and "orthographic" in str(e.value)


# ------------------------------------------------------------------------------------------
# bad input through the CLI: exit 2, one message naming node and port, no traceback


def cli_scene(tmp_path, lights, photo=True):
    import yaml

    from nodes.io.images import encode_image

    d = doc()
    d["lights"] = lights
    if photo:
        (tmp_path / "photo.exr").write_bytes(encode_image(np.full((32, 32, 3), 0.3, np.float32),
                                                          ".exr", 16))
        d["photo"] = "photo.exr"
    (tmp_path / "scene.yaml").write_text(yaml.safe_dump(d))
    (tmp_path / "g.yaml").write_text(
        "graphkit: 1\nnodes:\n"
        "  scene: {type: LoadScene, params: {path: scene.yaml}}\n"
        "  textures: {type: ProjectTextures, inputs: {scene: scene.scene, camera: scene.camera,"
        " photo: scene.photo}, params: {resolution: 16}}\n"
        "  radiosity: {type: RadiositySolve, inputs: {scene: scene.scene, projection:"
        " textures.projection}, params: {max_level: 2, min_area: 0.05, rounds: 1,"
        " reflectance_iterations: 1}}\n"
        "outputs: {lights: radiosity.lights}\n")


def run_cli(tmp_path):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "graphkit", "run", "g.yaml", "--out", "out",
                           "--cache", "cache"], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)


FACING_WALL = [[-.1, .1, 1], [-.1, -.1, 1], [.1, -.1, 1], [.1, .1, 1]]  # normal −z, at z = 1
BEHIND_WALL = [[-.1, .1, -1], [-.1, -.1, -1], [.1, -.1, -1], [.1, .1, -1]]  # away from it


def test_cli_no_emittance_and_no_photo(tmp_path):
    cli_scene(tmp_path, [{"name": "L", "vertices": FACING_WALL}], photo=False)
    r = run_cli(tmp_path)
    assert r.returncode == 2, r.stderr
    assert "scene" in r.stderr and "LoadScene" in r.stderr and "path" in r.stderr
    assert "light 'L' gives no emittance and the scene file names no photo" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "out").exists()


def test_cli_light_nothing_shows(tmp_path):
    """L, unseen (its back faces the camera) but lighting the wall, is estimated; C behind the
    wall, facing away, lights nothing the camera sees: refused by name."""
    cli_scene(tmp_path, [{"name": "L", "vertices": FACING_WALL},
                         {"name": "C", "emittance": "estimate", "vertices": BEHIND_WALL}])
    r = run_cli(tmp_path)
    assert r.returncode == 2, r.stderr
    assert "radiosity" in r.stderr and "RadiositySolve" in r.stderr and "scene" in r.stderr
    assert "light 'C' cannot be estimated" in r.stderr and "'L'" not in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "out").exists()
    cli_scene(tmp_path, [{"name": "L", "vertices": FACING_WALL}])
    r = run_cli(tmp_path)
    assert r.returncode == 0, r.stderr
    import json

    lights = json.loads((tmp_path / "out" / "lights.json").read_text())["json"]["lights"]
    assert lights["L"]["source"] == "estimated" and min(lights["L"]["emittance"]) > 0


def test_cli_nan_emittance(tmp_path):
    cli_scene(tmp_path, [{"name": "L", "emittance": [1.0, float("nan"), 1.0],
                          "vertices": FACING_WALL}])
    r = run_cli(tmp_path)
    assert r.returncode == 2, r.stderr
    assert "LoadScene" in r.stderr and "light 'L': emittance must be 3 finite" in r.stderr
    assert "Traceback" not in r.stderr
