"""The studio's live view of AppearanceRig (Jimenez 2010 §4.2, eq. 6: real-time blush).

Sliders for the rig weights w_1 … w_k (w_0 = 1 − Σ, so the weights sum to one as eq. 6
asks) and the global hemoglobin scale.  Each move runs the rig's own compute and the
ApplyHemoglobin that reads its output (Beer–Lambert recolouring of the photo) on the whole
photo, so a change can be seen at once.  Letting go writes ``weights`` and
``hemoglobin_scale`` (or the graph params they are bound to) and the graph re-runs through
the cache.
"""
from __future__ import annotations

from graphkit import BadInput
from graphkit.node import Context
from graphkit.studio import LiveView


class BlushView(LiveView):
    title = "blush rig"
    js = "studio_view.js"

    def _setup(self):
        if getattr(self, "_ready", None) is None:
            g = self.studio.graph
            apply = [n for n, p in self.consumers(self.node, "hemoglobin")
                     if g.nodes[n].type == "ApplyHemoglobin" and p == "new_hemoglobin"]
            if not apply:
                raise BadInput("hemoglobin", "no ApplyHemoglobin reads this rig: nothing to show")
            self._apply = apply[0]
            rig_in = self.inputs()
            ap_in = self.studio.input_values(self._apply)
            if ap_in is None:
                raise BadInput("hemoglobin", f"'{self._apply}' has not run yet")
            if rig_in["neutral"].pixels.shape[:2] != ap_in["image"].pixels.shape[:2]:
                raise BadInput("neutral", "the rig's maps are not the photo's size")
            self._rig = rig_in
            self._ap = {k: v for k, v in ap_in.items() if k != "new_hemoglobin"}
            self._ready = True

    def data(self) -> dict:
        self._setup()
        p = self.params
        k = len(p.weights) - 1
        sl = [{"key": f"w{i}", "label": f"w_{i}" + (" (flush)" if k == 1 else ""), "min": 0.0, "max": 1.0,
               "step": 0.01, "value": float(p.weights[i]),
               "description": f"weight of basis entry {i} (w_0 = 1 − the others, eq. 6)"} for i in range(1, k + 1)]
        sl.append({"key": "hemoglobin_scale", "label": "hemoglobin scale", "min": 0.0, "max": 2.0, "step": 0.01,
                   "value": float(p.hemoglobin_scale), "description": "global factor (1.27 anger, 0.81 fear; §7)"})
        h, w = self._ap["image"].pixels.shape[:2]
        return {"sliders": sl, "note": f"preview: '{self.node}' → '{self._apply}' on the whole {w}×{h} photo"}

    def _params(self, values):
        p = self.params
        k = len(p.weights) - 1
        w = [float(values.get(f"w{i}", p.weights[i])) for i in range(1, k + 1)]
        return [1.0 - sum(w)] + w, float(values.get("hemoglobin_scale", p.hemoglobin_scale))

    def frame(self, values: dict):
        self._setup()
        w, hs = self._params(values)
        if w[0] < -1e-9:
            raise BadInput("weights", f"w_1 … w_k sum to {1 - w[0]:.3g} > 1: w_0 would be negative")
        rig = self.gnode.cls(self.params.model_copy(update={"weights": w, "hemoglobin_scale": hs}),
                             Context(node=self.node))
        h = rig.compute(**self._rig)
        ap = self.studio.graph.nodes[self._apply]
        return ap.cls(ap.params, Context(node=self._apply)).compute(**self._ap, new_hemoglobin=h)

    def commit(self, values: dict) -> list[dict]:
        w, hs = self._params(values)
        w = [round(x, 6) for x in w]
        return self.change(self.node, "weights", w) + self.change(self.node, "hemoglobin_scale", round(hs, 6))
