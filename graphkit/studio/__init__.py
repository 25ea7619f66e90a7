"""The studio: ``graphkit serve GRAPH`` — a local web page over one graph.

The server (app.py: token gate, uvicorn) serves the routes (routes.py) and the live-view
protocol (live.py: the websocket, previews pushed as runs compute them) over a graph session
(core.py: the graph, its edits and runs; runs.py: one run; state.py: what a page draws).

Node packages add live views with :class:`LiveView` (views.py); the server itself needs the
``studio`` extra (starlette, uvicorn, websockets), imported only when it starts.
"""
from .views import LiveView

__all__ = ["LiveView", "serve"]


def serve(graph, **kw) -> int:
    from .app import serve as _serve

    return _serve(graph, **kw)
