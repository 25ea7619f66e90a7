"""The ``embree`` backends of the Loscos nodes that cast rays (``--backend embree``).

Each runs the node's own compute unchanged with its rays cast by Intel Embree
(:func:`nodes.common.rays.using`): ProjectTextures (texel → camera), RadiositySolve and
TextureRefine (the links' attenuation factors V, §2.3), Relight (the links re-evaluated around
virtual polygons, §4.5).  Unocclude casts no ray: its blocked light is the solution's links'
V, so it follows the backend that solved them.  The numpy compute is the reference;
``graphkit conform`` checks these against it on :func:`ray_examples` (a small room with a box
that casts shadows).
"""
from __future__ import annotations

import functools

import numpy as np

from graphkit import Backend, Context, Image
from nodes.common import rays


class _Embree(Backend):
    name = "embree"
    version = "1"
    #: float32 ray-triangle tests against the float64 reference: a ray that grazes a polygon's
    #: edge may answer otherwise, and the values it lights move a little
    tolerance = {"rtol": 1e-4, "atol": 1e-5}

    @classmethod
    def available(cls) -> bool:
        return rays.embree_missing() is None

    @classmethod
    def why_unavailable(cls) -> str:
        return rays.embree_missing() or ""

    def compute(self, **inputs):
        from graphkit.registry import default_registry

        node = default_registry().node_class(self.node)  # the node type's own compute
        with rays.using("embree"):
            return node(self.params, self.ctx).compute(**inputs)


class ProjectTexturesEmbree(_Embree):
    node = "ProjectTextures"


class RadiositySolveEmbree(_Embree):
    node = "RadiositySolve"


class TextureRefineEmbree(_Embree):
    node = "TextureRefine"


class RelightEmbree(_Embree):
    node = "Relight"


@functools.lru_cache(maxsize=1)
def ray_examples() -> dict:
    """Inputs of the ray-casting nodes' examples (made once per process): a 2 m room open at the
    front, two ceiling lights and a box on the floor that shadows the floor and the walls;
    40×32 px.  {"scene", "camera", "photo", "projection", "solution", "refined"}."""
    from .radiosity import RadiositySolve, TextureRefine
    from .scene import example_room
    from .textures import ProjectTextures

    box = [[0.25, 0, 0, -0.2], [0, 0.3, 0, -0.7], [0, 0, 0.25, -0.3], [0, 0, 0, 1]]
    sc, cam, photo = example_room(box)

    def run(node, params, **kw):
        return node(node.Params(**params), Context()).compute(**kw)

    pr = run(ProjectTextures, RAY_PARAMS["ProjectTextures"], scene=sc, camera=cam, photo=photo)
    sol = run(RadiositySolve, RAY_PARAMS["RadiositySolve"], scene=sc, projection=pr)["solution"]
    ref = run(TextureRefine, RAY_PARAMS["TextureRefine"], scene=sc, solution=sol, projection=pr)
    return {"scene": sc, "camera": cam, "photo": photo, "projection": pr, "solution": sol,
            "refined": ref}


RAY_PARAMS = {"ProjectTextures": {"resolution": 8},
              "RadiositySolve": {"eps_bf": 0.5, "eps_bfv": 0.05, "min_area": 0.02, "max_level": 4},
              "TextureRefine": {"max_level": 4, "min_area": 0.01, "max_rounds": 1}}
