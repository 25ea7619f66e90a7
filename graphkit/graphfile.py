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

Everything is checked before anything runs; each problem is reported as ``file:line:col``
with the node and port, and a did-you-mean where one fits.  Only plain YAML data is accepted
(no tags that build objects), so a graph file cannot run code.
"""
from __future__ import annotations

import difflib
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

from .errors import BadInput, Diagnostic, GraphError, GraphkitError, UsageError
from .hashing import key_digest
from .node import Node, probe
from .registry import NUMPY, Registry

FORMAT = 1
TOP_KEYS = ("graphkit", "name", "description", "params", "nodes", "outputs")
NODE_KEYS = ("type", "inputs", "params", "backend", "doc")
_PLAIN_TAGS = {
    "tag:yaml.org,2002:str", "tag:yaml.org,2002:int", "tag:yaml.org,2002:float",
    "tag:yaml.org,2002:bool", "tag:yaml.org,2002:null",
}
_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_\-]*$")
_REF_RE = re.compile(r"\$\{params\.([A-Za-z_][A-Za-z0-9_]*)\}")
MAX_YAML_NODES = 200_000
#: deepest nesting of YAML collections a graph file (or a --set value) may have.  libyaml's
#: composer recurses in C (a file 30 000 levels deep overflows the C stack: a segfault) and the
#: rest of loading recurses in Python, so depth is checked on the parser's events first.
MAX_YAML_DEPTH = 100


class _CoreResolver(yaml.resolver.BaseResolver):
    """Plain scalars resolved by the YAML 1.2 core schema, not PyYAML's YAML 1.1 rules: ``yes``,
    ``no``, ``on``, ``off`` are strings, ``1:20`` is a string (not sexagesimal 80), ``010`` is
    ten, ``0o17`` and ``0x1F`` are integers, ``1e3`` is a float, ``1_000`` is a string."""


for _tag, _regexp, _first in (
    ("null", r"(?:~|null|Null|NULL|)\Z", ["~", "n", "N", ""]),
    ("bool", r"(?:true|True|TRUE|false|False|FALSE)\Z", list("tTfF")),
    ("int", r"(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)\Z", list("-+0123456789")),
    ("float", r"(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
              r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))\Z", list("-+.0123456789")),
):
    _CoreResolver.add_implicit_resolver(f"tag:yaml.org,2002:{_tag}", re.compile(_regexp), _first)

if getattr(yaml, "__with_libyaml__", False):  # libyaml's parser (≈10× faster); same nodes and marks
    class _Loader(yaml.cyaml.CParser, _CoreResolver):
        def __init__(self, stream):
            yaml.cyaml.CParser.__init__(self, stream)
            _CoreResolver.__init__(self)
else:  # pragma: no cover - PyYAML built without libyaml
    class _Loader(yaml.reader.Reader, yaml.scanner.Scanner, yaml.parser.Parser, yaml.composer.Composer,
                  _CoreResolver):
        def __init__(self, stream):
            yaml.reader.Reader.__init__(self, stream)
            yaml.scanner.Scanner.__init__(self)
            yaml.parser.Parser.__init__(self)
            yaml.composer.Composer.__init__(self)
            _CoreResolver.__init__(self)

_INT_RE = re.compile(r"[-+]?[0-9]+\Z")
_FLOAT_RE = re.compile(r"[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?\Z")


def core_scalar(tag: str, value: str) -> Any:
    """The python value of a YAML 1.2 core-schema scalar (``tag`` resolved or explicit);
    ValueError when ``value`` is not a valid text of that tag (e.g. ``!!int 1:20``)."""
    kind = tag.rpartition(":")[2]
    if kind == "str":
        return value
    if kind == "null":
        if value in ("~", "null", "Null", "NULL", ""):
            return None
    elif kind == "bool":
        if value in ("true", "True", "TRUE"):
            return True
        if value in ("false", "False", "FALSE"):
            return False
    elif kind == "int":
        if _INT_RE.match(value):
            return int(value, 10)
        if value[:2] in ("0o", "0x") and len(value) > 2:
            return int(value[2:], 8 if value[1] == "o" else 16)
    elif kind == "float":
        low = value.lower()
        if low in (".inf", "+.inf", "-.inf", ".nan"):
            return float(low.replace(".", ""))
        if _FLOAT_RE.match(value) or _INT_RE.match(value):
            return float(value)
    raise ValueError(f"not a YAML 1.2 {kind}")


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

    def edges(self) -> list[tuple[str, str, str]]:
        """Every connection into this node as (port, source node, source port)."""
        out = []
        for port, ref in self.inputs.items():
            for src, sport in (ref if isinstance(ref, list) else [ref]):
                out.append((port, src, sport))
        return out

    def sources(self) -> set[str]:
        return {src for _, src, _ in self.edges()}

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


def _to_py(doc: _Doc, n: yaml.Node, path: tuple) -> Any:
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
            out[k] = _to_py(doc, vn, path + (k,))
        return out
    if isinstance(n, yaml.SequenceNode):
        if n.tag != "tag:yaml.org,2002:seq":
            doc.at(path, f"YAML tag '{short}' is not allowed: graph files hold plain data only")
            return None
        return [_to_py(doc, x, path + (i,)) for i, x in enumerate(n.value)]
    if n.tag not in _PLAIN_TAGS:
        doc.at(path, f"YAML tag '{short}' is not allowed: graph files hold plain data only")
        return None
    try:
        return core_scalar(n.tag, n.value)
    except (ValueError, OverflowError) as e:
        doc.at(path, f"bad scalar {n.value!r}: {e}")
        return None


def _check_depth(text: str, file: str) -> None:
    """GraphError at the first collection nested deeper than MAX_YAML_DEPTH.  The parser's
    events come without recursion (both libyaml's and PyYAML's parsers keep explicit stacks),
    and the scan stops at the first collection that is too deep, so a 10⁶-deep file costs
    nothing; on the project's graphs it adds about half the cost of composing."""
    loader = _Loader(text)
    start, end = (yaml.MappingStartEvent, yaml.SequenceStartEvent), (yaml.MappingEndEvent, yaml.SequenceEndEvent)
    depth = 0
    try:
        while True:
            ev = loader.get_event()
            if ev is None or isinstance(ev, yaml.StreamEndEvent):
                return
            if isinstance(ev, start):
                depth += 1
                if depth > MAX_YAML_DEPTH:
                    raise GraphError(Diagnostic(file, *_mark(ev), f"YAML nested too deeply: more than "
                                                f"{MAX_YAML_DEPTH} levels of lists and mappings"))
            elif isinstance(ev, end):
                depth -= 1
    finally:
        loader.dispose()


def parse_yaml(text: str, file: str) -> _Doc:
    """Parse YAML text into python data (YAML 1.2 core-schema scalars, plain data only) with
    the place of every value; GraphError for malformed YAML or nesting over MAX_YAML_DEPTH."""
    doc = _Doc(file)
    loader = None
    try:
        _check_depth(text, file)
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
    try:
        doc.data = _to_py(doc, root, ())
    except RecursionError:  # cannot happen below MAX_YAML_DEPTH; kept as a guard
        raise GraphError(Diagnostic(file, 1, 1, "malformed YAML: nested too deeply")) from None
    return doc


# ---------------------------------------------------------------------------------------------
# validation


def did_you_mean(word: str, choices) -> str:
    choices = list(choices)
    low = {c.lower(): c for c in choices}
    if word.lower() in low and low[word.lower()] != word:
        return f"; did you mean '{low[word.lower()]}'?"
    m = difflib.get_close_matches(word, choices, n=1, cutoff=0.6)
    return f"; did you mean '{m[0]}'?" if m else ""


def parse_set(items: list[str]) -> dict[str, Any]:
    """``["k=v", ...]`` from ``--set``; values are parsed as YAML scalars/flow values, read
    as in graph files (YAML 1.2 core schema: ``--set label=no`` is the string "no")."""
    out = {}
    for it in items or []:
        k, eq, v = it.partition("=")
        k = k.strip()
        if not eq or not k:
            raise UsageError(f"--set expects NAME=VALUE, got {it!r}")
        if not v.strip():
            out[k] = ""
            continue
        try:
            doc = parse_yaml(v, f"--set {k}")
        except GraphError as e:
            why = "; ".join(d.message for d in e.diagnostics)
            raise UsageError(f"--set {k}: cannot parse value {v!r}: {why}") from None
        if doc.diags:
            raise UsageError(f"--set {k}: cannot parse value {v!r}: " + "; ".join(d.message for d in doc.diags))
        out[k] = doc.data
    return out


def load_graph(path: str | os.PathLike, registry: Registry, overrides: dict | None = None,
               check_backends: bool = True, text: str | bytes | None = None) -> Graph:
    """Load, resolve and validate a graph file; raise GraphError listing every problem.

    ``text``: the file's content as edited but not saved (the studio); ``path`` then only names
    it in messages and anchors its relative paths."""
    path = os.fspath(path)
    if isinstance(path, bytes):
        path = os.fsdecode(path)
    if "\0" in path:
        raise UsageError(f"{path!r}: a graph file path cannot hold a NUL byte")
    if text is None and os.path.isdir(path):
        raise UsageError(f"{path}: is a folder, not a graph file")
    if text is None and os.path.exists(path) and not os.path.isfile(path):
        raise UsageError(f"{path}: is not a regular file (a FIFO, socket or device), not a graph file")
    try:
        raw = Path(path).read_bytes() if text is None else (
            text.encode() if isinstance(text, str) else text)
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
    try:
        return _validate(doc, data, path, registry, overrides or {}, check_backends)
    except RecursionError:  # e.g. a --set value or a validator: exit 2, never a crash
        raise GraphError(Diagnostic(path, 1, 1, "nested too deeply to load")) from None


def _kind(v) -> str:
    return {dict: "a mapping", list: "a list", str: "a string", type(None): "nothing"}.get(type(v), type(v).__name__)


def _validate(doc: _Doc, data: dict, path: str, reg: Registry, overrides: dict,
              check_backends: bool) -> Graph:
    for k in data:
        if k not in TOP_KEYS:
            doc.at((k,), f"unknown top-level key '{k}'{did_you_mean(k, TOP_KEYS)}", key=True)
    if "graphkit" not in data:
        doc.at((), "missing 'graphkit: 1' (the graph file format version)")
    elif data["graphkit"] != FORMAT:
        doc.at(("graphkit",), f"unsupported graph format {data['graphkit']!r}; this graphkit reads format {FORMAT}")
    name = data.get("name", Path(path).stem)
    if not isinstance(name, str) or not _NAME_RE.match(name):
        doc.at(("name",), f"'name' must be a word of letters, digits, '_' or '-', got {name!r}")
        name = Path(path).stem

    gparams = data.get("params") or {}
    if not isinstance(gparams, dict):
        doc.at(("params",), f"'params' must be a mapping of name: default value, got {_kind(gparams)}")
        gparams = {}
    for k in gparams:
        if not _NAME_RE.match(k):
            doc.at(("params", k), f"graph param name {k!r} must be letters, digits and '_'", key=True)
    gparams = dict(gparams)
    for k, v in overrides.items():
        if k not in gparams:
            raise UsageError(f"--set {k}: the graph has no param '{k}'{did_you_mean(k, gparams)}"
                             + (f" (its params: {', '.join(gparams)})" if gparams else " (it has no params)"))
        gparams[k] = v

    nodes_raw = data.get("nodes")
    if nodes_raw is None:
        doc.at((), "missing 'nodes'")
        nodes_raw = {}
    elif not isinstance(nodes_raw, dict):
        doc.at(("nodes",), f"'nodes' must be a mapping of node name: node, got {_kind(nodes_raw)}")
        nodes_raw = {}

    nodes: dict[str, GNode] = {}
    pending_inputs: list[tuple[str, str, Any]] = []
    base_dir = os.path.dirname(os.path.abspath(path))
    for nname, spec in nodes_raw.items():
        npath = ("nodes", nname)
        if not _NAME_RE.match(nname):
            doc.at(npath, f"node name {nname!r} must start with a letter or '_' and hold letters, digits, '_' or '-'", key=True)
            continue
        if not isinstance(spec, dict):
            doc.at(npath, f"node '{nname}' must be a mapping with 'type', 'inputs', 'params', got {_kind(spec)}")
            continue
        for k in spec:
            if k not in NODE_KEYS:
                doc.at(npath + (k,), f"node '{nname}': unknown key '{k}'{did_you_mean(k, NODE_KEYS)}", key=True)
        tname = spec.get("type")
        if not isinstance(tname, str):
            doc.at(npath + ("type",) if "type" in spec else npath, f"node '{nname}': missing or bad 'type'")
            continue
        if tname in reg.conflicts:
            where = " and by ".join(e.where() for e in reg.conflicts[tname])
            doc.at(npath + ("type",), f"node '{nname}': node type '{tname}' is provided twice: by {where}")
            continue
        if tname not in reg.nodes:
            doc.at(npath + ("type",), f"node '{nname}': unknown node type '{tname}'{did_you_mean(tname, reg.nodes)}")
            continue
        try:
            cls = reg.node_class(tname)
        except GraphkitError as e:
            doc.at(npath + ("type",), f"node '{nname}': {e}")
            continue
        params = _node_params(doc, npath, nname, cls, spec.get("params"), gparams)
        files: dict[str, str] = {}
        if params is not None:
            for fp in cls.input_file_params():
                value = getattr(params, fp)
                if value in (None, ""):
                    continue
                try:
                    resolved = cls.resolve_file(fp, value, base_dir)
                except BadInput as e:
                    doc.at(npath + ("params", fp), f"node '{nname}' ({tname}), param '{fp}': {e.message}")
                    continue
                if not os.path.isfile(resolved):
                    doc.at(npath + ("params", fp), f"node '{nname}' ({tname}), param '{fp}': file not found: {resolved}")
                    continue
                files[fp] = resolved
                try:
                    named = cls.referenced_files(fp, resolved)
                except BadInput as e:
                    doc.at(npath + ("params", fp), f"node '{nname}' ({tname}), param '{fp}': {e.message}")
                    continue
                for label, p in named.items():
                    if not os.path.isfile(p):
                        doc.at(npath + ("params", fp), f"node '{nname}' ({tname}), param '{fp}': "
                               f"{resolved} names {label} {p}, which is not found")
                    else:
                        files[f"{fp}:{label}"] = p
        backend = spec.get("backend")
        if backend is not None:
            names = reg.backend_names(tname)
            if not isinstance(backend, str) or backend not in names:
                doc.at(npath + ("backend",), f"node '{nname}' ({tname}): unknown backend {backend!r}"
                       f"{did_you_mean(str(backend), names)} (available: {', '.join(names)})")
                backend = None
            elif check_backends and backend != NUMPY:
                try:
                    why = probe(reg.backend_class(tname, backend))
                except GraphkitError as e:
                    why = str(e)
                if why:
                    doc.at(npath + ("backend",), f"node '{nname}' ({tname}): pinned backend '{backend}' is not available here: {why}")
        ins = spec.get("inputs") or {}
        if not isinstance(ins, dict):
            doc.at(npath + ("inputs",), f"node '{nname}': 'inputs' must be a mapping of port: node.port")
            ins = {}
        for port in ins:
            if port not in cls.in_ports:
                doc.at(npath + ("inputs", port), f"node '{nname}' ({tname}) has no input port '{port}'"
                       f"{did_you_mean(port, cls.in_ports)} (its inputs: {', '.join(cls.in_ports) or 'none'})", key=True)
        for port, p in cls.in_ports.items():
            if port not in ins and not p.optional:
                doc.at(npath + ("inputs",) if "inputs" in spec else npath,
                       f"node '{nname}' ({tname}): missing required input '{port}' ({p.type})")
        gn = GNode(nname, tname, cls, params, {}, backend, files, *doc.where(npath, key=True))
        nodes[nname] = gn
        for port, ref in ins.items():
            if port in cls.in_ports:
                pending_inputs.append((nname, port, ref))

    # connections, now that every node is known
    for nname, port, ref in pending_inputs:
        where = ("nodes", nname, "inputs", port)
        pdecl = nodes[nname].cls.in_ports[port]
        if pdecl.variadic:
            refs = ref if isinstance(ref, list) else [ref]
            wheres = [where + (i,) for i in range(len(refs))] if isinstance(ref, list) else [where]
        elif isinstance(ref, list):
            doc.at(where, f"node '{nname}', input '{port}' takes one connection, not a list")
            continue
        else:
            refs, wheres = [ref], [where]
        srcs = []
        for r, w in zip(refs, wheres):
            src = _parse_ref(doc, w, r, nodes, f"node '{nname}', input '{port}'")
            if src is None:
                continue
            have = nodes[src[0]].cls.out_ports[src[1]].type
            if not pdecl.type.accepts(have):
                doc.at(w, f"node '{nname}', input '{port}' takes {pdecl.type} but {src[0]}.{src[1]} gives {have}")
                continue
            srcs.append(src)
        if len(srcs) == len(refs):
            nodes[nname].inputs[port] = srcs if pdecl.variadic else srcs[0]

    outputs: dict[str, tuple[str, str]] = {}
    outs_raw = data.get("outputs")
    if isinstance(outs_raw, list):
        for i, ref in enumerate(outs_raw):
            src = _parse_ref(doc, ("outputs", i), ref, nodes, "output")
            if src:
                outputs[f"{src[0]}.{src[1]}"] = src
    elif isinstance(outs_raw, dict):
        for oname, ref in outs_raw.items():
            if not _NAME_RE.match(str(oname)):
                doc.at(("outputs", oname), f"output name {oname!r} must be letters, digits, '_' or '-'", key=True)
                continue
            src = _parse_ref(doc, ("outputs", oname), ref, nodes, f"output '{oname}'")
            if src:
                outputs[oname] = src
    elif outs_raw is not None:
        doc.at(("outputs",), f"'outputs' must be a list of node.port or a mapping name: node.port, got {_kind(outs_raw)}")

    if not doc.diags:
        _check_cycles(doc, nodes)
    if doc.diags:
        raise GraphError(doc.diags)
    if not outputs:  # default: every output of every node nobody consumes
        used = {n for g in nodes.values() for n in g.sources()}
        for n, g in nodes.items():
            if n not in used:
                for p in g.cls.out_ports:
                    outputs[f"{n}.{p}"] = (n, p)
    return Graph(name, os.path.abspath(path), base_dir, gparams, nodes, outputs)


def _parse_ref(doc, where, ref, nodes, what) -> tuple[str, str] | None:
    if not isinstance(ref, str) or "." not in ref:
        doc.at(where, f"{what}: expected 'node.port', got {ref!r}")
        return None
    src, _, sport = ref.rpartition(".")
    if src not in nodes:
        doc.at(where, f"{what}: no node named '{src}'{did_you_mean(src, nodes)}")
        return None
    outs = nodes[src].cls.out_ports
    if sport not in outs:
        doc.at(where, f"{what}: node '{src}' ({nodes[src].type}) has no output port '{sport}'"
               f"{did_you_mean(sport, outs)} (its outputs: {', '.join(outs)})")
        return None
    return src, sport


def _substitute(doc, path, v, gparams):
    if isinstance(v, str):
        m = _REF_RE.fullmatch(v.strip())
        if m:
            k = m.group(1)
            if k not in gparams:
                doc.at(path, f"unknown graph param '{k}'{did_you_mean(k, gparams)}")
                return None
            return gparams[k]

        def rep(mm):
            k = mm.group(1)
            if k not in gparams:
                doc.at(path, f"unknown graph param '{k}'{did_you_mean(k, gparams)}")
                return mm.group(0)
            return str(gparams[k])

        return _REF_RE.sub(rep, v)
    if isinstance(v, dict):
        return {k: _substitute(doc, path + (k,), x, gparams) for k, x in v.items()}
    if isinstance(v, list):
        return [_substitute(doc, path + (i,), x, gparams) for i, x in enumerate(v)]
    return v


def _node_params(doc, npath, nname, cls, raw, gparams):
    ppath = npath + ("params",)
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        doc.at(ppath, f"node '{nname}': 'params' must be a mapping, got {_kind(raw)}")
        return None
    n_diags = len(doc.diags)
    raw = _substitute(doc, ppath, raw, gparams)
    if len(doc.diags) > n_diags:  # an unknown ${params.X}: already reported
        return None
    try:
        return cls.Params.model_validate(raw)
    except ValidationError as e:
        fields = list(cls.Params.model_fields)
        for err in e.errors():
            loc = tuple(err["loc"])
            field_name = str(loc[0]) if loc else ""
            if err["type"] == "extra_forbidden":
                doc.at(ppath + loc, f"node '{nname}' ({cls.type_name}): unknown param '{field_name}'"
                       f"{did_you_mean(field_name, fields)} (its params: {', '.join(fields) or 'none'})", key=True)
            elif err["type"] == "missing":
                doc.at(ppath, f"node '{nname}' ({cls.type_name}): missing required param '{field_name}'")
            else:
                got = err.get("input")
                got_s = f" (got {got!r})" if not isinstance(got, (dict, list)) else ""
                doc.at(ppath + loc, f"node '{nname}' ({cls.type_name}), param '{'.'.join(map(str, loc))}': {err['msg']}{got_s}")
        return None
    except Exception as e:  # a validator that raised something unusual
        doc.at(ppath, f"node '{nname}' ({cls.type_name}): bad params: {e}")
        return None


def _check_cycles(doc, nodes):
    # graphlib (stdlib) rather than networkx: validation runs on every start, and importing
    # networkx costs ~0.2 s of the 0.6 s budget for an all-cached re-run.
    from graphlib import CycleError, TopologicalSorter

    ts = TopologicalSorter({n: sorted(g.sources()) for n, g in nodes.items()})
    try:
        ts.prepare()
    except CycleError as e:
        cyc = list(e.args[1])  # [a, b, ..., a]: each depends on the next
        names = list(reversed(cyc))
        doc.at(("nodes", names[0]), "cycle: " + " → ".join(names), key=True)


__all__ = ["Graph", "GNode", "load_graph", "parse_set"]
