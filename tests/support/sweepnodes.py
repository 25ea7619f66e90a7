"""Node types for the sweep, dry-run and Dask tests (loaded through GRAPHKIT_PLUGINS).

``Count`` appends its cache key to a log file (O_APPEND, one line per compute), so a test can
count how often each key was really computed, across threads, processes and Dask workers.
``KillWorker`` kills its own process (SIGKILL): once (a marker file remembers it) or always.
"""
from __future__ import annotations

import os
import signal
import time

import numpy as np

from graphkit import Array, Backend, Field, File, Image, In, Node, OutputPath


class Count(Node):
    """value filled into ``size`` elements (+ the input); logs every compute to ``log``."""

    inputs = {"x": In(Array, optional=True)}
    outputs = {"out": Array}

    class Params(Node.Params):
        log: str = Field(description="file that gets one line (the cache key) per compute")
        value: float = 0.0
        size: int = Field(8, ge=1)
        seconds: float = Field(0.0, ge=0, description="sleep this long first (overlap tests)")

    def compute(self, x=None):
        time.sleep(self.params.seconds)
        fd = os.open(self.params.log, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, f"{self.ctx.key} {self.ctx.node} {os.getpid()}\n".encode())
        finally:
            os.close(fd)
        out = np.full(self.params.size, self.params.value, np.float64)
        return out if x is None else out + x[: self.params.size].sum()


class KillWorker(Node):
    """Kills the process computing it: the first time only (``once``), or every time."""

    inputs = {"x": In(Array, optional=True)}
    outputs = {"out": Array}

    class Params(Node.Params):
        marker: str = Field(description="file created by the first (killed) attempt")
        always: bool = False
        value: float = 1.0

    def compute(self, x=None):
        try:
            os.close(os.open(self.params.marker, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644))
            first = True
        except FileExistsError:
            first = False
        if first or self.params.always:
            os.kill(os.getpid(), signal.SIGKILL)
        return np.full(4, self.params.value)


class NoopAlt(Backend):
    """A second backend of the engine test node Noop (dry-run reasons: backend changed)."""

    node = "Noop"
    name = "alt"
    version = "1"

    def compute(self, x=None):
        return x if x is not None else np.zeros(1)


class Stack(Node):
    """The input arrays one after another, in order (fan-in order tests)."""

    inputs = {"xs": In(Array, variadic=True)}
    outputs = {"out": Array}

    def compute(self, xs):
        return np.concatenate([np.ravel(x) for x in xs])


class ImageMean(Node):
    """The mean of an image's pixels, per channel."""

    inputs = {"image": In(Image)}
    outputs = {"out": Array}

    def compute(self, image):
        return image.pixels.reshape(-1, image.channels).mean(axis=0, dtype=np.float64)


class WriteText(Node):
    """A text file into --out."""

    outputs = {"file": File}

    class Params(Node.Params):
        path: OutputPath
        text: str = ""

    def compute(self):
        return File(self.params.path, self.params.text.encode())
