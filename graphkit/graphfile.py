"""Loading graph files (YAML, format 1): the first stage of a graph's way through the engine.

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

The loader here turns a graph file (:func:`read_graph`) or a dict into plain data with the
place of every value; :func:`load_graph`, :func:`load_dict` and :func:`load` then hand it to
:mod:`graphkit.validate`, which checks it and builds the plain :mod:`graphkit.model` (that
module and the checks import nothing from here: no YAML past this stage).

Everything is checked before anything runs (:mod:`graphkit.validate`, one checker per concern);
each problem is reported as ``file:line:col`` with the node and port, and a did-you-mean where
one fits.  Only plain YAML data is accepted (no tags that build objects), so a graph file cannot
run code.  :func:`load_dict` takes the same graph as a Python dict, through the same checks.
"""
from __future__ import annotations

import contextlib
import gc
import os
import re
from pathlib import Path
from typing import Any

import yaml

from .errors import Diagnostic, GraphError, UsageError
from .model import GNode, Graph, kind  # noqa: F401 - GNode, Graph: also imported from here
from .registry import Registry
from .suggest import did_you_mean  # noqa: F401 - also imported from here by older callers
from .validate import validate

_PLAIN_TAGS = {
    "tag:yaml.org,2002:str", "tag:yaml.org,2002:int", "tag:yaml.org,2002:float",
    "tag:yaml.org,2002:bool", "tag:yaml.org,2002:null",
}
MAX_YAML_NODES = 200_000
#: deepest nesting of YAML collections a graph file (or a --set value) may have, checked on the
#: parser's events as they come (:class:`_Composer` keeps explicit stacks; the checks and
#: digests of values after it recurse over a value's nesting, never over the graph's depth).
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
    which = tag.rpartition(":")[2]
    if which == "str":
        return value
    parse = _CORE_SCALARS.get(which)
    got = _NOT_CORE if parse is None else parse(value)
    if got is _NOT_CORE:
        raise ValueError(f"not a YAML 1.2 {which}")
    return got


_NOT_CORE = object()  # a text that is not a valid scalar of the tag


def _core_int(value: str) -> Any:
    if _INT_RE.match(value):
        return int(value, 10)
    if value[:2] in ("0o", "0x") and len(value) > 2:
        return int(value[2:], 8 if value[1] == "o" else 16)
    return _NOT_CORE


def _core_float(value: str) -> Any:
    low = value.lower()
    if low in (".inf", "+.inf", "-.inf", ".nan"):
        return float(low.replace(".", ""))
    if _FLOAT_RE.match(value) or _INT_RE.match(value):
        return float(value)
    return _NOT_CORE


_NULLS = ("~", "null", "Null", "NULL", "")
_BOOLS = {"true": True, "True": True, "TRUE": True, "false": False, "False": False, "FALSE": False}
_CORE_SCALARS = {
    "null": lambda v: None if v in _NULLS else _NOT_CORE,
    "bool": lambda v: _BOOLS.get(v, _NOT_CORE),
    "int": _core_int,
    "float": _core_float,
}


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

    def for_file(self, file: str) -> "_Doc":
        """This parse read as the graph file ``file``: its places and data shared, its problems
        placed in ``file``; what a check adds goes to the copy only."""
        doc = _Doc(file)
        doc.locs, doc.key_locs, doc.count, doc.data = self.locs, self.key_locs, self.count, self.data
        doc.diags = [Diagnostic(file, d.line, d.col, d.message) for d in self.diags]
        return doc


def _mark(n) -> tuple[int, int]:
    return n.start_mark.line + 1, n.start_mark.column + 1


_STARTS = (yaml.MappingStartEvent, yaml.SequenceStartEvent)
_ENDS = (yaml.MappingEndEvent, yaml.SequenceEndEvent)


class _Composer:
    """Python data and the place of every value, straight from the parser's events.

    libyaml's parser makes the events in C; the ``yaml.Node`` tree that PyYAML's composer would
    build from them (a Python object and a resolver call per value: about 80 % of the time of
    loading a large graph file) is skipped.  One pass, with explicit stacks and no recursion,
    does what composing and walking the tree did: collections nested deeper than
    MAX_YAML_DEPTH are refused at the first one, an alias is read again from its anchor's
    events (each time it is used, counted against MAX_YAML_NODES), keys must be plain scalars,
    and tags other than the plain ones are reported at their place."""

    def __init__(self, doc: _Doc, loader):
        self.doc, self.loader = doc, loader
        self.depth = 0
        self.anchors: dict[str, list] = {}  # anchor -> its node's events (complete)
        self.recording: list[tuple[str, list, int]] = []  # anchors being read: (name, events, depth)
        self.replays: list = []  # iterators over the events of the aliases being read again
        self.documents = 0
        self.composing = True  # False once composing failed: only the parser's checks are left
        self.too_deep = False
        self.tags: dict[tuple, str] = {}  # (text, implicit) -> resolved tag of a plain scalar

    def event(self):
        """The next event: from an alias being read again, else from the parser."""
        while self.replays:
            ev = next(self.replays[-1], None)
            if ev is not None:
                return ev
            self.replays.pop()
        ev = self.loader.get_event()
        kind = type(ev)
        if kind in _STARTS:
            self.depth += 1
            if self.depth > MAX_YAML_DEPTH:
                self.too_deep = True
                raise GraphError(Diagnostic(self.doc.file, *_mark(ev), f"YAML nested too deeply: more than "
                                            f"{MAX_YAML_DEPTH} levels of lists and mappings"))
        elif kind in _ENDS:
            self.depth -= 1
        if self.composing and (self.recording or kind is yaml.DocumentStartEvent
                               or getattr(ev, "anchor", None) is not None):
            self._anchor(ev)
        return ev

    def finish(self, error: Exception) -> None:
        """After ``error``, read the rest of the stream: a syntax error or nesting over
        MAX_YAML_DEPTH anywhere is reported first, and after an error found while converting
        values (too many, a cyclic alias) a composition error too, in the order loading used to
        find them (parse the whole stream, then compose, then convert)."""
        if self.too_deep:
            return
        self.replays.clear()
        self.composing = not isinstance(error, yaml.composer.ComposerError)
        while not isinstance(self.event(), (yaml.StreamEndEvent, type(None))):
            pass

    def _anchor(self, ev) -> None:
        """Record the events of anchored nodes; refuse undefined aliases, reused anchors and a
        second document (as PyYAML's composer)."""
        for _, events, _ in self.recording:
            events.append(ev)
        name = getattr(ev, "anchor", None)
        known = name in self.anchors or name in {a for a, _, _ in self.recording}
        if isinstance(ev, yaml.DocumentStartEvent):
            self.documents += 1
            if self.documents > 1:
                raise yaml.composer.ComposerError("expected a single document in the stream", None,
                                                  "but found another document", ev.start_mark)
        elif isinstance(ev, yaml.AliasEvent):
            if not known:
                raise yaml.composer.ComposerError(None, None, "found undefined alias", ev.start_mark)
        elif name is not None:
            if known:
                raise yaml.composer.ComposerError("found duplicate anchor; first occurrence", None,
                                                  "second occurrence", ev.start_mark)
            self.recording.append((name, [ev], self.depth - isinstance(ev, _STARTS)))
        while self.recording and self.recording[-1][2] == self.depth and not isinstance(ev, _STARTS):
            a, events, _ = self.recording.pop()
            self.anchors[a] = events

    def node(self):
        """The next node's first event, an alias replaced by its anchor's events."""
        ev = self.event()
        while isinstance(ev, yaml.AliasEvent):
            if ev.anchor not in self.anchors:  # its own anchor, still being read: a cycle
                raise GraphError(Diagnostic(self.doc.file, 1, 1, "malformed YAML: nested too deeply"))
            self.replays.append(iter(self.anchors[ev.anchor]))
            ev = self.event()
        return ev

    def skip(self, ev) -> None:
        """Read past the node that starts with ``ev`` (aliases in it are not read again)."""
        depth = isinstance(ev, _STARTS)
        while depth:
            ev = self.event()
            depth += isinstance(ev, _STARTS) - isinstance(ev, _ENDS)

    def document(self) -> tuple[bool, Any]:
        """(whether the stream holds a document, its data)."""
        self.event()  # StreamStartEvent
        ev = self.event()
        if isinstance(ev, yaml.StreamEndEvent):
            return False, None
        data = self.compose()
        self.event()  # DocumentEndEvent
        self.event()  # StreamEndEvent (a second document is refused by _anchor)
        return True, data

    def compose(self):
        """The root node's data: an explicit stack of the collections being filled."""
        stack: list[tuple[tuple, Any]] = []  # (path, dict or list)
        ev, path = self.node(), ()
        while True:
            if isinstance(ev, _ENDS):
                path, value = stack.pop()
            else:
                value = self.value(ev, path)
                if isinstance(value, _Open):
                    stack.append((path, value.data))
                    ev, path = self._child(stack)
                    continue
            if not stack:
                return value
            parent = stack[-1][1]
            if isinstance(parent, list):
                parent.append(value)
            else:
                parent[path[-1]] = value
            ev, path = self._child(stack)

    def _child(self, stack) -> tuple[Any, tuple]:
        """The first event of the next child of the innermost collection, and its path (the
        collection's end event when it has no more); a mapping's key is read here."""
        ppath, parent = stack[-1]
        if isinstance(parent, list):
            return self.node(), ppath + (len(parent),)
        while True:
            kev = self.node()
            if isinstance(kev, yaml.MappingEndEvent):
                return kev, ppath
            key = self.key(kev, ppath, parent)
            if key is not None:
                return self.node(), ppath + (key,)
            self.skip(self.event())  # the value of a refused key (an alias in it is not read)

    def key(self, kev, ppath: tuple, parent: dict) -> str | None:
        """A mapping key's text, or None (reported) when it cannot be one."""
        doc = self.doc
        if not isinstance(kev, yaml.ScalarEvent) or self.tag(kev) not in _PLAIN_TAGS:
            doc.diags.append(Diagnostic(doc.file, *_mark(kev), "mapping keys must be plain scalars"))
            self.skip(kev)
            return None
        k = str(kev.value)  # keys are names: take their text (YAML 1.1 would make `off` False)
        if k == "<<":
            doc.diags.append(Diagnostic(doc.file, *_mark(kev), "YAML merge keys ('<<') are not supported"))
        elif k in parent:
            doc.diags.append(Diagnostic(doc.file, *_mark(kev), f"duplicate key '{k}'"))
        else:
            doc.key_locs[ppath + (k,)] = _mark(kev)
            return k
        return None

    def value(self, ev, path: tuple):
        """The python value of the node starting with ``ev`` (an _Open for a collection to fill)."""
        doc = self.doc
        doc.count += 1
        if doc.count > MAX_YAML_NODES:
            raise GraphError(Diagnostic(doc.file, *_mark(ev), f"graph file too large (over {MAX_YAML_NODES} YAML values, aliases included)"))
        doc.locs[path] = _mark(ev)
        tag = self.tag(ev)
        kind = _MAP if isinstance(ev, yaml.MappingStartEvent) else _SEQ if isinstance(ev, yaml.SequenceStartEvent) else None
        if (tag != kind) if kind else (tag not in _PLAIN_TAGS):
            doc.at(path, f"YAML tag '{tag.replace('tag:yaml.org,2002:', '!!')}' is not allowed: graph files hold plain data only")
            self.skip(ev)
            return None
        if kind:
            return _Open({} if kind == _MAP else [])
        try:
            return core_scalar(tag, ev.value)
        except (ValueError, OverflowError) as e:
            doc.at(path, f"bad scalar {ev.value!r}: {e}")
            return None

    def tag(self, ev) -> str:
        """A node event's tag, resolved as PyYAML's composer does (by :class:`_CoreResolver`)."""
        if ev.tag is not None and ev.tag != "!":
            return ev.tag
        if isinstance(ev, yaml.ScalarEvent):
            key = (ev.value, ev.implicit)
            tag = self.tags.get(key)
            if tag is None:
                tag = self.tags[key] = self.loader.resolve(yaml.ScalarNode, ev.value, ev.implicit)
            return tag
        return _MAP if isinstance(ev, yaml.MappingStartEvent) else _SEQ


_MAP, _SEQ = "tag:yaml.org,2002:map", "tag:yaml.org,2002:seq"


class _Open:
    """A collection just started: filled by the events that follow."""

    __slots__ = ("data",)

    def __init__(self, data):
        self.data = data


def parse_yaml(text: str, file: str) -> _Doc:
    """Parse YAML text into python data (YAML 1.2 core-schema scalars, plain data only) with
    the place of every value; GraphError for malformed YAML or nesting over MAX_YAML_DEPTH."""
    doc = _Doc(file)
    loader = _Loader(text)
    composer = _Composer(doc, loader)
    try:
        try:
            found, data = composer.document()
        except (yaml.composer.ComposerError, GraphError) as e:
            composer.finish(e)
            raise
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
    finally:
        loader.dispose()
    if not found:
        raise GraphError(Diagnostic(file, 1, 1, "the graph file is empty"))
    doc.data = data
    return doc


# ---------------------------------------------------------------------------------------------
# validation


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
               check_backends: bool = True, text: str | bytes | None = None, parsed: _Doc | None = None) -> Graph:
    """Load, resolve and validate a graph file; raise GraphError listing every problem.

    ``text``: the file's content as edited but not saved (the studio); ``path`` then only names
    it in messages and anchors its relative paths.  ``parsed``: ``text`` as :func:`parse_yaml`
    read it already (the studio's document), used instead of parsing it again."""
    path = _graph_path(path)
    try:
        with gc_paused():
            doc = read_graph(path, text, parsed)
            return validate(doc, doc.data, os.path.abspath(path), os.path.dirname(os.path.abspath(path)), registry,
                            overrides or {}, check_backends)
    except RecursionError:  # e.g. a --set value or a validator: exit 2, never a crash
        raise GraphError(Diagnostic(path, 1, 1, "nested too deeply to load")) from None


@contextlib.contextmanager
def gc_paused():
    """The cyclic garbage collector paused while a graph is loaded: loading allocates a large
    structure that lives on (no garbage cycles), which the collector would otherwise traverse
    again and again as it grows (a third of a 10k-node graph's validation)."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _graph_path(path: str | os.PathLike) -> str:
    path = os.fspath(path)
    if isinstance(path, bytes):
        path = os.fsdecode(path)
    if "\0" in path:
        raise UsageError(f"{path!r}: a graph file path cannot hold a NUL byte")
    return path


def read_graph(path: str, text: str | bytes | None = None, parsed: _Doc | None = None) -> _Doc:
    """The graph file ``path`` (or its unsaved ``text``, or that text's ``parsed`` document) as
    plain data with places: a mapping, not yet checked (:func:`graphkit.validate.validate` does that)."""
    raw = _read_bytes(path) if text is None else (text.encode() if isinstance(text, str) else text)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise GraphError(Diagnostic(path, 1, 1, f"graph file is not UTF-8 text: {e.reason} at byte {e.start}")) from None
    doc = parse_yaml(text, path) if parsed is None else parsed.for_file(path)
    if doc.diags:
        raise GraphError(doc.diags)
    if not isinstance(doc.data, dict):
        raise GraphError(Diagnostic(path, 1, 1, f"a graph file must be a mapping, got {kind(doc.data)}"))
    return doc


def _read_bytes(path: str) -> bytes:
    if os.path.isdir(path):
        raise UsageError(f"{path}: is a folder, not a graph file")
    if os.path.exists(path) and not os.path.isfile(path):
        raise UsageError(f"{path}: is not a regular file (a FIFO, socket or device), not a graph file")
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise UsageError(f"{path}: graph file not found") from None
    except OSError as e:
        raise UsageError(f"{path}: cannot read graph file: {e.strerror or e}") from None


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
        raise GraphError(_PathDiagnostic(source, 0, 0, f"a graph must be a mapping, got {kind(data)}", ""))
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


__all__ = ["Graph", "GNode", "load_graph", "load_dict", "load", "read_graph", "parse_set"]
