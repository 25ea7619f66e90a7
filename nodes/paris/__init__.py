"""Paris, Sillion, Quan 2003, *Lightweight Face Relighting* (seeds/paris2003_…)."""

NODES = {
    "RatioImage": "nodes.paris.ratio:RatioImage",
    "SkinSegment": "nodes.paris.skin:SkinSegment",
    "ProbeLight": "nodes.paris.probe:ProbeLight",
    "ShininessFromSaturation": "nodes.paris.shininess:ShininessFromSaturation",
    "ReflectanceMap": "nodes.paris.reflectance:ReflectanceMap",
    "FitSkinPhong": "nodes.paris.fit:FitSkinPhong",
    "ShadeFace": "nodes.paris.render:ShadeFace",
    "Render": "nodes.paris.render:Render",
    "MakeLight": "nodes.paris.render:MakeLight",
    "EnvironmentLights": "nodes.paris.environment:EnvironmentLights",
    "LightSize": "nodes.paris.render:LightSize",
    "FrameFace": "nodes.paris.render:FrameFace",
    "MeshMask": "nodes.paris.render:MeshMask",
    "SmoothMesh": "nodes.paris.mesh:SmoothMesh",
    "CompositeFace": "nodes.paris.composite:CompositeFace",
    "FlashAtLens": "nodes.paris.flash:FlashAtLens",
}
