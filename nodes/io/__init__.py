"""Image and mesh files: LoadImage / SaveImage (OpenImageIO), LoadMesh / SaveMesh (trimesh);
ContactSheet lays images out for a person to look at."""

NODES = {
    "LoadImage": "nodes.io.images:LoadImage",
    "SaveImage": "nodes.io.images:SaveImage",
    "LoadMesh": "nodes.io.meshes:LoadMesh",
    "SaveMesh": "nodes.io.meshes:SaveMesh",
    "ContactSheet": "nodes.io.sheet:ContactSheet",
    "LoadCameraJson": "nodes.io.cameras:LoadCameraJson",
}
