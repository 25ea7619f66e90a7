"""Sweeps and batches: one node, or a sub-graph, instantiated over many values.

A graph file names its sweeps under the top-level key ``sweeps`` and nodes opt in with
``foreach: SWEEP``::

    sweeps:
      light:                                 # a list of values (scalars or mappings)
        values: [-60, -30, 0, 30, 60]
        name: "az{value:+04.0f}"             # optional instance-name template
      grid:                                  # a product of lists (first axis slowest)
        matrix: {azimuth: [-30, 0, 30], elevation: [0, 20]}
      ring:                                  # evenly spaced numbers, stop excluded
        range: {start: 0, stop: 360, step: 11.25}
      photo:                                 # files matching a glob, relative to the graph file
        glob: photos/*.png
    nodes:
      l:    {type: MakeLight, foreach: light, params: {azimuth_deg: "${light.value}"}}
      save: {type: SaveImage, foreach: light, inputs: {image: l.image},
             params: {path: "relit/${light.name}.exr"}}
      sheet: {type: ContactSheet, inputs: {images: "relit[*].image"},
              params: {labels: "${light[*].name}"}}

Each instance has *fields*: ``value`` (the list item, the matrix point as a mapping, the glob's
absolute path), ``name`` (unique in the sweep, safe in a file name), ``index`` (0-based), plus the
keys of a mapping item, the matrix axes, or for a glob ``path``, ``file`` and ``stem``.
``${SWEEP.FIELD}`` is the field of the node's own instance; ``${SWEEP[*].FIELD}`` the list of it
over all instances (usable anywhere).  Every instance becomes an ordinary node named
``NODE[INSTANCE]`` with its own cache key.
"""
from __future__ import annotations

import glob as _glob
import itertools
import math
import os
import re
import string
from dataclasses import dataclass, field
from typing import Any, Callable

from .suggest import unknown_keys

SWEEP_KINDS = ("values", "matrix", "range", "glob")
SWEEP_KEYS = SWEEP_KINDS + ("name", "doc")
MAX_INSTANCES = 100_000
MAX_NAME = 120
_SWEEP_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_FIELD_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_UNSAFE = re.compile(r"[^A-Za-z0-9_.+=,@-]+")
#: ``${NS.FIELD}`` / ``${NS[*].FIELD}``: NS is ``params`` or a sweep
SUB_RE = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(\[\*\])?\.([A-Za-z_][A-Za-z0-9_]*)\}")


@dataclass(frozen=True)
class Instance:
    name: str
    index: int
    fields: dict[str, Any]


@dataclass
class Sweep:
    name: str
    kind: str
    instances: list[Instance]
    line: int = 0
    col: int = 0
    _by_name: dict[str, Instance] = field(default_factory=dict, repr=False)
    _fields: list[str] = field(default_factory=list, repr=False)

    def __post_init__(self):
        self._by_name = {i.name: i for i in self.instances}
        seen: dict[str, None] = {}
        for i in self.instances:
            seen.update(dict.fromkeys(i.fields))
        self._fields = list(seen)

    def __len__(self) -> int:
        return len(self.instances)

    def names(self) -> list[str]:
        return [i.name for i in self.instances]

    def get(self, name: str) -> Instance | None:
        return self._by_name.get(name)

    def fields(self) -> list[str]:
        """Every field name some instance has."""
        return self._fields


def instance_node(base: str, instance: str) -> str:
    """The name of one instance of a swept node: ``relit[az030]``."""
    return f"{base}[{instance}]"


def safe_name(text: str) -> str:
    """``text`` as an instance name: runs of characters unsafe in file names become ``_``."""
    s = _UNSAFE.sub("_", text).lstrip(".")
    return s


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float) and v.is_integer() and abs(v) < 1e15:
        return str(int(v))
    return str(v)


def _short(v: Any) -> str:
    t = repr(v)
    return t if len(t) <= 60 else t[:57] + "..."


def _kind(v) -> str:
    return {dict: "a mapping", list: "a list", str: "a string", type(None): "nothing"}.get(type(v), type(v).__name__)


# ---------------------------------------------------------------------------------------------
# parsing the `sweeps:` section


def parse_sweeps(doc, raw, base_dir: str, substitute: Callable) -> dict[str, Sweep]:
    """Every sweep of the ``sweeps`` mapping; problems are reported on ``doc`` (file:line:col)."""
    out: dict[str, Sweep] = {}
    if raw is None:
        return out
    if not isinstance(raw, dict):
        doc.at(("sweeps",), f"'sweeps' must be a mapping of sweep name: sweep, got {_kind(raw)}")
        return out
    for sname, spec in raw.items():
        path = ("sweeps", sname)
        if not _SWEEP_NAME_RE.match(sname) or sname == "params":
            doc.at(path, f"sweep name {sname!r} must be letters, digits and '_' (and not 'params')", key=True)
            continue
        if not isinstance(spec, dict):
            doc.at(path, f"sweep '{sname}' must be a mapping with one of {', '.join(SWEEP_KINDS)}, got {_kind(spec)}")
            continue
        unknown_keys(doc, path, spec, SWEEP_KEYS, f"sweep '{sname}': ")
        kinds = [k for k in SWEEP_KINDS if k in spec]
        if len(kinds) != 1:
            doc.at(path, f"sweep '{sname}' needs exactly one of {', '.join(SWEEP_KINDS)}"
                   + (f" (it has {', '.join(kinds)})" if kinds else ""), key=True)
            continue
        kind = kinds[0]
        n0 = len(doc.diags)
        value = substitute(path + (kind,), spec[kind])  # ${params.X} may give the list
        if len(doc.diags) > n0:
            continue
        items = _PARSERS[kind](doc, path + (kind,), sname, value, base_dir)
        if items is None:
            continue
        instances = _name_instances(doc, path, sname, spec, kind, items)
        if instances is not None:
            line, col = doc.where(path, key=True)
            out[sname] = Sweep(sname, kind, instances, line, col)
    return out


def _values(doc, path, sname, value, base_dir):
    if not isinstance(value, list):
        doc.at(path, f"sweep '{sname}': 'values' must be a list, got {_kind(value)}")
        return None
    if not value:
        doc.at(path, f"sweep '{sname}': 'values' is an empty list: a sweep needs at least one value")
        return None
    items = []
    for i, v in enumerate(value):
        fields = {"value": v}
        default = _fmt(v)
        if isinstance(v, dict):
            bad = [k for k in v if not _FIELD_RE.match(str(k)) or k in ("index",)]
            if bad:
                doc.at(path + (i, bad[0]), f"sweep '{sname}', value {i}: field name {bad[0]!r} must be letters, "
                       "digits and '_' (and not 'index')", key=True)
                return None
            fields.update(v)
            default = str(v["name"]) if "name" in v else str(i)
        elif isinstance(v, list):
            default = str(i)
        items.append((fields, default, path + (i,), _short(v)))
    return items


def _matrix(doc, path, sname, value, base_dir):
    axes = _matrix_axes(doc, path, sname, value)
    if axes is None:
        return None
    total = math.prod(len(v) for _, v in axes)
    if total > MAX_INSTANCES:
        doc.at(path, f"sweep '{sname}': the matrix has {total:,} instances (at most {MAX_INSTANCES:,})")
        return None
    items = []
    for combo in itertools.product(*(v for _, v in axes)):
        point = {ax: v for (ax, _), v in zip(axes, combo)}
        default = ",".join(f"{ax}={_fmt(v)}" for ax, v in point.items())
        items.append(({"value": point, **point}, default, path, default))
    return items


def _matrix_axes(doc, path, sname, value) -> list[tuple[str, list]] | None:
    """The matrix's (axis name, values), or None (reported) when it is not a mapping of
    field name: non-empty list."""
    if not isinstance(value, dict) or not value:
        doc.at(path, f"sweep '{sname}': 'matrix' must be a mapping of axis name: list of values, got "
               + ("an empty mapping" if value == {} else _kind(value)))
        return None
    for ax, vals in value.items():
        if not _FIELD_RE.match(ax) or ax in ("value", "name", "index"):
            doc.at(path + (ax,), f"sweep '{sname}': axis name {ax!r} must be letters, digits and '_' "
                   "(and not value, name or index)", key=True)
            return None
        if not isinstance(vals, list) or not vals:
            doc.at(path + (ax,), f"sweep '{sname}': axis '{ax}' must be a non-empty list, got "
                   + ("an empty list" if vals == [] else _kind(vals)))
            return None
    return list(value.items())


def _range(doc, path, sname, value, base_dir):
    nums = _range_numbers(doc, path, sname, value)
    if nums is None:
        return None
    start, stop, step = nums
    if step == 0:
        doc.at(path + ("step",), f"sweep '{sname}': range step must not be 0")
        return None
    count = math.ceil((stop - start) / step - 1e-9)
    if count <= 0:
        doc.at(path, f"sweep '{sname}': range from {start} to {stop} by {step} is empty (stop is excluded)")
        return None
    if count > MAX_INSTANCES:
        doc.at(path, f"sweep '{sname}': the range has {count:,} values (at most {MAX_INSTANCES:,})")
        return None
    ints = all(isinstance(x, int) for x in (start, stop, step))
    items = []
    for i in range(count):
        v = start + i * step if ints else round(start + i * step, 12)
        name = _fmt(v)
        items.append(({"value": v}, name, path, name))
    return items


def _range_numbers(doc, path, sname, value) -> tuple | None:
    """(start, stop, step) of a range, or None (reported) when they are not finite numbers."""
    keys = ("start", "stop", "step")
    if not isinstance(value, dict):
        doc.at(path, f"sweep '{sname}': 'range' must be a mapping {{start, stop, step}}, got {_kind(value)}")
        return None
    n0 = len(doc.diags)
    unknown_keys(doc, path, value, keys, f"sweep '{sname}', range: ")
    if len(doc.diags) > n0:
        return None
    nums = []
    for k, default in (("start", 0), ("stop", None), ("step", 1)):
        v = value.get(k, default)
        if v is None or isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            doc.at(path + ((k,) if k in value else ()), f"sweep '{sname}': range '{k}' must be a finite number"
                   + ("" if k in value else " (it is missing)"))
            return None
        nums.append(v)
    return tuple(nums)


def _glob_files(doc, path, sname, value, base_dir):
    if not isinstance(value, str) or not value.strip():
        doc.at(path, f"sweep '{sname}': 'glob' must be a file pattern such as photos/*.png, got {_kind(value)}")
        return None
    pattern = os.path.join(base_dir, value)
    # the folder the pattern's wildcards start from: instance names are paths below it
    parts = re.split(r"[*?\[]", value, maxsplit=1)
    root = os.path.join(base_dir, os.path.dirname(parts[0])) if len(parts) > 1 else os.path.dirname(pattern)
    files = sorted(p for p in _glob.glob(pattern, recursive=True) if os.path.isfile(p))
    if not files:
        doc.at(path, f"sweep '{sname}': glob {value!r} matches no files (looked in {os.path.abspath(root)})")
        return None
    if len(files) > MAX_INSTANCES:
        doc.at(path, f"sweep '{sname}': glob {value!r} matches {len(files):,} files (at most {MAX_INSTANCES:,})")
        return None
    items = []
    for p in files:
        ap = os.path.abspath(p)
        rel = os.path.relpath(ap, os.path.abspath(root))
        stem = os.path.splitext(os.path.basename(ap))[0]
        default = os.path.splitext(rel)[0].replace(os.sep, "_")
        items.append(({"value": ap, "path": ap, "file": os.path.basename(ap), "stem": stem}, default, path,
                      os.path.relpath(ap, base_dir)))
    return items


_PARSERS = {"values": _values, "matrix": _matrix, "range": _range, "glob": _glob_files}


def _template(doc, path, sname, tmpl) -> list[str] | None:
    """The field names a ``name:`` template uses (``{field}`` or ``{field:spec}`` only)."""
    if not isinstance(tmpl, str) or not tmpl:
        doc.at(path, f"sweep '{sname}': 'name' must be a template string such as \"az{{value}}\", got {_kind(tmpl)}")
        return None
    used = []
    try:
        for _, fname, spec, conv in string.Formatter().parse(tmpl):
            if fname is None:
                continue
            if not _FIELD_RE.match(fname) or conv or (spec and "{" in spec):
                doc.at(path, f"sweep '{sname}': name template field {{{fname}}} must be a plain field name "
                       "(optionally with a format spec, e.g. {value:03d})")
                return None
            used.append(fname)
    except ValueError as e:
        doc.at(path, f"sweep '{sname}': bad name template {tmpl!r}: {e}")
        return None
    return used


def _name_instances(doc, path, sname, spec, kind, items) -> list[Instance] | None:
    tmpl = spec.get("name")
    used = None
    if tmpl is not None:
        used = _template(doc, path + ("name",), sname, tmpl)
        if used is None:
            return None
    instances, seen = [], {}
    for i, (fields, default, where, label) in enumerate(items):
        fields = {**fields, "index": i}
        raw_name = default if tmpl is None else _format_name(doc, path + ("name",), sname, tmpl, used, fields)
        if raw_name is None:
            return None
        name = safe_name(raw_name) or str(i)
        at = path + ("name",) if tmpl is not None else where
        if len(name) > MAX_NAME:
            doc.at(at, f"sweep '{sname}': instance {i} would be named {name[:40]!r}… ({len(name)} characters, at "
                   f"most {MAX_NAME}); give the sweep a shorter 'name' template")
            return None
        if name in seen:
            j = seen[name]
            example = "{file}" if kind == "glob" else "{index}"
            hint = "" if tmpl is not None else f" (set a 'name' template, e.g. name: \"{example}\")"
            doc.at(at, f"sweep '{sname}': instances {j} ({items[j][3]}) and {i} ({label}) are both named "
                   f"'{name}', so their outputs would collide{hint}")
            return None
        seen[name] = i
        fields["name"] = name
        instances.append(Instance(name, i, fields))
    return instances


def _format_name(doc, path, sname, tmpl: str, used: list[str], fields: dict) -> str | None:
    """An instance's name from the sweep's ``name`` template, or None (reported)."""
    i = fields["index"]
    missing = [f for f in used if f not in fields]
    if missing:
        doc.at(path, f"sweep '{sname}': name template uses {{{missing[0]}}}, but instance {i} "
               f"has no such field (its fields: {', '.join(fields)})")
        return None
    try:
        return tmpl.format_map({k: fields[k] for k in used})
    except (ValueError, TypeError, KeyError) as e:
        doc.at(path, f"sweep '{sname}': name template {tmpl!r} does not fit instance {i} "
               f"({_fmt(fields['value'])!r}): {e}")
        return None


__all__ = ["Sweep", "Instance", "parse_sweeps", "instance_node", "SUB_RE"]
