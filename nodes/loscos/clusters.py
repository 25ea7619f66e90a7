"""Cluster links above the root polygons, for scenes of many polygons (Smits, Arvo &
Greenberg 1994; Sillion 1995).

Starting links from every pair of root polygons costs P² (a 20k-triangle room: 4·10⁸ pairs).
Instead a binary bounding-volume hierarchy of the polygons (spatial median splits of their
centroids on the longest axis) starts from one link, the root cluster with itself, and
refines node pairs top-down:

* a self-link splits into its children's four ordered pairs (a polygon's self-link is
  dropped), so the ordered pairs of distinct polygons are covered exactly once;
* a link R ← S of two disjoint bounding spheres at gap g = |c_R − c_S| − ρ_R − ρ_S > 0 is
  kept as a cluster link when its transport bound min(1, max(A_R, A_S) / (π g²)) · B_S / B̄
  (A the members' total area, B_S the largest member radiosity, B̄ the median polygon's: the
  polygon links' BF criterion, :func:`hierarchy.refine_links` (b)) is at most ``eps_bf``,
  and when S holds no light polygon (links from lights always reach the polygons, where
  TextureRefine, Unocclude and the virtual objects work on them);
* otherwise the larger sphere is split; a pair of two polygons becomes a candidate polygon
  link, refined as before (:func:`hierarchy.refine_links`).

A cluster link gathers with each member's own cosine towards the other end's centre
(oriented, so a cluster does not light its back faces): the irradiance at receiver polygon p
from sender polygons q is

    H_p = V/π · a_p · Σ_q b_q B_q,   a_p = max(0, n_p·(c_S − x_p)) / |c_S − x_p|²,
                                      b_q = A_q max(0, n_q·(c_R − x_q)) / |c_R − x_q|²,

the point form factor A_q cos θ_p cos θ_q / (π d²) with 1/d² split as 1/(d_pS d_qR) (x the
polygons' centroids, c the clusters' centres).  So each link is a rank-one block,
stored as its members' weights (entries (link, polygon, weight)), and the gather adds
W·diag(V)·U to the polygon links' matrix, at the root polygons, whose irradiance the push
step hands to their leaves and whose radiosity is the pull's area average.  V: the fraction
of unblocked rays between points drawn on the two ends' members (by their weights), the
same batched rays as the polygon links.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nodes.common import rays

from . import geometry as G


#: a cluster link's two bounding spheres are at least this many times the larger radius apart
SEPARATION = 1.0


@dataclass(eq=False)
class Tree:
    """Binary BVH over P polygons.  Node k: members ``order[start[k]:stop[k]]``, children
    ``left[k]``, ``right[k]`` (-1: a single polygon, ``order[start[k]]``), bounding sphere
    (``centre``, ``radius``), members' total area, largest luminance and whether a light
    polygon is among them."""

    order: np.ndarray
    start: np.ndarray
    stop: np.ndarray
    left: np.ndarray
    right: np.ndarray
    centre: np.ndarray
    radius: np.ndarray
    area: np.ndarray
    B: np.ndarray
    light: np.ndarray

    @property
    def single(self) -> np.ndarray:
        return self.left < 0

    @property
    def poly(self) -> np.ndarray:
        """(K,) the polygon of a single-polygon node (else a member)."""
        return self.order[self.start]


def build_tree(corners: np.ndarray, area: np.ndarray, B: np.ndarray, light: np.ndarray) -> Tree:
    """The BVH of polygons with corners (P,4,3), areas (P,), luminances (P,) and light flags."""
    x = corners.mean(1)
    order = np.arange(len(x))
    start, stop, left, right = [0], [len(x)], [-1], [-1]
    todo = [0]
    while todo:
        k = todo.pop()
        a, b = start[k], stop[k]
        if b - a < 2:
            continue
        seg = order[a:b]
        axis = int(np.argmax(np.ptp(x[seg], 0)))
        mid = (b - a) // 2
        order[a:b] = seg[np.argpartition(x[seg, axis], mid)]
        for lo, hi in ((a, a + mid), (a + mid, b)):
            (left if lo == a else right)[k] = len(start)
            todo.append(len(start))
            start.append(lo), stop.append(hi), left.append(-1), right.append(-1)
    start, stop = np.array(start), np.array(stop)
    K = len(start)
    centre, radius = np.zeros((K, 3)), np.zeros(K)
    A, Bmax, lit = np.zeros(K), np.zeros(K), np.zeros(K, bool)
    for k in range(K):  # members' corners' box centre, the farthest corner from it
        m = order[start[k]:stop[k]]
        c = corners[m].reshape(-1, 3)
        centre[k] = 0.5 * (c.min(0) + c.max(0))
        radius[k] = np.sqrt(((c - centre[k]) ** 2).sum(1).max())
        A[k], Bmax[k], lit[k] = area[m].sum(), B[m].max(), light[m].any()
    return Tree(order, start, stop, np.array(left), np.array(right), centre, radius, A, Bmax, lit)


def refine_clusters(t: Tree, eps: float, B_ref: float):
    """Top-down refinement of the root's self-link (module docstring).  Returns the
    candidate polygon pairs (r, s) and the kept cluster links (R, S) as node ids."""
    R, S = np.zeros(1, np.int64), np.zeros(1, np.int64)
    pairs, kept = [], []
    while len(R):
        same = R == S
        both = t.single[R] & t.single[S]
        pairs.append((t.poly[R[both & ~same]], t.poly[S[both & ~same]]))
        go = ~both
        R, S, same = R[go], S[go], same[go]
        gap = np.linalg.norm(t.centre[R] - t.centre[S], axis=1) - t.radius[R] - t.radius[S]
        far = gap > SEPARATION * np.maximum(t.radius[R], t.radius[S])
        F = np.minimum(1.0, np.maximum(t.area[R], t.area[S]) / (np.pi * np.where(far, gap, 1) ** 2))
        keep = ~same & far & ~t.light[S] & (F * t.B[S] / B_ref <= eps)
        kept.append((R[keep], S[keep]))
        # split a self-link into its children's pairs, else the larger sphere (a cluster)
        sr = same & ~keep
        lr, rr = t.left[R[sr]], t.right[R[sr]]
        nr = [lr, lr, rr, rr]
        ns = [lr, rr, lr, rr]
        rest = ~same & ~keep
        Rr, Sr = R[rest], S[rest]
        split_r = ~t.single[Rr] & (t.single[Sr] | (t.radius[Rr] >= t.radius[Sr]))
        a, b = Rr[split_r], Sr[split_r]
        nr += [t.left[a], t.right[a]]
        ns += [b, b]
        a, b = Rr[~split_r], Sr[~split_r]
        nr += [a, a]
        ns += [t.left[b], t.right[b]]
        R, S = np.concatenate(nr), np.concatenate(ns)
    cat = lambda xs, i: np.concatenate([x[i] for x in xs])  # noqa: E731
    return (cat(pairs, 0), cat(pairs, 1)), (cat(kept, 0), cat(kept, 1))


def members(t: Tree, nodes: np.ndarray):
    """(link position, polygon) of every member of each node in ``nodes``."""
    n = t.stop[nodes] - t.start[nodes]
    link = np.repeat(np.arange(len(nodes)), n)
    off = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    return link, t.order[np.repeat(t.start[nodes], n) + off]


def side_weights(x: np.ndarray, normal: np.ndarray, towards: np.ndarray) -> np.ndarray:
    """max(0, n·(c − x)) / |c − x|² for member centroids x, normals n, other-end centres c."""
    d = towards - x
    return np.clip(np.einsum("nc,nc->n", d, normal), 0, None) / np.maximum(
        np.einsum("nc,nc->n", d, d), 1e-12)


@dataclass(eq=False)
class ClusterLinks:
    """Cluster links in the members' weights: receiver entries (link, polygon) ``r`` (E,2)
    with weights ``rw`` (a_p), sender entries ``s``, ``sw`` (b_q), and V per link."""

    V: np.ndarray
    r: np.ndarray
    rw: np.ndarray
    s: np.ndarray
    sw: np.ndarray


def link_weights(t: Tree, R, S, x, normal, area) -> ClusterLinks:
    """The members' weights of links R ← S (V still 1), less the links that carry nothing
    (no receiver member faces the sender's centre, or no sender member the receiver's)."""
    lr, pr = members(t, R)
    ls, ps = members(t, S)
    rw = side_weights(x[pr], normal[pr], t.centre[S][lr])
    sw = area[ps] * side_weights(x[ps], normal[ps], t.centre[R][ls])
    live = (np.bincount(lr, rw, len(R)) > 0) & (np.bincount(ls, sw, len(R)) > 0)
    new = np.cumsum(live) - 1
    r, s = live[lr], live[ls]
    return ClusterLinks(np.ones(int(live.sum())), np.stack([new[lr[r]], pr[r]], 1), rw[r],
                        np.stack([new[ls[s]], ps[s]], 1), sw[s])


def _draw(link, w, n_links, k, rng):
    """(n_links, k) entry indices drawn per link by weight w (entries sorted by link); -1
    where a link's weights are all 0."""
    return draw_entries(link, w, np.arange(n_links), k, rng)


def draw_entries(link, w, rows, k, rng):
    """(len(rows), k) entry indices drawn by weight w among the entries of link ``rows[i]``
    for each i (entries sorted by link); -1 where that link's weights are all 0."""
    cw = np.cumsum(w)
    first = np.searchsorted(link, rows)
    last = np.searchsorted(link, rows, side="right")
    base = np.where(first > 0, cw[np.maximum(first - 1, 0)], 0.0)
    tot = np.where(last > first, cw[np.maximum(last - 1, 0)], 0.0) - base
    u = base[:, None] + rng.random((len(rows), k)) * tot[:, None]
    idx = np.clip(np.searchsorted(cw, u, side="right"), first[:, None],
                  np.maximum(last - 1, first)[:, None])
    return np.where(tot[:, None] > 0, idx, -1)


def cluster_transport(cl: ClusterLinks, occ, n_rays: int, rng, at_once: int = 1 << 18):
    """Per cluster link, from n_rays² point pairs drawn by the rank-one kernel (receiver
    member p by a_p·A_p, sender member q by b_q, a uniform point on each): the scale of its
    weights that makes its transport the Monte Carlo estimate of the true one (the mean of
    the point kernel cos·cos/(π r²) over the rank-one kernel a_p b_q / (π A_q) — the bias
    of splitting 1/r² at the ends' centres removed), and V, the kernel-weighted fraction of
    the pairs' rays that no polygon blocks (as the polygon links' V)."""
    o, u, v, n, tri = occ
    M, k = len(cl.V), n_rays * n_rays
    area = np.linalg.norm(np.cross(u, v), axis=1) * np.where(tri, 0.5, 1.0)
    ir = _draw(cl.r[:, 0], cl.rw * area[cl.r[:, 1]], M, k, rng)
    js = _draw(cl.s[:, 0], cl.sw, M, k, rng)
    ok = (ir >= 0) & (js >= 0)
    er, es = ir[ok], js[ok]
    pr, ps = cl.r[er, 1], cl.s[es, 1]

    def point(p):
        st = G.fold(rng.random((len(p), 2)), tri[p])
        return o[p] + st[:, :1] * u[p] + st[:, 1:] * v[p]

    p0, p1 = point(pr), point(ps)
    d = p1 - p0
    r2 = np.maximum(np.einsum("nc,nc->n", d, d), 1e-12)
    kern = (np.clip(np.einsum("nc,nc->n", d, n[pr]), 0, None)
            * np.clip(-np.einsum("nc,nc->n", d, n[ps]), 0, None) / (r2 * r2))
    ratio = np.zeros(ir.shape)
    ratio[ok] = kern * area[ps] / (cl.rw[er] * cl.sw[es])
    blocked = np.zeros(len(pr), bool)
    for a in range(0, len(pr), at_once):
        b = slice(a, a + at_once)
        blocked[b] = rays.occluded(p0[b], p1[b], occ, ignore=np.stack([pr[b], ps[b]], 1))
    free = np.zeros(ir.shape)
    free[ok] = ~blocked
    tot = ratio.sum(1)
    V = np.where(tot > 0, (ratio * free).sum(1) / np.maximum(tot, 1e-300), 0.0)
    return tot / np.maximum(ok.sum(1), 1), V


def cluster_matrices(cl: ClusterLinks, N: int):
    """(W, U, Uu): irradiance at the N elements = W @ (U @ B) (U: with V, Uu: V = 1)."""
    import scipy.sparse as sp

    L = len(cl.V)
    W = sp.csr_matrix((cl.rw / np.pi, (cl.r[:, 1], cl.r[:, 0])), shape=(N, L))
    U = sp.csr_matrix((cl.sw * cl.V[cl.s[:, 0]], (cl.s[:, 0], cl.s[:, 1])), shape=(L, N))
    Uu = sp.csr_matrix((cl.sw, (cl.s[:, 0], cl.s[:, 1])), shape=(L, N))
    return W, U, Uu
