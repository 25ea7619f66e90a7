"""Image and mesh files: LoadImage / SaveImage (OpenImageIO), LoadPhoto (8-bit sRGB photos), LoadEnvironment (equirectangular HDR maps), LoadMesh / SaveMesh (trimesh);
ContactSheet lays images out for a person to look at, AnimatedPreview plays them (GIF); Blur
smooths an image."""

NODES = {
    "LoadImage": "nodes.io.images:LoadImage",
    "LoadEnvironment": "nodes.io.environment:LoadEnvironment",
    "LoadPhoto": "nodes.io.photo:LoadPhoto",
    "SaveImage": "nodes.io.images:SaveImage",
    "LoadMesh": "nodes.io.meshes:LoadMesh",
    "SaveMesh": "nodes.io.meshes:SaveMesh",
    "ContactSheet": "nodes.io.sheet:ContactSheet",
    "AnimatedPreview": "nodes.io.animation:AnimatedPreview",
    "Blur": "nodes.io.filters:Blur",
    "LoadCameraJson": "nodes.io.cameras:LoadCameraJson",
}
