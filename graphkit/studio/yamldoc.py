"""The graph file as an editable text: a param edit replaces just that value's characters.

PyYAML's composer gives the start and end of every value in the file, so a change splices
the new value (in YAML flow style) over the old one and leaves everything else — comments,
key order, line breaks, quoting of other values — as the author wrote it.  A param that was
not in the file is added to its node's ``params`` (flow or block, as that mapping is).
"""
from __future__ import annotations

import functools
from typing import Any

import yaml

_Loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def flow(value: Any) -> str:
    """``value`` as one line of YAML flow text."""
    text = yaml.safe_dump([value], default_flow_style=True, width=1 << 30, allow_unicode=True)
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
