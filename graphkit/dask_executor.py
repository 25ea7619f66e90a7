"""Run a graph on a Dask cluster.

Each node becomes one Dask task that calls the same :meth:`Session.run_node` the local
executor uses, on a worker, against the same store; tasks pass only digests, values travel
through the store.  So the store must be reachable by every worker: a local folder for a
``LocalCluster`` on this machine, a shared folder or an fsspec URL (``s3://…``) for a real
cluster.  Without ``--scheduler`` a ``LocalCluster`` on 127.0.0.1 is started for the run.
"""
from __future__ import annotations

import threading
import time
import uuid

from .errors import GraphkitError, UsageError
from .executor import Progress, RunResult
from .runner import Session

_sessions: dict[str, Session] = {}
_sessions_lock = threading.Lock()


def _worker_session(token, graph, store_location, backend_order) -> Session:
    with _sessions_lock:
        s = _sessions.get(token)
        if s is None:
            from .registry import default_registry
            from .store import Store

            s = Session(graph, default_registry(), Store(store_location).open(), backend_order)
            _sessions.clear()  # one run at a time per worker keeps memory bounded
            _sessions[token] = s
        return s


class _Failed:
    """A node's GraphkitError carried back as a value (so workers do not log tracebacks)."""

    def __init__(self, error: GraphkitError):
        self.error = error


def _dask_node(token, graph, store_location, backend_order, name, dep_names, *dep_outcomes):
    for o in dep_outcomes:
        if isinstance(o, _Failed):
            return o
    try:
        session = _worker_session(token, graph, store_location, backend_order)
        outs = dict(zip(dep_names, dep_outcomes))
        g = graph.nodes[name]
        digests = g.map_inputs(lambda src, sport: outs[src].outputs[sport])
        return session.run_node(name, digests)
    except GraphkitError as e:
        return _Failed(e)


def run_dask(session: Session, targets: list[str], scheduler: str | None = None, jobs: int = 2,
             progress: Progress | None = None) -> RunResult:
    from distributed import Client, LocalCluster, as_completed

    progress = progress or Progress()
    loc = session.store.location
    if loc.startswith("memory://"):
        raise UsageError("the dask executor needs a cache the workers can reach (a folder or a shared "
                         "fsspec URL), not memory://")
    graph = session.graph
    order = graph.upstream(targets)
    token = uuid.uuid4().hex
    result = RunResult(graph.name, executor="dask")
    cluster = None
    t0 = time.perf_counter()
    if scheduler is None:
        cluster = LocalCluster(n_workers=max(1, jobs), threads_per_worker=1, processes=True,
                               host="127.0.0.1", dashboard_address=None)
    client = Client(scheduler or cluster, set_as_default=False)
    try:
        progress.start(len(order))
        gfut = client.scatter(graph, broadcast=True)
        futs = {}
        for n in order:
            deps = sorted(graph.nodes[n].sources())
            futs[n] = client.submit(_dask_node, token, gfut, loc, session.backend_order, n, deps,
                                    *[futs[d] for d in deps], key=f"{n}-{token}", pure=False)
        names = {f.key: n for n, f in futs.items()}
        for fut in as_completed(list(futs.values()), loop=client.loop):
            o = fut.result()
            if isinstance(o, _Failed):
                raise o.error
            result.outcomes[names[fut.key]] = o
            progress.done(o)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    result.outcomes = {n: result.outcomes[n] for n in order}
    result.seconds = time.perf_counter() - t0
    return result
