"""Running graphs from Python (what `graphkit run` does, as a function)."""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from .executor import Progress, RunResult, locked_run, record_last_run, run_local
from .graphfile import load
from .model import Graph
from .plan import make_plan
from .publish import export_outputs
from .registry import Registry, default_registry
from .runner import Session
from .store import Store, check_out_folder


@dataclass
class Run:
    """The result of :func:`run_graph`: per-node outcomes plus the files written."""

    graph: Graph
    result: RunResult
    session: Session
    files: list[Path] = field(default_factory=list)

    @property
    def computed(self) -> list[str]:
        return self.result.computed

    @property
    def cached(self) -> list[str]:
        return self.result.cached

    def value(self, output: str):
        """The value of a graph output (by output name) or of ``node.port``."""
        node, port = self.graph.outputs.get(output) or tuple(output.rsplit(".", 1))
        o = self.result.outcomes[node]
        return self.session.value(o.outputs[port], self.graph.nodes[node].cls.out_ports[port].type, (node, port))


def run_graph(path: str | os.PathLike | dict | Graph, *, cache: str | os.PathLike | None = None,
              out: str | os.PathLike | None = None, overrides: dict | None = None,
              backends: list[str] | None = None, jobs: int = 1, outputs: list[str] | None = None,
              executor: str = "local", scheduler: str | None = None,
              registry: Registry | None = None, progress: Progress | None = None,
              scheduler_timeout: float = 10.0) -> Run:
    """Load, validate and run a graph (a file, a dict, or a loaded Graph); write its outputs into
    ``out`` when given.  The stages, in order: load + validate, plan, run, publish.

    ``cache``: a folder or an fsspec URL; None: the graph file's ``cache:``, else
    $GRAPHKIT_CACHE, else ./.graphkit-cache (Graph.cache_setting)."""
    registry = registry or default_registry()
    graph = load(path, registry, overrides or {})  # a graph file, a dict (load_dict) or a Graph
    plan = make_plan(graph, outputs, out)  # outputs: an output name, or a swept output's group name
    cache, options, _ = graph.cache_setting(cache)
    if out is not None:
        check_out_folder(out, cache)
    store = Store(cache, options=options).open()
    progress = progress or Progress()
    session = Session(graph, registry, store, backends, notice=progress.notice, report=progress.report)

    def run() -> RunResult:
        ok = False
        try:
            if executor == "dask":
                from .dask_executor import run_dask

                result = run_dask(session, plan.targets, scheduler, jobs, progress, timeout=scheduler_timeout)
            else:
                result = run_local(session, plan.targets, jobs, progress)
            ok = True
        finally:
            progress.finish(ok)
        return result

    def publish(result: RunResult) -> Run:
        record_last_run(session, result)
        done = Run(graph, result, session)
        if out is not None:
            done.files = export_outputs(session, result, out, {"targets": list(graph.outputs)})
        return done

    # the store lock is held (shared) from the first lookup until the outputs are exported, on
    # every executor, so a concurrent `cache gc` waits instead of removing what this run reads
    return locked_run(store, run, publish)
