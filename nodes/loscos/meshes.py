"""Triangle meshes into a Loscos scene: mesh files through trimesh, triangles into polygons.

* :func:`mesh_polygons` — a triangle mesh's faces as the scene's polygons: pairs of coplanar
  triangles that form a parallelogram become one (a maximum matching, preferring consecutive
  faces: a quad split in two), every other triangle stays a triangle, written (a, b, c, c)
  (geometry.is_triangle).  Merging is never required: ``merge=False`` keeps every triangle.
* :func:`mesh_parts` — a mesh file's named parts: an OBJ's materials (``usemtl``; trimesh
  splits OBJ files by material), a glTF/GLB's meshes (node transforms applied), a PLY's one
  mesh (named by the scene entry), each with its file colour (MTL ``Kd``, glTF base colour)
  when it has one.

Errors name the file, the part and the face index (:class:`MeshError`); scene.py turns them
into one bad-input message.
"""
from __future__ import annotations

import os

import numpy as np

FORMATS = (".obj", ".ply", ".gltf", ".glb")


class MeshError(ValueError):
    """A mesh that cannot become scene polygons (the message names where)."""


def check_mesh(V: np.ndarray, F: np.ndarray, where: str) -> np.ndarray:
    """Unit normals (K,3) of the faces; MeshError for no faces, a bad index, a non-finite
    vertex, or a degenerate (zero-area) triangle, naming the first one."""
    if len(F) == 0:
        raise MeshError(f"{where}: the mesh has no faces")
    if F.min() < 0 or F.max() >= len(V):
        raise MeshError(f"{where}: a face indexes a vertex the mesh does not have")
    bad = np.flatnonzero(~np.isfinite(V).all(1))
    if len(bad):
        f = np.flatnonzero(np.isin(F, bad).any(1))
        at = f"face {f[0]}" if len(f) else "an unused vertex"
        raise MeshError(f"{where}: vertex {bad[0]} is not finite ({at})")
    tri = V[F]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nn = np.linalg.norm(n, axis=1)
    edge = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(1)
    deg = np.flatnonzero(nn <= 1e-10 * np.maximum(edge, 1e-300) ** 2)
    if len(deg):
        raise MeshError(f"{where}: face {deg[0]} is degenerate (zero area: its vertices are "
                        f"collinear or repeated; {len(deg)} such face(s))")
    return n / nn[:, None]


def mesh_polygons(vertices, faces, where: str, merge: bool = True,
                  rel_tol: float = 1e-5) -> np.ndarray:
    """A triangle mesh → the scene's polygons (K,4,3), counter-clockwise as the triangles are
    (front = their winding): merged parallelogram pairs first (in face order), then the
    triangles left, as (a, b, c, c)."""
    import networkx as nx

    V = np.asarray(vertices, float)
    F = np.asarray(faces, np.int64).reshape(-1, 3)
    n = check_mesh(V, F, where)
    match, g = [], None
    if merge:
        size = float(np.ptp(V, axis=0).max()) or 1.0
        edges = {}
        for f, (a, b, c) in enumerate(F):
            for u, w in ((a, b), (b, c), (c, a)):
                edges.setdefault((min(u, w), max(u, w)), []).append(f)
        g = nx.Graph()
        for (u, w), fs in edges.items():
            if len(fs) != 2:
                continue
            f1, f2 = fs
            if np.dot(n[f1], n[f2]) < 1 - 1e-6:
                continue
            p = [x for x in F[f1] if x not in (u, w)][0]
            q = [x for x in F[f2] if x not in (u, w)][0]
            if np.linalg.norm(V[p] + V[q] - V[u] - V[w]) <= rel_tol * size:
                g.add_edge(f1, f2, weight=2.0 if abs(f1 - f2) == 1 else 1.0, quad=(p, u, q, w))
        match = sorted(tuple(sorted(m)) for m in nx.max_weight_matching(g, maxcardinality=True))
    out = []
    for f1, f2 in match:
        q = V[list(g.edges[f1, f2]["quad"])]
        if np.dot(np.cross(q[1] - q[0], q[3] - q[0]), n[f1]) < 0:
            q = q[[0, 3, 2, 1]]
        out.append(q)
    paired = np.zeros(len(F), bool)
    paired[[f for m in match for f in m]] = True
    for f in np.flatnonzero(~paired):
        a, b, c = V[F[f]]
        out.append(np.stack([a, b, c, c]))
    return np.array(out)


def mesh_parts(path: str, name: str | None = None) -> list[tuple[str, np.ndarray, np.ndarray,
                                                                     np.ndarray | None]]:
    """A mesh file's parts: (name, vertices (n,3), faces (k,3), file albedo (3,) or None).

    ``name`` names a single-mesh file's part (default: the file's stem)."""
    import trimesh

    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise MeshError(f"{path}: not a mesh file trimesh reads here (one of {', '.join(FORMATS)})")
    try:
        loaded = trimesh.load(path, process=False, maintain_order=True)
    except Exception as e:  # trimesh raises many kinds on a broken file
        raise MeshError(f"{path}: not a readable mesh ({type(e).__name__}: {e})") from None
    stem = name or os.path.splitext(os.path.basename(path))[0]
    if isinstance(loaded, trimesh.Trimesh):
        return [_part(stem, loaded)]
    parts = []
    for node in loaded.graph.nodes_geometry:
        T, gname = loaded.graph[node]
        m = loaded.geometry[gname]
        if not isinstance(m, trimesh.Trimesh):
            continue
        parts.append(_part(str(gname), m.copy().apply_transform(T) if not np.allclose(T, np.eye(4))
                           else m))
    if not parts:
        raise MeshError(f"{path}: the mesh has no faces")
    return parts


def _part(name, m):
    return (name, np.asarray(m.vertices, float), np.asarray(m.faces, np.int64), _albedo(m))


def _albedo(m) -> np.ndarray | None:
    """The file's diffuse colour of a trimesh mesh (MTL Kd, glTF base colour), or None."""
    mat = getattr(getattr(m, "visual", None), "material", None)
    for attr in ("diffuse", "baseColorFactor", "main_color"):
        c = getattr(mat, attr, None)
        if c is not None:
            c = np.asarray(c, float).reshape(-1)[:3]
            return c / 255.0 if c.max() > 1.0 or np.issubdtype(np.asarray(
                getattr(mat, attr)).dtype, np.integer) else c
    return None
