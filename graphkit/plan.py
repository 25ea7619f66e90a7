"""Plan: what a run computes, decided before anything runs.

The third stage of a graph's way through the engine — load (:mod:`graphkit.loader`, a plain
:mod:`graphkit.model`) → validate (:mod:`graphkit.validate`) → plan → run
(:mod:`graphkit.runner` per node, :mod:`graphkit.executor` over the plan) → publish.  From a
validated graph and the outputs asked for: the nodes to run, in a topological order, what each
waits for, and the names the outputs will have in ``--out`` (checked now, where known).

Keys are not planned: a node's cache key holds the digests of its inputs, known only once the
nodes upstream have run (so a node that gives the same bytes again stops the re-run there).
"""
from __future__ import annotations

from dataclasses import dataclass

from .model import Graph
from .paths import OutputNames


@dataclass
class Plan:
    graph: Graph
    targets: list[str]  # the nodes whose outputs are asked for
    order: list[str]  # every node they need, in a topological order

    def dependencies(self) -> tuple[dict[str, set[str]], dict[str, list[str]]]:
        """({node: the nodes of the plan it waits for}, {node: the nodes of the plan that wait for it})."""
        wanted = set(self.order)
        waiting = {n: self.graph.nodes[n].sources() & wanted for n in self.order}
        dependants: dict[str, list[str]] = {n: [] for n in self.order}
        for n in self.order:
            for s in waiting[n]:
                dependants[s].append(n)
        return waiting, dependants


def make_plan(graph: Graph, outputs: list[str] | None = None, out=None) -> Plan:
    """The plan of a run of ``graph``'s outputs (only ``outputs`` when given: output names, or
    swept output groups); with ``out``, the output names are checked against --out first."""
    if outputs:
        graph.select_outputs(outputs)
    if out is not None:
        check_output_plan(graph)
    targets = sorted({n for n, _ in graph.outputs.values()})
    return Plan(graph, targets, graph.upstream(targets))


def plan_nodes(graph: Graph, targets: list[str], first: list[str] | None = None) -> Plan:
    """The plan that runs the nodes ``targets`` need.  ``first``: nodes (of those needed) to run
    as early as the graph allows, with what they need before them (the studio's previews on
    show); the rest follows in the usual order."""
    order = graph.upstream(targets)
    if first:
        needed = set(order)
        early = graph.upstream([n for n in first if n in needed])
        seen = set(early)
        order = early + [n for n in order if n not in seen]  # still topological: early is closed upstream
    return Plan(graph, list(targets), order)


def check_output_plan(graph: Graph) -> None:
    """Before anything runs: the output names known now (all but File outputs', known once
    their node has run) fit in --out (:class:`graphkit.paths.OutputNames`)."""
    names = OutputNames()
    for oname, (node, port) in graph.outputs.items():
        ptype = graph.nodes[node].cls.out_ports[port].type
        if ptype.name != "File":
            names.admit(f"{oname}{'.npy' if ptype.export_ext == '.npy' else ptype.export_ext}")


__all__ = ["Plan", "make_plan", "plan_nodes", "check_output_plan"]
