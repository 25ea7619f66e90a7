"""The graph file as an editable text: a param edit replaces just that value's characters.

PyYAML's composer gives the start and end of every value in the file, so a change splices
the new value (in YAML flow style) over the old one and leaves everything else — comments,
key order, line breaks, quoting of other values — as the author wrote it.  A param that was
not in the file is added to its node's ``params`` (flow or block, as that mapping is).

The node editor's edits (``with_edits``: add, remove, rename a node, set or clear an input)
splice the same way: a node that an edit does not touch keeps its text.  Every value written
goes through ``yaml.safe_dump`` (plain data, never a tag) and every name must match the
loader's ``NAME_RE``, so nothing typed in the editor can put code into the file.
"""
from __future__ import annotations

import functools
from typing import Any

import yaml

_Loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def flow(value: Any, sort_keys: bool = True) -> str:
    """``value`` as one line of YAML flow text."""
    text = yaml.safe_dump([value], default_flow_style=True, width=1 << 30, allow_unicode=True,
                          sort_keys=sort_keys)
    return text.strip()[1:-1].strip()


def _compose(text: str):
    loader = _Loader(text)
    try:
        return loader.get_single_node()
    finally:
        loader.dispose()


def _get(mapping, key):
    """(key node, value node) of ``key`` in a YAML MappingNode, or (None, None)."""
    if not isinstance(mapping, yaml.MappingNode):
        return None, None
    for k, v in mapping.value:
        if isinstance(k, yaml.ScalarNode) and k.value == key:
            return k, v
    return None, None


class YamlDoc:
    """The text of a graph file; ``with_params`` gives an edited copy."""

    def __init__(self, text: str):
        self.text = text

    @functools.cached_property
    def _data(self) -> Any:
        from ..errors import GraphError
        from ..graphfile import parse_yaml

        try:
            return parse_yaml(self.text, "")
        except GraphError:  # malformed YAML: the graph loader says where
            return None

    def data(self) -> Any:
        """The document as plain data, read as the graph loader reads it (YAML 1.2 core
        schema); None when it is not readable YAML.  Parsed once per text and shared: read it,
        do not modify it."""
        return None if self._data is None else self._data.data

    def parsed(self):
        """The parse behind :meth:`data` (graphkit.graphfile's, for ``load_graph(parsed=...)``:
        one parse per text), or None when the text is not readable YAML."""
        return self._data

    def with_params(self, changes: list[tuple[str | None, str, Any]]) -> "YamlDoc":
        """A copy with each ``(node or None for a graph param, param, value)`` set."""
        text = self.text
        for node, name, value in changes:
            text = _set(text, node, name, value)
        return YamlDoc(text)


    def with_edits(self, edits: list[dict]) -> "YamlDoc":
        """A copy with each node-editor edit applied (``{"op": ...}``; see :data:`EDITS`)."""
        text = self.text
        for e in edits:
            op = EDITS.get(e.get("op")) if isinstance(e, dict) else None
            if op is None:
                raise ValueError(f"unknown edit {e!r}: expected an op of {', '.join(EDITS)}")
            text = op(text, e)
        return YamlDoc(text)


def _name(v, what: str) -> str:
    from ..model import NAME_RE

    if not isinstance(v, str) or not NAME_RE.match(v):
        raise ValueError(f"{what} {v!r} is not a name (letters, digits, _ and -, not starting with a digit)")
    return v


def _nodes(text: str):
    root = _compose(text)
    if not isinstance(root, yaml.MappingNode):
        raise ValueError("the graph file is not a mapping")
    _, nodes = _get(root, "nodes")
    return root, nodes


def _add_node(text: str, e: dict) -> str:
    name, typ = _name(e.get("name"), "node name"), _name(e.get("type"), "node type")
    params = e.get("params") or {}
    if not isinstance(params, dict):
        raise ValueError("params must be a mapping")
    root, nodes = _nodes(text)
    if _get(nodes, name)[0] is not None:
        raise ValueError(f"there is a node '{name}' already")
    spec = {"type": typ, **({"params": params} if params else {})}
    block = "\n  " + f"{flow(name)}: {flow(spec, False)}"  # the first node, on its own line
    if nodes is None:
        return _add_key(text, root, "nodes", block)
    if (isinstance(nodes, yaml.ScalarNode) and nodes.value in ("", "~", "null")) or (
            isinstance(nodes, yaml.MappingNode) and not nodes.value):
        s, e = nodes.start_mark.index, nodes.end_mark.index
        return text[:s].rstrip(" ") + block + text[e:]
    if not isinstance(nodes, yaml.MappingNode):
        raise ValueError("'nodes' is not a mapping")
    return _add_key(text, nodes, name, flow(spec, False))


def _set_input(text: str, e: dict) -> str:
    """``inputs.PORT`` of a node set to ``e["source"]`` ("node.port", a list of them for a
    variadic port), or removed when it is None."""
    node, port = _name(e.get("node"), "node"), _name(e.get("port"), "input")
    src = e.get("source")
    refs = src if isinstance(src, list) else [] if src is None else [src]
    for r in refs:
        if not isinstance(r, str) or r.count(".") < 1:
            raise ValueError(f"an input's source is NODE.PORT, got {r!r}")
        a, _, b = r.rpartition(".")
        _name(a, "node"), _name(b, "output")
    root, nodes = _nodes(text)
    _, owner = _get(nodes, node)
    if owner is None:
        raise ValueError(f"no node '{node}' in the graph file")
    _, inputs = _get(owner, "inputs")
    if src is None:
        return text if inputs is None else _remove_key(text, inputs, port)
    if inputs is None or (isinstance(inputs, yaml.ScalarNode) and inputs.value in ("", "~", "null")):
        if inputs is not None:
            return _replace_value(text, inputs, flow({port: src}))
        return _add_key(text, owner, "inputs", flow({port: src}))
    _, old = _get(inputs, port)
    return _add_key(text, inputs, port, flow(src)) if old is None else _replace_value(text, old, flow(src))


def _remove_node(text: str, e: dict) -> str:
    """The node, every input fed by it and every graph output of it, removed."""
    name = _name(e.get("name"), "node")
    for node, port, refs in _references(text, name):
        keep = [r for r in refs if r.rpartition(".")[0] != name]
        text = _set_input(text, {"node": node, "port": port,
                                 "source": None if not keep else keep if len(refs) > 1 or len(keep) > 1 else keep[0]})
    root, nodes = _nodes(text)
    _, outputs = _get(root, "outputs")
    if isinstance(outputs, yaml.MappingNode):
        for k, v in list(outputs.value):
            if isinstance(v, yaml.ScalarNode) and v.value.rpartition(".")[0] == name:
                text = _remove_key(text, _get(_compose(text), "outputs")[1], k.value)
    root, nodes = _nodes(text)
    if _get(nodes, name)[0] is None:
        raise ValueError(f"no node '{name}' in the graph file")
    return _remove_key(text, nodes, name)


def _references(text: str, name: str) -> list[tuple[str, str, list[str]]]:
    """(node, input, its sources) of every input with a source on node ``name``."""
    _, nodes = _nodes(text)
    out = []
    for k, spec in (nodes.value if isinstance(nodes, yaml.MappingNode) else []):
        _, inputs = _get(spec, "inputs")
        for p, v in (inputs.value if isinstance(inputs, yaml.MappingNode) else []):
            refs = [x.value for x in v.value] if isinstance(v, yaml.SequenceNode) else [v.value]
            if any(isinstance(r, str) and r.rpartition(".")[0] == name for r in refs):
                out.append((k.value, p.value, refs))
    return out


def _rename_node(text: str, e: dict) -> str:
    """Node ``old`` renamed ``new``, with every reference to it (inputs, graph outputs)."""
    old, new = _name(e.get("name"), "node"), _name(e.get("new"), "new name")
    root, nodes = _nodes(text)
    key, _ = _get(nodes, old)
    if key is None:
        raise ValueError(f"no node '{old}' in the graph file")
    if old != new and _get(nodes, new)[0] is not None:
        raise ValueError(f"there is a node '{new}' already")
    spans = [(key, flow(new))] + [(x, flow(new + "." + x.value.rpartition(".")[2])) for x in _sources(root, nodes)
                                  if x.value.rpartition(".")[0] == old]
    for n, value in sorted(spans, key=lambda sv: -sv[0].start_mark.index):  # last first: indices stay
        text = text[:n.start_mark.index] + value + text[n.end_mark.index:]
    return text


def _sources(root, nodes) -> list:
    """Every "node.port" scalar of the file: the nodes' inputs and the graph's outputs."""
    values = []
    for _, spec in nodes.value:
        _, inputs = _get(spec, "inputs")
        values += [v for _, v in inputs.value] if isinstance(inputs, yaml.MappingNode) else []
    _, outputs = _get(root, "outputs")
    values += [v for _, v in outputs.value] if isinstance(outputs, yaml.MappingNode) else []
    flat = [x for v in values for x in (v.value if isinstance(v, yaml.SequenceNode) else [v])]
    return [x for x in flat if isinstance(x, yaml.ScalarNode)]


#: the node editor's edits: op → function(text, edit) → text
EDITS = {"add_node": _add_node, "remove_node": _remove_node, "rename_node": _rename_node,
         "set_input": _set_input}


def _remove_key(text: str, mapping, key: str) -> str:
    """``text`` without ``key`` (and its value) of ``mapping`` (flow or block)."""
    items = mapping.value if isinstance(mapping, yaml.MappingNode) else []
    i = next((i for i, (k, _) in enumerate(items) if k.value == key), None)
    if i is None:
        return text
    k, v = items[i]
    if mapping.flow_style:
        s, e = k.start_mark.index, v.end_mark.index
        if i + 1 < len(items):
            e = items[i + 1][0].start_mark.index
        elif i > 0:
            s = items[i - 1][1].end_mark.index
        return text[:s] + text[e:]
    s = text.rfind("\n", 0, k.start_mark.index) + 1
    e = v.end_mark.index
    if isinstance(v, yaml.ScalarNode) or v.flow_style:
        nl = text.find("\n", e)
        e = len(text) if nl < 0 else nl + 1
    elif not text[text.rfind("\n", 0, e) + 1:e].strip():  # a block value ends at the next key's column
        e = text.rfind("\n", 0, e) + 1
    if len(items) == 1:  # the mapping's last key: an empty flow mapping in its place
        head = text[:s].rstrip(" \n")
        return head + " {}\n" + text[e:]
    return text[:s] + text[e:]


def _line_indent(text: str, index: int) -> int:
    start = text.rfind("\n", 0, index) + 1
    return index - start


def _set(text: str, node: str | None, name: str, value: Any) -> str:
    root = _compose(text)
    if not isinstance(root, yaml.MappingNode):
        raise ValueError("the graph file is not a mapping")
    new = flow(value)
    owner = _owner(root, node)
    _, params = _get(owner, "params")
    if params is not None and not isinstance(params, yaml.MappingNode):
        if isinstance(params, yaml.ScalarNode) and params.value in ("", "~", "null"):
            s, e = params.start_mark.index, params.end_mark.index
            return text[:s] + "{" + f"{flow(name)}: {new}" + "}" + text[e:]
        raise ValueError(f"'params' of {'the graph' if node is None else repr(node)} is not a mapping")
    if params is None:
        return _add_key(text, owner, "params", "{" + f"{flow(name)}: {new}" + "}")
    _, old = _get(params, name)
    if old is None:
        return _add_key(text, params, name, new)
    return _replace_value(text, old, new)


def _owner(root: yaml.MappingNode, node: str | None):
    """The mapping whose ``params`` hold the param: the graph's (``node`` None) or a node's."""
    if node is None:
        return root
    _, nodes = _get(root, "nodes")
    _, owner = _get(nodes, node)
    if owner is None:
        raise KeyError(f"no node '{node}' in the graph file")
    return owner


def _replace_value(text: str, old: yaml.Node, new: str) -> str:
    """``text`` with the value ``old`` replaced by the flow-style ``new``."""
    s, e = old.start_mark.index, old.end_mark.index
    span = text[s:e]
    tail = span[len(span.rstrip()):]  # block values end at the next key: keep the break
    if isinstance(old, (yaml.MappingNode, yaml.SequenceNode)) and not old.flow_style:
        head = text[:s]
        cut = head.rstrip(" ")
        if cut.endswith("\n"):  # a block value starts on its own line: put the flow value after the key
            head = cut[:-1] + " "
        return head + new + tail + text[e:]
    rest = text[e:]
    pad = len(rest) - len(rest.lstrip(" "))
    if tail == "" and pad and rest[pad:pad + 1] == "#":  # keep a trailing comment's column
        rest = " " * max(1, pad - (len(new) - len(span))) + rest[pad:]
    return text[:s] + new + tail + rest


def _add_key(text: str, mapping: yaml.MappingNode, key: str, value: str) -> str:
    """``key: value`` added as the last entry of ``mapping``."""
    entry = f"{flow(key)}: {value}"
    if mapping.flow_style:
        e = mapping.end_mark.index  # just after the closing brace
        close = text.rfind("}", mapping.start_mark.index, e)
        inner = text[mapping.start_mark.index + 1:close].strip()
        sep = ", " if inner else ""
        return text[:close] + sep + entry + text[close:]
    if not mapping.value:
        raise ValueError("cannot add to an empty block mapping")
    first_key = mapping.value[0][0]
    indent = _line_indent(text, first_key.start_mark.index)
    last_val = mapping.value[-1][1]
    e = last_val.end_mark.index
    # after the last value's line (block values already end at a line start)
    if isinstance(last_val, yaml.ScalarNode) or last_val.flow_style:
        nl = text.find("\n", e)
        e = len(text) if nl < 0 else nl + 1
    pre = "" if text[:e].endswith("\n") or not text[:e] else "\n"
    return text[:e] + pre + " " * indent + entry + "\n" + text[e:]
