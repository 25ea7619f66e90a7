"""The studio's live view of CosmeticShade and KMStack (Huang 2013: real-time makeup).

One slider per layer scales that layer's thickness map; each move runs the node's own
compute on a crop around the face (the ``skin`` mask, else where any layer is), so a change
can be seen at once.  Letting go writes the new thicknesses into the CosmeticMap that makes
the map (its ``thickness_mm``, or the graph params it is bound to) and the graph re-runs
through the cache.
"""
from __future__ import annotations

import numpy as np

from graphkit import Image
from graphkit.studio import LiveView


class MakeupView(LiveView):
    title = "makeup layers (face crop)"
    js = "studio_view.js"

    def _setup(self):
        if getattr(self, "_crop", None) is None:
            v = {k: x for k, x in self.inputs().items() if x is not None}
            t = v["thickness"].pixels
            skin = v.get("skin")
            weights = skin.alpha if skin is not None else t.sum(axis=2)
            box = self.crop_box(weights, margin=0.08)
            self._crop = self.crop_inputs(v, box, t.shape[:2])
            self._t = self._crop["thickness"].pixels.astype(np.float32)
        return self._crop

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
                "note": f"preview: the node on a {x}×{y} crop around the face"}

    def frame(self, values: dict):
        crop = self._setup()
        f = np.array([float(values.get(f"layer{i}", 1.0)) for i in range(self._t.shape[2])], np.float32)
        out = self.compute(**{**crop, "thickness": Image(self._t * f)})
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
