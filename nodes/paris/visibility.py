"""A visibility basis: the environment lights' shadows without a shadow map per rotation
(issue 26 item 6).

Once per mesh and camera, each covered point's visibility towards ``n`` fixed directions
spread evenly over the sphere (a Fibonacci spiral) is kept: one ray per point and direction it
faces, through the mesh (Embree; the ray starts ``OFFSET`` × the mesh's size off the point
along its normal).  An environment light — a median-cut region of the map, given as one
direction — then takes the mean visibility of the basis directions within a cone round it
(``CONE`` × the directions' mean spacing √(4π/n)), each weighted by its cosine at the point
(0 below the horizon) and by 1 − (angle / cone)², falling smoothly to 0 at the rim: the
fraction of an area light of about that size reaching the point, a soft shadow with no map
drawn.  Every direction of the sphere has a basis direction within 0.77 spacing (measured for
n = 64 … 4096), so the cone never comes up empty.  Where every direction in it is below the
point's horizon the point is lit (its light's own n·l is then ~0).

The basis is kept at the covered pixels of a grid of ``stride`` pixels (the fewest such that
at most ``BASIS_POINTS`` points are kept: an environment's penumbrae are wide) and read back
at every covered pixel bilinearly from its covered grid neighbours (1 where none is covered).
"""
from __future__ import annotations

import threading
import time

import numpy as np

#: the cone round an environment light: this many times the basis directions' mean spacing
CONE = 1.0
#: a point's rays start this fraction of the mesh's bounding-box diagonal off it, along its normal
OFFSET = 1e-4
#: at most this many points hold the basis (the grid's stride grows past it)
BASIS_POINTS = 1 << 15
#: fill() draws this many directions at a time, then sleeps FILL_PAUSE seconds (a render waiting
#: for the lock or the GIL takes it then)
FILL_CHUNK = 8
FILL_PAUSE = 0.002
FILL_MESSAGE = "filling environment shadows"  # what the studio shows on the node while fill() runs


def fibonacci_sphere(n: int) -> np.ndarray:
    """``n`` unit directions spread evenly over the sphere (golden-angle spiral), n×3."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    r = np.sqrt(1.0 - z * z)
    t = k * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(t), r * np.sin(t), z], 1)


class VisibilityBasis:
    """The visibility of a :class:`~nodes.paris.render.Surface`'s points towards ``count``
    directions: a ray from each point (lifted ``OFFSET`` off it along its normal) towards each
    direction it faces, through ``mesh`` (world frame; Embree).  A direction is drawn when a
    light first needs it (:meth:`draw`) and kept: a single render draws the ~3 directions
    round each of its lights, a turning environment the ones it comes to."""

    def __init__(self, mesh, surface, count: int):
        from embreex import mesh_construction, rtcore_scene

        self.dirs = fibonacci_sphere(count)
        self.cone = CONE * np.sqrt(4 * np.pi / count)  # radians
        cov = surface.coverage
        self.stride = s = max(1, int(np.ceil(np.sqrt(cov.sum() / BASIS_POINTS))))
        grid = np.zeros_like(cov)
        grid[::s, ::s] = True
        keep = (grid & cov)[cov]  # the surface's rows kept in the basis
        self.normals = surface.normals[keep]
        self._n = np.ascontiguousarray(self.normals.T, np.float32)  # 3×P: a row per axis
        V = np.asarray(mesh.vertices, np.float64)
        lift = OFFSET * float(np.linalg.norm(np.ptp(V, axis=0)))
        self._origins = (surface.points[keep] + lift * self.normals).astype(np.float32)
        self._scene = rtcore_scene.EmbreeScene(robust=True)
        mesh_construction.TriangleMesh(self._scene, V[np.asarray(mesh.faces, np.int64)].astype(np.float32))
        self.vis = np.zeros((count, len(self.normals)), np.uint8)  # a row per direction: 1 where the ray escapes
        self.drawn = np.zeros(count, bool)
        self._lock = threading.Lock()
        self._filler = None  # fill_in_background's thread
        self._reader = None if s == 1 else _grid_reader(cov, keep, s)

    def cone_of(self, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(the basis directions within the cone round unit ``direction``, their angles)."""
        ang = np.arccos(np.clip(self.dirs @ direction, -1.0, 1.0))
        near = np.flatnonzero(ang < self.cone)
        return near, ang[near]

    def draw(self, directions) -> None:
        """Draw the basis directions the cones round ``directions`` (unit, world) need and
        that are not drawn yet (in this thread: embreex holds the GIL, two threads cast no
        faster)."""
        with self._lock:  # (Render computes on several threads draw each direction once)
            need = np.unique(np.concatenate([self.cone_of(d)[0] for d in directions] or [np.zeros(0, int)]))
            self._cast(need[~self.drawn[need]])

    def fill(self, chunk: int = FILL_CHUNK, report=lambda fraction, message: None) -> int:
        """Draw every direction not drawn yet, ``chunk`` at a time, the lock and the GIL let go
        between chunks (a render's :meth:`draw` waits at most a chunk: ~2 ms a direction at
        1024²); the number drawn.  ``report(fraction drawn, FILL_MESSAGE)`` at each whole
        per cent and when done."""
        drawn, told = 0, -1
        while True:
            with self._lock:
                todo = np.flatnonzero(~self.drawn)[:chunk]
                self._cast(todo)
                done = float(self.drawn.mean())
            if int(done * 100) > told:
                told = int(done * 100)
                report(done, FILL_MESSAGE)
            if not len(todo):
                return drawn
            drawn += len(todo)
            time.sleep(FILL_PAUSE)

    def fill_in_background(self, report=lambda fraction, message: None) -> None:
        """:meth:`fill` on a daemon thread, started once (a live session's preprocess: every
        later rotation finds its directions drawn); its progress to ``report`` (fill)."""
        with self._lock:
            if self._filler is None and not self.drawn.all():
                self._filler = threading.Thread(target=self.fill, kwargs={"report": report},
                                                name="visibility-basis-fill", daemon=True)
                self._filler.start()

    def _cast(self, ks: np.ndarray) -> None:
        """Cast the rays of basis directions ``ks`` (the lock held)."""
        for k in ks:
            idx = np.flatnonzero(self.normals @ self.dirs[k] > 0)
            if len(idx):
                org = self._origins[idx]
                d = np.broadcast_to(self.dirs[k].astype(np.float32), org.shape).copy()
                self.vis[k, idx] = self._scene.run(org, d, query="OCCLUDED") < 0
            self.drawn[k] = True

    def light(self, direction: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """The fraction of an environment light round the unit ``direction`` (world; drawn:
        :meth:`draw`) reaching the surface's points ``rows`` (indices into its points)."""
        num = np.zeros(self._n.shape[1], np.float32)
        den = np.zeros_like(num)
        for k, a in zip(*self.cone_of(direction)):
            assert self.drawn[k], "draw() the light's directions first"
            d = self.dirs[k].astype(np.float32)
            # cos⁺ × the weight, falling smoothly to 0 at the cone's rim
            c = np.maximum(self._n[0] * d[0] + self._n[1] * d[1] + self._n[2] * d[2], 0)
            c *= np.float32(1.0 - (a / self.cone) ** 2)
            num += c * self.vis[k]
            den += c
        v = np.where(den > 0, num / np.where(den > 0, den, 1), 1).astype(np.float64)
        if self._reader is not None:
            v = self._reader(v)
        return v[rows]


def _grid_reader(cov: np.ndarray, keep: np.ndarray, s: int):
    """A function: values at the kept grid points (the surface's rows ``keep``) → values at
    every covered pixel (row-major), bilinear from the covered grid neighbours (their weights
    renormalised; 1 where none is covered)."""
    H, W = cov.shape
    slot = np.full(((H - 1) // s + 2, (W - 1) // s + 2), -1, np.int64)  # grid point → kept row
    ys, xs = np.nonzero(cov)
    slot[ys[keep] // s, xs[keep] // s] = np.arange(int(keep.sum()))
    gy, gx = ys / s, xs / s
    y0, x0 = np.floor(gy).astype(np.int64), np.floor(gx).astype(np.int64)
    ty, tx = gy - y0, gx - x0
    corners = []
    for dy, dx, w in ((0, 0, (1 - ty) * (1 - tx)), (0, 1, (1 - ty) * tx), (1, 0, ty * (1 - tx)), (1, 1, ty * tx)):
        i = slot[y0 + dy, x0 + dx]
        corners.append((np.maximum(i, 0), np.where(i >= 0, w, 0.0)))
    total = sum(w for _, w in corners)

    def read(v: np.ndarray) -> np.ndarray:
        acc = sum(v[i] * w for i, w in corners)
        return np.where(total > 0, acc / np.where(total > 0, total, 1.0), 1.0)
    return read
