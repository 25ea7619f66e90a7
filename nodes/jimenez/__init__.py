"""Jimenez et al. 2010, *A Practical Appearance Model for Dynamic Facial Color* (seeds/jimenez2010_…)."""

NODES: dict[str, str] = {
    "SkinChromophores": "nodes.jimenez.chromophores:SkinChromophores",
    "ApplyHemoglobin": "nodes.jimenez.chromophores:ApplyHemoglobin",
    "LocalHistMatch": "nodes.jimenez.histmatch:LocalHistMatch",
    "AppearanceRig": "nodes.jimenez.histmatch:AppearanceRig",
    "FlushTarget": "nodes.jimenez.histmatch:FlushTarget",
    "SkinColorLUT": "nodes.jimenez.skinlut:SkinColorLUT",
    "SkinShade": "nodes.jimenez.shade:SkinShade",
    "ScatterRelit": "nodes.jimenez.scatter:ScatterRelit",
}
