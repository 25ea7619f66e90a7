"""The studio's live view of Render (Paris 2003 §5): the face relit in the browser with WebGL2.

The page draws the §5 model (Phong × detail texture, shadow maps, eye highlights, exposure and
the clamp) itself, with the programs of ``shaders/glsl/`` preprocessed for GLSL ES 3.00 by
``graphkit.glsl`` (the same source the moderngl backend compiles as GLSL 3.30), from the scene
``nodes.paris.glscene.scene`` prepares from the node's inputs as the current run computed them
(the mesh, detail texture, material and camera) — the same arrays and uniforms the opengl
backend uses.  The first light is dragged on a sphere widget (direction, intensity, colour):
each change makes it a directional light whose uniforms and shadow-map frame the page computes
itself (studio_view.js lightFrame, float64, from :meth:`FaceView._frame_constants`: the
formulas of :meth:`FaceView.frame`, which the page asks instead where a value is not valid, for
its error; tests/test_studio_face.py compares the two), then re-renders the shadow map and the
lighting pass; the surface pass is kept.  Letting go writes nothing: the lights are other nodes' outputs.

Also here: CompositeFace's view (:class:`CompositeView`, the whole photo relit as a light moves)
and ProbeLight's (:class:`ProbeView`, the mirror ball marked by hand).
"""
from __future__ import annotations

import base64

import numpy as np

from graphkit import BadInput, Light
from graphkit.studio import LiveView


def _arr(a, dtype="f4"):
    a = np.ascontiguousarray(np.asarray(a, dtype=dtype))
    return {"b64": base64.b64encode(a.astype("<" + dtype).tobytes()).decode(), "dtype": dtype,
            "shape": list(a.shape)}


def _mat(m):
    """A matrix, column-major (as GLSL takes it)."""
    return [float(x) for x in np.asarray(m, np.float64).T.ravel()]


def _vec(v):
    return [float(x) for x in np.asarray(v, np.float64).ravel()]


def _window_depth_map(clip) -> list:
    """(a, b, c) with window depth = a + b·z + c/z for light-frame depth z under the clip matrix
    ``clip`` (its z row (0, 0, P22, P23); w = 1 (orthographic) or z (perspective)) and GL's
    default depth range: shade.frag's SM_WINDOW."""
    P = np.asarray(clip, np.float64)
    if P[3, 2] == 0.0:  # orthographic: z_ndc = P22 z + P23
        return [0.5 + 0.5 * P[2, 3], 0.5 * P[2, 2], 0.0]
    return [0.5 + 0.5 * P[2, 2], 0.0, 0.5 * P[2, 3]]  # perspective: z_ndc = P22 + P23 / z


class FaceView(LiveView):
    title = "face relighting (WebGL2, Paris §5)"
    js = "studio_view.js"

    def _lights(self, values: dict, lights=None):
        lights = list(self.inputs()["lights"] if lights is None else lights)
        if not lights:
            raise BadInput("lights", "no light to drag")
        l0 = lights[0]
        if values:
            upd = {}
            if "direction" in values:
                d = np.asarray(values["direction"], np.float64)
                if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
                    raise BadInput("direction", f"not a direction: {values['direction']!r}")
                upd["direction"] = tuple(d / np.linalg.norm(d))
                upd["kind"] = "directional"
            if "intensity" in values:
                upd["intensity"] = float(values["intensity"])
            if "color" in values:
                upd["color"] = tuple(float(c) for c in values["color"])
            lights[0] = Light(**{**l0.model_dump(), **upd})
        return lights

    def _scene(self, values: dict):
        from .glscene import scene

        v = self.inputs()
        if v.get("environment") is not None:
            raise BadInput("environment", "the WebGL face view does not draw an environment's "
                                          "spherical-harmonic ambient: follow the node's output "
                                          "(e.g. LoadEnvironment's rotation slider) instead")
        return scene(self.params, v["mesh"], v["camera"], v["material"], self._lights(values),
                     v.get("detail"), v.get("texture_camera"), v.get("ambient"))

    def _light_part(self, job, p, n_faces: int):
        """The lights' uniforms and shadow-map frames for the page.  A shadow map is drawn
        from the drawn mesh's world positions (depth.vert WORLD: ``world_clip`` = the light's
        clip matrix × its frame, float64 on the host) into a depth texture (shade.frag
        SM_WINDOW: ``zmap``); its faces are sent only where the light's frame drops some of
        the mesh's ``n_faces`` faces (a point light with vertices behind it)."""
        out = {"lights": [{"kind": int(k), "dir": _vec(d), "pos": _vec(pos), "rgb": _vec(rgb)}
                          for k, d, pos, rgb in job["lights"]]}
        if job["shadow"] is not None:
            out["shadow"] = [None if sm is None else {
                "to_light": _mat(sm["to_light"]), "proj": _vec(sm["proj"]), "bias": _vec(sm["bias"]),
                "world_clip": _mat(np.asarray(sm["clip"]) @ np.asarray(sm["to_light"])),
                "zmap": _window_depth_map(sm["clip"]),
                "faces": None if len(sm["faces"]) == n_faces else _arr(sm["faces"], "u4")}
                for sm in job["shadow"]]
            out["shadow_map_size"] = int(p.shadow_map_size)
        return out

    def data(self) -> dict:
        from graphkit.glsl import source

        from .glscene import not_drawn

        job, lights, _, eyes = self._scene({})
        p = self.params
        cam = self.inputs()["camera"]
        kd, i_s, s, amb = job["material"]
        nl = max(len(job["lights"]), 1)
        ortho = int(bool(job["cam_ortho"]))
        det = job["detail"]
        d = {"W": job["W"], "H": job["H"], "vertices": _arr(job["vertices"]),
             "faces": _arr(job["main"][1], "u4"), "clip": _mat(job["main"][0]),
             "cam_pos": _vec(job["cam_pos"]), "cam_back": _vec(job["cam_back"]),
             "cam_rotation": _mat(cam.rotation.T),  # row-major rotation (world → camera)
             "kd": _vec(kd), "i_s": i_s, "shininess": s, "ambient": _vec(amb),
             "background": _vec(p.background), "exposure": float(p.exposure), "clamp": bool(p.clamp),
             "bbox": [int(x) for x in job["bbox"]], "bg_out": _vec(job["bg_out"]),
             "ray_org": _mat(job["ray_org"]), "ray_dir": _mat(job["ray_dir"]),  # each pixel's world ray
             "boxes": [[int(x) for x in b] for b in job["boxes"]],  # eyes: _eye_boxes
             "mesh_faces": _arr(job["mesh_faces"], "u4"),
             **self._light_part(job, p, len(job["mesh_faces"])),
             # what the page does not draw (glscene.not_drawn): said above the picture, never silent
             "not_drawn": not_drawn(p, self.inputs()["mesh"], self.inputs().get("lights") or ())}
        if det is not None:
            tc = det["cam"]
            d["detail"] = {"pixels": _arr(det["pixels"]), "size": [int(tc.width), int(tc.height)],
                           "proj": _mat(det["proj"]), "tol": float(det["tol"]), "q": _arr(det["q"]),
                           "faces": _arr(det["geom"][1], "u4"), "clip": _mat(det["geom"][0])}
        if eyes is not None:
            c, a, R = eyes
            d["eyes"] = {"c": _vec(c), "axis": _vec(a), "R": float(R), "s": float(p.eye_shininess),
                         "ks": float(p.eye_specular), "fwd": _vec(job["fwd"])}
        # SM_BILINEAR: the 3×3 PCF as 4 depth-compare samples of the power-of-two atlas (the
        # same count as 9 fetches, exactly; shade.frag); glsl_taps below: the 9 fetches (tests)
        defs = {"N_LIGHTS": nl, "ORTHO": ortho, "SHADOWS": int(job["shadow"] is not None), "EYES": 0,
                "SM_WINDOW": 1, "SM_BILINEAR": 1}
        # EXACT: the surface pass intersects each pixel's ray (ray_org, ray_dir) with the exact
        # triangle (SwiftShader snaps vertices to 1/16 px; see gbuffer.frag)
        gdefs = {"ORTHO": ortho, "DETAIL": int(det is not None), "EXACT": 1}
        d["glsl"] = {
            "depth": [source("depth.vert", "es300"), source("depth.frag", "es300")],
            "shadow": [source("depth.vert", "es300", {"WORLD": 1}), source("depth.frag", "es300", {"DEPTH_ONLY": 1})],
            "gbuffer": [source("gbuffer.vert", "es300", gdefs), source("gbuffer.frag", "es300", gdefs)],
            # the lighting pass over the covered pixels' rectangles (studio_view.js coverRects)
            "shade": [source("rects.vert", "es300", defs), source("shade.frag", "es300", defs)],
            "display": [source("screen.vert", "es300"), source("display.frag", "es300")],
        }
        # the view's frames: the same lighting pass straight onto the canvas (DISPLAY); the
        # float programs above are what readImage() reads back
        d["glsl"]["shade_display"] = [source("rects.vert", "es300", {**defs, "DISPLAY": 1}),
                                      source("shade.frag", "es300", {**defs, "DISPLAY": 1})]
        if eyes is not None:  # drawn over the eyes' boxes only (_eye_boxes)
            for k, extra in (("shade_eyes", {}), ("shade_eyes_display", {"DISPLAY": 1})):
                d["glsl"][k] = [source("screen.vert", "es300", {**defs, "EYES": 1, **extra}),
                                source("shade.frag", "es300", {**defs, "EYES": 1, **extra})]
            d["eye_boxes"], d["boxes"] = self._eye_boxes(job, cam)
        # the lighting programs again with DIRECTIONAL (lights.glsl: the point-light code left
        # out), used while every light is directional (always once a drag has made light 0 one)
        d["glsl_directional"] = {
            k: [src if i == 0 else source("shade.frag", "es300", {**defs, "DIRECTIONAL": 1,
                                                                  "EYES": int("eyes" in k),
                                                                  "DISPLAY": int("display" in k)})
                for i, src in enumerate(d["glsl"][k])]
            for k in ("shade", "shade_display", "shade_eyes", "shade_eyes_display") if k in d["glsl"]}
        # the general lighting programs with the 9 texel fetches of the PCF instead (SM_BILINEAR
        # 0), for readImage('taps'): tests/test_studio_face.py checks the image is the same
        d["glsl_taps"] = {
            k: [src if i == 0 else source("shade.frag", "es300", {**defs, "SM_BILINEAR": 0,
                                                                  "EYES": int("eyes" in k)})
                for i, src in enumerate(d["glsl"][k])]
            for k in ("shade", "shade_eyes") if k in d["glsl"]}
        l0 = lights[0]
        d["light"] = {"direction": _vec(l0.direction), "intensity": float(l0.intensity),
                      "color": _vec(l0.color), "kind": l0.kind,
                      # as given (metres): what frame() keeps of it when it makes light 0 directional
                      "position": _vec(self._lights({})[0].position)}
        d["light_frame"] = self._frame_constants()
        return d

    @staticmethod
    def _eye_boxes(job, camera):
        """(the eyes' boxes, the mesh's boxes without them): one screen box per eye (its
        cornea sphere's cube, glscene.screen_box; every pixel whose ray meets that sphere is
        in it), not glscene's one box round both (213×64 pixels at face_relight left60 512²,
        most of it the nose between the eyes), so the eyes' program (the heavier one) shades
        less and the mesh's rectangles (coverRects) the rest."""
        from .glscene import _eye_cube_corners, box_minus, screen_box

        c, a, R = job["eyes"]
        eyes = [screen_box(camera, camera.to_camera(_eye_cube_corners((np.asarray(c)[k:k + 1], a, R))))
                for k in range(len(c))]
        boxes = [job["bbox"]]
        for e in eyes:
            boxes = [q for b in boxes for q in box_minus(b, e)]
        return [[int(x) for x in e] for e in eyes if e[2] > 0 and e[3] > 0], [[int(x) for x in b] for b in boxes]

    def _frame_constants(self) -> dict:
        """What the page needs to compute light 0's part itself when a drag makes it a
        directional light (studio_view.js lightFrame: the same formulas as frame() here, i.e.
        glscene.light_part → _shadow_setup → raster.shadow_frame, in float64): the drawn mesh's
        float64 vertices (the light frame fits them all; its depth range the ones its faces
        use), the camera's y axis (the map's up) and the shadow map's margin and size."""
        from .glscene import SHADOW_MARGIN, used_vertices

        camera, _, V, F, _ = self._mesh_for_lights()
        used = used_vertices(F, len(V))
        return {"V": _arr(V, "f8"), "used": None if len(used) == len(V) else _arr(used, "u4"),
                "up": _vec(camera.rotation[1]),
                "margin": SHADOW_MARGIN,
                "size": int(self.params.shadow_map_size)}

    def _mesh_for_lights(self):
        """(camera, drawn mesh, its vertices, faces), kept while the node's inputs are the same
        values (their digests): a drag recomputes only the lights' uniforms and shadow frames."""
        from .render import prepare_render

        g = self.studio.graph
        key = repr(g.nodes[self.node].map_inputs(
            lambda src, sport: (self.studio.nodes.get(src) or {}).get("digests", {}).get(sport)))
        if getattr(self, "_kept", None) is None or self._kept[0] != key:
            v = self.inputs()
            _, m = prepare_render(v["mesh"], v["camera"], v["lights"], v.get("detail"),
                                  v.get("texture_camera"), self.params.fill_holes)
            self._kept = (key, v["camera"], m, np.asarray(m.vertices, np.float64),
                          np.asarray(m.faces, np.int64).reshape(-1, 3), v["lights"])
        return self._kept[1:]

    def frame(self, values: dict):
        from .glscene import light_part
        from .render import check_render_inputs, world_lights

        camera, m, V, F, given = self._mesh_for_lights()
        lights = world_lights(check_render_inputs(self._lights(values, given), None, None), camera, m)
        part, _ = light_part(self.params, V, F, lights, camera.rotation[1])
        return {"image": np.zeros((1, 1, 3), np.float32), "scene": self._light_part(part, self.params, len(F))}


class CompositeView(LiveView):
    """The studio's live view of CompositeFace: the whole photograph relit as the first light of
    the Render that feeds ``relit`` is moved (azimuth and elevation about the photo camera's
    axis, MakeLight's convention).  Each move re-renders the face with that light (Render keeps
    its light-independent work between calls) and composites it (CompositeFace keeps its
    feather and fill plan), on the server: the frame is the node's own output — for a photo
    over ``PREVIEW_MAX_PX``, its output on the photo reduced by a whole factor (the face rendered
    through the camera reduced alike, feather and scale in pixels alike), so that a phone's
    12 megapixels follow a slider too.  Letting go sets the angles of the MakeLight that gives
    that light, when one does, and the graph then runs at full size."""

    #: the most pixels a frame is made on (a 12-megapixel phone photo: 1344×1008, a third of
    #: its width); benchmarks/bench_live_views.py --views composite --size N
    PREVIEW_MAX_PX = 1_500_000

    title = "the whole photograph relit"
    js = "composite_view.js"

    def _source(self):
        """(the Render node feeding ``relit``, its first light's node) — BadInput otherwise."""
        g = self.studio.graph
        src = self.gnode.inputs.get("relit")
        if not src or g.nodes[src[0]].type != "Render":
            raise BadInput("relit", "the live view moves the light of the Render that gives `relit`; "
                                    "connect a Render's image there")
        lights = g.nodes[src[0]].inputs.get("lights") or []
        return src[0], (lights[0][0] if lights else None)

    def _angles(self) -> tuple[float, float]:
        _, light = self._source()
        if light is not None and self.studio.graph.nodes[light].type == "MakeLight":
            p = self.studio.graph.nodes[light].params
            return float(p.azimuth_deg), float(p.elevation_deg)
        return 0.0, 0.0

    def data(self) -> dict:
        az, el = self._angles()
        k = self._factor()
        return {"sliders": [
            {"key": "azimuth", "label": "light azimuth (°)", "min": -90.0, "max": 90.0, "step": 1.0, "value": az,
             "description": "towards the image's right, about the photo camera's axis"},
            {"key": "elevation", "label": "light elevation (°)", "min": -60.0, "max": 80.0, "step": 1.0,
             "value": el, "description": "up, about the photo camera's axis"}],
            "note": "preview: Render with the first light moved, then this node, on the whole photo"
                    + (f" (reduced {k}× for the preview; letting go runs it at full size)" if k > 1 else "")}

    def _factor(self) -> int:
        """The whole factor the photo is reduced by for frames (1: its own size)."""
        from graphkit.studio.views import NotReady

        try:
            h, w = self.inputs()["photo"].pixels.shape[:2]
        except NotReady:  # not computed yet: the note says so once it is
            return 1
        return preview_factor(h, w, self.PREVIEW_MAX_PX)

    def frame(self, values: dict):
        from .render import MakeLight, Render

        render, _ = self._source()
        given = self.studio.input_values(render)
        if given is None:
            raise BadInput("relit", f"node '{render}': its inputs are not computed yet (run the graph first)")
        az, el = self._angles()
        old = given["lights"][0]
        light = MakeLight(MakeLight.Params(azimuth_deg=float(values.get("azimuth", az)),
                                           elevation_deg=float(values.get("elevation", el)),
                                           color=old.color, intensity=old.intensity, ambient=old.ambient)
                          ).compute(camera=given["camera"])
        photo, params = self.inputs()["photo"], None
        n = preview_factor(*photo.pixels.shape[:2], self.PREVIEW_MAX_PX)
        if n > 1:
            photo, given = self._reduced(photo, n), {**given, "camera": reduced_camera(given["camera"], n)}
            p = self.params
            params = p.model_copy(update={"feather": p.feather and p.feather / n, "scale": p.scale and p.scale / n})
        r = Render(self.studio.graph.nodes[render].params).compute(
            **{**{k: v for k, v in given.items() if v is not None}, "lights": [light, *given["lights"][1:]]})
        return self.compute(params=params, photo=photo, relit=r["image"], coverage=r["coverage"])["image"]

    def _reduced(self, photo, k: int):
        """The photo reduced ``k`` times (kept while the run's photo is the same object)."""
        kept = getattr(self, "_kept", None)
        if kept is None or kept[0] is not photo or kept[1] != k:
            self._kept = kept = (photo, k, type(photo)(reduce_image(photo.pixels, k), photo.colorspace))
        return kept[2]

    def commit(self, values: dict) -> list[dict]:
        _, light = self._source()
        if light is None or self.studio.graph.nodes[light].type != "MakeLight":
            return []
        az, el = self._angles()
        return (self.change(light, "azimuth_deg", float(values.get("azimuth", az)))
                + self.change(light, "elevation_deg", float(values.get("elevation", el))))


def preview_factor(h: int, w: int, max_px: int) -> int:
    """The smallest whole factor that brings an h×w image to at most ``max_px`` pixels."""
    k = 1
    while (h // k) * (w // k) > max_px:
        k += 1
    return k


def reduce_image(px: np.ndarray, k: int) -> np.ndarray:
    """The mean of each k×k block (OpenCV's INTER_AREA at a whole factor; the rows and columns
    past the last whole block dropped)."""
    if k == 1:
        return px
    import cv2

    h, w = px.shape[0] // k, px.shape[1] // k
    a = cv2.resize(np.ascontiguousarray(px[:h * k, :w * k]), (w, h), interpolation=cv2.INTER_AREA)
    return a.reshape((h, w) + px.shape[2:])


def reduced_camera(camera, k: int):
    """The camera of an image reduced ``k`` times by :func:`reduce_image`: pixel (x, y) of the
    reduced image is (k·x, k·y) of the original (continuous coordinates)."""
    w, h = camera.width // k, camera.height // k
    return camera.reframed(w, h, 1.0 / k, (k * w / 2.0, k * h / 2.0))


def probe_start(node, probe, camera=None) -> tuple[list, str, str]:
    """(circle, how, refusal) the probe view starts from, for ProbeLight ``node`` on the photo
    ``probe``: the circle given in the graph ("given") or found by the node's own finder
    ("found"), else ProbeLight's refusal and the finder's best circle, which it was not sure
    of ("best": often within a snap of the ball — its outline closed on too little of it, or its
    bias bound; where the finder names a likelier circle inside it, the ball's own outline
    inside its cast shadow's, that one), or where it had none in the frame the frame's middle
    ("guess")."""
    from .ballfind import MIN_RADIUS_PX
    from .checks import rgb_pixels

    p = node.params
    h, w = probe.pixels.shape[:2]
    best = []
    try:
        px = rgb_pixels(probe, "probe", grey=True, float64=False)
        c = node._ball(px, "probe", p.centre_x, p.centre_y, p.radius, node._probe_fov(camera), best=best)
        return [float(x) for x in c], "given" if p.radius is not None else "found", ""
    except BadInput as e:
        f = best[0] if best else None
        c = (f.start or (f.cx, f.cy, f.r)) if f is not None else None
        if c is not None and np.all(np.isfinite(c)) and c[2] >= MIN_RADIUS_PX and 0 <= c[0] <= w and 0 <= c[1] <= h:
            return [round(float(x), 2) for x in c], "best", str(e)
        return [w / 2, h / 2, min(w, h) / 4], "guess", str(e)


class ProbeView(LiveView):
    """The studio's live view of ProbeLight: the mirror ball marked by hand where the node
    refuses to find it (or to check the circle it found).  The page shows the whole probe
    photo (the preview of the node's ``probe`` input, its median at mid grey to start with, at
    any zoom) with a circle in the node's pixel convention (continuous coordinates, pixel
    centres at +0.5: the image's own coordinates, as the page's SVG overlay has them): the
    circle given, the one found, or after a refusal a starting guess and the refusal's text.
    Dragging it or typing its numbers asks
    :meth:`frame` for the flash direction ProbeLight computes with ``centre_x``,
    ``centre_y``, ``radius`` given (the node's own compute, on the server), or its message.
    "Snap to outline" asks it (``snap`` in the values) for the ball's outline fitted near the
    circle (:func:`nodes.paris.probe.snap_outline`: a circle dragged a few pixels off comes back
    to a fraction of a pixel where the outline closes), and how far to trust it.
    "Apply" writes the three params into the graph (or the graph params they are bound to)
    and saves the graph file, after the node accepted the circle."""

    title = "probe ball (mark the mirror ball)"
    js = "probe_view.js"
    KEYS = ("centre_x", "centre_y", "radius")
    _start_memo: dict = {}  # (input digests, params) → the starting circle: the finder runs once

    def data(self) -> dict:
        import os

        v = self.inputs()
        src, sport = self.gnode.inputs["probe"]
        h, w = v["probe"].pixels.shape[:2]
        key = (repr(self.gnode.map_inputs(
            lambda s, sp: (self.studio.nodes.get(s) or {}).get("digests", {}).get(sp))), repr(self.params))
        if key not in self._start_memo:
            if len(self._start_memo) > 8:
                self._start_memo.clear()
            self._start_memo[key] = probe_start(self.gnode.cls(self.params), v["probe"], v.get("camera"))
        circle, how, reason = self._start_memo[key]
        # the photo shown with its median at mid grey (an HDR probe's level is anything)
        med = float(np.median(v["probe"].pixels.reshape(h, w, -1).mean(-1)))
        exposure = round(float(np.clip(np.log2(0.18 / med), -8, 8)), 1) if med > 0 else 0.0
        return {"probe": {"node": src, "port": sport}, "width": int(w), "height": int(h),
                "circle": dict(zip(self.KEYS, circle)), "how": how, "reason": reason,
                "exposure": exposure, "file": os.path.basename(self.studio.path)}

    def _params(self, values: dict):
        """The node's Params with the circle of ``values`` (checked as the graph's are)."""
        from pydantic import ValidationError

        circle = {}
        for k in self.KEYS:
            x = values.get(k)
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not np.isfinite(x):
                raise BadInput(k, f"give a number (got {x!r})")
            circle[k] = float(x)
        try:
            return type(self.params).model_validate({**self.params.model_dump(), **circle})
        except ValidationError as e:
            err = e.errors()[0]
            raise BadInput(str(err["loc"][0]), f"{err['msg']} (got {err.get('input')!r})") from None

    def frame(self, values: dict):
        given = self.inputs()
        if values.get("snap"):
            return {"image": np.zeros((1, 1, 3), np.float32), "snap": self._snap(values, given)}
        light = self.compute(params=self._params(values), **given)["light"]
        frame = "world" if given.get("camera") is not None else "probe camera (x right, y down, z forward)"
        return {"image": np.zeros((1, 1, 3), np.float32), "direction": _vec(light.direction), "frame": frame}

    def _snap(self, values: dict, given: dict) -> dict:
        """:func:`nodes.paris.probe.snap_outline` near the circle of ``values``, its circle
        keyed by the node's params (rounded to 1/100 px, as "Apply" writes them)."""
        from .checks import rgb_pixels
        from .probe import snap_outline

        p = self._params(values)
        node = self.gnode.cls(p)
        px = rgb_pixels(given["probe"], "probe", grey=True, float64=False)
        out = snap_outline(px, (p.centre_x, p.centre_y, p.radius), node._probe_fov(given.get("camera")))
        if out["circle"] is not None:
            out["circle"] = dict(zip(self.KEYS, (round(float(v), 2) for v in out["circle"])))
        return out

    def commit(self, values: dict) -> list[dict]:
        p = self._params(values)
        values = {k: round(getattr(p, k), 2) for k in self.KEYS}  # 1/100 px
        self.frame(values)  # ProbeLight refuses a circle it cannot use (its message): nothing written
        return [c for k in self.KEYS for c in self.change(self.node, k, values[k])]
