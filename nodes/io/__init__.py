"""Image and mesh files: LoadImage / SaveImage (OpenImageIO), LoadMesh / SaveMesh (trimesh)."""

NODES = {
    "LoadImage": "nodes.io.images:LoadImage",
    "SaveImage": "nodes.io.images:SaveImage",
    "LoadMesh": "nodes.io.meshes:LoadMesh",
    "SaveMesh": "nodes.io.meshes:SaveMesh",
}
