"""The visibility basis of Render's environment shadows (nodes/paris/visibility.py, Render's
``environment_basis``; issue 26 item 6): the cone round a light never comes up empty, a ball's
soft shadow on a wall sits where the hard one is, a basis drawn lazily gives the same bytes as
one drawn in another order, the coarse grid reads back exactly at its points, and the GL
programs name it as not drawn."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from graphkit import Camera, Light
from graphkit.node import Context
from nodes.paris import visibility as VB
from nodes.paris.environment import EnvironmentLighting
from nodes.paris.models import PhongMaterial
from nodes.paris.render import Render, surface

CAM = Camera(width=96, height=80, fx=110, fy=110, cx=48, cy=40)
TOWARDS = np.array([0.35, -0.25, -0.9]) / np.linalg.norm([0.35, -0.25, -0.9])  # the light, from the wall


def ball_and_wall():
    """A wall at z = 6 behind a ball (radius 0.8 at z = 4.5): the ball shadows the wall."""
    wall = trimesh.Trimesh([[-2.5, -2.2, 6], [2.5, -2.2, 6], [2.5, 2.2, 6], [-2.5, 2.2, 6], [0, 0, 6]],
                           [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]], process=False)
    ball = trimesh.creation.icosphere(subdivisions=4, radius=0.8)
    ball.apply_translation([0.0, 0.0, 4.5])
    return trimesh.util.concatenate([wall, ball])


def exact(mesh, points, normals, direction):
    """Hard visibility of the points towards ``direction``: one ray each, as the basis casts."""
    from embreex import mesh_construction, rtcore_scene

    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    sc = rtcore_scene.EmbreeScene(robust=True)
    mesh_construction.TriangleMesh(sc, V[F].astype(np.float32))
    org = (points + VB.OFFSET * np.linalg.norm(np.ptp(V, axis=0)) * normals).astype(np.float32)
    d = np.broadcast_to(np.asarray(direction, np.float32), org.shape).copy()
    return (sc.run(org, d, query="OCCLUDED") < 0).astype(float)


@pytest.mark.parametrize("n", [64, 2048])
def test_every_direction_has_basis_directions_in_its_cone(n):
    """The Fibonacci basis covers the sphere within 0.77 of its spacing (< CONE): every light
    reads at least one direction, weighted ≥ 0.4."""
    b = VB.fibonacci_sphere(n)
    assert np.allclose(np.linalg.norm(b, axis=1), 1)
    d = np.random.default_rng(0).normal(size=(20000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    nearest = np.arccos(np.clip(d @ b.T, -1, 1)).min(1)
    assert nearest.max() < 0.8 * np.sqrt(4 * np.pi / n) <= VB.CONE * np.sqrt(4 * np.pi / n)


def test_a_balls_soft_shadow_sits_on_its_hard_one():
    """On the wall: 0 in the umbra (every direction within two cones of the light blocked), 1
    where every such direction is clear, between 0 and 1 only in the penumbra; the shadow's
    area (Σ 1 − visibility) within 10 % of the hard shadow's."""
    mesh = ball_and_wall()
    s = surface(mesh, CAM)
    basis = VB.VisibilityBasis(mesh, s, 2048)
    wall = np.flatnonzero(np.abs(s.points[:, 2] - 6) < 1e-6)
    basis.draw([TOWARDS])
    v = basis.light(TOWARDS, wall)
    P, N = s.points[wall], s.normals[wall]
    ring = [TOWARDS]  # directions round the light, out to two cones
    for r in (1.0, 2.0):
        a = np.cross(TOWARDS, [0, 1, 0])
        a /= np.linalg.norm(a)
        c = np.cross(TOWARDS, a)
        for t in np.linspace(0, 2 * np.pi, 12, endpoint=False):
            d = np.cos(r * basis.cone) * TOWARDS + np.sin(r * basis.cone) * (np.cos(t) * a + np.sin(t) * c)
            ring.append(d)
    hard = np.stack([exact(mesh, P, N, d) for d in ring])
    umbra, clear = hard.max(0) == 0, hard.min(0) == 1
    assert umbra.sum() > 20 and clear.sum() > 1000
    assert np.all(v[umbra] == 0) and np.all(v[clear] == 1)
    assert np.all((v >= 0) & (v <= 1)) and ((v > 0.05) & (v < 0.95)).sum() > 50  # a penumbra
    shadow, hard_shadow = (1 - v).sum(), (1 - hard[0]).sum()
    assert abs(shadow / hard_shadow - 1) < 0.1, (shadow, hard_shadow)


def render(basis: int, lighting, ctx: Context | None = None, **kw):
    mat = PhongMaterial(diffuse=(0.6, 0.45, 0.35), specular=0.2, shininess=20.0)
    p = Render.Params(shadow_map_size=256, clamp=False, environment_basis=basis, **kw)
    return Render(p, ctx).compute(mesh=ball_and_wall(), camera=CAM, material=mat, environment=lighting)["image"].pixels


def lighting(turn: float = 0.0):
    c, s = np.cos(turn), np.sin(turn)
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return EnvironmentLighting(lights=(Light(direction=tuple(R @ TOWARDS), intensity=0.8),
                                       Light(direction=tuple(R @ [-0.5, -0.3, -0.81]), intensity=0.5)),
                               sh=((0.2, 0.2, 0.2),) + ((0.0, 0.0, 0.0),) * 8)


def test_render_from_the_basis_follows_the_shadow_maps_and_draws_lazily():
    """Render's environment shadows from the basis: close to the shadow maps' (the same
    shadows, soft); the same bytes whatever the order its directions were drawn in (a turn
    and back, or a fresh basis); only the directions round the lights are drawn."""
    import nodes.paris.render as R

    R._GEOMETRY.clear()
    a = render(2048, lighting())
    g = [g for g in R._GEOMETRY.values() if g.bases][0]
    drawn = int(g.bases[2048].drawn.sum())
    assert 2 <= drawn <= 12  # ~3 a light
    maps = render(0, lighting())
    shadowed = render(2048, lighting(), shadows=False)
    assert (shadowed - a).max() > 0.1  # it shadows
    assert np.mean(np.abs(a - maps)) < 0.25 * np.mean(np.abs(shadowed - maps))  # (0.14: the penumbrae)
    render(2048, lighting(0.4))
    assert np.array_equal(render(2048, lighting()), a)  # after another turn drew more
    R._GEOMETRY.clear()
    render(2048, lighting(0.4))
    assert np.array_equal(render(2048, lighting()), a)  # drawn in another order


def face_basis():
    import nodes.paris.render as R

    return [g for g in R._GEOMETRY.values() if g.bases][0].bases[2048]


def test_a_live_session_fills_the_basis_in_the_background_without_stalling_a_render(monkeypatch):
    """In a batch run Render draws only its lights' directions; in a live session
    (Context.interactive, the studio) its first render starts a thread drawing the rest, a chunk
    at a time, so a render meanwhile is not held until the fill ends; the filled basis holds
    the bytes a lazily drawn one does, and a rotation after it draws nothing and renders the
    same bytes.  The fill's progress goes to Context.background_progress (the studio shows it
    on the node): whole per cents, rising, the last one 1.0."""
    import nodes.paris.render as R

    R._GEOMETRY.clear()
    render(2048, lighting())
    assert face_basis()._filler is None and not face_basis().drawn.all()  # a batch run: lazy
    render(2048, lighting(0.4))
    turned = render(2048, lighting(1.1))
    lazy = face_basis()
    R._GEOMETRY.clear()
    monkeypatch.setattr(VB, "FILL_CHUNK", 64)  # 32 chunks, 40 ms apart: a render in between
    monkeypatch.setattr(VB, "FILL_PAUSE", 0.04)
    told = []
    render(2048, lighting(), Context(interactive=True, background=lambda f, m: told.append((f, m))))
    b = face_basis()
    assert b._filler is not None
    render(2048, lighting(0.4), Context(interactive=True))  # (draws its own directions between chunks)
    assert b._filler.is_alive() and not b.drawn.all()  # not held until the fill ended
    b._filler.join(30)
    assert b.drawn.all()
    fractions = [f for f, _ in told]
    assert len(told) > 10 and fractions == sorted(fractions) and fractions[-1] == 1.0 and fractions[-2] < 1.0
    assert len({int(f * 100) for f in fractions}) == len(fractions)  # one report per whole per cent at most
    assert {m for _, m in told} == {VB.FILL_MESSAGE}
    rows = np.flatnonzero(lazy.drawn)
    assert np.array_equal(b.vis[rows], lazy.vis[rows])
    assert np.array_equal(render(2048, lighting(1.1)), turned)
    assert b.fill() == 0  # nothing left to draw


def test_the_coarse_grid_reads_back_its_points_and_interpolates_between():
    """Past BASIS_POINTS the basis holds every stride-th pixel: read back exactly there, a
    linear field (x) is reproduced between them (bilinear), and a constant stays constant."""
    mesh = ball_and_wall()
    s = surface(mesh, CAM)
    cov = s.coverage
    ys, xs = np.nonzero(cov)
    for st in (2, 3):
        grid = np.zeros_like(cov)
        grid[::st, ::st] = True
        keep = (grid & cov)[cov]
        read = VB._grid_reader(cov, keep, st)
        kx = xs[keep].astype(float)
        got = read(kx)
        assert np.array_equal(got[keep], kx)
        y0, x0 = ys // st * st, xs // st * st
        pad = np.pad(cov, (0, st))  # (outside: uncovered)
        inner = pad[y0, x0] & pad[y0, x0 + st] & pad[y0 + st, x0] & pad[y0 + st, x0 + st]  # 4 neighbours
        assert inner.mean() > 0.8
        assert np.allclose(got[inner], xs[inner], atol=1e-9)
        assert np.allclose(read(np.full(keep.sum(), 0.25)), 0.25)


def test_gl_programs_name_the_basis_as_not_drawn():
    from nodes.paris.glscene import not_drawn

    m = ball_and_wall()
    p = Render.Params(mouth="skin")
    why = not_drawn(p, m, [], lighting())
    assert "visibility basis" in why and "environment_basis: 0" in why
    assert not_drawn(p.model_copy(update={"environment_basis": 0}), m, [], lighting()) is None
    assert not_drawn(p.model_copy(update={"shadows": False}), m, [], lighting()) is None
    assert not_drawn(p, m, [Light()], None) is None
    assert not_drawn(p, m, [], lighting().model_copy(update={"lights": ()})) is None
