"""Cross-process locks on an fsspec file system: flock on a local folder, leases elsewhere.

``FsspecFS.lock`` uses these for a store at an fsspec URL, so that concurrent runs (other
processes, Dask workers on other machines) compute each key once and ``cache gc`` waits for runs:

* ``file://…`` is a folder on this machine (or an NFS mount): the lock is an ``flock`` on a lock
  file, as for a plain folder; the OS releases it when the process dies;
* ``memory://…`` lives in one process: a thread lock is enough;
* object stores (``s3://``, ``gs://``, …) have no locks: a **lease** is an object created with
  the store's atomic primitive, an exclusive create (``open(path, "xb")``: a conditional PUT,
  ``If-None-Match: *``, on S3 and GCS), holding its owner and an expiry time.  A thread renews it
  every ``ttl/5`` seconds while it is held (a node done sooner never renews); release deletes it
  unless it is finished (below) (in a run, behind the node's record, off its critical path:
  graphkit.store.behind).
  Renewal and release are one request each (a PUT, a DELETE) while the lease is far from its
  expiry: nobody breaks an unexpired lease, so it is still the owner's; only an owner that could
  not renew for half a ttl reads the lease back first (someone may have broken it).  A key's
  lease whose record the owner wrote is not deleted at all: a lease whose record exists is
  finished (a run that meets one looks the record up and does not wait), and ``cache gc``
  removes it.  A lease whose expiry has passed
  (its owner died, or lost the store for a whole ttl) is broken by the next run that wants it,
  which says once what it waits for; so is at once one whose owner ran on this machine (its host
  name) and is gone (:func:`dead_here`).  Where a file system has no exclusive create, the lease is
  written and read back after a pause (a documented weaker mode: two runs may then both win and
  compute a key twice, never a wrong result).  Expiry times are the owner's clock: the machines
  sharing a cache must agree on the time within a few seconds (NTP).

Runs and gc on an object store: each run holds a lease of its own under ``active/`` (shared);
``cache gc`` and ``verify --repair`` take the ``store.lock`` lease (exclusive) and then wait until
no run lease is alive; a run that finds ``store.lock`` held drops its own lease and waits.  So gc
never removes what a run is writing, a lease it holds, or a record it is about to write.

A lock only saves duplicated work: records and objects are written whole and are
content-addressed, so a key computed twice (a broken lease) still gives one correct entry.
"""
from __future__ import annotations

import contextlib
import json
import os
import socket
import sys
import threading
import time
import uuid
from typing import Callable

#: seconds a lease lasts without renewal (GRAPHKIT_LOCK_TTL): what a dead owner costs the next run
DEFAULT_TTL = 10.0
#: renewals per ttl: a slow owner that still renews is never broken (it renews 5 times per ttl)
RENEWALS_PER_TTL = 5
_POLL_MAX = 0.5
_WARNED: set[str] = set()  # file systems whose weaker lease mode was announced
ACTIVE = "active"


def _ttl() -> float:
    try:
        return max(1.0, float(os.environ.get("GRAPHKIT_LOCK_TTL", DEFAULT_TTL)))
    except ValueError:
        return DEFAULT_TTL


class LeaseLost(Exception):
    """The store stopped answering while a lease was held (raised on release, in the owner's
    thread: the renewal thread never raises)."""


def read_lease(fs, path: str) -> dict | None:
    """The lease at ``path``: None if there is none, {} if it is not one this module wrote."""
    try:
        cur = json.loads(fs.cat_file(path))
    except FileNotFoundError:
        return None
    except (ValueError, TypeError, OSError):
        return {}  # half-written or unreadable: treated as expired below once old enough
    if not isinstance(cur, dict) or not isinstance(cur.get("expires", 0), (int, float)):
        return {}  # not a lease this module wrote: as unreadable
    return cur


def alive(cur: dict | None) -> bool:
    """Whether a lease's owner may still hold it: its expiry has not passed, and it is not known
    dead — an owner on this machine whose process is gone (:func:`dead_here`) is not waited for."""
    return bool(cur) and cur.get("expires", 0) >= time.time() and not dead_here(cur)


def dead_here(cur: dict) -> bool:
    """Whether the lease was written by a process of this machine (its host name) that no longer
    runs: a run killed here, or one that finished and left its key's lease (finished, see the
    module docstring) before that key's record went to quarantine.  A live process with that pid
    (a reused one), another user's, or another host's owner: not known dead (the ttl decides).  Two
    machines sharing a host name would at worst compute a key twice, never a wrong result."""
    pid = cur.get("pid")
    if cur.get("host") != socket.gethostname() or not isinstance(pid, int) or pid <= 0 or pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:  # (PermissionError: it runs, as another user)
        return False
    return False


class Lease:
    """An exclusive lease on ``path`` in the fsspec file system ``fs`` (see the module docstring).

    ``on_wait(holder, ttl)`` is called once when the lease is held by someone else.  ``done()``,
    if given, says whether the work the lease guards is out (a key's record exists): a lease met
    while it is, is a finished one that its owner left behind (:attr:`finished`), and acquire
    returns at once without holding it (``waited``: the caller looks the record up)."""

    def __init__(self, fs, path: str, ttl: float | None = None,
                 on_wait: Callable[[dict, float], None] | None = None,
                 done: Callable[[], bool] | None = None):
        self.fs, self.path = fs, path
        self.ttl = ttl or _ttl()
        self.token = uuid.uuid4().hex
        self.on_wait = on_wait
        self.done = done
        #: set by the owner once the guarded work is out: release leaves the lease where it is
        #: (finished, as ``done()`` tells others) instead of deleting it: one request less
        self.finished = False
        self._held = False
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._renewer: threading.Thread | None = None
        self._unreadable_since: float | None = None
        self._expires = 0.0  # the expiry this lease last wrote
        #: whether acquire found the lease held (the key may have been computed meanwhile)
        self.waited = False

    def _body(self) -> bytes:
        self._expires = time.time() + self.ttl
        return json.dumps({"token": self.token, "host": socket.gethostname(), "pid": os.getpid(),
                           "expires": self._expires}).encode()

    def _surely_mine(self) -> bool:
        """Whether the lease as last written is still far from its expiry: nobody breaks a lease
        before it expires, so it is still this one's (with half a ttl for the clocks to disagree),
        and renewing or releasing it needs no read first."""
        return time.time() < self._expires - self.ttl / 2

    def _mine(self) -> bool:
        """Whether the lease is still this one's: by time (:meth:`_surely_mine`), else read back."""
        if self._surely_mine():
            return True
        cur = self._read()
        return bool(cur) and cur.get("token") == self.token

    def _read(self) -> dict | None:
        return read_lease(self.fs, self.path)

    def _try_create(self) -> bool | None:
        """True: acquired; False: held by someone; None: no exclusive create on this fs."""
        for _ in range(2):
            try:
                with self.fs.open(self.path, "xb") as f:
                    f.write(self._body())
                return True
            except FileExistsError:
                return False
            except FileNotFoundError:  # (a file system with folders: the first lease in this one)
                self.fs.makedirs(self.path.rsplit("/", 1)[0], exist_ok=True)
            except (ValueError, NotImplementedError, TypeError):
                return None
        return False

    def _break_if_stale(self, cur: dict | None) -> None:
        if cur is None:
            return
        if cur == {}:  # unreadable (being written?): stale only if it stays so for a whole ttl
            self._unreadable_since = self._unreadable_since or time.time()
            if time.time() - self._unreadable_since < self.ttl:
                return
        if not alive(cur) and self._read() == cur:  # only break the lease judged stale, not a fresh one
            with contextlib.suppress(FileNotFoundError, OSError):
                self.fs.rm_file(self.path)

    def _write_and_check(self) -> bool:
        """The weaker mode (no exclusive create): write, wait, read back; said once per process."""
        if type(self.fs).__name__ not in _WARNED:
            _WARNED.add(type(self.fs).__name__)
            print(f"graphkit: warning: {type(self.fs).__name__} has no exclusive create (a conditional PUT): "
                  "per-key leases fall back to write-and-read-back, so two runs may compute a key twice "
                  "(never a wrong result)", file=sys.stderr, flush=True)
        cur = self._read()
        if alive(cur):
            return False
        self.fs.pipe_file(self.path, self._body())
        time.sleep(0.05)
        return (self._read() or {}).get("token") == self.token

    def acquire(self) -> None:
        delay, said = 0.01, False
        while True:
            got = self._try_create()
            if got is None:
                got = self._write_and_check()
            if got:
                break
            self.waited = True
            if self.done is not None and self.done():
                return  # a finished lease left behind: nothing to wait for, nothing held
            cur = self._read()
            if not said and self.on_wait is not None and cur is not None and (cur == {} or alive(cur)):
                # (one expired, or whose owner is known dead, is broken below: nothing to wait for)
                said = True
                self.on_wait(cur, self.ttl)
            self._break_if_stale(cur)
            time.sleep(delay)
            delay = min(_POLL_MAX, delay * 2)
        self._held = True
        self._renewer = threading.Thread(target=self._renew, daemon=True, name="graphkit-lease")
        self._renewer.start()

    def _renew(self) -> None:
        """Renew until released; never raises (a failure is kept in ``error``, raised on release)."""
        last_ok = time.monotonic()
        while not self._stop.wait(self.ttl / RENEWALS_PER_TTL):
            try:
                if not self._mine():
                    return  # broken by someone else: nothing to renew
                self.fs.pipe_file(self.path, self._body())
                last_ok = time.monotonic()
            except Exception as e:  # noqa: BLE001 - the client's own classes (botocore, aiohttp, …)
                if time.monotonic() - last_ok >= self.ttl:
                    self.error = e
                    return

    def release(self) -> None:
        self._stop.set()
        if self._renewer is not None:
            self._renewer.join()
        if self.error is not None:
            raise LeaseLost(f"{type(self.error).__name__}: {self.error}")
        held, self._held = self._held, False
        if held and not self.finished and self._mine():
            with contextlib.suppress(FileNotFoundError, OSError):
                self.fs.rm_file(self.path)

    def __enter__(self):
        self.acquire()
        return self

    def __exit__(self, *exc):
        self.release()


def _wait_for(fs, path: str, poll: float) -> None:
    """Until the lease at ``path`` is gone or expired."""
    while alive(read_lease(fs, path)):
        time.sleep(poll)


@contextlib.contextmanager
def shared(fs, root: str, on_wait: Callable[[], None] | None = None):
    """A run's hold on the store at ``root``: a lease of its own under active/, taken while no
    ``store.lock`` lease (gc) is alive."""
    said = False
    while True:
        mine = Lease(fs, f"{root}/{ACTIVE}/{uuid.uuid4().hex}.lease")
        mine.acquire()  # (a unique name: never held by anyone else)
        if not alive(read_lease(fs, f"{root}/store.lock")):
            break
        mine.release()
        if not said and on_wait is not None:
            said = True
            on_wait()
        _wait_for(fs, f"{root}/store.lock", _POLL_MAX)
    try:
        yield
    finally:
        mine.release()


@contextlib.contextmanager
def exclusive(fs, root: str, on_wait: Callable[[], None] | None = None):
    """gc's hold on the store at ``root``: the ``store.lock`` lease, then no run lease alive
    (expired ones, of runs that died, are removed)."""
    said = [False]

    def waiting(*_):
        if not said[0] and on_wait is not None:
            said[0] = True
            on_wait()

    with Lease(fs, f"{root}/store.lock", on_wait=waiting):
        while True:
            live = False
            for path in _listing(fs, f"{root}/{ACTIVE}"):
                cur = read_lease(fs, path)
                if alive(cur):
                    live = True
                elif cur is not None:
                    Lease(fs, path)._break_if_stale(cur)
            if not live:
                break
            waiting()
            time.sleep(_POLL_MAX)
        yield


def _listing(fs, folder: str) -> list[str]:
    try:
        return list(fs.find(folder))
    except FileNotFoundError:
        return []


def local_root(fs, root: str) -> str | None:
    """The folder behind an fsspec file system when it is this machine's (``file://``)."""
    try:
        from fsspec.implementations.local import LocalFileSystem
    except ImportError:  # pragma: no cover
        return None
    return root if isinstance(fs, LocalFileSystem) else None


def is_in_process(fs) -> bool:
    try:
        from fsspec.implementations.memory import MemoryFileSystem
    except ImportError:  # pragma: no cover
        return False
    return isinstance(fs, MemoryFileSystem)


__all__ = ["Lease", "LeaseLost", "alive", "exclusive", "local_root", "is_in_process", "read_lease", "shared"]
