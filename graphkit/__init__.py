"""graphkit: typed node graphs from YAML, a content-hash cache, pluggable compute backends.

The engine knows nothing about faces or light: node types come from plugins (the built-in
``nodes`` package registers itself the same way a third-party plugin does).
"""
from pydantic import Field

from .api import Run, run_graph
from .graphfile import load, load_dict
from .status import status
from .errors import BadInput, GraphError, GraphkitError, NodeFailed
from .node import Backend, Context, In, InputFile, Node, Out, OutputPath
from .types import (Array, Camera, File, Image, Json, Light, Mask, Mesh, PortType, Scalar,
                    Spectrum, Vector)

__version__ = "0.1.0"

__all__ = [
    "Node", "Backend", "In", "Out", "InputFile", "OutputPath", "Context", "Field",
    "Image", "Mask", "Mesh", "Camera", "Light", "Spectrum", "File", "Scalar", "Vector", "Array",
    "Json", "PortType", "BadInput", "GraphError", "GraphkitError", "NodeFailed", "run_graph", "Run",
    "load", "load_dict", "status",
]
