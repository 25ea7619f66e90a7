"""The studio: ``graphkit serve GRAPH`` — a local web page over one graph (see app.py, core.py).

Node packages add live views with :class:`LiveView` (views.py); the server itself needs the
``studio`` extra (starlette, uvicorn, websockets), imported only when it starts.
"""
from .views import LiveView

__all__ = ["LiveView", "serve"]


def serve(graph, **kw) -> int:
    from .app import serve as _serve

    return _serve(graph, **kw)
