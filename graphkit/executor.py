"""Executors: run the part of a graph that the requested outputs need.

* :func:`run_local` — an embedded thread pool (default); no server.
* :func:`graphkit.dask_executor.run_dask` — the same node units on a Dask cluster.

Both return a :class:`RunResult`; :func:`graphkit.publish.export_outputs` then writes the
requested outputs into the ``--out`` folder (only after every node succeeded, published as one
unit with the run manifest).
"""
from __future__ import annotations

import time
from collections import deque
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from typing import Any

from .paths import safe_relpath  # noqa: F401 - the one output-name rule (also graphkit.executor.safe_relpath)
from .runner import NodeOutcome, Session


@dataclass
class RunResult:
    graph_name: str
    outcomes: dict[str, NodeOutcome] = field(default_factory=dict)
    seconds: float = 0.0
    executor: str = "local"

    @property
    def computed(self) -> list[str]:
        return [n for n, o in self.outcomes.items() if not o.hit]

    @property
    def cached(self) -> list[str]:
        return [n for n, o in self.outcomes.items() if o.hit]


class Progress:
    """Receives run events; the CLI shows them (rich on a terminal, plain lines otherwise)."""

    def start(self, total: int) -> None: ...
    def running(self, node: str, node_type: str) -> None: ...
    def done(self, o: NodeOutcome) -> None: ...
    def report(self, node: str, fraction: float, message: str) -> None: ...
    def notice(self, message: str) -> None: ...
    def finish(self, ok: bool) -> None: ...


def input_digests(session: Session, name: str, outcomes: dict[str, NodeOutcome]) -> dict[str, str]:
    g = session.graph.nodes[name]
    return g.map_inputs(lambda src, sport: outcomes[src].outputs[sport])


def run_local(session: Session, targets: list[str], jobs: int = 1,
              progress: Progress | None = None, first: list[str] | None = None) -> RunResult:
    """Run the nodes ``targets`` need, ``jobs`` at a time, in threads of this process.

    ``first``: nodes (of those needed) to run as early as the graph allows, with what they
    need before them (the studio's previews on show); the rest follows in the usual order."""
    progress = progress or Progress()
    graph = session.graph
    order = graph.upstream(targets)
    if first:
        needed = set(order)
        early = graph.upstream([n for n in first if n in needed])
        seen = set(early)
        order = early + [n for n in order if n not in seen]  # still topological: early is closed upstream
    result = RunResult(graph.name)
    t0 = time.perf_counter()
    progress.start(len(order))
    with session.store.run_lock():
        try:
            if jobs <= 1:
                for n in order:
                    progress.running(n, graph.nodes[n].type)
                    o = session.run_node(n, input_digests(session, n, result.outcomes))
                    result.outcomes[n] = o
                    progress.done(o)
            else:
                _run_pool(session, order, jobs, progress, result)
        finally:
            session.store.commit()  # the last group commit: what ran is durable, even on failure
    result.seconds = time.perf_counter() - t0
    return result


def _run_pool(session: Session, order: list[str], jobs: int, progress: Progress, result: RunResult) -> None:
    graph = session.graph
    wanted = set(order)
    waiting = {n: graph.nodes[n].sources() & wanted for n in order}
    dependants: dict[str, list[str]] = {n: [] for n in order}
    for n in order:
        for s in waiting[n]:
            dependants[s].append(n)
    ready = deque(n for n in order if not waiting[n])
    running: dict[Any, str] = {}
    error: BaseException | None = None
    with ThreadPoolExecutor(max_workers=jobs, thread_name_prefix="graphkit") as pool:
        while ready or running:
            while ready and error is None and len(running) < jobs:
                n = ready.popleft()
                progress.running(n, graph.nodes[n].type)
                fut = pool.submit(session.run_node, n, input_digests(session, n, result.outcomes))
                running[fut] = n
            if not running:
                break
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for fut in finished:
                n = running.pop(fut)
                exc = fut.exception()
                if exc is not None:
                    error = error or exc
                    continue
                o = fut.result()
                result.outcomes[n] = o
                progress.done(o)
                for d in dependants[n]:
                    waiting[d].discard(n)
                    if not waiting[d]:
                        ready.append(d)
            if error is not None:
                ready.clear()
    if error is not None:
        raise error


def record_last_run(session: Session, result: RunResult) -> None:
    """Remember each node's key parts so `graphkit explain` can say what changed."""
    data = {}
    for n, o in result.outcomes.items():
        data[n] = {"key": o.key, "parts": session.readable_parts(session.graph.nodes[n], o.parts),
                   "outputs": o.outputs}
    session.store.save_run(graph_id(session.graph), data)


def graph_id(graph) -> str:
    import hashlib

    return f"{graph.name}-{hashlib.blake2b(graph.path.encode(), digest_size=6).hexdigest()}"


__all__ = ["run_local", "RunResult", "Progress"]

