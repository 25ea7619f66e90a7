"""The node API.

A node type is a class with typed ports, pydantic ``Params``, a ``version`` and a pure
``compute``::

    class RatioImage(Node):
        \"\"\"a / max(b, eps), per channel (Paris 2003 §3).\"\"\"
        version = "1"
        inputs = {"a": In(Image, "numerator"), "b": In(Image, "denominator")}
        outputs = {"ratio": Image}

        class Params(Node.Params):
            eps: float = Field(1e-4, gt=0, description="floor of the denominator")

        def compute(self, a, b):
            return {"ratio": Image(a.pixels / np.maximum(b.pixels, self.params.eps))}

``compute`` receives input values as keyword arguments and returns a dict of output values
(or the bare value when there is one output).  It must depend only on its params and inputs:
the engine caches its result by their content.  Raise :class:`BadInput` for unusable inputs.

Alternative implementations are :class:`Backend` subclasses naming the node type they serve;
the node's own ``compute`` is always the ``numpy`` reference backend.
"""
from __future__ import annotations

import contextlib
import re
from dataclasses import dataclass, field
from typing import Annotated, Any, Callable, ClassVar

from pydantic import BaseModel, ConfigDict

from .contract import Constraints, declaration_problem
from .errors import BadInput
from .types import PortType, port_type


@dataclass(frozen=True)
class In:
    """An input port declaration, with what the port needs (see :mod:`graphkit.contract`):
    ``channels`` (a count or a tuple of allowed counts), ``same_size_as`` (another input port),
    ``finite``, bounds ``ge``/``gt``/``le``/``lt`` on every value, and ``min_items`` (variadic
    ports).  The engine checks them before ``compute``."""

    type: Any
    doc: str = ""
    optional: bool = False
    variadic: bool = False  # takes a list of connections; compute gets a list
    channels: int | tuple[int, ...] | None = None
    same_size_as: str | None = None
    finite: bool = False
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    min_items: int | None = None

    def constraints(self) -> Constraints:
        return Constraints.make(self.channels, same_size_as=self.same_size_as, finite=self.finite,
                                ge=self.ge, gt=self.gt, le=self.le, lt=self.lt, min_items=self.min_items)


@dataclass(frozen=True)
class Out:
    """An output port declaration."""

    type: Any
    doc: str = ""


@dataclass(frozen=True)
class Port:
    name: str
    type: PortType
    doc: str = ""
    optional: bool = False
    variadic: bool = False
    constraints: Constraints = Constraints()


class _InputFileMarker:
    """Marks a ``str`` param as the path of an input file: the cache key uses its content."""


InputFile = Annotated[str, _InputFileMarker()]


class _OutputPathMarker:
    """Marks a ``str`` param as the name of the File a node writes into ``--out``."""


#: a param naming the file a node's File output is written to (relative to ``--out``); the engine
#: checks before anything runs that no two exported files share a name (e.g. sweep instances)
OutputPath = Annotated[str, _OutputPathMarker()]


@dataclass
class Context:
    """What a running node may know about its run (all of it deterministic)."""

    node: str = ""
    node_type: str = ""
    key: str = ""  # the cache key of this computation
    graph_name: str = ""
    recipe_digest: str = ""  # digest of the part of the graph this node's result depends on
    base_dir: str = "."  # folder of the graph file (relative input paths start here)
    # the cache digests of this computation's inputs (port → digest, a list for a variadic
    # port; empty outside the engine): content keys a node may use to keep expensive set-up
    # between calls (its output must not depend on whether it did)
    inputs: dict = field(default_factory=dict)
    report: Callable[[float, str], None] = field(default=lambda frac, msg: None)
    # one line the run shows its user (an assumption made, data left out); computed once, so
    # a cached result does not repeat it
    tell: Callable[[str], None] = field(default=lambda msg: None)
    # a live session (the studio): the next change is likely soon, so a node may go on, in a
    # background thread of its own, preparing in-process state for it (its outputs must not
    # depend on whether it did); False in a batch run, where that would only cost CPU
    interactive: bool = False
    background: Callable[[float, str], None] = field(default=lambda frac, msg: None)

    def progress(self, fraction: float, message: str = "") -> None:
        """Report progress of a long compute (0…1); shown by the CLI."""
        self.report(fraction, message)

    def background_progress(self, fraction: float, message: str = "") -> None:
        """Report progress (0…1, 1 when done) of work this node goes on with in a background
        thread after its compute returned (``interactive``); the studio shows it on the node.
        Callable from any thread, after the run ended too; it never raises."""
        with contextlib.suppress(Exception):
            self.background(fraction, message)

    def notice(self, message: str) -> None:
        """Tell the user something about this computation (shown as a ``notice:`` line, also
        with ``-q``): what was assumed, what was left out and how much."""
        self.tell(message)


class _Computable:
    """Shared machinery of Node and Backend: params + context, calling compute."""

    class Params(BaseModel):
        model_config = ConfigDict(extra="forbid", frozen=True)

    def __init__(self, params: BaseModel | None = None, ctx: Context | None = None):
        self.params = params if params is not None else self.Params()
        self.ctx = ctx or Context()

    def bad_input(self, port: str | None, message: str) -> BadInput:
        """Build a BadInput error for ``port``; use as ``raise self.bad_input(...)``."""
        return BadInput(port, message)


class Node(_Computable):
    """Base class of node types (see the module docstring)."""

    version: ClassVar[str] = "1"
    inputs: ClassVar[dict[str, Any]] = {}
    outputs: ClassVar[dict[str, Any]] = {}
    #: per-node tolerances for the backend conformance harness (rtol, atol, and bad_fraction:
    #: the share of output values allowed outside rtol/atol, e.g. silhouette pixels)
    tolerance: ClassVar[dict[str, float]] = {"rtol": 1e-5, "atol": 1e-6}
    #: True when the result embeds provenance (the run's recipe digest and key)
    provenance: ClassVar[bool] = False
    #: names of this class's staticmethods that a backend may replace with its own version
    #: (e.g. an OpenCL kernel of the per-pixel maths, while compute's checks and host maths run
    #: as they are); a backend may hook nothing else
    hooks: ClassVar[tuple[str, ...]] = ()
    #: "module:Class" of the studio's live view of this node type (a
    #: graphkit.studio.LiveView subclass, imported only by the studio), or None
    studio_view: ClassVar[str | None] = None

    # filled by __init_subclass__
    type_name: ClassVar[str]
    in_ports: ClassVar[dict[str, Port]]
    out_ports: ClassVar[dict[str, Port]]
    constrained_ports: ClassVar[tuple[str, ...]] = ()  # the input ports that declare constraints

    def __init_subclass__(cls, **kw):
        super().__init_subclass__(**kw)
        cls.type_name = cls.__dict__.get("type_name", cls.__name__)
        cls.in_ports = {}
        for name, decl in cls.inputs.items():
            d = decl if isinstance(decl, In) else In(decl)
            cls.in_ports[name] = Port(name, port_type(d.type), d.doc, d.optional, d.variadic, d.constraints())
        for port in cls.in_ports.values():
            problem = declaration_problem(port, cls.in_ports)
            if problem:
                raise TypeError(f"{cls.__name__}: input '{port.name}': {problem}")
        cls.constrained_ports = tuple(n for n, p in cls.in_ports.items() if p.constraints)
        _check_declarations(cls)
        cls.out_ports = {}
        for name, decl in cls.outputs.items():
            d = decl if isinstance(decl, Out) else Out(decl)
            cls.out_ports[name] = Port(name, port_type(d.type), d.doc)
        if "Params" in cls.__dict__:
            p = cls.Params
            if p.model_config.get("extra") != "forbid":
                p.model_config["extra"] = "forbid"
                p.model_rebuild(force=True)

    def compute(self, **inputs) -> Any:  # pragma: no cover - abstract
        raise NotImplementedError

    @classmethod
    def examples(cls) -> list[tuple[dict, dict]]:
        """(params, inputs) cases for the backend conformance harness."""
        return []

    @classmethod
    def resolve_file(cls, param: str, value: str, base_dir: str) -> str:
        """Turn an ``InputFile`` param into a real path (override for schemes like builtin:).

        BadInput when the path cannot be an input file (a NUL byte, a folder, a FIFO, socket
        or device: opening a FIFO would wait forever); a missing file is reported by the caller."""
        import os

        from .errors import BadInput
        from .paths import input_file_problem

        path = value if os.path.isabs(value) else os.path.join(base_dir, value)
        problem = input_file_problem(path)
        if problem:
            raise BadInput(param, problem)
        return path

    @classmethod
    def referenced_files(cls, param: str, path: str) -> dict[str, str]:
        """Files that the input file ``path`` names and the node also reads (e.g. a scene file's
        photograph): {label: path}.  Their content goes into the cache key too."""
        return {}

    @classmethod
    def input_file_params(cls) -> list[str]:
        out = []
        for name, f in cls.Params.model_fields.items():
            if any(isinstance(m, _InputFileMarker) for m in f.metadata):
                out.append(name)
        return out

    @classmethod
    def output_path_params(cls) -> list[str]:
        """The params typed :data:`OutputPath` (names of the files this node writes)."""
        return [name for name, f in cls.Params.model_fields.items()
                if any(isinstance(m, _OutputPathMarker) for m in f.metadata)]


def _check_declarations(cls: type[Node]) -> None:
    """TypeError unless ``hooks`` names staticmethods of ``cls`` and ``studio_view`` is a
    "module:Class" string."""
    import inspect

    if isinstance(cls.hooks, str) or not all(isinstance(h, str) for h in cls.hooks):
        raise TypeError(f"{cls.__name__}.hooks must be a tuple of names, got {cls.hooks!r}")
    for h in cls.hooks:
        if not isinstance(inspect.getattr_static(cls, h, None), staticmethod):
            raise TypeError(f"{cls.__name__}.hooks names '{h}', which is not a staticmethod of {cls.__name__}")
    view = cls.studio_view
    if view is not None and not (isinstance(view, str) and _TARGET.fullmatch(view)):
        raise TypeError(f"{cls.__name__}.studio_view must be a \"module:Class\" string, got {view!r}")


_TARGET = re.compile(r"[A-Za-z_][\w.]*:[A-Za-z_][\w.]*")


class Backend(_Computable):
    """An alternative implementation of one node type's compute.

    Set ``node`` (the node type name), ``name`` and ``version``; ``Params`` is taken from the
    node type.  ``available()`` returns True when the backend can run here; when it returns
    False or raises, the text of ``why_unavailable()`` (or the exception) is shown to users.
    """

    node: ClassVar[str]
    name: ClassVar[str]
    version: ClassVar[str] = "1"

    @classmethod
    def available(cls) -> bool:
        return True

    @classmethod
    def why_unavailable(cls) -> str:
        return "available() returned False"

    @classmethod
    def declines_preference(cls) -> str | None:
        """None when a run's preference order (``--backend``) may choose this backend here;
        else why not (e.g. an OpenCL backend that is slower than numpy on a CPU device): the
        run then uses the next backend and says so once.  A node that pins the backend still
        gets it.  Called only when the backend is available."""
        return None

    def compute(self, **inputs) -> Any:  # pragma: no cover - abstract
        raise NotImplementedError


def probe(backend: type[Backend]) -> str | None:
    """None when ``backend`` is available, else the reason it is not."""
    try:
        ok = backend.available()
    except Exception as e:  # noqa: BLE001 - any failure of a probe means "not available"
        return f"{type(e).__name__}: {e}"
    return None if ok else backend.why_unavailable()

