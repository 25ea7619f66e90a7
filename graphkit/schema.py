"""JSON Schema of graph files, generated from the installed node types.

Editors that speak the YAML language server use it through a first line
``# yaml-language-server: $schema=graph.schema.json``.
"""
from __future__ import annotations

from .model import CACHE_OPTIONS
from .registry import Registry

#: ``node.port``, ``node[*].port`` (every instance of a swept node) or ``node[INSTANCE].port``
REF = r"^[A-Za-z_][A-Za-z0-9_\-]*(\[[^\]\s]+\])?\.[A-Za-z_][A-Za-z0-9_]*$"
#: ``${params.NAME}``, ``${SWEEP.FIELD}`` or ``${SWEEP[*].FIELD}``
PARAM_REF = r"\$\{[A-Za-z_][A-Za-z0-9_]*(\[\*\])?\.[A-Za-z_][A-Za-z0-9_]*\}"
NAME = r"^[A-Za-z_][A-Za-z0-9_\-]*$"


_NESTED = ("items", "additionalProperties")
_NESTED_LISTS = ("prefixItems", "anyOf", "oneOf", "allOf")


def _allow_refs(s):
    """Let every value in a param schema also be a ``${params.NAME}`` string."""
    if not isinstance(s, dict):
        return s
    s = dict(s)
    for k in _NESTED:
        if isinstance(s.get(k), dict):
            s[k] = _allow_refs(s[k])
    for k in _NESTED_LISTS:
        if isinstance(s.get(k), list):
            s[k] = [_allow_refs(x) for x in s[k]]
    if isinstance(s.get("properties"), dict):
        s["properties"] = {k: _allow_refs(v) for k, v in s["properties"].items()}
    if "type" in s or "$ref" in s or "enum" in s or "const" in s:
        return {"anyOf": [s, {"type": "string", "pattern": PARAM_REF}], "description": s.get("description", "")}
    return s


def _port_schema(port) -> dict:
    """A connection to ``port``; its description and ``x-constraints`` say what the value
    must be (checked when the graph runs, see graphkit.contract)."""
    one = {"type": "string", "pattern": REF}
    needs = port.constraints.describe()
    desc = f"{port.type}: {port.doc}" + (f" (needs: {'; '.join(needs)})" if needs else "")
    extra = {"x-constraints": port.constraints.to_json()} if needs else {}
    if port.variadic:
        return {"oneOf": [one, {"type": "array", "items": one}], "description": desc, **extra}
    return {**one, "description": desc, **extra}


def node_schema(reg: Registry, name: str) -> tuple[dict, dict]:
    cls = reg.node_class(name)
    params = cls.Params.model_json_schema()
    defs = params.pop("$defs", {})
    params["additionalProperties"] = False
    for k, v in params.get("properties", {}).items():  # any value may be a ${params.NAME}
        params["properties"][k] = _allow_refs(v)
    defs = {k: _allow_refs(v) for k, v in defs.items()}
    s = {
        "type": "object",
        "description": (cls.__doc__ or "").strip(),
        "properties": {
            "type": {"const": name},
            "doc": {"type": "string"},
            "foreach": {"type": "string", "pattern": r"^[A-Za-z_][A-Za-z0-9_]*$",
                        "description": "instantiate this node once per instance of this sweep"},
            "backend": {"enum": reg.backend_names(name)},
            "inputs": {
                "type": "object",
                "additionalProperties": False,
                "properties": {p: _port_schema(port) for p, port in cls.in_ports.items()},
                "required": [p for p, port in cls.in_ports.items() if not port.optional],
            },
            "params": params,
        },
        "required": ["type"],
        "additionalProperties": False,
    }
    return s, defs


def sweeps_schema() -> dict:
    """The ``sweeps:`` section (see graphkit.sweeps)."""
    listish = {"anyOf": [{"type": "array", "minItems": 1}, {"type": "string", "pattern": PARAM_REF}]}
    num = {"anyOf": [{"type": "number"}, {"type": "string", "pattern": PARAM_REF}]}
    common = {"name": {"type": "string", "description": "instance-name template, e.g. \"az{value:03.0f}\""},
              "doc": {"type": "string"}}
    kinds = {
        "values": {**listish, "description": "one instance per item (scalars or mappings of fields)"},
        "matrix": {"anyOf": [{"type": "object", "minProperties": 1,
                              "additionalProperties": {"type": "array", "minItems": 1}},
                             {"type": "string", "pattern": PARAM_REF}],
                   "description": "one instance per point of the product of the axes' lists"},
        "range": {"type": "object", "additionalProperties": False, "required": ["stop"],
                  "properties": {"start": num, "stop": num, "step": num},
                  "description": "numbers from start (default 0) by step (default 1), stop excluded"},
        "glob": {"type": "string", "minLength": 1,
                 "description": "one instance per file matching this pattern, relative to the graph file"},
    }
    return {
        "type": "object",
        "description": "named sweeps; a node with `foreach: NAME` is instantiated once per instance",
        "propertyNames": {"pattern": r"^[A-Za-z_][A-Za-z0-9_]*$", "not": {"const": "params"}},
        "additionalProperties": {"oneOf": [
            {"type": "object", "additionalProperties": False, "required": [k], "properties": {k: v, **common}}
            for k, v in kinds.items()
        ]},
    }


def graph_schema(reg: Registry) -> dict:
    variants, all_defs = [], {}
    for name in reg.node_names():
        try:
            s, defs = node_schema(reg, name)
        except Exception:  # noqa: BLE001 - a broken plugin node is left out of the schema
            continue
        all_defs.update(defs)
        variants.append({"if": {"properties": {"type": {"const": name}}, "required": ["type"]}, "then": s})
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "graphkit graph file (format 1)",
        "type": "object",
        "required": ["graphkit", "nodes"],
        "additionalProperties": False,
        "properties": {
            "graphkit": {"const": 1},
            "name": {"type": "string", "pattern": NAME},
            "description": {"type": "string"},
            "params": {"type": "object"},
            "sweeps": sweeps_schema(),
            "cache": {"type": "object", "additionalProperties": False, "required": ["url"],
                      "properties": {"url": {"type": "string", "minLength": 1},
                                     "options": {"type": "object", "additionalProperties": False,
                                                 "properties": {k: {} for k in CACHE_OPTIONS}}}},
            "outputs": {"oneOf": [
                {"type": "array", "items": {"type": "string", "pattern": REF}},
                {"type": "object", "additionalProperties": {"type": "string", "pattern": REF}},
            ]},
            "nodes": {
                "type": "object",
                "additionalProperties": {
                    "type": "object",
                    "properties": {"type": {"enum": reg.node_names()}},
                    "required": ["type"],
                    "allOf": variants,
                },
            },
        },
        "$defs": all_defs,
    }
