"""Writes behind a computed node, off the run's critical path (object stores, inside a run).

On an object store each write is a round trip.  A node computed under its key's lease needs
two after its compute: its objects (one batch), then its record, and then the lease is let go
(renewal stops; a lease whose record is written is left, finished: graphkit.leases), each after
the one before (a record never names an object not yet there; a lease is never let go before
the record is there, so a run that waited for it finds the record and does not compute the key
again).  :meth:`WritesBehind.hold` keeps that order but runs them in a
thread of its own: the node's outcome (its digests, its values in memory) goes on to the nodes
that need it at once.  The run waits for every write behind before its outputs are exported
and before it lets go of the store (:meth:`drain`, from ``Store.commit``), so ``cache gc``,
which waits for the run, still never removes a lease, an object or a record the run is writing.
A write behind that fails is raised in the run's own thread: at the next key lock or at the drain.
"""
from __future__ import annotations

import contextlib
import threading
from concurrent.futures import Future, ThreadPoolExecutor, wait
from typing import Callable

#: threads writing behind (each node's writes go out in order, nodes beside each other)
WORKERS = 8
#: nodes whose writes may wait behind at once (each holds its lease, renewed, until they are
#: out): a run whose nodes are done faster than the store takes their writes waits here
PENDING = 32


class WritesBehind:
    def __init__(self):
        self._tls = threading.local()
        self._guard = threading.Lock()
        self._pool: ThreadPoolExecutor | None = None
        self._running: set[Future] = set()
        self._error: BaseException | None = None
        self._room = threading.BoundedSemaphore(PENDING)

    def later(self, write: Callable[[], None]) -> None:
        """``write()`` now, or, inside :meth:`hold` in this thread, behind the key lock (in order)."""
        pending = getattr(self._tls, "pending", None)
        if pending is None:
            write()
        else:
            pending.append(write)

    @contextlib.contextmanager
    def hold(self, lock: contextlib.AbstractContextManager):
        """Hold ``lock`` (a key's lease); the writes :meth:`later` collects inside it, then its
        release, go out in that order in a thread of their own when the body ends.  A body that
        raises drops what it collected and releases the lock at once, as ``with lock:`` would."""
        self.check()
        outer = getattr(self._tls, "pending", None)
        with contextlib.ExitStack() as stack:
            waited = stack.enter_context(lock)
            self._tls.pending = mine = []
            try:
                yield waited
            finally:
                self._tls.pending = outer
            self._submit(mine, stack.pop_all().close)

    def _submit(self, writes: list[Callable[[], None]], release: Callable[[], None]) -> None:
        def run() -> None:
            try:
                for write in writes:
                    write()
            except Exception as e:  # noqa: BLE001 - raised in the run's thread (check, drain)
                self._fail(e)
            finally:
                try:
                    release()
                except Exception as e:  # noqa: BLE001
                    self._fail(e)
                self._room.release()
        self._room.acquire()
        with self._guard:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(WORKERS, thread_name_prefix="graphkit-behind")
            fut = self._pool.submit(run)
            self._running.add(fut)
        fut.add_done_callback(self._finished)

    def _finished(self, fut: Future) -> None:
        with self._guard:
            self._running.discard(fut)

    def _fail(self, e: BaseException) -> None:
        with self._guard:
            self._error = self._error or e

    def check(self) -> None:
        """Raise (once) what a write behind raised."""
        with self._guard:
            e, self._error = self._error, None
        if e is not None:
            raise e

    def wait(self) -> None:
        """Until every write behind so far is done (what failed is kept for :meth:`check`)."""
        while True:
            with self._guard:
                running = set(self._running)
            if not running:
                return
            wait(running)

    def drain(self) -> None:
        """:meth:`wait`, then :meth:`check`."""
        self.wait()
        self.check()
