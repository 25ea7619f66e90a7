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

import importlib
import inspect
from pathlib import Path
from typing import Any

from ..errors import GraphkitError


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
            raise GraphkitError(f"node '{self.node}': its inputs are not computed yet (run the graph first)")
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
        ncls = registry.node_class(node_type)
    except Exception:  # noqa: BLE001 - unknown or broken node type: no view
        ncls = None
    spec = getattr(ncls, "studio_view", None) if ncls is not None else None
    if isinstance(spec, str) and ":" in spec:
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
