"""Errors the engine reports to users.

Every user-facing failure is one of these; the CLI prints ``str(err)`` (never a traceback) and
exits with ``err.exit_code``: 2 for a bad graph or bad input, 1 for a node that failed.
"""
from __future__ import annotations


class GraphkitError(Exception):
    """Base of all errors that the CLI reports as one clear message."""

    exit_code = 2


def interrupt_in(e: BaseException | None) -> bool:
    """Whether a Ctrl-C (KeyboardInterrupt) is ``e`` or in its chain of causes: Python 3.11 wraps
    what a class's ``__set_name__`` raises in a RuntimeError (a SIGINT during pydantic's import
    reads "Error calling __set_name__ …"), and the engine names the node or plugin it broke."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


class Diagnostic:
    """One problem at a place in a graph file.

    A plain class rather than a dataclass: this module is imported before the command line
    catches Ctrl-C, and ``dataclasses`` costs ~10 ms of imports (inspect, ast, …)."""

    __slots__ = ("file", "line", "col", "message")

    def __init__(self, file: str, line: int, col: int, message: str):
        self.file = file
        self.line = line  # 1-based
        self.col = col  # 1-based
        self.message = message

    def _tuple(self):
        return (self.file, self.line, self.col, self.message)

    def __eq__(self, other):
        return self._tuple() == other._tuple() if isinstance(other, Diagnostic) else NotImplemented

    def __hash__(self):
        return hash(self._tuple())

    def __repr__(self) -> str:
        return f"Diagnostic(file={self.file!r}, line={self.line!r}, col={self.col!r}, message={self.message!r})"

    def __reduce__(self):
        return (Diagnostic, self._tuple())

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.col}: error: {self.message}"


class GraphError(GraphkitError):
    """A graph file that cannot be loaded or does not validate (exit 2)."""

    def __init__(self, diagnostics: list[Diagnostic] | Diagnostic):
        if isinstance(diagnostics, Diagnostic):
            diagnostics = [diagnostics]
        self.diagnostics = diagnostics
        super().__init__("\n".join(str(d) for d in diagnostics))

    def __reduce__(self):
        return (GraphError, (self.diagnostics,))


class UsageError(GraphkitError):
    """Bad command-line use or environment (missing file, bad --set, unwritable cache)."""


class BadInput(GraphkitError):
    """Raised by a node when an input value (or a param) is unusable: exit 2.

    ``port`` names the input port (or param) at fault; the engine adds the node's name and type.
    """

    def __init__(self, port: str | None, message: str):
        self.port = port
        self.message = message
        self.node: str | None = None
        self.node_type: str | None = None
        super().__init__(message)

    def __reduce__(self):  # keep the port and node across processes (Dask workers)
        return (_rebuild_bad_input, (self.port, self.message, self.node, self.node_type))

    def __str__(self) -> str:
        where = []
        if self.node:
            where.append(f"node '{self.node}' ({self.node_type})")
        if self.port:
            where.append(f"port '{self.port}'")
        prefix = ", ".join(where)
        return f"bad input: {prefix}: {self.message}" if prefix else f"bad input: {self.message}"


class BackendCannotRun(GraphkitError):
    """Raised by a backend's ``compute`` when it cannot run *these* inputs here although it is
    available (e.g. the image does not fit in the device's memory).  The engine then computes
    the node with the numpy reference (one notice) when the backend was only preferred, and
    refuses with exit 2 naming the node, the backend and ``reason`` when the node pins it."""

    def __init__(self, reason: str):
        self.reason = reason
        super().__init__(reason)

    def __reduce__(self):
        return (BackendCannotRun, (self.reason,))


class NodeFailed(GraphkitError):
    """A node's compute raised an unexpected exception (exit 1)."""

    exit_code = 1

    def __init__(self, node: str, node_type: str, cause: BaseException):
        self.node, self.node_type, self.cause = node, node_type, cause
        super().__init__(
            f"node '{node}' ({node_type}) failed: {type(cause).__name__}: {cause}"
        )

    def __reduce__(self):
        cause = self.cause
        try:
            import pickle

            pickle.dumps(cause)
        except Exception:  # noqa: BLE001 - an unpicklable cause travels as its text
            cause = RuntimeError(f"{type(self.cause).__name__}: {self.cause}")
        return (NodeFailed, (self.node, self.node_type, cause))


class CacheError(GraphkitError):
    """The cache store cannot be used (read-only, full, corrupt): exit 2."""


class CanonicalError(GraphkitError):
    """A value that has no canonical encoding (so it cannot be part of a cache key)."""


def _rebuild_bad_input(port, message, node, node_type):
    e = BadInput(port, message)
    e.node, e.node_type = node, node_type
    return e
