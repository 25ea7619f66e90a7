"""Discovery of node types and backends through entry points.

Groups:

* ``graphkit.nodes``    — an entry point loads a Node subclass, a module (all Node subclasses
  defined in it), or a dict ``{type name: "module:Class"}`` (imported lazily, only when a graph
  uses that type — this keeps start-up fast).
* ``graphkit.backends`` — the same forms with Backend subclasses; a dict maps
  ``"NodeType/backend"`` to ``"module:Class"``.

The environment variable ``GRAPHKIT_PLUGINS`` (comma-separated ``module`` or ``module:attr``)
adds providers without installing them, which is handy while writing a plugin.  A module that
defines ``NODES`` and/or ``BACKENDS`` dicts (what its entry points would name) registers those,
lazily; any other module registers the Node and Backend classes defined in it.
"""
from __future__ import annotations

import importlib
import inspect
import os
import threading
from dataclasses import dataclass, field
from types import ModuleType
from typing import Any

from .errors import GraphkitError, interrupt_in
from .node import Backend, Node

NUMPY = "numpy"


@dataclass
class Entry:
    name: str
    provider: str  # distribution (or "GRAPHKIT_PLUGINS") that registered it
    target: str | type  # "module:Class" or the class itself
    _cls: type | None = None

    def where(self) -> str:
        t = self.target if isinstance(self.target, str) else f"{self.target.__module__}:{self.target.__qualname__}"
        return f"'{self.provider}' ({t})"


@dataclass
class Registry:
    nodes: dict[str, Entry] = field(default_factory=dict)
    backends: dict[str, dict[str, Entry]] = field(default_factory=dict)
    conflicts: dict[str, list[Entry]] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    # ---- registration ---------------------------------------------------------------------
    def add_node(self, name: str, provider: str, target: str | type) -> None:
        e = Entry(name, provider, target)
        if name in self.conflicts:
            self.conflicts[name].append(e)
        elif name in self.nodes:
            prev = self.nodes.pop(name)
            if prev.target == target:  # the same class reached twice
                self.nodes[name] = prev
                return
            self.conflicts[name] = [prev, e]
            self.problems.append(
                f"node type '{name}' is provided twice: by {prev.where()} and by {e.where()}; "
                "uninstall one of them"
            )
        else:
            self.nodes[name] = e

    def add_backend(self, node: str, name: str, provider: str, target: str | type) -> None:
        per = self.backends.setdefault(node, {})
        if name == NUMPY:
            self.problems.append(f"{provider}: backend name 'numpy' is reserved for the reference")
            return
        if name in per and per[name].target != target:
            self.problems.append(
                f"backend '{name}' of node type '{node}' is provided twice: by "
                f"{per[name].where()} and by {provider}; the first is used"
            )
            return
        per[name] = Entry(name, provider, target)

    def add_provider(self, group: str, provider: str, obj: Any) -> None:
        if group == "nodes":
            if isinstance(obj, dict):
                for name, target in obj.items():
                    self.add_node(name, provider, target)
                return
            for cls in _classes(obj, Node):
                self.add_node(cls.type_name, provider, cls)
        else:
            if isinstance(obj, dict):
                for k, target in obj.items():
                    node, _, name = k.partition("/")
                    self.add_backend(node, name, provider, target)
                return
            for cls in _classes(obj, Backend):
                self.add_backend(cls.node, cls.name, provider, cls)

    # ---- lookup -----------------------------------------------------------------------------
    def node_names(self) -> list[str]:
        return sorted(self.nodes)

    def node_class(self, name: str) -> type[Node]:
        if name in self.conflicts:
            where = " and by ".join(e.where() for e in self.conflicts[name])
            raise GraphkitError(f"node type '{name}' is provided twice: by {where}")
        e = self.nodes[name]
        return self._load(e, Node)

    def backend_names(self, node: str) -> list[str]:
        return [NUMPY] + sorted(self.backends.get(node, {}))

    def backend_class(self, node: str, name: str) -> type:
        if name == NUMPY:
            return self.node_class(node)
        return self._load(self.backends[node][name], Backend)

    def hooks(self, name: str) -> tuple[str, ...]:
        """The hooks node type ``name`` declares (``Node.hooks``): what a backend may replace."""
        return self.node_class(name).hooks

    def studio_view(self, name: str) -> str | None:
        """The "module:Class" of node type ``name``'s studio live view (``Node.studio_view``)."""
        return self.node_class(name).studio_view

    def _load(self, e: Entry, base: type) -> type:
        with self._lock:
            if e._cls is None:
                cls = e.target
                if isinstance(e.target, str):
                    try:
                        cls = _import_target(e.target)
                    except Exception as exc:  # noqa: BLE001
                        raise GraphkitError(
                            f"cannot import {e.name} from {e.where()}: {type(exc).__name__}: {exc}"
                        ) from exc
                if not (isinstance(cls, type) and issubclass(cls, base)):
                    raise GraphkitError(f"{e.where()} is not a {base.__name__} subclass")
                if base is Node and cls.type_name != e.name:
                    raise GraphkitError(
                        f"plugin {e.where()} registers node type '{e.name}', but the class's type_name "
                        f"is '{cls.type_name}': make the registered name and type_name the same")
                e._cls = cls
            return e._cls


def _import_target(target: str) -> Any:
    mod, _, attr = target.partition(":")
    obj: Any = importlib.import_module(mod)
    for part in filter(None, attr.split(".")):
        obj = getattr(obj, part)
    return obj


def _classes(obj: Any, base: type) -> list[type]:
    if isinstance(obj, type):
        return [obj] if issubclass(obj, base) else []
    if isinstance(obj, (list, tuple)):
        return [c for o in obj for c in _classes(o, base)]
    if isinstance(obj, ModuleType):
        return [
            c for _, c in inspect.getmembers(obj, inspect.isclass)
            if issubclass(c, base) and c is not base and c.__module__ == obj.__name__
            and not inspect.isabstract(c) and c.__dict__.get("compute") is not None
        ]
    return []


_default: Registry | None = None
_default_lock = threading.Lock()


def default_registry() -> Registry:
    """The registry built from installed entry points (and GRAPHKIT_PLUGINS), built once."""
    global _default
    with _default_lock:
        if _default is None:
            _default = discover()
        return _default


def discover() -> Registry:
    reg = Registry()
    _add_entry_points(reg)
    for spec in filter(None, (s.strip() for s in os.environ.get("GRAPHKIT_PLUGINS", "").split(","))):
        _add_env_plugin(reg, spec)
    return reg


def _add_entry_points(reg: Registry) -> None:
    """The providers of the installed ``graphkit.nodes`` and ``graphkit.backends`` entry points."""
    from importlib.metadata import entry_points

    for group in ("nodes", "backends"):
        for ep in entry_points(group=f"graphkit.{group}"):
            provider = ep.dist.name if ep.dist is not None else ep.value
            try:
                obj = ep.load()
            except Exception as exc:  # noqa: BLE001 - a broken plugin must not stop the rest
                if interrupt_in(exc):  # a Ctrl-C during its import: not a broken plugin
                    raise KeyboardInterrupt from None
                reg.problems.append(
                    f"plugin '{provider}' ({ep.value}) failed to load and was skipped: "
                    f"{type(exc).__name__}: {exc}"
                )
                continue
            reg.add_provider(group, provider, obj)


def _add_env_plugin(reg: Registry, spec: str) -> None:
    """The provider that one GRAPHKIT_PLUGINS entry (``module`` or ``module:attr``) names."""
    try:
        obj = _import_target(spec)
    except Exception as exc:  # noqa: BLE001
        if interrupt_in(exc):
            raise KeyboardInterrupt from None
        reg.problems.append(f"GRAPHKIT_PLUGINS: '{spec}' failed to import: {type(exc).__name__}: {exc}")
        return
    provider = f"GRAPHKIT_PLUGINS:{spec}"
    if isinstance(obj, ModuleType) and (hasattr(obj, "NODES") or hasattr(obj, "BACKENDS")):
        # the dicts an installed plugin's entry points name ({"Type": "module:Class"},
        # {"Type/backend": "module:Class"}): imported lazily, as when installed
        for group, attr in (("nodes", "NODES"), ("backends", "BACKENDS")):
            table = getattr(obj, attr, None)
            if table is not None and not isinstance(table, dict):
                reg.problems.append(f"GRAPHKIT_PLUGINS: '{spec}'.{attr} must be a dict, got {type(table).__name__}")
            elif table is not None:
                reg.add_provider(group, provider, table)
    elif isinstance(obj, dict):  # "NodeType/backend" keys are backends, plain names node types
        reg.add_provider("nodes", provider, {k: v for k, v in obj.items() if "/" not in k})
        reg.add_provider("backends", provider, {k: v for k, v in obj.items() if "/" in k})
    else:
        reg.add_provider("nodes", provider, obj)
        reg.add_provider("backends", provider, obj)
