"""Cross-process locks on an fsspec file system: flock on a local folder, leases elsewhere.

``FsspecFS.lock`` uses :func:`fsspec_lock` for the per-key locks of a store at an fsspec URL,
so that concurrent runs (other processes, Dask workers on other machines) compute each key once:

* ``file://…`` is a folder on this machine (or an NFS mount): the lock is an ``flock`` on a lock
  file, as for a plain folder; the OS releases it when the process dies;
* ``memory://…`` lives in one process: a thread lock is enough;
* object stores (``s3://``, ``gs://``, …) have no locks: a **lease** file is created with an
  exclusive create (``open(path, "xb")``, conditional writes on S3/GCS), holds the owner and an
  expiry time, is renewed by a thread every ``ttl/3`` seconds while held and removed on release.
  A lease whose expiry passed (its owner died) is broken.  Where a file system has no exclusive
  create, the lease is written and read back after a pause, and lost to a later writer.

A lock only saves duplicated work: records and objects are written atomically and are
content-addressed, so a key computed twice (a broken lease, a race while breaking one) still
gives one correct entry.
"""
from __future__ import annotations

import contextlib
import json
import os
import socket
import threading
import time
import uuid

#: seconds a lease lasts without renewal (GRAPHKIT_LOCK_TTL)
DEFAULT_TTL = 60.0
_POLL_MAX = 0.5


def _ttl() -> float:
    try:
        return max(1.0, float(os.environ.get("GRAPHKIT_LOCK_TTL", DEFAULT_TTL)))
    except ValueError:
        return DEFAULT_TTL


class Lease:
    """An exclusive lease on ``path`` in the fsspec file system ``fs`` (see the module docstring)."""

    def __init__(self, fs, path: str, ttl: float | None = None):
        self.fs, self.path = fs, path
        self.ttl = ttl or _ttl()
        self.token = uuid.uuid4().hex
        self._stop = threading.Event()
        self._renewer: threading.Thread | None = None

    def _body(self) -> bytes:
        return json.dumps({"token": self.token, "host": socket.gethostname(), "pid": os.getpid(),
                           "expires": time.time() + self.ttl}).encode()

    def _read(self) -> dict | None:
        try:
            cur = json.loads(self.fs.cat_file(self.path))
        except FileNotFoundError:
            return None
        except (ValueError, TypeError, OSError):
            return {}  # half-written or unreadable: treated as expired below once old enough
        if not isinstance(cur, dict) or not isinstance(cur.get("expires", 0), (int, float)):
            return {}  # not a lease this module wrote: as unreadable
        return cur

    def _try_create(self) -> bool | None:
        """True: acquired; False: held by someone; None: no exclusive create on this fs."""
        try:
            with self.fs.open(self.path, "xb") as f:
                f.write(self._body())
            return True
        except FileExistsError:
            return False
        except (ValueError, NotImplementedError, TypeError):
            return None

    def _break_if_stale(self) -> None:
        cur = self._read()
        if cur is None:
            return
        if cur == {}:  # unreadable (being written?): stale only if it stays so for a whole ttl
            self._unreadable_since = getattr(self, "_unreadable_since", None) or time.time()
            if time.time() - self._unreadable_since < self.ttl:
                return
        if cur.get("expires", 0) < time.time():
            again = self._read()  # only break the lease we judged stale, not a fresh one
            if again == cur:
                with contextlib.suppress(FileNotFoundError, OSError):
                    self.fs.rm_file(self.path)

    def acquire(self) -> None:
        parent = self.path.rsplit("/", 1)[0]
        with contextlib.suppress(Exception):
            self.fs.makedirs(parent, exist_ok=True)
        delay = 0.01
        while True:
            got = self._try_create()
            if got is None:  # no exclusive create here: write, wait, read back
                cur = self._read()
                got = False
                if cur is None or cur.get("expires", 0) < time.time():
                    self.fs.pipe_file(self.path, self._body())
                    time.sleep(0.05)
                    got = (self._read() or {}).get("token") == self.token
            if got:
                break
            self._break_if_stale()
            time.sleep(delay)
            delay = min(_POLL_MAX, delay * 2)
        self._renewer = threading.Thread(target=self._renew, daemon=True, name="graphkit-lease")
        self._renewer.start()

    def _renew(self) -> None:
        while not self._stop.wait(self.ttl / 3):
            cur = self._read()
            if not cur or cur.get("token") != self.token:
                return  # broken by someone else: nothing to renew
            with contextlib.suppress(Exception):
                self.fs.pipe_file(self.path, self._body())

    def release(self) -> None:
        self._stop.set()
        if self._renewer is not None:
            self._renewer.join()
        cur = self._read()
        if cur and cur.get("token") == self.token:
            with contextlib.suppress(FileNotFoundError, OSError):
                self.fs.rm_file(self.path)

    def __enter__(self):
        self.acquire()
        return self

    def __exit__(self, *exc):
        self.release()


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


__all__ = ["Lease", "local_root", "is_in_process"]
