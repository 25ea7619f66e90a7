"""Batched ray casting against planar parallelograms: one occlusion query, two backends.

:func:`occluded` answers, for N segments p0→p1, whether one of the scene's parallelograms
(two-sided) crosses the open segment.  Every ray the Loscos nodes cast goes through it (form-factor
visibility, the texel → camera test, the links re-evaluated around a virtual object).

* ``numpy`` — the reference: every segment against every parallelogram in float64
  (O(N·P) memory and time, chunked).
* ``embree`` — Intel Embree through ``embreex``: the parallelograms as two triangles each in a BVH,
  built once per set of occluders (:func:`scene`, cached on the arrays' bytes) and reused by
  every later call.  Embree tests in float32, so a ray that grazes an edge or a surface may
  answer differently from the reference (see nodes/loscos/README.md for the measured effect).

The backend is chosen per call stack with :func:`using` (a context variable, so concurrent
node computes do not see each other's choice); the default is the reference.
"""
from __future__ import annotations

import contextlib
import contextvars
import threading

import numpy as np

BACKENDS = ("numpy", "embree")
_backend: contextvars.ContextVar[str] = contextvars.ContextVar("rays_backend", default="numpy")
# segments start and end this fraction of their length inside (the reference's open interval)
T_EPS = 1e-6
#: Embree hits this close to a segment's end (in t) are decided by the float64 reference
END_EPS = 1e-4


@contextlib.contextmanager
def using(name: str):
    """Cast the rays of the enclosed code with backend ``name`` ("numpy" or "embree")."""
    if name not in BACKENDS:
        raise ValueError(f"unknown ray-casting backend '{name}' (one of {', '.join(BACKENDS)})")
    tok = _backend.set(name)
    try:
        yield
    finally:
        _backend.reset(tok)


def backend() -> str:
    return _backend.get()


def embree_missing() -> str | None:
    """None when the Embree backend can run here, else why not."""
    try:
        import embreex.rtcore_scene  # noqa: F401
    except ImportError as e:
        return f"embreex is not installed ({e}); pip install embreex"
    return None


def occluded(p0: np.ndarray, p1: np.ndarray, occ, ignore: np.ndarray | None = None) -> np.ndarray:
    """Whether each segment p0→p1 (N,3) crosses one of the parallelograms ``occ`` = (o, u, v, n)
    (each (P,3); two-sided), end points excluded (t ∈ (T_EPS, 1 − T_EPS)).  A fifth entry
    ``tri`` (P,) bool, if given, makes those occluders the triangles (o, o+u, o+v).

    ``ignore`` (N,2) int: parallelogram indices not tested for each segment (its own sender and
    receiver; -1 for none)."""
    p0 = np.asarray(p0, np.float64)
    p1 = np.asarray(p1, np.float64)
    if len(p0) == 0 or len(occ[0]) == 0:
        return np.zeros(len(p0), bool)
    if _backend.get() == "embree":
        return _occluded_embree(p0, p1, occ, ignore)
    return _occluded_numpy(p0, p1, *occ[:4], tri=_tri(occ), ignore=ignore)


def boxes_meet(lo: np.ndarray, hi: np.ndarray, occ, ignore: np.ndarray | None = None,
               chunk: int = 1 << 22, max_occluders: int = 4096) -> np.ndarray:
    """(M,) bool: the box [lo, hi] (M,3) meets the bounding box of an occluder of ``occ`` (as
    :func:`occluded`'s) other than the two in ``ignore`` (M,2).  A segment inside a box that
    meets none is blocked by none: its rays need no casting.  Over ``max_occluders`` all True
    (the M × P test would cost more than it saves).  Boxes are tested ``chunk`` box–occluder
    pairs at a time (a few MB of temporaries)."""
    o, u, v = (np.asarray(a, np.float64) for a in occ[:3])
    if len(o) > max_occluders:
        return np.ones(len(lo), bool)
    c = np.stack([o, o + u, o + u + v, o + v], 1)
    olo, ohi = c.min(1), c.max(1)
    out = np.empty(len(lo), bool)
    step = max(1, chunk // max(len(o), 1))
    for a in range(0, len(lo), step):
        b = min(len(lo), a + step)
        meet = lo[a:b, None, 0] <= ohi[None, :, 0]
        for ax in range(3):  # one axis at a time: (n,P) temporaries, not (n,P,3)
            if ax:
                meet &= lo[a:b, None, ax] <= ohi[None, :, ax]
            meet &= hi[a:b, None, ax] >= olo[None, :, ax]
        n = np.count_nonzero(meet, axis=1)
        if ignore is not None:  # less the ignored occluders the box meets (each once)
            ig = ignore[a:b]
            row = np.arange(b - a)
            for k in range(ig.shape[1]):
                ok = (ig[:, k] >= 0) & np.all(ig[:, :k] != ig[:, k:k + 1], axis=1)
                n -= ok & meet[row, np.maximum(ig[:, k], 0)]
        out[a:b] = n > 0
    return out


def dual_basis(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Dual basis of parallelogram edge pairs (P, 3): (x − o)·du, (x − o)·dv are the in-plane
    coordinates (s, t) of a point x on the plane o + s·u + t·v."""
    uu = np.einsum("pc,pc->p", u, u)
    vv = np.einsum("pc,pc->p", v, v)
    uv = np.einsum("pc,pc->p", u, v)
    det = uu * vv - uv * uv
    du = (vv[:, None] * u - uv[:, None] * v) / det[:, None]
    dv = (uu[:, None] * v - uv[:, None] * u) / det[:, None]
    return du, dv


def _occluded_numpy(p0, p1, occ_o, occ_u, occ_v, occ_n, tri=None, ignore=None,
                    chunk: int = 1 << 21):
    """:func:`occluded`'s reference (:func:`_occluded_all`, or past ``MANY_OCCLUDERS``
    :func:`_occluded_near`), ``chunk`` segment–occluder pairs at a time."""
    if len(occ_o) > MANY_OCCLUDERS and len(p0) > 1:
        return _occluded_near(p0, p1, occ_o, occ_u, occ_v, occ_n, tri, ignore, chunk=chunk)
    return _occluded_all(p0, p1, occ_o, occ_u, occ_v, occ_n, tri, ignore, chunk)


def _occluded_all(p0, p1, occ_o, occ_u, occ_v, occ_n, tri=None, ignore=None,
                  chunk: int = 1 << 21):
    """Every segment against every occluder, ``chunk`` segment–occluder pairs at a time (its
    (n, P, 3) float64 temporaries: ~50 MB each, whatever P; 100k segments a block held 48 GB
    at 20k polygons)."""
    N = len(p0)
    out = np.zeros(N, bool)
    du, dv = dual_basis(occ_u, occ_v)
    pid = np.arange(len(occ_o))
    on = np.einsum("pc,pc->p", occ_o, occ_n)
    step = max(1, chunk // len(occ_o))
    for a in range(0, N, step):
        b = min(N, a + step)
        o = p0[a:b]
        d = p1[a:b] - o
        den = d @ occ_n.T  # (n,P)
        num = on[None, :] - o @ occ_n.T
        with np.errstate(divide="ignore", invalid="ignore"):
            t = num / den
        ok = (np.abs(den) > 1e-14) & (t > T_EPS) & (t < 1 - T_EPS)
        q = o[:, None, :] + np.where(ok, t, 0.0)[..., None] * d[:, None, :] - occ_o[None]
        s = np.einsum("npc,pc->np", q, du)
        tt = np.einsum("npc,pc->np", q, dv)
        hit = ok & (s >= 0) & (s <= 1) & (tt >= 0) & (tt <= 1)
        if tri is not None and np.any(tri):
            hit &= ~tri[None, :] | (s + tt <= 1)
        if ignore is not None:
            ig = ignore[a:b]
            hit &= (pid[None, :] != ig[:, 0:1]) & (pid[None, :] != ig[:, 1:2])
        out[a:b] = hit.any(1)
    return out


def _crosses(p0, p1, occ, k) -> np.ndarray:
    """Whether segment i (open, as :func:`occluded`'s) crosses occluder k[i]: the reference's
    float64 test with one occluder per segment (Embree's near-end hits)."""
    o, u, v, n = (np.asarray(a, np.float64)[k] for a in occ[:4])
    du, dv = dual_basis(u, v)
    d = p1 - p0
    den = np.einsum("nc,nc->n", d, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("nc,nc->n", o - p0, n) / den
    ok = (np.abs(den) > 1e-14) & (t > T_EPS) & (t < 1 - T_EPS)
    q = p0 + np.where(ok, t, 0.0)[:, None] * d - o
    s, tt = np.einsum("nc,nc->n", q, du), np.einsum("nc,nc->n", q, dv)
    return ok & (s >= 0) & (s <= 1) & (tt >= 0) & (tt <= 1) & (~_tri(occ)[k] | (s + tt <= 1))


#: above this many occluders the reference tests a group of segments only against the
#: occluders whose bounding boxes meet the group's (:func:`_occluded_near`)
MANY_OCCLUDERS = 4096


def _occluded_near(p0, p1, occ_o, occ_u, occ_v, occ_n, tri=None, ignore=None,
                   group: int = 32, chunk: int = 1 << 21):
    """:func:`_occluded_numpy` over many occluders: the segments sorted by their midpoints'
    cells (16³ over their box), ``group`` at a time, each group against the occluders whose
    boxes meet the group's box (the same answers: an occluder that meets a segment lies in
    its box)."""
    c = np.stack([occ_o, occ_o + occ_u, occ_o + occ_u + occ_v, occ_o + occ_v], 1)
    olo, ohi = c.min(1), c.max(1)
    mid = 0.5 * (p0 + p1)
    lo, hi = mid.min(0), mid.max(0)
    cell = np.clip(((mid - lo) / np.maximum(hi - lo, 1e-12) * 16).astype(np.int64), 0, 15)
    order = np.lexsort((cell[:, 2], cell[:, 1], cell[:, 0]))
    out = np.zeros(len(p0), bool)
    tri = np.zeros(len(occ_o), bool) if tri is None else np.asarray(tri, bool)
    local = np.full(len(occ_o) + 1, -1)  # global occluder id → its place in the group's set
    for a in range(0, len(order), group):
        k = order[a:a + group]
        glo = np.minimum(p0[k], p1[k]).min(0)
        ghi = np.maximum(p0[k], p1[k]).max(0)
        sub = np.flatnonzero(np.all((olo <= ghi) & (ohi >= glo), 1))
        if not len(sub):
            continue
        ig = None
        if ignore is not None:
            local[sub] = np.arange(len(sub))
            ig = local[ignore[k]]
            local[sub] = -1
        out[k] = _occluded_all(p0[k], p1[k], occ_o[sub], occ_u[sub], occ_v[sub], occ_n[sub],
                               tri[sub], ig, chunk)
    return out


_SCENES: dict[bytes, object] = {}
_MAX_SCENES = 8
_SCENES_LOCK = threading.Lock()


def scene(occ):
    """The Embree scene of parallelograms (o, u, v, n[, tri]): triangles (o, o+u, o+u+v) and
    (o, o+u+v, o+v), or the one triangle (o, o+u, o+v) of a triangle occluder; with the
    occluder of each primitive.  Built once per set of occluders and kept (the last few)."""
    import xxhash

    o, u, v = (np.ascontiguousarray(a, np.float64) for a in occ[:3])
    tri = _tri(occ)
    key = xxhash.xxh3_128_digest(o.tobytes() + u.tobytes() + v.tobytes() + tri.tobytes())
    with _SCENES_LOCK:  # callers on several threads build each scene once
        return _SCENES.get(key) or _build_scene(key, o, u, v, tri)


def _build_scene(key, o, u, v, tri):
    """:func:`scene`'s Embree scene, built and kept under key (the caller holds the lock)."""
    from embreex import mesh_construction, rtcore_scene

    c = np.stack([o, o + u, o + u + v, o + v], 1)
    tris = np.stack([np.where(tri[:, None, None], c[:, [0, 1, 3]], c[:, [0, 1, 2]]),
                     c[:, [0, 2, 3]]], 1)
    keep = np.stack([np.ones(len(o), bool), ~tri], 1).reshape(-1)
    emb = rtcore_scene.EmbreeScene(robust=True)
    mesh_construction.TriangleMesh(emb, tris.reshape(-1, 3, 3)[keep].astype(np.float32))
    sc = (emb, np.repeat(np.arange(len(o)), 2)[keep])
    if len(_SCENES) >= _MAX_SCENES:
        _SCENES.pop(next(iter(_SCENES)))
    _SCENES[key] = sc
    return sc


def _tri(occ) -> np.ndarray:
    return np.asarray(occ[4], bool) if len(occ) > 4 else np.zeros(len(occ[0]), bool)


def _occluded_embree(p0, p1, occ, ignore=None, rounds: int = 16):
    sc, prim_poly = scene(occ)
    d = p1 - p0
    org = (p0 + T_EPS * d).astype(np.float32)
    dirs = d.astype(np.float32)
    tfar = np.full(len(p0), 1 - 2 * T_EPS, np.float32)
    hit = sc.run(org, dirs, dists=tfar, query="OCCLUDED") >= 0
    if ignore is None:
        return hit
    # a blocked ray whose first hit is one of its own two parallelograms (float32 at an end
    # point, or grazing its own plane) goes on past that hit, up to ``rounds`` times (each step
    # twice the last: a ray that starts on a mesh's small triangle re-hits it); what is left
    # (0.1 % of the rays in embree.ray_examples) is cast again by the reference.  A hit within
    # END_EPS of the ray's end (a polygon touching the receiving one, as a box standing on the
    # floor: float32 puts a grazing ray's end point on either side of it) is decided in float64
    # against that polygon alone (:func:`_crosses`; the rest of the segment, under END_EPS of
    # it, is taken as clear: casting on from a float32 hit so near finds the same polygon again)
    todo = np.flatnonzero(hit)
    t0 = np.zeros(len(p0))
    for k in range(rounds):
        r = sc.run((p0[todo] + (T_EPS + t0[todo, None]) * d[todo]).astype(np.float32),
                   dirs[todo], dists=(tfar[todo] - t0[todo]).astype(np.float32), output=1)
        got = r["primID"] >= 0
        prim = prim_poly[np.maximum(r["primID"], 0)]
        past = got & ((prim == ignore[todo, 0]) | (prim == ignore[todo, 1]))
        near = np.flatnonzero(got & ~past & (T_EPS + t0[todo] + r["tfar"] > 1 - END_EPS))
        hit[todo[near]] = _crosses(p0[todo[near]], p1[todo[near]], occ, prim[near])
        hit[todo[~got]] = False
        t0[todo[past]] += r["tfar"][past] + T_EPS * 2.0 ** k  # a float32 re-hit: larger steps
        todo = todo[past]
        if len(todo) == 0:
            break
    hit[todo] = _occluded_numpy(p0[todo], p1[todo], *occ[:4], tri=_tri(occ), ignore=ignore[todo])
    return hit
