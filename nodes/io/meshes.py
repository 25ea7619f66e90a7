"""LoadMesh / SaveMesh through trimesh (PLY, OBJ, STL, GLB, OFF)."""
from __future__ import annotations

from pathlib import PurePosixPath

from pydantic import field_validator

from graphkit import BadInput, Field, File, InputFile, Mesh, Node, OutputPath
from graphkit.paths import safe_relpath

from .builtin import BuiltinFiles

MESH_EXTS = (".ply", ".obj", ".stl", ".glb", ".off")


class LoadMesh(BuiltinFiles, Node):
    """Read a triangle mesh file with trimesh (vertices are kept as stored: no merging);
    ``builtin:sample_capture/mesh.ply`` names the Paris sample capture's head."""

    builtin_what = "mesh"
    version = "1"
    outputs = {"mesh": Mesh}

    class Params(Node.Params):
        path: InputFile = Field(description="mesh file, relative to the graph file, or builtin:NAME")

    def compute(self):
        import trimesh

        path = self.resolve_file("path", self.params.path, self.ctx.base_dir)
        try:
            m = trimesh.load(path, force="mesh", process=False)
        except Exception as e:  # noqa: BLE001 - trimesh raises many kinds
            raise BadInput("path", f"cannot read mesh {path}: {e}") from None
        if not isinstance(m, trimesh.Trimesh) or len(m.faces) == 0:
            raise BadInput("path", f"{path} holds no triangles")
        return m


class SaveMesh(Node):
    """Write a mesh into the output folder (the extension picks the format)."""

    version = "1"
    inputs = {"mesh": Mesh}
    outputs = {"file": File}

    class Params(Node.Params):
        path: OutputPath = Field(description="file name inside --out, e.g. face.ply")

        @field_validator("path")
        @classmethod
        def _relative(cls, v: str) -> str:
            return safe_relpath(v, MESH_EXTS)

    def compute(self, mesh):
        data = mesh.export(file_type=PurePosixPath(self.params.path).suffix[1:].lower())
        return File(self.params.path, data if isinstance(data, bytes) else data.encode())
