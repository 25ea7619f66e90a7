"""Checking a parsed graph: one small checker per concern.

The checkers run in this order over the parsed data, each reporting every problem it finds
through ``doc.at(key path, message)``, which places it at the graph file's ``line:col`` (for a
graph given as a Python dict, it names the key path):

* :func:`check_structure`  top-level keys, format version, name, graph params (and ``--set``)
* :func:`check_sweeps`     the ``sweeps:`` section (see :mod:`graphkit.sweeps`)
* :func:`check_nodes`      each node's keys, type, pinned backend and ``foreach``
* :func:`check_params`     each node's (or instance's) params and input files
* :func:`check_references` each input connection ``node.port`` / ``node[*].port`` and required inputs
* :func:`check_types`      that every connection's port types fit
* :func:`check_outputs`    ``outputs:``, and that no two outputs write the same file
* :func:`check_cycles`     that the graph has no cycle

Nothing is built until every checker has run, so one run of ``validate`` lists every problem.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError

from .errors import BadInput, GraphError, GraphkitError, UsageError
from .model import CACHE_KEYS, CACHE_OPTIONS, FORMAT, NODE_KEYS, NAME_RE, TOP_KEYS, GNode, Graph, kind
from .node import probe
from .paths import OutputNames, UnsafePath, safe_relpath
from .registry import NUMPY, Registry
from .suggest import did_you_mean, unknown_keys
from .sweeps import SUB_RE, Sweep, instance_node, parse_sweeps
from .types import mismatch_names

_MISSING = object()
_ANY_REF = re.compile(r"\$\{[^}]*\}")
_REF = re.compile(r"^(?P<node>[^\[\].\s]+)(?:\[(?P<pick>[^\]]*)\])?\.(?P<port>[^.\[\]\s]+)$")


@dataclass
class Ref:
    """One connection as written: ``node.port``, ``node[*].port`` or ``node[INSTANCE].port``."""

    src: str
    port: str
    pick: str | None
    where: tuple
    text: str


@dataclass
class Spec:
    """One entry of ``nodes:`` that passed :func:`check_nodes`."""

    name: str
    path: tuple
    raw: dict
    type: str
    cls: type
    backend: str | None
    sweep: Sweep | None = None
    instances: list[str] = field(default_factory=list)  # its GNode names, in sweep order
    refs: dict[str, list[Ref]] = field(default_factory=dict)  # input port -> connections
    ref_keys: list[str] | None = None  # params that hold a ${...} reference
    file_params: list[str] = field(default_factory=list)  # its InputFile params

    def label(self, instance: str | None = None) -> str:
        n = instance_node(self.name, instance) if instance is not None else self.name
        return f"node '{n}' ({self.type})"


class Check:
    """What the checkers share: the document (places + diagnostics), the registry, the results."""

    def __init__(self, doc, data: dict, graph_path: str, base_dir: str, reg: Registry,
                 overrides: dict, check_backends: bool):
        self.doc, self.data, self.reg = doc, data, reg
        self.graph_path, self.base_dir = graph_path, base_dir
        self.overrides, self.check_backends = overrides, check_backends
        stem = Path(graph_path).stem
        self.name = stem if NAME_RE.match(stem) else "graph"  # a dict's source is "<dict>"
        self.gparams: dict[str, Any] = {}
        self.sweeps: dict[str, Sweep] = {}
        self.declared: set[str] = set()  # every node name written in the file
        self.specs: dict[str, Spec] = {}
        self.nodes: dict[str, GNode] = {}
        self.outputs: dict[str, tuple[str, str]] = {}
        self.output_refs: list[tuple[str | None, Ref]] = []
        self.output_groups: dict[str, list[str]] = {}
        self.order: list[str] = []
        raw = data.get("sweeps")
        self.raw_sweeps: dict = raw if isinstance(raw, dict) else {}
        self.silent_misses = 0  # references to a broken sweep: not reported again, but not valid

    def at(self, path, message, key=False):
        self.doc.at(path, message, key=key)

    @property
    def n_diags(self) -> int:
        return len(self.doc.diags)


# ---------------------------------------------------------------------------------------------
# ${...} substitution


def substitute(c: Check, path: tuple, v: Any, ctx) -> Any:
    """``v`` with every ``${params.X}``, ``${SWEEP.FIELD}`` and ``${SWEEP[*].FIELD}`` replaced.

    ``ctx`` is (spec, instance) inside a node, ``"sweeps"`` inside the sweeps section.  A whole
    string that is one reference keeps the value's type; references inside text become text.
    """
    if isinstance(v, str):
        if "${" not in v:
            return v
        m = SUB_RE.fullmatch(v.strip())
        if m:
            r = _resolve(c, path, m, ctx)
            return None if r is _MISSING else r
        for bad in _ANY_REF.findall(v):
            if not SUB_RE.fullmatch(bad):
                c.at(path, f"malformed reference {bad!r}: write ${{params.NAME}}, ${{SWEEP.FIELD}} or "
                     "${SWEEP[*].FIELD}")
                return v

        def rep(mm):
            r = _resolve(c, path, mm, ctx)
            return mm.group(0) if r is _MISSING else str(r)

        return SUB_RE.sub(rep, v)
    if isinstance(v, dict):
        return {k: substitute(c, path + (k,), x, ctx) for k, x in v.items()}
    if isinstance(v, list):
        return [substitute(c, path + (i,), x, ctx) for i, x in enumerate(v)]
    return v


def _resolve(c: Check, path, m, ctx):
    ns, star, fld = m.group(1), m.group(2), m.group(3)
    ref = m.group(0)
    if ns == "params":
        return _resolve_param(c, path, ref, star, fld)
    if ctx == "sweeps":
        c.at(path, f"{ref}: a sweep's definition may use graph params (${{params.NAME}}) only")
        return _MISSING
    sw = c.sweeps.get(ns)
    if sw is None:
        if ns in c.raw_sweeps:
            c.silent_misses += 1  # a sweep with its own (already reported) problem
            return _MISSING
        known = list(c.sweeps)
        c.at(path, f"unknown sweep '{ns}' in {ref}{did_you_mean(ns, known + ['params'])}"
             + (f" (sweeps: {', '.join(known)})" if known else " (the graph has no sweeps; graph params are ${params.NAME})"))
        return _MISSING
    fields = sw.fields()
    if fld not in fields:
        c.at(path, f"sweep '{ns}' has no field '{fld}'{did_you_mean(fld, fields)} (its fields: {', '.join(fields)})")
        return _MISSING
    return _resolve_field(c, path, ref, sw, star, fld, ctx)


def _resolve_param(c: Check, path, ref: str, star, fld: str):
    """The value of ``${params.FLD}``."""
    if star:
        c.at(path, f"{ref}: graph params have no instances; write ${{params.{fld}}}")
        return _MISSING
    if fld not in c.gparams:
        c.at(path, f"unknown graph param '{fld}'{did_you_mean(fld, c.gparams)}")
        return _MISSING
    return c.gparams[fld]


def _resolve_field(c: Check, path, ref: str, sw: Sweep, star, fld: str, ctx):
    """The value of field ``fld`` (which sweep ``sw`` has) for the instance of ``ctx``, or the
    list of it over every instance (``star``)."""
    ns = sw.name
    if star:
        missing = [i.name for i in sw.instances if fld not in i.fields]
        if missing:
            c.at(path, f"{ref}: instance '{missing[0]}' of sweep '{ns}' has no field '{fld}'")
            return _MISSING
        return [i.fields[fld] for i in sw.instances]
    spec, inst = ctx
    if spec.sweep is not sw:
        c.at(path, f"node '{spec.name}' is not swept over '{ns}' ("
             + (f"foreach: {spec.sweep.name}" if spec.sweep else "it has no foreach")
             + f"); {ns}[*] gives the list over all instances: ${{{ns}[*].{fld}}}")
        return _MISSING
    if fld not in inst.fields:
        c.at(path, f"instance '{inst.name}' of sweep '{ns}' has no field '{fld}' (its fields: {', '.join(inst.fields)})")
        return _MISSING
    return inst.fields[fld]


def _uses_own_sweep(v: Any, sweep: str) -> bool:
    if isinstance(v, str):
        return "${" in v and any(m.group(1) == sweep and not m.group(2) for m in SUB_RE.finditer(v))
    if isinstance(v, dict):
        return any(_uses_own_sweep(x, sweep) for x in v.values())
    if isinstance(v, list):
        return any(_uses_own_sweep(x, sweep) for x in v)
    return False


# ---------------------------------------------------------------------------------------------
# the checkers


def check_structure(c: Check) -> None:
    """Top-level keys, the format version, the name and the graph params (with ``--set``)."""
    data = c.data
    for k in data:
        if k not in TOP_KEYS:
            c.at((k,), f"unknown top-level key '{k}'{did_you_mean(k, TOP_KEYS)}", key=True)
    if "graphkit" not in data:
        c.at((), "missing 'graphkit: 1' (the graph file format version)")
    elif data["graphkit"] != FORMAT:
        c.at(("graphkit",), f"unsupported graph format {data['graphkit']!r}; this graphkit reads format {FORMAT}")
    name = data.get("name", c.name)
    if not isinstance(name, str) or not NAME_RE.match(name):
        c.at(("name",), f"'name' must be a word of letters, digits, '_' or '-', got {name!r}")
    else:
        c.name = name
    gparams = data.get("params") or {}
    if not isinstance(gparams, dict):
        c.at(("params",), f"'params' must be a mapping of name: default value, got {kind(gparams)}")
        gparams = {}
    for k in gparams:
        if not NAME_RE.match(k):
            c.at(("params", k), f"graph param name {k!r} must be letters, digits and '_'", key=True)
    gparams = dict(gparams)
    for k, v in c.overrides.items():
        if k not in gparams:
            raise UsageError(f"--set {k}: the graph has no param '{k}'{did_you_mean(k, gparams)}"
                             + (f" (its params: {', '.join(gparams)})" if gparams else " (it has no params)"))
        gparams[k] = v
    c.gparams = gparams


def check_cache(c: Check) -> dict:
    """The ``cache:`` section: ``url`` (a folder, relative to the graph file, or an fsspec URL)
    and ``options`` that say where the store is (never credentials)."""
    raw = c.data.get("cache")
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        c.at(("cache",), f"'cache' must be a mapping with url and options, got {kind(raw)}")
        return {}
    for k in raw:
        if k not in CACHE_KEYS:
            c.at(("cache", k), f"unknown cache key '{k}'{did_you_mean(k, CACHE_KEYS)} (a graph's cache has "
                 f"{' and '.join(CACHE_KEYS)})", key=True)
    url, opts = raw.get("url"), raw.get("options") or {}
    if not isinstance(url, str) or not url.strip():
        c.at(("cache", "url") if "url" in raw else ("cache",), "the cache's 'url' must be a folder or an fsspec URL "
             "(e.g. s3://bucket/graphkit-cache)")
        return {}
    if "://" not in url and not os.path.isabs(url):
        url = os.path.join(c.base_dir, url)
    return {"url": url, "options": _cache_options(c, opts)}


def _cache_options(c: Check, opts) -> dict:
    """A graph file's cache options: only those that say where the cache is (a graph file is
    shared and committed: credentials come from the environment or the command line)."""
    if not isinstance(opts, dict):
        c.at(("cache", "options"), f"the cache's 'options' must be a mapping, got {kind(opts)}")
        return {}
    for k in opts:
        if k not in CACHE_OPTIONS:
            c.at(("cache", "options", k), f"cache option '{k}' cannot be set in a graph file, which says only where "
                 f"the cache is ({', '.join(CACHE_OPTIONS)}): give credentials and other options with "
                 "--cache-option, GRAPHKIT_CACHE_OPTIONS or the AWS environment", key=True)
    return {("client_kwargs.region_name" if k == "region_name" else k): v for k, v in opts.items()}


def check_sweeps(c: Check) -> None:
    """The ``sweeps:`` section: lists, matrices, ranges and globs (relative to the graph file)."""
    c.sweeps = parse_sweeps(c.doc, c.data.get("sweeps"), c.base_dir,
                            lambda path, v: substitute(c, path, v, "sweeps"))


def check_nodes(c: Check) -> None:
    """Each node's keys, its type (known, importable, not provided twice), backend and foreach."""
    nodes_raw = c.data.get("nodes")
    if nodes_raw is None:
        c.at((), "missing 'nodes'")
        return
    if not isinstance(nodes_raw, dict):
        c.at(("nodes",), f"'nodes' must be a mapping of node name: node, got {kind(nodes_raw)}")
        return
    for nname, raw in nodes_raw.items():
        npath = ("nodes", nname)
        if not NAME_RE.match(nname):
            c.at(npath, f"node name {nname!r} must start with a letter or '_' and hold letters, digits, '_' or '-'", key=True)
            continue
        c.declared.add(nname)
        if not isinstance(raw, dict):
            c.at(npath, f"node '{nname}' must be a mapping with 'type', 'inputs', 'params', got {kind(raw)}")
            continue
        unknown_keys(c.doc, npath, raw, NODE_KEYS, f"node '{nname}': ")
        cls = _node_type(c, npath, nname, raw.get("type"), "type" in raw)
        if cls is None:
            continue
        tname = raw["type"]
        backend = _backend(c, npath, nname, tname, raw.get("backend"))
        sweep = None
        fe = raw.get("foreach")
        if fe is not None:
            if not isinstance(fe, str) or fe not in c.sweeps:
                if isinstance(fe, str) and fe in c.raw_sweeps:
                    continue  # the sweep itself is broken: reported there
                c.at(npath + ("foreach",), f"node '{nname}': foreach must name a sweep, got {fe!r}"
                     f"{did_you_mean(str(fe), c.sweeps)}"
                     + (f" (sweeps: {', '.join(c.sweeps)})" if c.sweeps else " (the graph has no 'sweeps')"))
                continue
            sweep = c.sweeps[fe]
        c.specs[nname] = Spec(nname, npath, raw, tname, cls, backend, sweep)


def _node_type(c: Check, npath, nname, tname, given: bool):
    reg = c.reg
    if not isinstance(tname, str):
        c.at(npath + ("type",) if given else npath, f"node '{nname}': missing or bad 'type'")
        return None
    if tname in reg.conflicts:
        where = " and by ".join(e.where() for e in reg.conflicts[tname])
        c.at(npath + ("type",), f"node '{nname}': node type '{tname}' is provided twice: by {where}")
        return None
    if tname not in reg.nodes:
        c.at(npath + ("type",), f"node '{nname}': unknown node type '{tname}'{did_you_mean(tname, reg.nodes)}")
        return None
    try:
        return reg.node_class(tname)
    except GraphkitError as e:
        c.at(npath + ("type",), f"node '{nname}': {e}")
        return None


def _backend(c: Check, npath, nname, tname, backend):
    if backend is None:
        return None
    reg = c.reg
    names = reg.backend_names(tname)
    if not isinstance(backend, str) or backend not in names:
        c.at(npath + ("backend",), f"node '{nname}' ({tname}): unknown backend {backend!r}"
             f"{did_you_mean(str(backend), names)} (available: {', '.join(names)})")
        return None
    if c.check_backends and backend != NUMPY:
        try:
            why = probe(reg.backend_class(tname, backend))
        except GraphkitError as e:
            why = str(e)
        if why:
            c.at(npath + ("backend",), f"node '{nname}' ({tname}): pinned backend '{backend}' is not available here: {why}")
    return backend


def check_params(c: Check) -> None:
    """Each node's params (per instance of a swept node) and the input files they name."""
    for spec in c.specs.values():
        raw = spec.raw.get("params")
        if raw is not None and not isinstance(raw, dict):
            c.at(spec.path + ("params",), f"node '{spec.name}': 'params' must be a mapping, got {kind(raw)}")
            continue
        raw = raw or {}
        line, col = c.doc.where(spec.path, key=True)
        if spec.sweep is None:
            made = _params_and_files(c, spec, None, raw)
            if made is not None:
                c.nodes[spec.name] = GNode(spec.name, spec.type, spec.cls, made[0], {}, spec.backend, made[1],
                                           line, col, base=spec.name)
                spec.instances = [spec.name]
            continue
        shared = None  # params that do not use the instance are checked once, for all instances
        if not _uses_own_sweep(raw, spec.sweep.name):
            shared = _params_and_files(c, spec, spec.sweep.instances[0], raw)
            if shared is None:
                continue
        names = []
        for inst in spec.sweep.instances:
            made = shared or _params_and_files(c, spec, inst, raw)
            if made is None:
                break  # one instance's problems are enough: the others would repeat them
            n = instance_node(spec.name, inst.name)
            c.nodes[n] = GNode(n, spec.type, spec.cls, made[0], {}, spec.backend, made[1], line, col,
                               base=spec.name, instance=inst.name, sweep=spec.sweep.name)
            names.append(n)
        spec.instances = names


def _params_and_files(c: Check, spec: Spec, inst, raw: dict):
    """(params model, {InputFile param: path}) of one node or instance, or None (reported)."""
    if spec.ref_keys is None:  # which params hold ${...}: only those are substituted per instance
        spec.ref_keys = [k for k, v in raw.items() if _has_ref(v)]
        spec.file_params = spec.cls.input_file_params()
    values = _substituted(c, spec, inst, raw)
    params = None if values is None else _params_model(c, spec, inst, values)
    if params is None:
        return None
    if not spec.file_params:
        return params, {}
    files = _input_files(c, spec, _label(spec, inst), params)
    return None if files is None else (params, files)


def _label(spec: Spec, inst) -> str:
    return spec.label(inst.name if inst is not None and spec.sweep is not None else None)


def _substituted(c: Check, spec: Spec, inst, raw: dict) -> dict | None:
    """``raw`` params with their ``${...}`` references replaced for ``inst``; None on a problem."""
    ppath = spec.path + ("params",)
    n0, m0 = len(c.doc.diags), c.silent_misses
    values = dict(raw)
    for k in spec.ref_keys:
        values[k] = substitute(c, ppath + (k,), raw[k], (spec, inst))
    return None if len(c.doc.diags) > n0 or c.silent_misses > m0 else values


def _params_model(c: Check, spec: Spec, inst, values: dict):
    """The node's ``Params`` made from ``values``, or None (each problem reported)."""
    ppath = spec.path + ("params",)
    try:
        return spec.cls.Params.model_validate(values)
    except ValidationError as e:
        for err in e.errors():
            _param_error(c, spec, _label(spec, inst), ppath, err)
    except Exception as e:  # noqa: BLE001 - a validator that raised something unusual
        c.at(ppath, f"{_label(spec, inst)}: bad params: {e}")
    return None


def _param_error(c: Check, spec: Spec, label: str, ppath: tuple, err: dict) -> None:
    loc = tuple(err["loc"])
    field_name = str(loc[0]) if loc else ""
    if err["type"] == "extra_forbidden":
        fields = list(spec.cls.Params.model_fields)
        c.at(ppath + loc, f"{label}: unknown param '{field_name}'"
             f"{did_you_mean(field_name, fields)} (its params: {', '.join(fields) or 'none'})", key=True)
    elif err["type"] == "missing":
        c.at(ppath, f"{label}: missing required param '{field_name}'")
    else:
        got = err.get("input")
        got_s = f" (got {got!r})" if not isinstance(got, (dict, list)) else ""
        c.at(ppath + loc, f"{label}, param '{'.'.join(map(str, loc))}': {err['msg']}{got_s}")


def _has_ref(v: Any) -> bool:
    if isinstance(v, str):
        return "${" in v
    if isinstance(v, dict):
        return any(_has_ref(x) for x in v.values())
    if isinstance(v, list):
        return any(_has_ref(x) for x in v)
    return False


def _input_files(c: Check, spec: Spec, label: str, params) -> dict[str, str] | None:
    cls = spec.cls
    files: dict[str, str] = {}
    n0 = c.n_diags
    for fp in spec.file_params:
        value = getattr(params, fp)
        if value in (None, ""):
            continue
        where = spec.path + ("params", fp)
        try:
            resolved = cls.resolve_file(fp, value, c.base_dir)
        except BadInput as e:
            c.at(where, f"{label}, param '{fp}': {e.message}")
            continue
        if not os.path.isfile(resolved):
            c.at(where, f"{label}, param '{fp}': file not found: {resolved}")
            continue
        files[fp] = resolved
        try:
            named = cls.referenced_files(fp, resolved)
        except BadInput as e:
            c.at(where, f"{label}, param '{fp}': {e.message}")
            continue
        for flabel, p in named.items():
            if not os.path.isfile(p):
                c.at(where, f"{label}, param '{fp}': {resolved} names {flabel} {p}, which is not found")
            else:
                files[f"{fp}:{flabel}"] = p
    return files if c.n_diags == n0 else None


def parse_ref(c: Check, where: tuple, r: Any, what: str, consumer: Spec | None = None,
              variadic: bool = True) -> Ref | None:
    """A connection (``consumer`` given) or an output (``consumer`` None), checked; None if bad."""
    m = _REF.fullmatch(r) if isinstance(r, str) else None
    if m is None:
        c.at(where, f"{what}: expected 'node.port' (or 'node[*].port' for every instance), got {r!r}")
        return None
    node, pick, port = m.group("node"), m.group("pick"), m.group("port")
    src = c.specs.get(node)
    if src is None:
        if node not in c.declared:
            c.at(where, f"{what}: no node named '{node}'{did_you_mean(node, c.declared)}")
        return None  # else: the node has problems of its own, reported there
    outs = src.cls.out_ports
    if port not in outs:
        c.at(where, f"{what}: node '{node}' ({src.type}) has no output port '{port}'"
             f"{did_you_mean(port, outs)} (its outputs: {', '.join(outs)})")
        return None
    problem = _pick_problem(src, pick, port, consumer, variadic)
    if problem:
        c.at(where, f"{what}: {problem}")
        return None
    return Ref(node, port, pick, where, r)


def _pick_problem(src: Spec, pick: str | None, port: str, consumer: Spec | None, variadic: bool) -> str | None:
    """Why ``src.port`` (``src[pick].port``) cannot feed ``consumer`` (None: an output), or None."""
    node, sw = src.name, src.sweep
    if pick is None:
        if sw is not None and consumer is not None and consumer.sweep is not sw:
            whose = (f"'{consumer.name}' is swept over '{consumer.sweep.name}'" if consumer.sweep
                     else f"'{consumer.name}' is not swept")
            return (f"'{node}' has {len(sw)} instances (foreach: {sw.name}) and {whose}; "
                    f"write {node}[*].{port} to take all of them, in order"
                    + ("" if variadic else ", on an input that takes a list"))
        return None
    if sw is None:
        return (f"'{node}' is not swept (no foreach), so {node}[*] has nothing to gather" if pick == "*"
                else f"'{node}' is not swept (no foreach), so it has no instance '{pick}'")
    if pick == "*":
        return None if variadic else (f"{node}[*].{port} gives {len(sw)} values but this input takes one "
                                      "connection (gathering instances needs an input that takes a list)")
    if sw.get(pick) is None:
        return f"sweep '{sw.name}' has no instance '{pick}'{did_you_mean(pick, sw.names())}"
    return None


def check_references(c: Check) -> None:
    """Each node's input connections: known ports, required inputs, and ``node.port`` that exist
    (``node[*].port`` gathers every instance of a swept node into an input that takes a list)."""
    for spec in c.specs.values():
        ins = spec.raw.get("inputs") or {}
        if not isinstance(ins, dict):
            c.at(spec.path + ("inputs",), f"node '{spec.name}': 'inputs' must be a mapping of port: node.port")
            ins = {}
        _check_ports(c, spec, ins)
        for port, ref in ins.items():
            if port in spec.cls.in_ports:
                _connect_port(c, spec, port, ref)


def _check_ports(c: Check, spec: Spec, ins: dict) -> None:
    """Every input named is a port of the node, every required port is given."""
    in_ports = spec.cls.in_ports
    for port in ins:
        if port not in in_ports:
            c.at(spec.path + ("inputs", port), f"node '{spec.name}' ({spec.type}) has no input port '{port}'"
                 f"{did_you_mean(port, in_ports)} (its inputs: {', '.join(in_ports) or 'none'})", key=True)
    for port, p in in_ports.items():
        if port not in ins and not p.optional:
            c.at(spec.path + ("inputs",) if "inputs" in spec.raw else spec.path,
                 f"node '{spec.name}' ({spec.type}): missing required input '{port}' ({p.type})")


def _connect_port(c: Check, spec: Spec, port: str, ref: Any) -> None:
    """The connections written for input ``port``: kept in ``spec.refs`` when all are good."""
    pdecl = spec.cls.in_ports[port]
    where = spec.path + ("inputs", port)
    if pdecl.variadic and isinstance(ref, list):
        items = [(where + (i,), r) for i, r in enumerate(ref)]
    elif isinstance(ref, list):
        c.at(where, f"node '{spec.name}', input '{port}' takes one connection, not a list")
        return
    else:
        items = [(where, ref)]
    refs = [parse_ref(c, w, r, f"node '{spec.name}', input '{port}'", spec, pdecl.variadic) for w, r in items]
    if all(refs):
        spec.refs[port] = refs


def check_types(c: Check) -> None:
    """Every connection gives the type its input takes."""
    for spec in c.specs.values():
        for port, refs in list(spec.refs.items()):
            want = spec.cls.in_ports[port].type
            ok = True
            for r in refs:
                have = c.specs[r.src].cls.out_ports[r.port].type
                if not want.accepts(have):
                    w, h = mismatch_names(want, have)
                    c.at(r.where, f"node '{spec.name}', input '{port}' takes {w} but {r.text} gives {h}")
                    ok = False
            if not ok:
                del spec.refs[port]


def check_outputs(c: Check) -> None:
    """``outputs:`` as a list of ``node.port`` or a mapping name: ``node.port``."""
    outs_raw = c.data.get("outputs")
    entries = []
    if isinstance(outs_raw, list):
        entries = [(None, ("outputs", i), r) for i, r in enumerate(outs_raw)]
    elif isinstance(outs_raw, dict):
        for oname, r in outs_raw.items():
            if not NAME_RE.match(str(oname)):
                c.at(("outputs", oname), f"output name {oname!r} must be letters, digits, '_' or '-'", key=True)
                continue
            entries.append((oname, ("outputs", oname), r))
    elif outs_raw is not None:
        c.at(("outputs",), f"'outputs' must be a list of node.port or a mapping name: node.port, got {kind(outs_raw)}")
    for oname, where, r in entries:
        ref = parse_ref(c, where, r, "output" if oname is None else f"output '{oname}'")
        if ref is not None:
            c.output_refs.append((oname, ref))


def check_cycles(c: Check) -> None:
    """No node may depend on itself; on success ``c.order`` is a topological order of the nodes."""
    # graphlib (stdlib) rather than networkx: validation runs on every start, and importing
    # networkx costs ~0.2 s of the 0.6 s budget for an all-cached re-run.
    from graphlib import CycleError, TopologicalSorter

    deps = {n: sorted({r.src for refs in s.refs.values() for r in refs}) for n, s in c.specs.items()}
    ts = TopologicalSorter(deps)
    try:
        order = list(ts.static_order())
    except CycleError as e:
        cyc = list(e.args[1])  # [a, b, ..., a]: each depends on the next
        names = list(reversed(cyc))
        c.at(("nodes", names[0]), "cycle: " + " → ".join(names), key=True)
        return
    c.order = [n for s in order for n in c.specs[s].instances]


# ---------------------------------------------------------------------------------------------
# after the checks: wiring instances, outputs, output files


def connect(c: Check) -> None:
    """Fill every node's (instance's) inputs from its spec's connections."""
    for spec in c.specs.values():
        if not spec.refs:
            continue
        plans = []
        for port, refs in spec.refs.items():
            plans.append((port, spec.cls.in_ports[port].variadic, refs))
        for n in spec.instances:
            g = c.nodes[n]
            for port, variadic, refs in plans:
                srcs = [s for r in refs for s in _sources(c, r, g.instance)]
                g.inputs[port] = srcs if variadic else srcs[0]


def _sources(c: Check, r: Ref, instance: str | None) -> list[tuple[str, str]]:
    src = c.specs[r.src]
    if src.sweep is None:
        return [(r.src, r.port)]
    if r.pick is None:
        return [(instance_node(r.src, instance), r.port)]
    if r.pick == "*":
        return [(n, r.port) for n in src.instances]
    return [(instance_node(r.src, r.pick), r.port)]


def build_outputs(c: Check) -> None:
    """Expand the checked outputs (a swept node's output gives one per instance)."""
    for oname, r in c.output_refs:
        src = c.specs[r.src]
        if src.sweep is None or r.pick not in (None, "*"):
            node = r.src if src.sweep is None else instance_node(r.src, r.pick)
            c.outputs[oname or f"{node}.{r.port}"] = (node, r.port)
            continue
        group = []
        for n in src.instances:
            key = f"{oname}/{c.nodes[n].instance}" if oname else f"{n}.{r.port}"
            c.outputs[key] = (n, r.port)
            group.append(key)
        c.output_groups[oname or r.text] = group
    if not c.outputs:
        _default_outputs(c)


def _default_outputs(c: Check) -> None:
    """Every output of every node nobody consumes (a graph without ``outputs:``)."""
    used = {s for g in c.nodes.values() for s in g.sources()}
    for n in c.order:
        if n not in used:
            for p in c.nodes[n].cls.out_ports:
                c.outputs[f"{n}.{p}"] = (n, p)


def check_output_files(c: Check) -> None:
    """The files File outputs write into --out (their output path params) fit together there
    (:class:`graphkit.paths.OutputNames`: e.g. no two instances of a SaveImage write one name)."""
    names = OutputNames()
    for node, port in c.outputs.values():
        g = c.nodes[node]
        if g.cls.out_ports[port].type.name != "File":
            continue
        for p in getattr(g.cls, "output_path_params", lambda: [])():
            value = getattr(g.params, p, None)
            if isinstance(value, str) and value and not _claim_output_file(c, names, g, p, value):
                return


def _claim_output_file(c: Check, names: OutputNames, g: GNode, p: str, value: str) -> bool:
    """Claim the file of param ``p`` of node ``g``; False after a problem that ends the check."""
    spec = c.specs[g.base]
    where = spec.path + ("params", p)
    try:
        clash = names.claim(safe_relpath(value), g.name)
    except UnsafePath as e:
        c.at(where, f"{spec.label(g.instance)}, param '{p}': {e}")
        return True
    if clash is None:
        return True
    why, prev = clash
    if prev is None:
        c.at(where, f"{spec.label(g.instance)}, param '{p}': {why}; choose another name")
        return True
    other = c.nodes[prev]
    if other.base == g.base and g.sweep:
        c.at(where, f"{spec.label()}, param '{p}': instances '{other.instance}' and '{g.instance}' both "
             f"write {value!r} into --out; name the instance in it, e.g. \"…${{{g.sweep}.name}}…\"")
        return False
    c.at(where, f"nodes '{prev}' and '{g.name}' both write {value!r} into --out")
    return True


# ---------------------------------------------------------------------------------------------


def validate(doc, data: dict, graph_path: str, base_dir: str, reg: Registry, overrides: dict,
             check_backends: bool) -> Graph:
    """Run every checker; raise GraphError listing every problem, or return the Graph."""
    c = Check(doc, data, graph_path, base_dir, reg, overrides, check_backends)
    check_structure(c)
    cache = check_cache(c)
    check_sweeps(c)
    check_nodes(c)
    check_params(c)
    check_references(c)
    check_types(c)
    check_outputs(c)
    if not doc.diags:
        check_cycles(c)
    if doc.diags:
        raise GraphError(doc.diags)
    connect(c)
    build_outputs(c)
    check_output_files(c)
    if doc.diags:
        raise GraphError(doc.diags)
    graph = Graph(c.name, graph_path, base_dir, c.gparams, c.nodes, c.outputs, sweeps=c.sweeps,
                  output_groups=c.output_groups, cache=cache)
    graph.__dict__["_order"] = c.order
    return graph


__all__ = ["validate", "substitute"]
