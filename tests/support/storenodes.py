"""Node types for the store / output tests (loaded through GRAPHKIT_PLUGINS with enginenodes)."""
from __future__ import annotations

import numpy as np

from graphkit import Array, Field, File, In, InputFile, Node


class ReadBytes(Node):
    """The bytes of an input file as a uint8 array (file-memo tests)."""

    outputs = {"out": Array}

    class Params(Node.Params):
        path: InputFile

    def compute(self):
        import os

        with open(os.path.join(self.ctx.base_dir, self.params.path), "rb") as f:
            return np.frombuffer(f.read(), np.uint8).copy()


class WriteFile(Node):
    """A File output named ``name`` holding ``text`` (or the bytes of ``x``)."""

    inputs = {"x": In(Array, optional=True)}
    outputs = {"file": File}

    class Params(Node.Params):
        name: str = "out.txt"
        text: str = Field("", description="file content when x is not connected")

    def compute(self, x=None):
        data = self.params.text.encode() if x is None else np.ascontiguousarray(x).tobytes()
        return File(self.params.name, data)
