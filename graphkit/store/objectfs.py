"""A cache at an fsspec URL (``s3://``, ``gs://``, ``memory://``, ``file://``, …).

On object stores (paths are bucket/key: ``atomic_put``) each entry is one PUT, atomic there, with
no temp file and no look before it; there are no folders, no hard links (a record is an object
of its own) and a bucket is never created by a side effect (``graphkit cache init URL`` creates
one).  Locks are leases (graphkit.leases): a conditional PUT (``If-None-Match: *``) with a TTL,
renewed while held.  Reads of many entries go out together (``read_many``: s3fs is async).
A client error becomes one CacheError naming the URL and the fix (:func:`fs_errors`); the client
gets short timeouts and few retries (:data:`CLIENT_DEFAULTS`), so an unreachable server fails in
seconds.  Storage options come from ``GRAPHKIT_CACHE_OPTIONS`` (what ``--cache-option`` sets).
"""
from __future__ import annotations

import contextlib
import json
import os
import threading
import uuid
from typing import Any, Callable, Iterator

from ..errors import CacheError, UsageError
from .fs import FORMAT_PREFIX, Entry, FileSystem
from .localfs import LocalFS

#: client settings graphkit gives an fsspec file system unless told otherwise: an S3 server that
#: cannot be reached fails within seconds (botocore's defaults retry for half a minute), and a
#: batch of reads (a warm run's records) goes out together, not ten at a time
CLIENT_DEFAULTS = {"s3": {"config_kwargs": {"connect_timeout": 3, "read_timeout": 60,
                                            "retries": {"max_attempts": 2, "mode": "standard"},
                                            "max_pool_connections": 64},
                          "max_concurrency": 1}}  # (a read is one GET, not a HEAD for its size first)


#: fsspec storage options for the cache, as JSON (what `--cache-option KEY=VALUE` sets): they
#: travel to Dask workers started from this process in their environment
OPTIONS_ENV = "GRAPHKIT_CACHE_OPTIONS"


def cache_options() -> dict:
    """The storage options given for the cache (GRAPHKIT_CACHE_OPTIONS)."""
    raw = os.environ.get(OPTIONS_ENV)
    if not raw:
        return {}
    try:
        opts = json.loads(raw)
    except ValueError:
        opts = None
    if not isinstance(opts, dict):
        raise UsageError(f"{OPTIONS_ENV} must be a JSON object of fsspec storage options, e.g. "
                         '{"endpoint_url": "http://127.0.0.1:9000"}')
    return opts


def parse_cache_option(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` of `--cache-option`: VALUE as JSON when it is (numbers, true, {...}), else text;
    a dotted KEY sets a nested option (``config_kwargs.connect_timeout=5``)."""
    key, eq, value = text.partition("=")
    if not eq or not key.strip():
        raise UsageError(f"--cache-option {text!r}: expected KEY=VALUE, e.g. --cache-option endpoint_url=http://127.0.0.1:9000")
    try:
        return key.strip(), json.loads(value)
    except ValueError:
        return key.strip(), value


def merged_options(base: dict, extra: dict) -> dict:
    """``base`` with ``extra`` over it; dotted keys of ``extra`` and nested dicts merge."""
    out = json.loads(json.dumps(base))
    for key, value in extra.items():
        *path, last = key.split(".")
        at = out
        for k in path:
            at = at.setdefault(k, {})
        at[last] = merged_options(at[last], value) if isinstance(value, dict) and isinstance(at.get(last), dict) else value
    return out


@contextlib.contextmanager
def fs_errors(url: str, bucket: bool = False):
    """Turn what an object store's client raises into one CacheError naming the URL and the fix
    (FileNotFoundError passes, unless ``bucket``: then the bucket is missing)."""
    try:
        yield
    except (CacheError, FileExistsError):
        raise
    except FileNotFoundError:
        if not bucket:
            raise
        raise CacheError(f"cache {url}: the bucket does not exist; create it with `graphkit cache init {url}` "
                         "(it is never created implicitly)") from None
    except PermissionError as e:
        raise CacheError(f"cache {url}: access denied ({e}): check the credentials (AWS_PROFILE, "
                         "AWS_ACCESS_KEY_ID/AWS_SECRET_ACCESS_KEY, ~/.aws/credentials) and the bucket's policy") from None
    except OSError:
        raise  # (a file system's own error: the store says what it was doing)
    except Exception as e:  # noqa: BLE001 - the client's own classes (botocore, aiohttp, …)
        raise CacheError(f"cache {url}: cannot reach the object store ({type(e).__name__}: {e}); check the "
                         "endpoint (--cache-option endpoint_url=…, AWS_ENDPOINT_URL or FSSPEC_S3_ENDPOINT_URL), "
                         "the network and the credentials (`graphkit cache info` shows them), then run again") from None


#: what a cache's root holds (anything else below an object store's prefix: not a cache)
CACHE_NAMES = {"objects", "keys", "journal", "runs", "tmp", "quarantine", "locks", "active", "store.lock",
               "keys.lock", "filememo.json"}


def _quiet_client_loop(fs) -> None:
    """An async client (s3fs's aiohttp) leaves a task behind when a server goes away mid-request:
    its connection error, already raised to the caller (one CacheError), would be printed again
    with a traceback by asyncio when the task is collected.  Other errors are reported as usual."""
    loop = getattr(fs, "loop", None)
    if loop is None or getattr(loop, "_graphkit_quiet", False):
        return

    def handler(loop, context):
        exc = context.get("exception")
        if isinstance(exc, (OSError, ConnectionError)) or type(exc).__module__.startswith("aiohttp"):
            return
        loop.default_exception_handler(context)

    loop.set_exception_handler(handler)
    loop._graphkit_quiet = True


class FsspecFS(FileSystem):
    """Any fsspec file system (memory://, file://, s3://, …)."""

    _locks: dict[str, threading.Lock] = {}
    _locks_guard = threading.Lock()

    def __init__(self, url: str, options: dict | None = None):
        """``options``: storage options (a graph file's), under those of GRAPHKIT_CACHE_OPTIONS."""
        import fsspec

        self._leases: dict[str, Any] = {}  # the key leases this process holds, by rel

        protocol = fsspec.core.split_protocol(url)[0]
        self.options = merged_options(merged_options(CLIENT_DEFAULTS.get(protocol, {}), options or {}),
                                      cache_options())
        try:
            self.fs, self.root = fsspec.core.url_to_fs(url, **self.options)
        except TypeError as e:
            raise UsageError(f"cache {url}: a storage option is not one this file system takes ({e})") from None
        self.url = url
        self.root = self.root.rstrip("/")
        _quiet_client_loop(self.fs)
        #: paths are bucket/key (s3, gcs, azure): no folders to make, and a bucket is never
        #: created by a side effect (fsspec's makedirs creates a missing one); a PUT is atomic
        #: and costs one request, as a look before it would
        self.buckets = self.atomic_put = self.fs.root_marker == ""

    def describe(self) -> str:
        return self.url

    def path(self, rel: str) -> str:
        return f"{self.root}/{rel}"

    def ensure(self) -> None:
        if self.buckets:
            return self._check_prefix()
        for d in ("objects", "keys", "runs", "tmp"):
            self.fs.makedirs(self.path(d), exist_ok=True)

    def info(self) -> dict[str, str]:
        """What `graphkit cache info` shows: the file system, its options, and for S3 the
        endpoint, region and where the credentials came from (never the secret)."""
        shown = {k: ("***" if k in ("key", "secret", "token", "password") else v) for k, v in self.options.items()}
        out = {"cache": self.url, "file system": f"{type(self.fs).__module__}.{type(self.fs).__name__}",
               "options": json.dumps(shown, sort_keys=True)}
        client = getattr(self.fs, "s3", None)
        if client is not None:
            creds = getattr(getattr(client, "_request_signer", None), "_credentials", None)
            out.update({"endpoint": client.meta.endpoint_url, "region": client.meta.region_name,
                        "profile": os.environ.get("AWS_PROFILE") or self.options.get("profile") or "default",
                        "credentials": getattr(creds, "method", None) or "none found"})
        return out

    def _check_prefix(self) -> None:
        """The bucket exists and the prefix holds a graphkit cache or nothing (one listing)."""
        try:
            names = set(self.root_names())
        except FileNotFoundError:  # an empty prefix, or no bucket
            with fs_errors(self.url, bucket=True):
                self.fs.info(self.root.split("/", 1)[0])
            return
        foreign = sorted(n for n in names - CACHE_NAMES if not n.startswith(FORMAT_PREFIX))
        if foreign:
            raise CacheError(f"cache {self.url} holds objects that are not a graphkit cache's ({', '.join(foreign[:3])}"
                             f"{', …' if len(foreign) > 3 else ''}): give the cache a prefix of its own, "
                             f"e.g. {self.url.rstrip('/')}/graphkit-cache")

    def root_names(self) -> list[str]:
        with fs_errors(self.url):
            return [p.rstrip("/").rsplit("/", 1)[-1] for p in self.fs.ls(self.root, detail=False)]

    def init(self) -> str:
        """Create the bucket (or folder) on request: ``graphkit cache init URL``."""
        if not self.buckets:
            self.ensure()
            return f"cache {self.url} is ready"
        bucket = self.root.split("/", 1)[0]
        with fs_errors(self.url):
            if self.fs.exists(bucket):
                self.fs.info(bucket)  # (a bucket of someone else's reads as there: say why it fails)
                return f"cache {self.url} is ready (bucket {bucket} exists)"
            self.fs.mkdir(bucket)
        return f"created bucket {bucket} for cache {self.url}"

    def read(self, rel: str) -> bytes | None:
        try:
            with fs_errors(self.url):
                return self.fs.cat_file(self.path(rel))
        except FileNotFoundError:
            return None

    def read_many(self, rels: list[str]) -> dict[str, bytes | None]:
        """One concurrent batch of GETs (fsspec's multi-path ``cat``: s3fs sends them together)."""
        if len(rels) < 2:
            return {rel: self.read(rel) for rel in rels}
        paths = [self.path(rel) for rel in rels]
        out: dict[str, bytes | None] = {}
        with fs_errors(self.url):
            got = self.fs.cat(paths, on_error="return")
            for rel, p in zip(rels, paths):
                v = got.get(p)
                if isinstance(v, BaseException) and not isinstance(v, FileNotFoundError):
                    raise v
                out[rel] = v if isinstance(v, bytes) else None
        return out

    def exists(self, rel: str) -> bool:
        with fs_errors(self.url):
            return self.fs.exists(self.path(rel))

    def live_lease(self, rel: str) -> bool:
        """Whether ``rel`` is a lease whose owner still renews it (gc leaves it)."""
        from ..leases import alive, read_lease

        with fs_errors(self.url):
            return alive(read_lease(self.fs, self.path(rel)))

    def write_atomic(self, rel: str, chunks, sync: bool = False) -> None:
        """One PUT where a PUT is atomic (object stores: a reader sees the whole object or
        none); elsewhere a temp file moved into place."""
        data = b"".join(bytes(c) for c in chunks)
        with fs_errors(self.url):
            if self.buckets:
                self.fs.pipe_file(self.path(rel), data)
                return self._finished(rel)
            self._parent(rel)
            tmp = self.path(f"tmp/{uuid.uuid4().hex}")
            try:
                self.fs.pipe_file(tmp, data)
                self.fs.mv(tmp, self.path(rel))
            except BaseException:
                with contextlib.suppress(Exception):
                    self.fs.rm_file(tmp)
                raise

    def _finished(self, rel: str) -> None:
        """A key's record is written: its lease, held here, is finished (left, not deleted)."""
        if rel.startswith("keys/"):
            lease = self._leases.get(f"locks/{rel[5:-5]}.lock")
            if lease is not None:
                lease.finished = True

    def write_many(self, entries: dict[str, list]) -> None:
        """One concurrent batch of PUTs where a PUT is atomic (fsspec's multi-path ``pipe``)."""
        if not self.buckets or len(entries) < 2:
            return super().write_many(entries)
        with fs_errors(self.url):
            self.fs.pipe({self.path(rel): b"".join(bytes(c) for c in chunks) for rel, chunks in entries.items()})

    def _parent(self, rel: str) -> None:
        """Make the folder ``rel`` goes into (object stores have none)."""
        if not self.buckets:
            self.fs.makedirs(self.path(rel).rsplit("/", 1)[0], exist_ok=True)

    def remove(self, rel: str) -> None:
        with contextlib.suppress(FileNotFoundError), fs_errors(self.url):
            self.fs.rm_file(self.path(rel))

    def move_aside(self, rel: str, to_rel: str) -> bool:
        try:
            self._parent(to_rel)
            self.fs.mv(self.path(rel), self.path(to_rel))
            return True
        except Exception:  # noqa: BLE001 - best effort: the entry is skipped either way
            return False

    def entries(self, part: str) -> Iterator[Entry]:
        try:
            with fs_errors(self.url):
                found = self.fs.find(self.path(part), detail=True)
        except FileNotFoundError:
            return
        for p, info in found.items():
            mt = info.get("mtime") or info.get("created") or 0
            if hasattr(mt, "timestamp"):
                mt = mt.timestamp()
            yield Entry(p[len(self.root) + 1:], int(info.get("size") or 0), float(mt))

    def key_lock(self, key: str, on_wait: Callable[[dict, float], None] | None = None):
        """``on_wait(holder, ttl)``: told once when another run's lease is waited for (a flock's or
        a thread lock's holder is alive: nothing to say)."""
        from ..leases import is_in_process, local_root

        leased = local_root(self.fs, self.root) is None and not is_in_process(self.fs)
        return self.lock(f"locks/{key[:2]}/{key}.lock", on_wait=on_wait if leased else None,
                         done=lambda: self.read(f"keys/{key[:2]}/{key}.json") is not None)

    @contextlib.contextmanager
    def lock(self, rel: str, shared: bool = False, on_wait=None, done=None):
        """Locks that hold across processes (see graphkit.leases): flocks for file://, a thread
        lock for memory://, leases on object stores (``store.lock``: runs shared, gc exclusive;
        ``done``: a key's lease, finished once its record is written, see :meth:`write_atomic`)."""
        from .. import leases

        folder = leases.local_root(self.fs, self.root)
        if folder is not None:  # a folder on this machine: the same flocks as a plain folder
            with LocalFS(folder).lock(rel, shared, on_wait):
                yield
            return
        if leases.is_in_process(self.fs):
            with self._thread_lock(rel) if not shared else contextlib.nullcontext():
                yield
            return
        if rel == "store.lock":
            cm = (leases.shared if shared else leases.exclusive)(self.fs, self.root, on_wait)
        else:
            cm = leases.Lease(self.fs, self.path(rel), on_wait=on_wait, done=done)
        with self._thread_lock(rel) if not shared else contextlib.nullcontext(False) as waited, self._held(cm):
            self._leases[rel] = cm  # (the thread lock: one holder of rel in this process)
            try:
                yield waited or getattr(cm, "waited", None)
            finally:
                self._leases.pop(rel, None)

    @contextlib.contextmanager
    def _thread_lock(self, rel: str):
        """Threads of this process first, then other processes; yields whether another thread held
        it (it may have computed the key meanwhile: the caller looks again)."""
        with self._locks_guard:
            lock = self._locks.setdefault(f"{self.url}/{rel}", threading.Lock())
        waited = not lock.acquire(blocking=False)
        if waited:
            lock.acquire()
        try:
            yield waited
        finally:
            lock.release()

    @contextlib.contextmanager
    def _held(self, cm):
        """Hold ``cm`` (a lease); a store that stops answering while taking or releasing it is
        one CacheError (what the body raises passes unchanged)."""
        with fs_errors(self.url):
            cm.__enter__()
        try:
            yield
        except BaseException:
            with contextlib.suppress(Exception):
                cm.__exit__(None, None, None)
            raise
        with fs_errors(self.url):
            cm.__exit__(None, None, None)

