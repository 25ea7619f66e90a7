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
from typing import Any, Callable

from .paths import safe_relpath  # noqa: F401 - the one output-name rule (also graphkit.executor.safe_relpath)
from .plan import Plan, plan_nodes
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


def probably_new(session: Session, name: str, outcomes: dict[str, NodeOutcome]) -> bool:
    """Whether node ``name`` is probably not in the store: an input of it was computed in this run
    (a new input digest makes a new key, bar a value computed again to the bytes it had before).
    Such a node is looked up beside its lease's request (Session.run_node's ``missed``: on an
    object store, one round trip for both), not on its own first: a cold run waits one round
    trip per node for its store, not two.  A hit found that way is served as ever.  (On a
    folder, where reads do not go together, always False: it would change nothing.)"""
    return session.store.reads_together and any(not outcomes[src].hit for src in session.graph.nodes[name].sources())


def locked_run(store, work: Callable[[], Any], then: Callable[[Any], Any] | None = None) -> Any:
    """The one lock-then-commit sequence of a run: ``work()`` under the store's run lock (shared,
    so a concurrent ``cache gc`` waits instead of removing what the run reads), this run's
    writes committed as one group when it ends, also when it fails (what ran is durable); then
    ``then(work's result)`` (recording the run, exporting its outputs) still under the lock."""
    with store.run_lock():
        try:
            result = work()
        finally:
            store.commit()
        return result if then is None else then(result)


def run_local(session: Session, targets: list[str], jobs: int = 1,
              progress: Progress | None = None, first: list[str] | None = None) -> RunResult:
    """Run the nodes ``targets`` need, ``jobs`` at a time, in threads of this process.

    ``first``: nodes (of those needed) to run as early as the graph allows, with what they
    need before them (the studio's previews on show); the rest follows in the usual order."""
    progress = progress or Progress()
    plan = plan_nodes(session.graph, targets, first)
    result = RunResult(plan.graph.name)
    t0 = time.perf_counter()
    progress.start(len(plan.order))
    def work() -> None:
        read_ahead(session, plan.order)
        if jobs <= 1:
            _run_serial(session, plan, progress, result)
        else:
            _Pool(session, plan, jobs, progress, result).run()
    locked_run(session.store, work)
    result.seconds = time.perf_counter() - t0
    return result


def _run_serial(session: Session, plan: Plan, progress: Progress, result: RunResult) -> None:
    for n in plan.order:
        progress.running(n, plan.graph.nodes[n].type)
        o = session.run_node(n, input_digests(session, n, result.outcomes), probably_new(session, n, result.outcomes))
        result.outcomes[n] = o
        progress.done(o)


class _Pool:
    """The nodes of a plan run ``jobs`` at a time, each as soon as every node it needs is done;
    after a failure nothing new starts, what runs finishes, and the first error is raised.

    A ready node is first looked up in this (the scheduling) thread: a hit is done at once and
    readies its dependants with no round trip through the pool, so only the nodes that compute
    wake a worker (a warm run starts none)."""

    def __init__(self, session: Session, plan: Plan, jobs: int, progress: Progress, result: RunResult):
        self.session, self.jobs, self.progress, self.result = session, jobs, progress, result
        self.waiting, self.dependants = plan.dependencies()
        self.ready = deque(n for n in plan.order if not self.waiting[n])
        self.misses: deque[str] = deque()  # ready, looked up, not in the store: to compute
        self.running: dict[Any, str] = {}
        self.error: BaseException | None = None

    def run(self) -> None:
        with ThreadPoolExecutor(max_workers=self.jobs, thread_name_prefix="graphkit") as pool:
            while self.ready or self.misses or self.running:
                self._resolve_hits()
                self._start(pool)
                if not self.running:
                    break
                finished, _ = wait(self.running, return_when=FIRST_COMPLETED)
                for fut in finished:
                    self._finished(fut)
        if self.error is not None:
            raise self.error

    def _resolve_hits(self) -> None:
        """Look up every ready node, all of them at once (their records are read in one batch):
        the hits are done (readying more, looked up next), the misses queue, and so do the
        nodes that are :func:`probably_new` (looked up beside their leases)."""
        session, outcomes = self.session, self.result.outcomes
        while self.ready and self.error is None:
            batch = []
            for n in self.ready:
                (self.misses if probably_new(session, n, outcomes) else batch).append(n)
            self.ready.clear()
            try:
                found = session.cached_many([(n, input_digests(session, n, outcomes)) for n in batch])
            except Exception as e:  # noqa: BLE001 - as a worker's error: nothing new starts
                self.error = e
                return
            for n in batch:
                if found[n] is None:
                    self.misses.append(n)
                else:
                    self.progress.running(n, session.graph.nodes[n].type)
                    self._done(found[n])

    def _start(self, pool: ThreadPoolExecutor) -> None:
        session, outcomes = self.session, self.result.outcomes
        while self.misses and self.error is None and len(self.running) < self.jobs:
            n = self.misses.popleft()
            self.progress.running(n, session.graph.nodes[n].type)
            self.running[pool.submit(session.run_node, n, input_digests(session, n, outcomes), True)] = n

    def _finished(self, fut) -> None:
        n = self.running.pop(fut)
        exc = fut.exception()
        if exc is not None:
            self.error = self.error or exc
        else:
            self._done(fut.result())

    def _done(self, o: NodeOutcome) -> None:
        self.result.outcomes[o.name] = o
        self.progress.done(o)
        for d in self.dependants[o.name]:
            self.waiting[d].discard(o.name)
            if not self.waiting[d]:
                self.ready.append(d)


def read_ahead(session: Session, nodes: list[str]) -> None:
    """On a store that reads in batches (an object store): the records that the last run of this
    graph (its notes, see :func:`record_last_run`) found for ``nodes``, read now in one batch, so
    that a warm run does not wait a round trip per level of the graph to learn each next key.
    Each record is still checked as ever when its key comes up; notes that no longer match cost
    reads that go unused, never a wrong hit.  (Run under the run lock: what is read ahead is
    dropped when it is released.)"""
    store = session.store
    if not store.reads_together:
        return
    notes = session.last_notes = store.last_run(graph_id(session.graph)) or {}
    store.prefetch_records((notes.get(n) or {}).get("key") for n in nodes if isinstance(notes.get(n), dict))


def record_last_run(session: Session, result: RunResult) -> None:
    """Remember each node's key parts so `graphkit explain` can say what changed (not written
    again when the same as the notes this run read ahead from)."""
    data = {}
    for n, o in result.outcomes.items():
        data[n] = {"key": o.key, "parts": session.readable_parts(session.graph.nodes[n], o.parts),
                   "outputs": o.outputs}
    if data != session.last_notes:
        session.store.save_run(graph_id(session.graph), data)


def graph_id(graph) -> str:
    import hashlib

    return f"{graph.name}-{hashlib.blake2b(graph.path.encode(), digest_size=6).hexdigest()}"


__all__ = ["run_local", "locked_run", "RunResult", "Progress"]

