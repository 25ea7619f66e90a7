"""Huang et al. 2013, *Physically based cosmetic rendering* (seeds/huang2013_…).

Kubelka–Munk cosmetic layers (``km``: the one implementation of the maths), the example
cosmetics library (``data/cosmetics.json``) and the nodes below.  See README.md.
"""

NODES: dict[str, str] = {
    "KMLayer": "nodes.huang.layer:KMLayer",
    "KMInvert": "nodes.huang.layer:KMInvert",
    "CosmeticMap": "nodes.huang.layer:CosmeticMap",
    "KMStack": "nodes.huang.stack:KMStack",
    "CosmeticShade": "nodes.huang.shade:CosmeticShade",
}
