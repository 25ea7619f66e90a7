"""The point-to-polygon form factor's fast path (the whole polygon in front of the point: no
clipping) gives the same bits as the clipping path, so graphs keep their bytes; and both
match Lambert's closed form for a point under a rectangle's corner."""
from __future__ import annotations

import numpy as np

from nodes.loscos import geometry as G


def test_unclipped_path_gives_the_clipped_paths_bits():
    rng = np.random.default_rng(7)
    N = 20_000
    x = rng.normal(size=(N, 3))
    nx = rng.normal(size=(N, 3))
    nx /= np.linalg.norm(nx, axis=1, keepdims=True)
    o = x + nx * rng.uniform(0.05, 1, (N, 1)) + rng.normal(size=(N, 3)) * 0.5
    P = G.corners(o, rng.normal(size=(N, 3)) * 0.3, rng.normal(size=(N, 3)) * 0.3)
    R = P - x[:, None]
    d = np.einsum("nkc,nc->nk", R, nx)
    whole = (d > 0).all(1)
    assert 0.3 < whole.mean() < 0.95  # both paths are exercised by ff_point_polygon
    fast = G.ff_point_polygon(x[whole], nx[whole], P[whole])
    clipped = G._ff_clipped(R[whole], d[whole], nx[whole])
    assert np.array_equal(fast, clipped)


def test_corner_of_a_rectangle_matches_the_closed_form():
    # a differential area under the corner of an a×b rectangle at height c, parallel
    # (Howell's catalogue, C-11 limit): F = 1/(2π) [A/√(1+A²) atan(B/√(1+A²)) + B/√(1+B²) atan(A/√(1+B²))]
    a, b, c = 1.0, 2.0, 1.5
    A, B = a / c, b / c
    want = (A / np.sqrt(1 + A * A) * np.arctan(B / np.sqrt(1 + A * A))
            + B / np.sqrt(1 + B * B) * np.arctan(A / np.sqrt(1 + B * B))) / (2 * np.pi)
    P = np.array([[[0, 0, c], [a, 0, c], [a, b, c], [0, b, c]]], float)
    got = G.ff_point_polygon(np.zeros((1, 3)), np.array([[0, 0, 1.0]]), P)
    assert abs(got[0] - want) < 1e-12
    # tilted so that part of the rectangle is behind the point's plane: the clipping path
    got_half = G.ff_point_polygon(np.zeros((1, 3)), np.array([[0, 0, 1.0]]), P - [0, 0, c]
                                  + np.array([[0, 0, -0.5], [0, 0, -0.5], [0, 0, 1.0], [0, 0, 1.0]]))
    assert 0 < got_half[0] < 0.5
