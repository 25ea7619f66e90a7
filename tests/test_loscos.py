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
    from nodes.loscos.scene import check_camera_sees
    from nodes.loscos.textures import ProjectTextures

    sc, cam, _ = parse_scene(doc())
    _, cam_away, _ = parse_scene(doc(camera={"width": 32, "height": 32, "fov_deg": 40,
                                             "position": [0, 0, 3], "look_at": [0, 0, 6]}))
    with pytest.raises(BadInput, match="sees no polygon"):
        check_camera_sees(sc, cam_away, "path")
    with pytest.raises(BadInput, match="photo is 16×16 but the camera is 32×32") as e:
        ProjectTextures().compute(scene=sc, camera=cam, photo=Image(np.zeros((16, 16, 3))))
    assert e.value.args[0] == "photo" or "photo" in str(e.value)


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
