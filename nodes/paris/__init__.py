"""Paris, Sillion, Quan 2003, *Lightweight Face Relighting* (seeds/paris2003_…)."""

NODES = {
    "RatioImage": "nodes.paris.ratio:RatioImage",
    "SkinSegment": "nodes.paris.skin:SkinSegment",
}
