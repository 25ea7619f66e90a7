"""relightkit's built-in node library, one sub-package per paper or domain.

Each sub-package lists its node types in a ``NODES`` dict (type name → "module:Class"), which
``pyproject.toml`` registers under the ``graphkit.nodes`` entry-point group — the same
mechanism a third-party plugin uses.  Modules are imported only when a graph uses one of
their node types, so heavy imports stay out of start-up.

* ``io``       image and mesh files (OpenImageIO, trimesh)
* ``common``   shared maths (colour conversions, …) used by several papers
* ``paris``    Paris, Sillion, Quan 2003 — lightweight face relighting
* ``jimenez``  Jimenez et al. 2010 — dynamic facial colour
* ``loscos``   Loscos, Drettakis, Robert 2000 — relighting real scenes with radiosity
* ``huang``    Huang et al. 2013 — physically based cosmetics (Kubelka–Munk)
"""

# Backends of built-in node types that ship inside this package ("NodeType/name": "module:Class").
# Backends that need extra software (OpenCL, OpenGL) live in plugins/ as their own distributions.
BACKENDS: dict[str, str] = {
    # Embree ray casting for the Loscos nodes that cast rays (embreex, a dependency)
    "ProjectTextures/embree": "nodes.loscos.embree:ProjectTexturesEmbree",
    "RadiositySolve/embree": "nodes.loscos.embree:RadiositySolveEmbree",
    "TextureRefine/embree": "nodes.loscos.embree:TextureRefineEmbree",
    "Relight/embree": "nodes.loscos.embree:RelightEmbree",
}
