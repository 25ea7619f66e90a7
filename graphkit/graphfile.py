"""Loading and validating graph files (YAML, format 1).

::

    graphkit: 1
    name: demo
    params: {sigma: 2.0}                 # graph params, overridable with --set sigma=3
    nodes:
      photo: {type: LoadImage, params: {path: "builtin:astronaut"}}
      blur:
        type: Blur
        inputs: {image: photo.image}
        params: {sigma: "${params.sigma}"}
        backend: numpy                   # optional pin
    outputs: {blurred: blur.image}       # or a list of node.port

Sweeps (``sweeps:`` and a node's ``foreach:``) instantiate a node or a sub-graph over a list, a
product of lists or a file glob; see :mod:`graphkit.sweeps`.

Everything is checked before anything runs (:mod:`graphkit.validate`, one checker per concern);
each problem is reported as ``file:line:col`` with the node and port, and a did-you-mean where
one fits.  Only plain YAML data is accepted (no tags that build objects), so a graph file cannot
run code.  :func:`load_dict` takes the same graph as a Python dict, through the same checks.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

from .errors import Diagnostic, GraphError, UsageError
from .hashing import key_digest
from .node import Node
from .registry import Registry
from .suggest import did_you_mean  # noqa: F401 - also imported from here by older callers

FORMAT = 1
TOP_KEYS = ("graphkit", "name", "description", "params", "sweeps", "nodes", "outputs")
NODE_KEYS = ("type", "inputs", "params", "backend", "foreach", "doc")
_PLAIN_TAGS = {
    "tag:yaml.org,2002:str", "tag:yaml.org,2002:int", "tag:yaml.org,2002:float",
    "tag:yaml.org,2002:bool", "tag:yaml.org,2002:null",
}
_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_\-]*$")
MAX_YAML_NODES = 200_000
# libyaml's parser when the wheel has it (≈10× faster); both give the same nodes and marks
_Loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


@dataclass
class GNode:
    name: str
    type: str
    cls: type[Node]
    params: BaseModel
    # port -> (source node, source port); a variadic port holds a list of them
    inputs: dict[str, tuple[str, str] | list[tuple[str, str]]]
    backend: str | None  # pinned backend, if any
    files: dict[str, str]  # InputFile param -> resolved path
    line: int = 0
    col: int = 0
    base: str = ""  # the node's name in the graph file (an instance is named base[instance])
    instance: str | None = None  # the instance name, for a node swept with foreach
    sweep: str | None = None  # the sweep it is instantiated over

    def edges(self) -> list[tuple[str, str, str]]:
        """Every connection into this node as (port, source node, source port)."""
        out = []
        for port, ref in self.inputs.items():
            for src, sport in (ref if isinstance(ref, list) else [ref]):
                out.append((port, src, sport))
        return out

    def sources(self) -> set[str]:
        out = set()
        for ref in self.inputs.values():
            if isinstance(ref, list):
                out.update(src for src, _ in ref)
            else:
                out.add(ref[0])
        return out

    def map_inputs(self, fn) -> dict:
        """{port: fn(src, sport)} (a list of those for variadic ports)."""
        return {port: [fn(*r) for r in ref] if isinstance(ref, list) else fn(*ref)
                for port, ref in self.inputs.items()}


@dataclass
class Graph:
    name: str
    path: str
    base_dir: str
    params: dict[str, Any]
    nodes: dict[str, GNode]
    outputs: dict[str, tuple[str, str]]
    _recipes: dict[str, str] = field(default_factory=dict)
    sweeps: dict = field(default_factory=dict)  # name -> graphkit.sweeps.Sweep
    output_groups: dict[str, list[str]] = field(default_factory=dict)  # a swept output -> its outputs

    def select_outputs(self, names) -> None:
        """Keep only the outputs ``names`` (an output name, or the name of a swept output group)."""
        keep: list[str] = []
        unknown = []
        for n in names:
            if n in self.outputs:
                keep.append(n)
            elif n in self.output_groups:
                keep.extend(self.output_groups[n])
            else:
                unknown.append(n)
        if unknown:
            shown = list(self.output_groups) + [o for o in self.outputs
                                                if not any(o in g for g in self.output_groups.values())]
            raise UsageError(f"unknown output(s) {', '.join(unknown)}{did_you_mean(unknown[0], shown)}; "
                             "the graph's outputs: " + ", ".join(shown))
        self.outputs = {k: v for k, v in self.outputs.items() if k in set(keep)}
        self.output_groups = {k: [o for o in v if o in self.outputs] for k, v in self.output_groups.items()}

    def instances(self, base: str) -> list[str]:
        """The nodes written as ``base`` in the graph file (its instances, or itself)."""
        return [n for n, g in self.nodes.items() if (g.base or n) == base]

    def upstream(self, names) -> list[str]:
        """The nodes ``names`` need, in a deterministic topological order."""
        need: set[str] = set()
        stack = list(names)
        while stack:
            n = stack.pop()
            if n in need:
                continue
            need.add(n)
            stack.extend(self.nodes[n].sources())
        return [n for n in self.order() if n in need]

    def order(self) -> list[str]:
        if "_order" not in self.__dict__:
            from graphlib import TopologicalSorter

            ts = TopologicalSorter({n: sorted(g.sources()) for n, g in self.nodes.items()})
            self.__dict__["_order"] = list(ts.static_order())
        return self.__dict__["_order"]

    def recipe_digest(self, name: str) -> str:
        """Digest of the part of the graph that ``name`` depends on (types, params, edges)."""
        if name not in self._recipes:
            g = self.nodes[name]
            self._recipes[name] = key_digest({
                "type": g.type, "version": g.cls.version,
                "params": g.params.model_dump(mode="json"),
                "inputs": g.map_inputs(lambda s, sp: [self.recipe_digest(s), sp]),
            })
        return self._recipes[name]

    def digest(self) -> str:
        return key_digest({n: self.recipe_digest(n) for n in self.nodes})


# ---------------------------------------------------------------------------------------------
# YAML → python with locations


class _Doc:
    """Parsed YAML: python data plus a map from key paths to (line, col)."""

    def __init__(self, file: str):
        self.file = file
        self.locs: dict[tuple, tuple[int, int]] = {}
        self.key_locs: dict[tuple, tuple[int, int]] = {}
        self.diags: list[Diagnostic] = []
        self.count = 0

    def at(self, path: tuple, message: str, key: bool = False) -> None:
        line, col = self.where(path, key)
        self.diags.append(Diagnostic(self.file, line, col, message))

    def where(self, path: tuple, key: bool = False) -> tuple[int, int]:
        p = tuple(path)
        while p:
            if key and p in self.key_locs:
                return self.key_locs[p]
            if p in self.locs:
                return self.locs[p]
            p = p[:-1]
        return self.locs.get((), (1, 1))


def _mark(n) -> tuple[int, int]:
    return n.start_mark.line + 1, n.start_mark.column + 1


def _to_py(doc: _Doc, n: yaml.Node, path: tuple, ctor) -> Any:
    doc.count += 1
    if doc.count > MAX_YAML_NODES:
        raise GraphError(Diagnostic(doc.file, *_mark(n), f"graph file too large (over {MAX_YAML_NODES} YAML values, aliases included)"))
    doc.locs[path] = _mark(n)
    short = n.tag.replace("tag:yaml.org,2002:", "!!")
    if isinstance(n, yaml.MappingNode):
        if n.tag != "tag:yaml.org,2002:map":
            doc.at(path, f"YAML tag '{short}' is not allowed: graph files hold plain data only")
            return None
        out: dict[str, Any] = {}
        for kn, vn in n.value:
            if not isinstance(kn, yaml.ScalarNode) or kn.tag not in _PLAIN_TAGS:
                doc.diags.append(Diagnostic(doc.file, *_mark(kn), "mapping keys must be plain scalars"))
                continue
            k = str(kn.value)  # keys are names: take their text (YAML 1.1 would make `off` False)
            if kn.value == "<<":
                doc.diags.append(Diagnostic(doc.file, *_mark(kn), "YAML merge keys ('<<') are not supported"))
                continue
            if k in out:
                doc.diags.append(Diagnostic(doc.file, *_mark(kn), f"duplicate key '{k}'"))
                continue
            doc.key_locs[path + (k,)] = _mark(kn)
            out[k] = _to_py(doc, vn, path + (k,), ctor)
        return out
    if isinstance(n, yaml.SequenceNode):
        if n.tag != "tag:yaml.org,2002:seq":
            doc.at(path, f"YAML tag '{short}' is not allowed: graph files hold plain data only")
            return None
        return [_to_py(doc, x, path + (i,), ctor) for i, x in enumerate(n.value)]
    if n.tag not in _PLAIN_TAGS:
        doc.at(path, f"YAML tag '{short}' is not allowed: graph files hold plain data only")
        return None
    try:
        return ctor.construct_object(n, deep=True)
    except (yaml.YAMLError, ValueError, OverflowError) as e:
        doc.at(path, f"bad scalar {n.value!r}: {e}")
        return None


def parse_yaml(text: str, file: str) -> _Doc:
    doc = _Doc(file)
    loader = None
    try:
        loader = _Loader(text)
        root = loader.get_single_node()
    except yaml.reader.ReaderError as e:  # a character YAML does not allow
        before = text[: e.position]
        line, col = before.count("\n") + 1, len(before) - (before.rfind("\n") + 1) + 1
        raise GraphError(Diagnostic(file, line, col, f"malformed YAML: character {e.character!r} is not allowed")) from None
    except yaml.MarkedYAMLError as e:
        m = e.problem_mark or e.context_mark
        line, col = (m.line + 1, m.column + 1) if m else (1, 1)
        msg = " ".join(x for x in (e.context, e.problem) if x) or "malformed YAML"
        raise GraphError(Diagnostic(file, line, col, f"malformed YAML: {msg}")) from None
    except yaml.YAMLError as e:
        raise GraphError(Diagnostic(file, 1, 1, f"malformed YAML: {e}")) from None
    except RecursionError:
        raise GraphError(Diagnostic(file, 1, 1, "malformed YAML: nested too deeply")) from None
    finally:
        if loader is not None:
            loader.dispose()
    if root is None:
        raise GraphError(Diagnostic(file, 1, 1, "the graph file is empty"))
    doc.data = _to_py(doc, root, (), yaml.constructor.SafeConstructor())
    return doc


# ---------------------------------------------------------------------------------------------
# validation


def parse_set(items: list[str]) -> dict[str, Any]:
    """``["k=v", ...]`` from ``--set``; values are parsed as YAML scalars/flow values."""
    out = {}
    for it in items or []:
        k, eq, v = it.partition("=")
        k = k.strip()
        if not eq or not k:
            raise UsageError(f"--set expects NAME=VALUE, got {it!r}")
        try:
            out[k] = yaml.safe_load(v) if v.strip() else ""
        except yaml.YAMLError as e:
            raise UsageError(f"--set {k}: cannot parse value {v!r}: {e}") from None
    return out


def load_graph(path: str | os.PathLike, registry: Registry, overrides: dict | None = None,
               check_backends: bool = True) -> Graph:
    """Load, resolve and validate a graph file; raise GraphError listing every problem."""
    path = str(path)
    try:
        raw = Path(path).read_bytes()
    except FileNotFoundError:
        raise UsageError(f"{path}: graph file not found") from None
    except OSError as e:
        raise UsageError(f"{path}: cannot read graph file: {e.strerror or e}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise GraphError(Diagnostic(path, 1, 1, f"graph file is not UTF-8 text: {e.reason} at byte {e.start}")) from None
    doc = parse_yaml(text, path)
    if doc.diags:
        raise GraphError(doc.diags)
    data = doc.data
    if not isinstance(data, dict):
        raise GraphError(Diagnostic(path, 1, 1, f"a graph file must be a mapping, got {_kind(data)}"))
    from .validate import validate

    return validate(doc, data, os.path.abspath(path), os.path.dirname(os.path.abspath(path)), registry,
                    overrides or {}, check_backends)


def load_dict(data: dict, registry: Registry, overrides: dict | None = None, *, base_dir: str | os.PathLike = ".",
              source: str = "<dict>", check_backends: bool = True) -> Graph:
    """Validate a graph given as a Python dict (the same structure as a graph file, as Mitsuba's
    ``load_dict``) through the same checks as :func:`load_graph`.  Relative paths (input files,
    globs) start at ``base_dir``; errors name the key path, e.g. ``<dict>: nodes.blur.params.sigma``."""
    doc = _DictDoc(source)
    data = doc.plain(data, ())
    if doc.diags:
        raise GraphError(doc.diags)
    if not isinstance(data, dict):
        raise GraphError(_PathDiagnostic(source, 0, 0, f"a graph must be a mapping, got {_kind(data)}", ""))
    from .validate import validate

    return validate(doc, data, source, os.path.abspath(base_dir), registry, overrides or {}, check_backends)


def load(source, registry: Registry | None = None, overrides: dict | None = None, **kw) -> Graph:
    """A graph from a graph file path or a dict (see :func:`load_graph`, :func:`load_dict`)."""
    if registry is None:
        from .registry import default_registry

        registry = default_registry()
    if isinstance(source, Graph):
        return source
    if isinstance(source, dict):
        return load_dict(source, registry, overrides, **kw)
    return load_graph(source, registry, overrides, **kw)


class _PathDiagnostic(Diagnostic):
    """A problem in a graph given as a dict: placed by its key path instead of line:col."""

    def __init__(self, file, line, col, message, keypath):
        super().__init__(file, line, col, message)
        self.keypath = keypath

    def __str__(self) -> str:
        return f"{self.file}: {self.keypath or '(top)'}: error: {self.message}"

    def __reduce__(self):
        return (_PathDiagnostic, (self.file, self.line, self.col, self.message, self.keypath))


class _DictDoc(_Doc):
    """The :class:`_Doc` of a graph given as a dict: diagnostics name the key path."""

    def at(self, path: tuple, message: str, key: bool = False) -> None:
        self.diags.append(_PathDiagnostic(self.file, 0, 0, message, ".".join(str(p) for p in path)))

    def where(self, path: tuple, key: bool = False) -> tuple[int, int]:
        return 0, 0

    def plain(self, v: Any, path: tuple) -> Any:
        """``v`` as plain graph data (tuples become lists); anything else is reported."""
        if isinstance(v, dict):
            out = {}
            for k, x in v.items():
                if not isinstance(k, str):
                    self.at(path, f"mapping keys must be strings, got {k!r}")
                    continue
                out[k] = self.plain(x, path + (k,))
            return out
        if isinstance(v, (list, tuple)):
            return [self.plain(x, path + (i,)) for i, x in enumerate(v)]
        if v is None or isinstance(v, (str, bool, int, float)):
            return v
        try:  # numpy scalars and the like
            import numpy as np

            if isinstance(v, np.generic):
                return v.item()
        except ImportError:  # pragma: no cover
            pass
        self.at(path, f"a graph holds plain data (str, number, bool, None, list, dict), got {type(v).__name__}")
        return None


def _kind(v) -> str:
    return {dict: "a mapping", list: "a list", str: "a string", type(None): "nothing"}.get(type(v), type(v).__name__)


__all__ = ["Graph", "GNode", "load_graph", "load_dict", "load", "parse_set"]
