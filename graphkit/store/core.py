"""The store core: values and records in, values and records out, per-key locks, run locks and
group commits, on whichever file system holds the cache (see docs/store.md for the layout).

Every value read is re-hashed against its digest and every record checked against its check
line (graphkit.store.codec, graphkit.store.records): a damaged entry is moved to ``quarantine/``
with one notice and recomputed, never served.  Objects are written before the record that names
them, each whole or not at all, so a reader or a killed process sees a whole entry or none.  On
a folder, a run makes its writes durable with one ``syncfs`` per ``COMMIT_INTERVAL_S`` and one
at its end, before it exports (group commit).  Per-key locks make concurrent runs compute each
key once; the run lock (shared by runs, exclusive for gc and ``verify --repair``) keeps
maintenance from removing what a run uses.
"""
from __future__ import annotations

import contextlib
import errno
import json
import os
import sys
import threading
import time
import uuid
from pathlib import Path
from typing import Any, Callable, Iterable

from ..errors import CacheError, UsageError
from ..types import BUILTIN_PORT_TYPES, PortType
from . import maintenance
from .behind import WritesBehind
from .codec import DIGEST, CorruptObject, check_object, encode_header, iter_chunks, object_rel, value_parts
from .fs import FORMAT_FILE, FORMAT_PREFIX, FORMAT_VERSION, FileSystem
from .localfs import LocalFS
from .objectfs import FsspecFS
from .records import cache_key, decode_record, encode_record, record_bytes, record_rel

def open_fs(location: str, options: dict | None = None) -> FileSystem:
    """The file system of a cache location: an fsspec URL (``scheme://…``, with storage
    ``options`` under those of the environment) or a folder."""
    return FsspecFS(location, options) if "://" in location else LocalFS(location)


class Store:
    """Content-addressed cache of node results (see the module docstring)."""

    #: a run makes its writes durable (one syncfs) at most this often, and when it ends
    COMMIT_INTERVAL_S = 1.0
    #: a record read within this many seconds of its last use is not re-marked as used: gc's
    #: least-recently-used order has this granularity, and warm re-runs write nothing
    TOUCH_GRANULARITY_S = 60.0

    def __init__(self, location: str | os.PathLike, sync: bool = True, options: dict | None = None):
        self.fs = open_fs(str(location), options)
        self.sync = sync
        self.location = self.fs.describe()
        self.read_only = False
        self._ready = False
        self._dirty = False
        self._last_commit = time.monotonic()
        self._commit_lock = threading.Lock()
        self._run_lock_depth = 0
        self._run_lock_guard = threading.Lock()
        self._run_cm: Any = None
        self._noticed: set[str] = set()
        #: digests of objects this process wrote or read back whole while holding the run lock
        #: (gc and verify --repair cannot remove them then): put_value does not look for them again
        self._present: set[str] = set()
        #: entries read ahead in one batch (:meth:`prefetch`), each taken by its next read
        self._ahead: dict[str, bytes | None] = {}
        #: a computed node's objects, record and lease release, off the critical path (object
        #: stores, inside a run: graphkit.store.behind); drained before the run ends
        self._behind = WritesBehind()
        #: the keyed check's secret (GRAPHKIT_CACHE_KEY; None: records carry no MAC)
        self.secret = cache_key()
        #: called with one line for each damaged entry found (Session sets it to its notice)
        self.on_notice: Callable[[str], None] | None = None

    # -- set-up and errors ---------------------------------------------------------------
    def init(self) -> str:
        """Create the cache (a bucket only on this request): what was done, in one line."""
        with self._errors("create the cache"):
            done = self.fs.init()
            self._check_format()
        return done

    def open(self) -> "Store":
        if not self._ready:
            with self._errors("create the cache folder"):
                self.fs.ensure()
                self.read_only = not self.fs.writable()  # a populated read-only cache still serves hits
                self._check_format()
            self._ready = True
        return self

    def _check_format(self) -> None:
        """The layout version, named by an empty file at the root: written when missing (a cache
        written before the file existed has this layout), refused when another version."""
        if self.fs.exists(FORMAT_FILE):
            return
        try:
            names = set(self.fs.root_names())
        except FileNotFoundError:
            names = set()
        if FORMAT_FILE in names:  # written by another client since the first look
            return
        others = sorted(n for n in names if n.startswith(FORMAT_PREFIX))
        if others:
            found = others[0][len(FORMAT_PREFIX):]
            newer = found.isdigit() and int(found) > FORMAT_VERSION
            fix = "use a newer graphkit with it" if newer else "remove it (its entries are recomputed)"
            raise CacheError(f"cache {self.location} has layout version {found}, {'newer' if newer else 'older'} "
                             f"than this graphkit's ({FORMAT_VERSION}): {fix}, or give this graphkit "
                             "another cache (--cache DIR)")
        if not self.read_only:
            with contextlib.suppress(OSError, CacheError):  # (read-only credentials: a later run writes it)
                self.fs.write_atomic(FORMAT_FILE, [])

    @contextlib.contextmanager
    def _errors(self, what: str):
        try:
            yield
        except OSError as e:
            reason = {errno.ENOSPC: "the disk is full", errno.EDQUOT: "the disk quota is exceeded",
                      errno.EROFS: "the file system is read-only", errno.EACCES: "permission denied",
                      errno.EPERM: "permission denied", errno.EFBIG: "the file size limit was reached"}.get(
                e.errno, e.strerror or str(e))
            raise CacheError(f"cache {self.location}: cannot {what}: {reason}") from None

    def notice(self, msg: str) -> None:
        if self.on_notice is not None:
            self.on_notice(msg)

    def _read_only_notice(self) -> None:
        if "ro" not in self._noticed:
            self._noticed.add("ro")
            self.notice(f"notice: cache {self.location} is read-only: results computed in this run "
                        "are not stored")

    @property
    def reads_together(self) -> bool:
        """Whether reads sent together cost one round trip (an object store), not one each."""
        return not self.fs.local

    @property
    def memo_file(self) -> Path | None:
        return self.fs.memo_file

    #: where the record of a key and the object of a digest are, below the cache root
    record_rel = staticmethod(record_rel)
    object_rel = staticmethod(object_rel)

    # -- records -------------------------------------------------------------------------
    def get_record(self, key: str, touch: bool = False) -> dict | None:
        """The record of ``key`` (None if absent or untrustworthy); ``touch`` marks it used for gc.

        A record that fails its check is quarantined with a notice and reads as a miss."""
        rel = f"keys/{key[:2]}/{key}.json"  # (record_rel, inlined: once per node of a warm run)
        if self._ahead and rel in self._ahead:
            raw, why, stale = *record_bytes(self._ahead.pop(rel, None), key), False
        else:
            in_run = self._run_lock_depth > 0
            raw, why, stale = self.fs.read_record(rel, key, self.TOUCH_GRANULARITY_S if touch else None, in_run,
                                                  in_run and touch and self.fs.hard_links and not self.read_only)
        return self._trusted(key, raw, why, stale)

    def get_records(self, keys: Iterable[str], touch: bool = False) -> dict[str, dict | None]:
        """:meth:`get_record` of many keys: on a file system that sends reads together, one batch."""
        keys = list(keys)
        if not self.fs.local:
            self.prefetch([record_rel(k) for k in keys])
        return {k: self.get_record(k, touch) for k in keys}

    def prefetch(self, rels: Iterable[str]) -> None:
        """Read these entries now, together, where the file system sends reads together (an
        object store: one concurrent batch; a folder reads each when asked): the next read of
        each takes its bytes from here."""
        if self.fs.local:
            return
        rels = [r for r in dict.fromkeys(rels) if r not in self._ahead]
        if len(rels) > 1:
            self._ahead.update(self.fs.read_many(rels))

    def prefetch_records(self, keys: Iterable[str]) -> None:
        """:meth:`prefetch` the records of these keys (text not of a key's hex form names none)."""
        self.prefetch(record_rel(k) for k in keys if isinstance(k, str) and DIGEST.fullmatch(k))

    def prefetch_values(self, digests: Iterable[str]) -> None:
        """:meth:`prefetch` the objects of these digests (values about to be loaded)."""
        self.prefetch(object_rel(d) for d in digests)

    def _trusted(self, key: str, raw: bytes | None, why: str | None, stale: bool) -> dict | None:
        """The record in ``raw`` if it passes its checks; else quarantined (a notice) and None."""
        if raw is None:
            if why is not None:
                self.quarantine(record_rel(key), f"cache record {key[:16]} {why}")
            return None
        rec, why = decode_record(raw, key, self.secret)
        if rec is None:
            self.quarantine(record_rel(key), f"cache record {key[:16]} {why}")
            return None
        if stale:  # used again long after its journal: it moves to this run's journal (gc's LRU)
            with contextlib.suppress(OSError):
                self.fs.append_record(key, raw)
        return rec

    def put_record(self, key: str, record: dict) -> None:
        if self.read_only:
            return self._read_only_notice()
        raw = encode_record(record, self.secret)
        if self.fs.atomic_put:  # (an object store: maybe behind a key lock; a folder writes now)
            self._behind.later(lambda: self._write_record(key, raw))
        else:
            self._write_record(key, raw)
        self._dirty = True

    def _write_record(self, key: str, raw: bytes) -> None:
        try:  # (not `with self._errors(...)` around it: a generator context per cold node)
            if not (self._journal_here() and self.fs.append_record(key, raw)):
                self.fs.write_atomic(record_rel(key), [raw])
        except OSError:
            with self._errors("write a cache record"):
                raise

    def _journal_here(self) -> bool:
        """Records go to a journal: a writable folder with hard links, inside a run."""
        return self._run_lock_depth > 0 and self.fs.hard_links and not self.read_only

    def quarantine(self, rel: str, what: str) -> None:
        """Move a damaged entry to quarantine/ (out of every lookup) and say so in one line."""
        if rel.startswith("objects/"):
            self._present.discard(rel.rsplit("/", 1)[-1])
        if not self.fs.exists(rel):
            return  # another thread or run has moved it already (and said so)
        name = rel.replace("/", "_")
        to = f"quarantine/{name}.{time.strftime('%Y%m%dT%H%M%S')}.{uuid.uuid4().hex[:6]}"
        inside = self.fs.inside(rel)  # (a shard folder replaced by a link out: nothing there is moved)
        moved = inside and not self.read_only and self.fs.move_aside(rel, to)
        where = "moved to quarantine/" if moved else (
            "left in place (the cache cannot be written)" if inside else "left in place (it lies outside the cache)")
        msg = f"notice: {what}: {where}; recomputing it"
        if msg not in self._noticed:
            self._noticed.add(msg)
            self.notice(msg)

    def quarantine_record(self, key: str, what: str) -> None:
        """Quarantine the record of ``key`` (see :meth:`quarantine`)."""
        self.quarantine(record_rel(key), what)

    # -- objects -------------------------------------------------------------------------
    def put_value(self, ptype: PortType, value: Any, parts=None) -> str:
        meta, arrays, digest = parts or value_parts(ptype, value)
        if self.read_only:
            self._read_only_notice()
            return digest
        if digest in self._present:
            return digest
        rel = object_rel(digest)
        if self.fs.atomic_put or not self.fs.exists(rel):
            head, offsets = encode_header(ptype.name, meta, arrays, digest)
            with self._errors("write a cache object"):
                self.fs.write_atomic(rel, iter_chunks(head, offsets, arrays))
                self._dirty = True
        self._seen_whole(digest)
        return digest

    def put_values(self, items: list[tuple[PortType, Any, Any]]) -> list[str]:
        """:meth:`put_value` of each (port type, value, parts): where a PUT is atomic (an object
        store), the objects go out in one batch (behind a key lock: see graphkit.store.behind);
        their digests, in order."""
        if not self.fs.atomic_put or self.read_only:
            return [self.put_value(*item) for item in items]
        todo, digests = {}, []
        for ptype, value, parts in items:
            meta, arrays, digest = parts or value_parts(ptype, value)
            digests.append(digest)
            if digest not in self._present:
                head, offsets = encode_header(ptype.name, meta, arrays, digest)
                todo[object_rel(digest)] = list(iter_chunks(head, offsets, arrays))
        if todo:
            self._behind.later(lambda: self._write_objects(todo))
        self._dirty = self._dirty or bool(todo)
        for d in digests:
            self._seen_whole(d)
        return digests

    def _write_objects(self, todo: dict[str, list]) -> None:
        with self._errors("write a cache object"):
            self.fs.write_many(todo)

    def _seen_whole(self, digest: str) -> None:
        """Object ``digest`` is in place, whole: while the run lock is held (gc and verify
        --repair wait for it, and an OS lock is never lost) put_value need not look for it again;
        the set empties when the lock is released."""
        if self._run_lock_depth and self.fs.flock:
            self._present.add(digest)

    def load_value(self, digest: str, ptype: PortType | None = None) -> Any:
        """The value named ``digest``, checked against it.

        A damaged object is quarantined and :class:`CorruptObject` raised; an absent one raises
        :class:`MissingObject` (both are :class:`CacheError`; a Session recomputes the value)."""
        rel = object_rel(digest)
        raw = self._ahead.pop(rel) if rel in self._ahead else self.fs.read(rel)
        try:
            tname, meta, arrays = check_object(raw, digest)
        except CorruptObject as e:
            self.quarantine(rel, f"cache object {digest[:16]} {e.why}")
            raise
        self._seen_whole(digest)
        if ptype is None:
            ptype = BUILTIN_PORT_TYPES.get(tname)
            if ptype is None:
                return meta.get("model", meta)
        return ptype.from_parts(meta, arrays)

    # -- durability ----------------------------------------------------------------------
    def commit(self, force: bool = True) -> None:
        """Group commit: make every write so far durable with one syncfs (see module docstring).

        ``force=False`` commits only if COMMIT_INTERVAL_S has passed since the last commit."""
        if force:
            self._behind.drain()  # (writes behind a key lock: done, or their error raised here)
        if not self._dirty or not self.sync:
            return
        now = time.monotonic()
        if not force and now - self._last_commit < self.COMMIT_INTERVAL_S:
            return
        with self._commit_lock:
            if not self._dirty:
                return
            self._dirty = False
            with contextlib.suppress(OSError):
                self.fs.commit()
            self._last_commit = time.monotonic()

    # -- locks ---------------------------------------------------------------------------
    def key_lock(self, key: str, node: str | None = None):
        """The per-key lock; a run that waits for another's lease says so once (which node, which
        lease, for how long at most)."""
        if self.read_only:
            return contextlib.nullcontext()

        def waiting(holder: dict, ttl: float) -> None:
            who = f"{holder.get('host', '?')}:{holder.get('pid', '?')}" if holder else "an unreadable lease"
            self.notice(f"notice: {'node ' + node if node else 'key ' + key[:16]} waits for lease "
                        f"{self.location}/locks/{key[:2]}/{key}.lock held by {who} (computing the same key); "
                        f"broken if not renewed within {ttl:g} s")
        lock = self.fs.key_lock(key, waiting)
        return self._behind.hold(lock) if self._run_lock_depth and self.fs.atomic_put else lock

    @contextlib.contextmanager
    def run_lock(self):
        """Held (shared) by runs from the first lookup until their outputs are exported; gc
        takes it exclusively.  Re-entrant within one Store."""
        with self._run_lock_guard:
            self._run_lock_depth += 1
            if self._run_lock_depth == 1:
                self.fs.end_run()  # (read outside a run: journals may have been removed since)
                cm = self.fs.lock("store.lock", shared=True)
                try:
                    with self._errors("lock the cache"):
                        cm.__enter__()
                except BaseException:
                    self._run_lock_depth -= 1
                    raise
                self._run_cm = cm
        try:
            yield
        finally:
            with self._run_lock_guard:
                self._run_lock_depth -= 1
                if self._run_lock_depth == 0:
                    self._behind.wait()  # (their errors: raised by commit, before the run ends)
                    self._present.clear()
                    self._ahead.clear()
                    self.fs.end_run()  # this run's journal is complete; what others wrote may change
                    self._run_cm.__exit__(None, None, None)

    def exclusive(self, what: str):
        """The store lock, exclusively (gc, verify --repair): waits for running runs, saying so."""
        def waiting():
            print(f"graphkit: {what} waits for the runs that use {self.location} to finish",
                  file=sys.stderr, flush=True)
        return self.fs.lock("store.lock", on_wait=waiting)

    # -- last runs (explain) -------------------------------------------------------------
    def save_run(self, graph_id: str, data: dict) -> None:
        if self.read_only:
            return
        with contextlib.suppress(OSError):
            self.fs.write_atomic(f"runs/{graph_id}.json", [json.dumps(data, sort_keys=True).encode()])

    def last_run(self, graph_id: str) -> dict | None:
        raw = self.fs.read(f"runs/{graph_id}.json")
        try:
            return json.loads(raw) if raw else None
        except ValueError:
            return None

    # -- maintenance (graphkit.store.maintenance) ----------------------------------------
    def records(self):
        """(key, record or None if untrustworthy, last use) for every record."""
        return ((r.key, r.record, r.mtime) for r in maintenance.Catalog(self).records)

    def usage(self) -> dict:
        return maintenance.Catalog(self, records=False).usage()

    def size(self) -> int:
        """Every byte the store holds (objects, records, tmp, quarantine, run notes, memo)."""
        return self.usage()["total"]

    def ls(self) -> list[dict]:
        return maintenance.ls(self)

    def clean_stale(self, dry_run: bool = False) -> dict:
        return maintenance.clean_stale(self, maintenance.Catalog(self, records=False), dry_run)

    def gc(self, max_bytes: int) -> dict:
        return maintenance.gc(self, max_bytes)

    def verify(self, repair: bool = False) -> list[str]:
        return maintenance.verify(self, repair)


def check_out_folder(out: str | os.PathLike, cache: str | os.PathLike) -> None:
    """Refuse an output folder that is the cache folder or lies inside it (exported files there
    would be taken for cache entries): one message naming both, and the fix."""
    loc = str(cache)
    if "://" in loc:
        if not loc.startswith("file://"):
            return
        loc = loc[len("file://"):]
    c, o = os.path.realpath(loc), os.path.realpath(out)
    if o == c or o.startswith(c.rstrip(os.sep) + os.sep):
        where = "is the cache folder" if o == c else f"lies inside the cache folder {c}"
        raise UsageError(f"--out {out} {where}: the cache holds only its own entries; "
                         "choose an output folder outside it (e.g. --out out)")
