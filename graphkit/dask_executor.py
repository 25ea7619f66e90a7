"""Run a graph on a Dask cluster.

Each node (each instance of a swept node) becomes one Dask task that calls the same
:meth:`Session.run_node` the local executor uses, on a worker, against the same store; tasks pass
only digests, values travel through the store.  So the store must be reachable by every worker:
a local folder for a ``LocalCluster`` on this machine, a shared folder or an fsspec URL
(``s3://…``) for a real cluster.  Without ``--scheduler`` a ``LocalCluster`` of ``--jobs`` worker
processes on 127.0.0.1 is started for the run.

Each key is computed once across workers and concurrent clients: ``run_node`` takes the store's
per-key lock (flock on a folder, a lease file on an object store) and re-reads the record under
it.  Failures map onto graphkit's exit codes:

* an unreachable scheduler (within ``timeout`` seconds), a malformed address, a scheduler with no
  workers, workers that cannot import a node type or open the cache: exit 2, one message
  (checked on every worker before anything runs);
* a node that raises: exit 1 (``NodeFailed``) or 2 (``BadInput``), as locally;
* a worker process that dies (killed, out of memory, a crash in native code): Dask runs its task
  again on another worker; a task that kills ``distributed.scheduler.allowed-failures`` + 1
  workers (default 3 + 1; ``DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES=1`` lowers it) is
  reported as that node's failure, exit 1.
"""
from __future__ import annotations

import re
import threading
from concurrent.futures import CancelledError
import time
import uuid

from .errors import GraphkitError, NodeFailed, UsageError
from .executor import Progress, RunResult
from .plan import plan_nodes
from .runner import Session

_sessions: dict[str, Session] = {}
_sessions_lock = threading.Lock()
_ADDRESS = re.compile(r"^(?:(tcp|tls|ws|wss|ucx|inproc)://)?(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.\-]+)(?::(\d{1,5}))?/?$")


class WorkerDied(Exception):
    """The cause of a NodeFailed when the task's worker processes kept dying."""


def _worker_session(token, graph, store_location, backend_order) -> Session:
    with _sessions_lock:
        s = _sessions.get(token)
        if s is None:
            from .memory import tune_malloc
            from .registry import default_registry
            from .store import Store

            tune_malloc()  # this worker's process, as the CLI does for its own
            s = Session(graph, default_registry(), Store(store_location, options=graph.cache_options(store_location)).open(),
                        backend_order)
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


def _probe_worker(needs: dict, store_location: str, version: str, options: dict | None = None) -> list[str]:
    """Run on every worker before the graph: what would stop it from running its tasks."""
    problems = []
    try:
        from . import __version__
        from .node import probe
        from .registry import default_registry
        from .store import Store

        if __version__ != version:
            problems.append(f"runs graphkit {__version__}, the client {version}")
        reg = default_registry()
        for node_type, pinned in sorted(needs.items()):
            if node_type not in reg.nodes:
                problems.append(f"has no node type '{node_type}' (install the plugin that provides it on "
                                "every worker, or set GRAPHKIT_PLUGINS there)")
                continue
            try:
                reg.node_class(node_type)
                for b in pinned:
                    why = probe(reg.backend_class(node_type, b))
                    if why:
                        problems.append(f"cannot run the pinned backend '{b}' of {node_type}: {why}")
            except GraphkitError as e:
                problems.append(str(e))
            except KeyError:
                problems.append(f"has no backend {sorted(pinned)} of {node_type}")
        try:
            Store(store_location, options=options).open()
        except GraphkitError as e:
            problems.append(f"cannot use the cache: {e}")
    except Exception as e:  # noqa: BLE001 - report, do not crash the worker
        problems.append(f"{type(e).__name__}: {e}")
    return problems


def _connect(scheduler: str | None, jobs: int, timeout: float):
    """(client, cluster or None), or UsageError (exit 2) naming what is wrong."""
    try:
        import dask  # noqa: F401
        from distributed import Client, LocalCluster
    except ImportError as e:
        raise UsageError(f"the dask executor needs dask and distributed ({e}); install relightkit[dask]") from None
    import logging

    if scheduler is None:
        cluster = LocalCluster(n_workers=max(1, jobs), threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address="127.0.0.1:0", worker_dashboard_address="127.0.0.1:0",
                               silence_logs=logging.CRITICAL)  # graphkit speaks for its own cluster
        return Client(cluster, set_as_default=False), cluster
    kw = {}
    if scheduler.endswith(".json"):  # a scheduler file (dask scheduler --scheduler-file)
        import os

        if not os.path.isfile(scheduler):
            raise UsageError(f"--scheduler {scheduler}: scheduler file not found")
        kw["scheduler_file"] = scheduler
        address = None
    else:
        m = _ADDRESS.fullmatch(scheduler.strip())
        if not m or (m.group(3) and not 0 < int(m.group(3)) < 65536):
            raise UsageError(f"--scheduler {scheduler!r}: not a Dask scheduler address (expected e.g. "
                             "tcp://host:8786, or a scheduler file *.json)")
        address = scheduler.strip()
    for name in ("distributed.client", "distributed.comm", "distributed.core", "distributed.batched"):
        logging.getLogger(name).setLevel(logging.CRITICAL)  # the error below says it once
    if address is not None:
        _identify(address, timeout)  # before a Client exists: a failed Client leaves a noisy __del__
    try:
        client = Client(address, timeout=timeout, set_as_default=False, **kw)
    except (OSError, TimeoutError) as e:
        raise UsageError(f"cannot reach the Dask scheduler at {scheduler} within {timeout:g} s "
                         f"({type(e).__name__}: {e}); is it running, and is the address right?") from None
    except Exception as e:  # noqa: BLE001 - anything else: not a usable scheduler
        raise UsageError(f"--scheduler {scheduler!r}: cannot use it as a Dask scheduler: {type(e).__name__}: {e}") from None
    return client, None


def _identify(address: str, timeout: float) -> None:
    """Ask the server at ``address`` who it is (Dask's ``identity`` call); UsageError (exit 2)
    when nothing answers in ``timeout`` seconds or the answer is not a Dask scheduler's."""
    import asyncio

    from distributed.comm import connect

    async def ask():
        comm = await connect(address, timeout=timeout)
        try:
            await comm.write({"op": "identity", "reply": True})
            return await asyncio.wait_for(comm.read(), timeout)
        finally:
            comm.abort()

    try:
        answer = asyncio.run(asyncio.wait_for(ask(), timeout + 1))
    except (OSError, TimeoutError, asyncio.TimeoutError) as e:
        raise UsageError(f"cannot reach the Dask scheduler at {address} within {timeout:g} s "
                         f"({type(e).__name__}: {e}); is it running, and is the address right?") from None
    except Exception as e:  # noqa: BLE001 - garbage on the wire (e.g. an HTTP server)
        raise UsageError(f"the server at {address} does not answer as a Dask scheduler (its reply is "
                         f"not Dask's protocol: {type(e).__name__}); is the address right?") from None
    if not isinstance(answer, dict) or answer.get("type") != "Scheduler":
        what = answer.get("type") if isinstance(answer, dict) else type(answer).__name__
        raise UsageError(f"the server at {address} is not a Dask scheduler (it says it is {what!r})")


def _preflight(client, session: Session, order: list[str], timeout: float, scheduler) -> None:
    graph = session.graph
    needs: dict[str, set] = {}
    for n in order:
        g = graph.nodes[n]
        needs.setdefault(g.type, set())
        if g.backend and g.backend != "numpy":
            needs[g.type].add(g.backend)
    from . import __version__

    try:
        client.wait_for_workers(1, timeout=timeout)
    except (TimeoutError, OSError):
        raise UsageError(f"the Dask scheduler at {scheduler} has no workers (waited {timeout:g} s)") from None
    try:
        loc = session.store.location
        found = client.run(_probe_worker, {k: sorted(v) for k, v in needs.items()}, loc, __version__,
                           session.graph.cache_options(loc))
    except Exception as e:  # noqa: BLE001 - e.g. a worker that cannot even unpickle graphkit
        raise UsageError(f"cannot check the Dask workers: {type(e).__name__}: {e}") from None
    lines = [f"worker {w} {p}" for w, ps in sorted(found.items()) for p in ps]
    if lines:
        more = f" (and {len(lines) - 5} more)" if len(lines) > 5 else ""
        raise UsageError("the Dask workers cannot run this graph:\n  " + "\n  ".join(lines[:5]) + more)


def run_dask(session: Session, targets: list[str], scheduler: str | None = None, jobs: int = 2,
             progress: Progress | None = None, timeout: float = 10.0) -> RunResult:
    progress = progress or Progress()
    loc = session.store.location
    if loc.startswith("memory://"):
        raise UsageError("the dask executor needs a cache the workers can reach (a folder or a shared "
                         "fsspec URL), not memory://")
    graph = session.graph
    order = plan_nodes(graph, targets).order
    token = uuid.uuid4().hex
    result = RunResult(graph.name, executor="dask")
    t0 = time.perf_counter()
    client, cluster = _connect(scheduler, jobs, timeout)
    try:
        _preflight(client, session, order, timeout, scheduler or "(local cluster)")
        _run(client, session, order, token, progress, result)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    result.outcomes = {n: result.outcomes[n] for n in order}
    result.seconds = time.perf_counter() - t0
    return result


def _run(client, session: Session, order: list[str], token: str, progress: Progress, result: RunResult) -> None:
    from distributed import as_completed

    try:
        from distributed import KilledWorker
    except ImportError:  # pragma: no cover - older distributed
        from distributed.scheduler import KilledWorker

    graph = session.graph
    loc = session.store.location
    progress.start(len(order))
    gfut = client.scatter(graph, broadcast=True)
    futs = {}
    for n in order:
        deps = sorted(graph.nodes[n].sources())
        futs[n] = client.submit(_dask_node, token, gfut, loc, session.backend_order, n, deps,
                                *[futs[d] for d in deps], key=f"{n}-{token}", pure=False)
    names = {f.key: n for n, f in futs.items()}
    try:
        for fut in as_completed(list(futs.values()), loop=client.loop):
            n = names[fut.key]
            try:
                o = fut.result()
            except KilledWorker as e:
                g = graph.nodes[n]
                last = getattr(e, "last_worker", None)
                last = getattr(last, "address", last) or "a worker"
                raise NodeFailed(n, g.type, WorkerDied(
                    f"the Dask worker running it died each time it was tried (KilledWorker, last on {last}): "
                    "it was killed, ran out of memory, or crashed in native code")) from None
            except (CancelledError, OSError) as e:
                raise UsageError(f"lost the Dask cluster while running node '{n}': {type(e).__name__}: {e}") from None
            if isinstance(o, _Failed):
                raise o.error
            result.outcomes[n] = o
            progress.done(o)
    except BaseException:
        client.cancel(list(futs.values()), force=True)
        raise
    for line in _workers_lost(client, token):
        progress.notice(line)


def _workers_lost(client, token: str) -> list[str]:
    """One notice for each Dask worker that left the cluster unasked while it held this run's
    tasks (killed, out of memory, crashed): the scheduler ran them again elsewhere, and the run
    says so in its own words instead of the workers' logged tracebacks."""

    def lost(dask_scheduler, token):  # runs on the scheduler: only plain strings come back
        found = []  # (events can hold objects its comms cannot send, e.g. a WorkerState)
        for _, msg in dask_scheduler.get_events("all"):
            if isinstance(msg, dict) and msg.get("action") == "remove-worker" and not msg.get("expected"):
                ours = [sorted(str(k)[: -len(token) - 1] for k in msg.get(f) or ()
                               if str(k).endswith(f"-{token}"))
                        for f in ("processing-tasks", "lost-computed-tasks")]
                if any(ours):
                    found.append((str(msg.get("worker", "?")), *ours))
        return found

    try:  # a nested function: cloudpickle sends it by value, the scheduler need not import graphkit
        found = client.run_on_scheduler(lost, token=token)
    except Exception:  # noqa: BLE001 - a report only; the run's results stand
        return []
    lines = []
    for worker, running, held in found:
        what = []
        if running:
            more = f" and {len(running) - 3} more" if len(running) > 3 else ""
            what.append(f"its tasks {', '.join(running[:3])}{more} (running or queued there) went to another worker")
        if held:
            what.append(f"{len(held)} finished result(s) it held were read again")
        lines.append(f"notice: Dask worker {worker} left during the run (killed, out of memory or crashed): "
                     + "; ".join(what))
    return lines
