"""SmoothMesh — a smooth face surface from a coarse mesh (Paris 2003 §6, Fig. 13)."""
from __future__ import annotations

import numpy as np

from graphkit import Field, In, Mesh, Node, Out

from .checks import check_mesh


class SmoothMesh(Node):
    """Loop subdivision (trimesh ``remesh.subdivide_loop``) of a coarse face mesh, with smooth
    area-weighted vertex normals of the result (Paris 2003 §6: the detail texture of a coarse
    mesh).

    The detail texture is the photo divided by the shaded face (§3); when the shaded face is
    drawn on a coarse mesh (the 852-triangle FaceMesh) its interpolated normals bend at every
    edge, and those creases show as light and dark lines in the detail texture and in every
    relit image.  Loop subdivision converges to a surface with continuous tangent planes, so
    after ``iterations`` steps (4× the triangles each) the normals vary smoothly across the
    old edges.  Boundary loops (the face's outline, the eyes, the mouth) follow Loop's boundary
    rule.  The surface moves slightly inwards where the coarse mesh is curved (the limit
    surface of an approximating scheme).

    The first N vertices of the output are the N input vertices (moved by the scheme); the
    vertex attribute ``source_vertex`` holds each output vertex's input index (−1 for the new
    ones), so nodes that know a vertex topology (Render's mediapipe eye contours) still find
    it.  Units: those of the mesh.
    """

    version = "1"
    inputs = {"mesh": In(Mesh, "coarse triangle mesh", finite=True)}
    outputs = {"mesh": Out(Mesh, "subdivided mesh, smooth normals")}

    class Params(Node.Params):
        iterations: int = Field(2, ge=0, le=5, description="Loop subdivision steps (×4 triangles each)")

    def compute(self, mesh):
        import trimesh

        check_mesh(mesh)
        V = np.asarray(mesh.vertices, np.float64)
        F = np.asarray(mesh.faces, np.int64)
        src = np.asarray(mesh.vertex_attributes.get("source_vertex", np.arange(len(V))), np.int64)
        if self.params.iterations:
            V2, F2 = trimesh.remesh.subdivide_loop(V, F, iterations=self.params.iterations)
        else:
            V2, F2 = V, F
        out = trimesh.Trimesh(np.asarray(V2, np.float64), np.asarray(F2, np.int64), process=False)
        s2 = np.full(len(V2), -1, np.int64)
        s2[:len(V)] = src
        out.vertex_attributes["source_vertex"] = s2
        return out
