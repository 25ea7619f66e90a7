"""graphkit: typed node graphs from YAML, a content-hash cache, pluggable compute backends.

The engine knows nothing about faces or light: node types come from plugins (the built-in
``nodes`` package registers itself the same way a third-party plugin does).

The names below are imported when first used (PEP 562), so ``import graphkit.cli`` costs
almost nothing: the command line then catches a Ctrl-C from its very first moment instead of
printing a traceback from the middle of importing numpy or pydantic.
"""
from __future__ import annotations

from importlib import import_module

from .errors import BackendCannotRun, BadInput, GraphError, GraphkitError, NodeFailed

__version__ = "0.1.0"

# name -> module that defines it
_LAZY = {
    "Field": "pydantic",
    "Run": ".api", "run_graph": ".api",
    "Backend": ".node", "Context": ".node", "In": ".node", "InputFile": ".node", "Node": ".node",
    "Out": ".node", "OutputPath": ".node",
    "load": ".graphfile", "load_dict": ".graphfile", "status": ".dryrun",
    "Array": ".types", "Camera": ".types", "File": ".types", "Image": ".types", "Json": ".types",
    "Light": ".types", "Mask": ".types", "Mesh": ".types", "PortType": ".types", "Scalar": ".types",
    "Spectrum": ".types", "Vector": ".types",
    "safe_relpath": ".paths",
}

__all__ = [
    "Node", "Backend", "In", "Out", "InputFile", "OutputPath", "Context", "Field",
    "Image", "Mask", "Mesh", "Camera", "Light", "Spectrum", "File", "Scalar", "Vector", "Array",
    "Json", "PortType", "BadInput", "BackendCannotRun", "GraphError", "GraphkitError", "NodeFailed", "run_graph", "Run",
    "safe_relpath", "load", "load_dict", "status",
]


def __getattr__(name: str):
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'graphkit' has no attribute {name!r}")
    value = getattr(import_module(mod, __name__), name)
    globals()[name] = value  # later look-ups do not come back here
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


TYPE_CHECKING = False  # not `typing.TYPE_CHECKING`: importing typing costs ~5 ms here
if TYPE_CHECKING:  # for type checkers and editors: the same names, imported eagerly
    from pydantic import Field

    from .api import Run, run_graph
    from .dryrun import status
    from .graphfile import load, load_dict
    from .node import Backend, Context, In, InputFile, Node, Out, OutputPath
    from .paths import safe_relpath
    from .types import (Array, Camera, File, Image, Json, Light, Mask, Mesh, PortType, Scalar,
                        Spectrum, Vector)
