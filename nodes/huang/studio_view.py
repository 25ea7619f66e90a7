"""The studio's live view of CosmeticShade and KMStack (Huang 2013: real-time makeup).

One slider per layer scales that layer's thickness map; each move runs the node's own
compute on the whole photo, so a change can be seen at once (CosmeticShade keeps what does not
depend on the map — surface, SSS plan, specular terms — between moves, and shades only the box
of the layers and the skin).  Letting go writes the new thicknesses into the CosmeticMap that makes
the map (its ``thickness_mm``, or the graph params it is bound to) and the graph re-runs
through the cache.
"""
from __future__ import annotations

import numpy as np

from graphkit import Image
from graphkit.studio import LiveView


class MakeupView(LiveView):
    title = "makeup layers"
    js = "studio_view.js"

    def _setup(self):
        if getattr(self, "_inputs", None) is None:
            self._inputs = {k: x for k, x in self.inputs().items() if x is not None}
            self._t = self._inputs["thickness"].pixels.astype(np.float32)
        return self._inputs

    def _names(self) -> list[str]:
        n = self._t.shape[2]
        cos = list(getattr(self.params, "cosmetics", []) or [])
        return [cos[i] if i < len(cos) else f"layer {i}" for i in range(n)]

    def data(self) -> dict:
        self._setup()
        y, x = self._t.shape[:2]
        return {"sliders": [{"key": f"layer{i}", "label": f"{name} × thickness", "min": 0.0, "max": 4.0,
                             "step": 0.01, "value": 1.0,
                             "description": f"factor on the thickness map of layer {i} ({name}), mm"}
                            for i, name in enumerate(self._names())],
                "note": f"preview: the node on the whole {x}×{y} photo"}

    def frame(self, values: dict):
        given = self._setup()
        f = np.array([float(values.get(f"layer{i}", 1.0)) for i in range(self._t.shape[2])], np.float32)
        out = self.compute(**{**given, "thickness": Image(self._t * f)})
        img = out["image"] if "image" in out else out["reflectance"]
        return img

    def commit(self, values: dict) -> list[dict]:
        g = self.studio.graph
        src = self.gnode.inputs.get("thickness")
        if not src or g.nodes[src[0]].type != "CosmeticMap":
            return []
        mp = g.nodes[src[0]]
        old = list(mp.params.thickness_mm)
        new = [round(float(t) * float(values.get(f"layer{i}", 1.0)), 6) for i, t in enumerate(old)]
        return self.change(src[0], "thickness_mm", new)
