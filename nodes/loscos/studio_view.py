"""The studio's live view of Relight (Loscos 2000 §5: interactive changes of the real lights).

One slider per real light scales its emittance; each move re-draws the image with Relight's
own linear fast path (``relight.relight_plan`` once, then ``display.modulate_pixels``: per
pixel a weighted sum of the per-light responses, no gathering), so a slider costs well
under a millisecond of arithmetic.  Letting go writes ``light_scale`` into the graph (re-run through the
cache).  A Relight that inserts virtual lights or boxes (§4.5) needs its full compute: there
the sliders only edit the params, and the graph re-runs on release.
"""
from __future__ import annotations

import numpy as np

from graphkit import BadInput
from graphkit.studio import LiveView


class RoomView(LiveView):
    title = "room lights (Relight fast path)"
    js = "studio_view.js"

    def _prep(self):
        if getattr(self, "_prepared", None) is None:
            from .relight import relight_plan

            v = self.inputs()
            self._sol = v["solution"]
            self._prepared = relight_plan(v["solution"], v["unoccluded"], v["projection"],
                                          v["photo"].pixels[:, :, :3],
                                          self.params.fixture_reflectance)
        return self._sol, self._prepared

    def fast(self) -> bool:
        p = self.params
        return not (p.virtual_lights or p.virtual_boxes)

    def data(self) -> dict:
        sol, _ = self._prep()
        p = self.params
        sliders = [{"key": n, "label": f"light {n} × emittance", "min": 0.0, "max": 4.0, "step": 0.01,
                    "value": float(p.light_scale.get(n, 1.0)),
                    "description": f"factor on the emittance of real light {n} (0 switches it off)"}
                   for n in sol.lights]
        return {"sliders": sliders, "fast": self.fast(),
                "note": "" if self.fast() else "this Relight inserts virtual lights or boxes (§4.5): "
                        "the sliders edit light_scale and the node re-runs on release"}

    def frame(self, values: dict):
        from .display import modulate_pixels
        from .relight import new_emittance

        sol, prep = self._prep()
        if not self.fast():
            raise BadInput("light_scale", "no fast path with virtual lights or boxes")
        scale = {n: float(values.get(n, self.params.light_scale.get(n, 1.0))) for n in sol.lights}
        e = new_emittance(sol, scale, self.params.emittance)
        return modulate_pixels(prep, e)

    def commit(self, values: dict) -> list[dict]:
        sol, _ = self._prep()
        scale = {n: round(float(v), 4) for n, v in values.items() if n in sol.lights and abs(float(v) - 1.0) > 1e-9}
        return self.change(self.node, "light_scale", scale)
