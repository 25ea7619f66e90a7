"""The plain graph model: what a graph is once loaded and validated, with no YAML in it.

A :class:`Graph` of :class:`GNode` s (type, node class, checked params, input connections,
pinned backend, input files) and its outputs.  The loader (:mod:`graphkit.graphfile`: YAML or a
dict → plain data with places) and the checks (:mod:`graphkit.validate`: plain data → this
model) build it; the plan, the runner and publishing read it.  The format's names (top-level and
node keys, what a name may hold) live here too, so the checks need nothing from the loader.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from typing import Any

from .errors import UsageError
from .hashing import key_digest
from .node import Node
from .suggest import did_you_mean

FORMAT = 1
TOP_KEYS = ("graphkit", "name", "description", "params", "sweeps", "nodes", "outputs", "cache")
#: a graph's ``cache:`` setting: where its cache is, and storage options that say only where
#: (never who: credentials come from the environment, --cache-option or GRAPHKIT_CACHE_OPTIONS)
CACHE_KEYS = ("url", "options")
CACHE_OPTIONS = ("endpoint_url", "region_name", "profile", "anon", "requester_pays")
NODE_KEYS = ("type", "inputs", "params", "backend", "foreach", "doc")
NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_\-]*$")


def kind(v) -> str:
    """How a message names the kind of a plain value ("a mapping", "a list", ...)."""
    return {dict: "a mapping", list: "a list", str: "a string", type(None): "nothing"}.get(type(v), type(v).__name__)


@dataclass
class GNode:
    name: str
    type: str
    cls: type[Node]
    params: Any  # the node's checked pydantic Params
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
    cache: dict = field(default_factory=dict)  # the graph file's cache setting: url, options

    def cache_setting(self, given: str | os.PathLike | None) -> tuple[str, dict, str]:
        """(cache location, storage options, where they come from) of a run of this graph:
        ``given`` (--cache), else the graph file's ``cache:``, else $GRAPHKIT_CACHE, else
        ./.graphkit-cache.  The graph's options go with the graph's url only."""
        if given is not None:
            return str(given), {}, "--cache"
        if self.cache.get("url"):
            return self.cache["url"], dict(self.cache.get("options") or {}), f"the graph file {self.path}"
        env = os.environ.get("GRAPHKIT_CACHE")
        return (env, {}, "$GRAPHKIT_CACHE") if env else (".graphkit-cache", {}, "the default")

    def cache_options(self, location: str) -> dict:
        """The graph file's storage options for ``location`` (none unless it is the graph's url)."""
        return dict(self.cache.get("options") or {}) if location == self.cache.get("url") else {}

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

    def pending(self, name: str, done) -> list[str]:
        """``name`` and the nodes it needs that are not in ``done``, sources first.  An explicit
        stack, no recursion: a graph's depth is not limited by Python's recursion limit.  The
        walk stops at nodes in ``done`` (their own sources are not visited)."""
        out: list[str] = []
        expanded: set[str] = set()
        stack = [(name, False)]
        while stack:
            n, finished = stack.pop()
            if finished:
                out.append(n)
            elif n not in expanded and n not in done:
                expanded.add(n)
                stack.append((n, True))
                stack.extend((s, False) for s in self.nodes[n].sources())
        return out

    def recipe_digest(self, name: str) -> str:
        """Digest of the part of the graph that ``name`` depends on (types, params, edges)."""
        for n in self.pending(name, self._recipes):  # sources first: their digests are known
            g = self.nodes[n]
            self._recipes[n] = key_digest({
                "type": g.type, "version": g.cls.version,
                "params": g.params.model_dump(mode="json"),
                "inputs": g.map_inputs(lambda s, sp: [self._recipes[s], sp]),
            })
        return self._recipes[name]

    def digest(self) -> str:
        return key_digest({n: self.recipe_digest(n) for n in self.nodes})


__all__ = ["Graph", "GNode", "FORMAT", "TOP_KEYS", "CACHE_KEYS", "CACHE_OPTIONS", "NODE_KEYS", "NAME_RE", "kind"]
