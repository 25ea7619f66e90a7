"""What `graphkit nodes` (and the studio's palette) says about a node type: one row per type,
built from its declared ports, constraints, params, backends, hooks and studio view."""
from __future__ import annotations


def node_info(reg, name: str) -> dict:
    """What `graphkit nodes` says about node type ``name`` (the --json row)."""
    import inspect

    cls = reg.node_class(name)
    return {
        "type": name, "version": cls.version, "provider": reg.nodes[name].provider,
        "doc": inspect.getdoc(cls) or "",
        "inputs": {p.name: {"type": p.type.name, "optional": p.optional, "variadic": p.variadic, "doc": p.doc,
                            "constraints": p.constraints.to_json()} for p in cls.in_ports.values()},
        "outputs": {p.name: {"type": p.type.name, "doc": p.doc} for p in cls.out_ports.values()},
        "params": {k: _param_info(f) for k, f in cls.Params.model_fields.items()},
        "backends": reg.backend_names(name),
        "hooks": list(reg.hooks(name)),
        "studio_view": reg.studio_view(name),
    }


def type_name(ann) -> str:
    """A param annotation as a person writes it: float, list[str], 'auto' | 'srgb', float | None."""
    import json
    import types
    import typing

    origin, args = typing.get_origin(ann), typing.get_args(ann)
    if origin is typing.Annotated:
        return type_name(args[0])
    if origin in (typing.Union, getattr(types, "UnionType", typing.Union)):
        return " | ".join(type_name(a) for a in args)
    if origin is typing.Literal:
        return " | ".join(json.dumps(a) for a in args)
    if origin is not None:
        return f"{type_name(origin)}[{', '.join(type_name(a) for a in args)}]" if args else type_name(origin)
    if ann is type(None):
        return "None"
    if isinstance(ann, type):
        return ann.__name__
    return str(ann).replace("typing.", "")


def _param_info(f) -> dict:
    from pydantic_core import PydanticUndefined, to_jsonable_python

    from .node import _InputFileMarker, _OutputPathMarker

    marks = {type(m) for m in f.metadata}
    t = "InputFile" if _InputFileMarker in marks else "OutputPath" if _OutputPathMarker in marks else type_name(f.annotation)
    info = {"type": t, "required": f.is_required(), "doc": f.description or ""}
    if not f.is_required():
        value = f.get_default(call_default_factory=True)
        if value is not PydanticUndefined:
            try:
                info["default"] = to_jsonable_python(value)
            except Exception:  # noqa: BLE001 - a default with no JSON form
                info["default"] = repr(value)
    return info
