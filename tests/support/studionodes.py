"""Small image nodes for the studio's tests (loaded through GRAPHKIT_PLUGINS=studionodes)."""
from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from graphkit import BadInput, Field, Image, In, Node


class Flat(Node):
    """A size×size RGB image of one linear value ``level``."""

    outputs = {"image": Image}

    class Params(Node.Params):
        level: float = Field(0.5, ge=0, le=1, description="linear value of every pixel")
        size: int = Field(32, ge=4, le=256, description="pixels per side")

    def compute(self):
        n = self.params.size
        return Image(np.full((n, n, 3), self.params.level, np.float32))


class Gain(Node):
    """image × 2**stops."""

    inputs = {"image": Image}
    outputs = {"image": Image}

    class Params(Node.Params):
        stops: float = Field(0.0, ge=-4, le=4, description="exposure change in stops")

    def compute(self, image):
        return Image(image.pixels * np.float32(2.0 ** self.params.stops))


class Boom(Node):
    """Fails (``mode: fail``: an exception; ``bad``: a BadInput) or passes the image through."""

    inputs = {"image": Image}
    outputs = {"image": Image}

    class Params(Node.Params):
        mode: str = Field("fail", description="fail | bad | ok")

    def compute(self, image):
        if self.params.mode == "fail":
            raise RuntimeError("boom went the node")
        if self.params.mode == "bad":
            raise BadInput("image", "this image is not good enough")
        return image


class Nap(Node):
    """Sleeps ``seconds`` (reporting progress), then passes the image through (Ctrl-C tests)."""

    inputs = {"image": Image}
    outputs = {"image": Image}

    class Params(Node.Params):
        seconds: float = Field(3.0, ge=0, le=60, description="how long to sleep")
        salt: int = Field(0, description="changes the key only")

    def compute(self, image):
        n = max(1, int(self.params.seconds / 0.05))
        for i in range(n):
            time.sleep(self.params.seconds / n)
            self.ctx.progress((i + 1) / n, "napping")
        return Image(image.pixels + np.float32(self.params.salt * 0))



class Warm(Node):
    """Passes the image through; in a live session it then "warms up" on a thread of its own:
    background progress 0.5, and 1.0 once the file ``until`` exists (a test makes it)."""

    inputs = {"image": Image}
    outputs = {"image": Image}

    class Params(Node.Params):
        until: str = Field("warm.done", description="file whose appearance ends the warm-up")

    def compute(self, image):
        if self.ctx.interactive:
            flag, report = Path(self.ctx.base_dir) / self.params.until, self.ctx.background_progress

            def warm():
                report(0.5, "warming up")
                for _ in range(1200):
                    if flag.exists():
                        break
                    time.sleep(0.05)
                report(1.0, "warming up")
            threading.Thread(target=warm, daemon=True).start()
        return Image(image.pixels)


def _gain_view():
    from graphkit.studio import LiveView

    class View(LiveView):
        """A live view for the tests: a stops slider drawn without the cache."""

        title = "gain (test view)"
        js = "studio_testview.js"

        def data(self):
            return {"sliders": [{"key": "stops", "min": -4, "max": 4, "step": 0.5,
                                 "value": self.params.stops}]}

        def frame(self, values):
            return self.inputs()["image"].pixels * np.float32(2.0 ** float(values["stops"]))

        def commit(self, values):
            return self.change(self.node, "stops", float(values["stops"]))

    return View


class ViewGain(Gain):
    """Gain with a studio live view."""

    studio_view = "studionodes:GAIN_VIEW"

    def compute(self, image):
        return super().compute(image)


def __getattr__(name):  # GAIN_VIEW is built on first use (graphkit.studio imported lazily)
    if name == "GAIN_VIEW":
        return _gain_view()
    raise AttributeError(name)


class FaceScene(Node):
    """A Render scene for the WebGL face view's tests: a sphere "head" (icosphere, 1.3k
    triangles) in front of a wall, a perspective camera, a Phong material and a random detail
    texture seen from the same camera."""

    from graphkit import Camera as _C, Mesh as _M
    from nodes.paris.models import PhongMaterial as _P

    outputs = {"mesh": _M, "camera": _C, "material": _P, "detail": Image}
    del _C, _M, _P

    class Params(Node.Params):
        size: int = Field(96, ge=16, le=1024, description="camera pixels per side")

    def compute(self):
        import trimesh

        from graphkit import Camera
        from nodes.paris.models import PhongMaterial

        n = self.params.size
        wall = trimesh.Trimesh([[-1.8, -1.8, 6], [1.8, -1.8, 6], [1.8, 1.8, 6], [-1.8, 1.8, 6], [0, 0, 6]],
                               [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]], process=False)
        ball = trimesh.creation.icosphere(subdivisions=3, radius=0.8)
        ball.apply_translation((0.0, 0.0, 4.5))
        cam = Camera(width=n, height=n, fx=1.1 * n, fy=1.1 * n, cx=n / 2, cy=n / 2)
        rng = np.random.default_rng(5)
        detail = Image(rng.uniform(0.6, 1.4, (n, n, 3)).astype(np.float32))
        return {"mesh": trimesh.util.concatenate([wall, ball]), "camera": cam,
                "material": PhongMaterial(diffuse=(0.6, 0.45, 0.35), specular=0.35, shininess=20.0),
                "detail": detail}
