"""The studio's live view of Relight (Loscos 2000 §5: interactive changes of the real lights).

One slider per real light scales its emittance; each move re-draws the image with Relight's
own linear fast path (``relight.relight_plan`` once, then ``display.modulate_pixels``: per
pixel a weighted sum of the per-light responses, no gathering), so a slider costs well
under a millisecond of arithmetic.  Letting go writes ``light_scale`` into the graph (re-run through the
cache).

A Relight that inserts virtual lights or boxes (§4.5) shows the room at the photograph's
resolution with a handle over each virtual thing: dragging a box moves its bottom centre to the
floor or table point under the pointer through :class:`virtual.VirtualSession` (only the links
whose shafts its old or new bounds cross are re-evaluated, and radiosity is updated, not solved
anew), and letting go writes its ``center`` into ``virtual_boxes`` (the graph re-runs Relight's
full §4.5 path through the cache).  There the light sliders only edit the params.
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

    def _session(self):
        """The virtual things of the params in a VirtualSession (made once per view)."""
        if getattr(self, "_virtual", None) is None:
            from .relight import new_emittance
            from .virtual import VirtualSession, box_thing, light_thing

            v, p = self.inputs(), self.params
            if v.get("camera") is None:
                raise BadInput("camera", "inserting virtual lights or boxes needs the camera")
            sol = v["solution"]
            S = VirtualSession(sol, v["unoccluded"], v["projection"], v["photo"].pixels[:, :, :3],
                               v["camera"], e_real=new_emittance(sol, p.light_scale, p.emittance),
                               rho_fix=p.fixture_reflectance)
            for L in p.virtual_lights:
                S.insert(light_thing(L.name, L.center, L.size, L.normal, L.emittance), "virtual_lights")
            for b in p.virtual_boxes:
                S.insert(box_thing(b.name, b.center, b.size, b.rotation_deg, b.reflectance))
            self._virtual = S
        return self._virtual

    def data(self) -> dict:
        sol, _ = self._prep()
        p = self.params
        sliders = [{"key": n, "label": f"light {n} × emittance", "min": 0.0, "max": 4.0, "step": 0.01,
                    "value": float(p.light_scale.get(n, 1.0)),
                    "description": f"factor on the emittance of real light {n} (0 switches it off)"}
                   for n in sol.lights]
        out = {"sliders": sliders, "fast": self.fast(),
               "note": "" if self.fast() else "this Relight inserts virtual lights or boxes (§4.5): "
                       "drag a box over the floor or a table; the sliders edit light_scale and the "
                       "node re-runs on release"}
        if not self.fast():
            S = self._session()
            H, W = S.plan.photo.shape[:2]
            out.update(room={"width": W, "height": H, "handles": S.handles()})
        return out

    def frame(self, values: dict):
        from .display import modulate_pixels
        from .relight import new_emittance

        sol, prep = self._prep()
        if not self.fast():
            S = self._session()
            d = values.get("drag")
            if d:
                S.move(str(d["name"]), to=floor_point(S, float(d["x"]), float(d["y"]), str(d["name"])))
            return {"image": S.image(), "handles": S.handles(), **S.stats}
        scale = {n: float(values.get(n, self.params.light_scale.get(n, 1.0))) for n in sol.lights}
        e = new_emittance(sol, scale, self.params.emittance)
        return modulate_pixels(prep, e)

    def commit(self, values: dict) -> list[dict]:
        sol, _ = self._prep()
        if values.get("drag"):  # the dragged box's centre (its last good place)
            S = self._session()
            d = values["drag"]
            try:
                S.move(str(d["name"]), to=floor_point(S, float(d["x"]), float(d["y"]), str(d["name"])))
            except BadInput:
                pass  # refused (a wall, no floor under the pointer): it stays where it was
            boxes = []
            for b in self.params.virtual_boxes:
                d = b.model_dump()
                if b.name in S.things:
                    t = S.things[b.name].thing
                    d["center"] = [round(float(x), 4) for x in 0.5 * (t.lo + t.hi)]
                d["size"], d["reflectance"] = list(d["size"]), list(d["reflectance"])
                boxes.append(d)
            return self.change(self.node, "virtual_boxes", boxes)
        scale = {n: round(float(v), 4) for n, v in values.items() if n in sol.lights and abs(float(v) - 1.0) > 1e-9}
        return self.change(self.node, "light_scale", scale)


def floor_point(S, x: float, y: float, name: str) -> np.ndarray:
    """The point of a floor or table top (a real polygon facing up, +y) under image point
    (x, y); BadInput naming the object when the pointer is elsewhere."""
    from .geometry import ray_first_hit
    from .textures import rays_at

    o, d = rays_at(S.camera, np.array([x]), np.array([y]))
    idx, t, _, _ = ray_first_hit(o, d, *S.occ, two_sided=True)
    n = S.h.P_n[idx[0]] if idx[0] >= 0 else np.zeros(3)
    if idx[0] < 0 or -np.sign(n @ d[0]) * n[1] < 0.9:  # its side that the camera sees, facing up
        raise BadInput("virtual_boxes", f"virtual object '{name}': the pointer ({x:.0f}, {y:.0f}) "
                                        "is not over a floor or a table top")
    return o[0] + t[0] * d[0]
