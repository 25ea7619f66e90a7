"""Live views: node-specific interactive panels that a node package adds to the studio.

A node type opts in with one class attribute naming a :class:`LiveView` subclass::

    class Relight(Node):
        studio_view = "nodes.loscos.studio_view:RoomView"

The view class names an ES module (``js``, a file next to the view's Python module) that the
page imports, and prepares the data that module draws from the node's inputs as computed
by the current run.  Slider moves go to :meth:`LiveView.frame` over the websocket (a fast
path that does not touch the cache: its image comes back as a PNG); letting go of a slider
sends :meth:`LiveView.commit`, whose param changes are written into the graph and re-run
through the cache like any other edit.  The engine knows nothing about what a view shows.
"""
from __future__ import annotations

import copy
import importlib
import inspect
from pathlib import Path
from typing import Any

from ..errors import GraphkitError


class NotReady(GraphkitError):
    """The view's inputs are not computed yet: the page waits for the run and asks again."""


class LiveView:
    """Base class of live views (see the module docstring)."""

    #: shown as the panel's title
    title: str = "live view"
    #: the ES module, relative to the folder of the module that defines the subclass; it
    #: exports ``mount(element, api)`` (see graphkit/studio/static/views.js)
    js: str = ""

    def __init__(self, studio, node: str):
        self.studio, self.node = studio, node

    @property
    def gnode(self):
        return self.studio.graph.nodes[self.node]

    @property
    def params(self):
        return self.gnode.params

    def inputs(self) -> dict:
        """The node's input values from the current run (BadInput if not computed yet)."""
        vals = self.studio.input_values(self.node)
        if vals is None:
            raise NotReady(f"node '{self.node}': its inputs are not computed yet (run the graph first)")
        return vals

    def data(self) -> dict:
        """JSON for the view's module: controls and their current values."""
        return {}

    def frame(self, values: dict) -> Any:
        """A preview for control ``values``: an Image / H×W×C linear float array, or a dict."""
        raise NotImplementedError

    def commit(self, values: dict) -> list[dict]:
        """Param changes (``{"node", "param", "value"}``) that make the graph show ``values``."""
        return []

    # -- helpers for subclasses ------------------------------------------------------------
    def raw_param(self, node: str, param: str):
        """The param as written in the graph file (e.g. ``"${params.weights}"``), or None."""
        data = self.studio.doc.data() or {}
        spec = (data.get("nodes") or {}).get(node) or {}
        return copy.deepcopy((spec.get("params") or {}).get(param))  # the document's data is shared

    def change(self, node: str, param: str, value) -> list[dict]:
        """The edit that sets ``node.param`` to ``value``; a param bound to a graph param
        (``${params.X}``) changes X instead, so the binding stays."""
        import re

        raw = self.raw_param(node, param)
        m = re.fullmatch(r"\s*\$\{params\.([A-Za-z_][A-Za-z0-9_]*)\}\s*", raw) if isinstance(raw, str) else None
        if m:
            return [{"node": None, "param": m.group(1), "value": value}]
        if isinstance(raw, list) and isinstance(value, list) and len(raw) == len(value):
            out, lit = [], []
            for r, v in zip(raw, value):
                mm = re.fullmatch(r"\s*\$\{params\.([A-Za-z_][A-Za-z0-9_]*)\}\s*", r) if isinstance(r, str) else None
                if mm:
                    out.append({"node": None, "param": mm.group(1), "value": v})
                    lit.append(r)
                else:
                    lit.append(v)
            if out:
                return out + ([{"node": node, "param": param, "value": lit}] if lit != raw else [])
        return [{"node": node, "param": param, "value": value}]

    def consumers(self, node: str, port: str) -> list[tuple[str, str]]:
        """(node, input port) pairs that read ``node.port``."""
        g = self.studio.graph
        return [(n, p) for n, gn in g.nodes.items() for p, s, sp in gn.edges() if (s, sp) == (node, port)]

    @staticmethod
    def crop_box(weights, margin: float = 0.1, min_side: int = 8) -> tuple[int, int, int, int]:
        """(y0, y1, x0, x1) around the non-zero ``weights`` (H×W), grown by ``margin`` of its size."""
        import numpy as np

        a = np.asarray(weights)
        ys, xs = np.nonzero(a > 0)
        H, W = a.shape[:2]
        if len(ys) == 0:
            return 0, H, 0, W
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        my, mx = int((y1 - y0) * margin) + 1, int((x1 - x0) * margin) + 1
        y0, y1 = max(0, y0 - my), min(H, max(y1 + my, y0 + min_side))
        x0, x1 = max(0, x0 - mx), min(W, max(x1 + mx, x0 + min_side))
        return int(y0), int(y1), int(x0), int(x1)

    @staticmethod
    def crop_inputs(values: dict, box: tuple[int, int, int, int], shape: tuple[int, int]) -> dict:
        """``values`` (a node's inputs) cut to ``box``: Images and Masks of the full ``shape``
        (H, W) are cropped, Cameras of that size get the crop's intrinsics; the rest is kept."""
        from ..types import Camera, Image, Mask

        y0, y1, x0, x1 = box

        def cut(v):
            if isinstance(v, list):
                return [cut(x) for x in v]
            if isinstance(v, Image) and v.pixels.shape[:2] == tuple(shape):
                return Image(v.pixels[y0:y1, x0:x1], v.colorspace)
            if isinstance(v, Mask) and v.alpha.shape == tuple(shape):
                return Mask(v.alpha[y0:y1, x0:x1])
            if isinstance(v, Camera) and (v.height, v.width) == tuple(shape):
                return v.model_copy(update={"width": x1 - x0, "height": y1 - y0,
                                            "cx": v.cx - x0, "cy": v.cy - y0})
            return v

        return {k: cut(v) for k, v in values.items()}

    def compute(self, *, params=None, **inputs):
        """Run the node's own compute (its reference backend) on ``inputs``, outside the cache,
        after its declared port constraints (as the engine does); ``params``: its checked
        Params instead of the graph's."""
        from ..contract import compute_checked
        from ..node import Context

        g = self.gnode
        ctx = Context(node=self.node, node_type=g.type, graph_name=self.studio.graph.name,
                      base_dir=self.studio.graph.base_dir)
        return compute_checked(g.cls(g.params if params is None else params, ctx), **inputs)

    @classmethod
    def js_path(cls) -> Path:
        return Path(inspect.getfile(cls)).resolve().parent / cls.js

    @classmethod
    def describe(cls) -> dict:
        return {"title": cls.title, "class": f"{cls.__module__}:{cls.__qualname__}"}


_cache: dict[str, type[LiveView] | None] = {}


def view_for(registry, node_type: str) -> type[LiveView] | None:
    """The LiveView class a node type names in ``studio_view`` (None when it has none)."""
    if node_type in _cache:
        return _cache[node_type]
    cls = None
    try:
        spec = registry.studio_view(node_type)
    except Exception:  # noqa: BLE001 - unknown or broken node type: no view
        spec = None
    if spec is not None:
        mod, _, attr = spec.partition(":")
        try:
            cls = getattr(importlib.import_module(mod), attr)
        except Exception as e:  # noqa: BLE001 - a broken view must not break the studio
            registry.problems.append(f"{node_type}: studio view {spec} failed to import: {type(e).__name__}: {e}")
            cls = None
        if cls is not None and not (isinstance(cls, type) and issubclass(cls, LiveView)):
            registry.problems.append(f"{node_type}: studio view {spec} is not a graphkit.studio.LiveView")
            cls = None
    _cache[node_type] = cls
    return cls
