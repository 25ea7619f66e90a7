"""A studio run: the current graph through the cache, its node events sent to the pages.

A newer change supersedes a running one: the stale run stops at the next node boundary (or at
the next progress report inside a long node), and what it had finished stays cached.  A node
that fails blocks what depends on it; the rest of the graph still runs.
"""
from __future__ import annotations

import contextlib
import json
import time
from pathlib import Path

from ..errors import GraphkitError
from ..executor import Progress, RunResult, record_last_run, run_local
from ..publish import export_outputs
from ..runner import NodeOutcome, Session
from ..store import Store


class Superseded(GraphkitError):
    """A newer change (or the server closing) made this run stale."""


class Closing(GraphkitError):
    """The studio is closing: nothing more is written."""


class GuardedStore:
    """The run's store, with writes refused once the studio closes and each write finished
    before it exits (so Ctrl-C never leaves a half-written entry behind)."""

    def __init__(self, store: Store, studio):
        self._store, self._studio = store, studio

    def __getattr__(self, name):
        return getattr(self._store, name)

    def _guard(self, fn, *a, **kw):
        with self._studio.write_guard():
            return fn(*a, **kw)

    def put_value(self, *a, **kw):
        return self._guard(self._store.put_value, *a, **kw)

    def put_record(self, *a, **kw):
        return self._guard(self._store.put_record, *a, **kw)

    def save_run(self, *a, **kw):
        return self._guard(self._store.save_run, *a, **kw)


class RunProgress(Progress):
    """Forwards node events to the studio and stops a stale run."""

    def __init__(self, studio, gen: int):
        self.studio, self.gen = studio, gen
        self.t0 = time.time()
        self.running_nodes: list[str] = []
        self.outcomes: dict[str, NodeOutcome] = {}
        self.pushed: dict[str, list[str]] = {}  # node -> digests of previews pushed before its store writes

    def outputs(self, node, digests, values):
        """Session.on_outputs: a node computed anew, its outputs hashed, not stored yet.  The
        previews on show of it are encoded and pushed now, from the values in memory, so the
        page decodes them while the store writes run (done() then waits for "shown")."""
        try:
            self.pushed[node] = self.studio.previews.push(self.studio.graph, node, digests, values)
        except Exception:  # noqa: BLE001 - a preview must not fail the node; done() retries
            self.pushed.pop(node, None)

    def running(self, node, node_type):
        self.studio.check_gen(self.gen)
        if time.time() - self.t0 > self.studio.STATE_DUE_S:
            self.studio.send_due_state()
        self.running_nodes.append(node)
        if node in self.outcomes:  # done by an earlier pass of this run
            return
        self.studio.node_event(node, state="running", seconds=None, message="", t0=time.time())

    def done(self, o: NodeOutcome):
        with contextlib.suppress(ValueError):
            self.running_nodes.remove(o.name)
        if o.name in self.outcomes:  # a later pass (after a failure elsewhere) found it cached
            return
        self.outcomes[o.name] = o
        wanted = self.pushed.pop(o.name, None)  # pushed before the store writes (outputs())
        if wanted is None:
            wanted = [] if o.hit else self.studio.previews.push(self.studio.graph, o.name, o.outputs)
        self.studio.node_event(o.name, state="cached" if o.hit else "done", seconds=round(o.seconds, 4),
                               message="", digests=o.outputs, backend=o.backend)
        if wanted:
            self.studio.previews.await_served(wanted, lambda: self.studio.current(self.gen))
            self.studio.send_due_state()

    def report(self, node, fraction, message):
        self.studio.check_gen(self.gen)
        self.studio.node_event(node, progress=round(float(fraction), 3), message=message)

    def notice(self, message):
        self.studio.emit({"type": "notice", "message": message})


def run_graph(studio, gen: int, graph) -> dict:
    """Run ``graph`` (the studio's run number ``gen``) and export it to the studio's --out
    folder; the run's info (status ok, failed, …)."""
    t0 = time.perf_counter()
    progress = RunProgress(studio, gen)
    session = Session(graph, studio.registry, GuardedStore(studio.store, studio), studio.backends,
                      notice=progress.notice, report=progress.report, on_outputs=progress.outputs)
    session.memo = studio.memo  # values stay in memory between runs of the studio
    session.interactive = True  # nodes may prepare for the next change in the background
    session.background = studio.background_event
    targets = sorted({n for n, _ in graph.outputs.values()})
    studio.reset_states(graph.upstream(targets))
    failed, global_error = _run_targets(studio, session, graph, targets, progress)
    studio.check_gen(gen)
    outcomes = dict(progress.outcomes)
    seconds = time.perf_counter() - t0
    result = RunResult(graph.name, outcomes, seconds, "studio")
    info = {"gen": gen, "seconds": round(seconds, 4),
            "computed": sorted(n for n, o in outcomes.items() if not o.hit),
            "cached": sorted(n for n, o in outcomes.items() if o.hit)}
    if outcomes:
        with contextlib.suppress(GraphkitError):
            record_last_run(session, result)
    studio.prune_memo(outcomes)
    if failed or global_error:
        info.update(status="failed", failed=failed, message=global_error or "")
        return info
    if studio.out is not None:
        info["files"] = _export(studio, session, result, graph, gen)
    info["status"] = "ok"
    return info


def _run_targets(studio, session, graph, targets: list[str], progress: RunProgress) -> tuple[dict, str | None]:
    """Run ``targets``; a failed node blocks what depends on it and the rest runs again.
    (failed node → message, the message of a failure no node can be blamed for)."""
    failed: dict[str, str] = {}
    blocked: set[str] = set()
    while True:
        todo = [t for t in targets if t not in failed and t not in blocked]
        if not todo:
            return failed, None
        try:
            run_local(session, todo, studio.jobs, progress, first=studio.previews.watched_nodes(graph))
            return failed, None
        except (Superseded, Closing):
            raise
        except GraphkitError as e:
            node = _blame(e, progress)
            if node is None or node in failed:
                return failed, str(e)
            failed[node] = str(e)
            studio.node_event(node, state="failed", message=str(e), seconds=None)
            for d in _downstream(graph, node):
                if d not in failed:
                    blocked.add(d)
                    studio.node_event(d, state="blocked", message=f"waits for '{node}', which failed")


def _blame(e: GraphkitError, progress: RunProgress) -> str | None:
    """The node a failure belongs to: the error's, else the one node that was running."""
    node = getattr(e, "node", None)
    if node is None and len(progress.running_nodes) == 1:
        node = progress.running_nodes[0]
    progress.running_nodes.clear()
    return node


def _downstream(graph, node: str) -> list[str]:
    out, frontier = [], {node}
    for n in graph.order():
        if graph.nodes[n].sources() & frontier and n not in frontier:
            frontier.add(n)
            out.append(n)
    return out


def _export(studio, session, result: RunResult, graph, gen: int) -> int:
    """Publish the run to the studio's --out folder; the number of files."""
    with studio.write_guard():
        studio.check_gen(gen)
        files = export_outputs(session, result, studio.out, {"targets": list(graph.outputs), "studio": True})
    manifest = None
    with contextlib.suppress(OSError, ValueError):
        manifest = json.loads(Path(studio.out, "manifest.json").read_text())
    studio.exported([str(f) for f in files], manifest)
    return len(files)
