"""The cache store: content-addressed value objects plus key records.

Layout (below the store root)::

    objects/ab/abcdef…   one value each, named by its digest (see ``encode_value``)
    keys/12/1234….json   one computation each: its key parts and output digests
    locks/12/1234….lock  per-key locks (flock; the OS releases them when a process dies)
    runs/NAME.json       the key parts of each node at the last run of graph NAME (for explain)
    tmp/                 files being written

Every write goes to ``tmp/``, is fsynced and renamed into place, objects before the record
that names them; so a reader (or a process killed at any point) sees either a whole entry or
none.  Runs hold a shared lock on the store and ``gc`` an exclusive one.

The same store works over an fsspec URL (``memory://…``, ``file://…``, ``s3://…``); there the
per-key lock is per process only, since object stores have no locks.
"""
from __future__ import annotations

import contextlib
import errno
import itertools
import json
import os
import struct
import threading
import time
import uuid
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from .errors import CacheError
from .hashing import parts_digest
from .types import BUILTIN_PORT_TYPES, PortType

MAGIC = b"GKOBJ1\n\0"
_counter = itertools.count()
_TOKEN = uuid.uuid4().hex[:12]  # with the pid, thread and counter: unique temp names on a shared folder
ALIGN = 64


# ---------------------------------------------------------------------------------------------
# value encoding


def value_parts(ptype: PortType, value: Any) -> tuple[dict, list[np.ndarray], str]:
    meta, arrays = ptype.to_parts(value)
    arrays = [np.ascontiguousarray(a) for a in arrays]
    return meta, arrays, parts_digest(ptype.name, meta, arrays)


def encode_header(ptype_name: str, meta: dict, arrays: list[np.ndarray], digest: str) -> tuple[bytes, list[int]]:
    descs, offsets, off = [], [], 0
    for a in arrays:
        off = (off + ALIGN - 1) // ALIGN * ALIGN
        descs.append({"dtype": a.dtype.str, "shape": list(a.shape), "offset": off, "nbytes": a.nbytes})
        offsets.append(off)
        off += a.nbytes
    header = json.dumps({"type": ptype_name, "meta": meta, "arrays": descs, "digest": digest},
                        sort_keys=True, separators=(",", ":")).encode()
    head = MAGIC + struct.pack("<Q", len(header)) + header
    pad = (-len(head)) % ALIGN
    return head + b"\0" * pad, offsets


def iter_chunks(head: bytes, offsets: list[int], arrays: list[np.ndarray]) -> Iterator[bytes | memoryview]:
    yield head
    pos = 0
    for off, a in zip(offsets, arrays):
        if off > pos:
            yield b"\0" * (off - pos)
        if a.nbytes:
            yield memoryview(a).cast("B")
        pos = off + a.nbytes


def decode_object(buf: bytes | memoryview) -> tuple[str, dict, list[np.ndarray], str]:
    buf = memoryview(buf)
    if bytes(buf[:8]) != MAGIC:
        raise ValueError("not a graphkit object (bad magic)")
    (hlen,) = struct.unpack("<Q", buf[8:16])
    header = json.loads(bytes(buf[16:16 + hlen]))
    base = 16 + hlen
    base += (-base) % ALIGN
    arrays = []
    for d in header["arrays"]:
        dt = np.dtype(d["dtype"])
        n = int(np.prod(d["shape"])) if d["shape"] else 1
        if base + d["offset"] + d["nbytes"] > len(buf):
            raise ValueError("truncated object")
        a = np.frombuffer(buf, dtype=dt, count=n, offset=base + d["offset"]).reshape(d["shape"])
        arrays.append(a)
    return header["type"], header["meta"], arrays, header["digest"]


# ---------------------------------------------------------------------------------------------
# file systems


class LocalFS:
    """A folder on this machine: fsync + rename writes, flock locks."""

    locks_are_shared = True

    def __init__(self, root: str):
        self.root = Path(root).absolute()
        self._prefix = str(self.root) + os.sep

    def describe(self) -> str:
        return str(self.root)

    def _p(self, rel: str) -> Path:
        return self.root / rel

    def _s(self, rel: str) -> str:  # plain-string path for the hot paths (pathlib is slow)
        return self._prefix + rel

    def ensure(self) -> None:
        for d in ("objects", "keys", "locks", "runs", "tmp"):
            self._p(d).mkdir(parents=True, exist_ok=True)

    def read(self, rel: str) -> bytes | None:
        try:
            with open(self._s(rel), "rb") as f:
                return f.read()
        except FileNotFoundError:
            return None

    def exists(self, rel: str) -> bool:
        return os.path.exists(self._s(rel))

    def write_atomic(self, rel: str, chunks, sync: bool = True) -> None:
        dest = self._s(rel)
        tmp = self._s(f"tmp/{_TOKEN}-{os.getpid()}-{threading.get_ident()}-{next(_counter)}")
        try:
            with open(tmp, "wb") as f:
                for c in chunks:
                    f.write(c)
                f.flush()
                if sync:
                    os.fsync(f.fileno())
            try:
                os.replace(tmp, dest)
            except FileNotFoundError:  # first write into this shard folder
                os.makedirs(os.path.dirname(dest), exist_ok=True)
                os.replace(tmp, dest)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise

    def remove(self, rel: str) -> None:
        with contextlib.suppress(FileNotFoundError):
            self._p(rel).unlink()

    def read_touch(self, rel: str, fresh_s: float) -> bytes | None:
        """Read a small file and mark it used (mtime = now) unless it was marked in the last
        ``fresh_s`` seconds: one open, fstat, read and close, and no utime on a warm re-run."""
        try:
            fd = os.open(self._s(rel), os.O_RDONLY)
        except FileNotFoundError:
            return None
        try:
            st = os.fstat(fd)
            data = os.read(fd, st.st_size + 1)
            while len(data) <= st.st_size:  # a short read (rare): read to the end
                more = os.read(fd, 1 << 16)
                if not more:
                    break
                data += more
            if time.time() - st.st_mtime > fresh_s:
                with contextlib.suppress(OSError):  # read-only caches stay readable
                    os.utime(fd)
            return data
        finally:
            os.close(fd)

    def listdir(self, rel: str) -> Iterator[tuple[str, int, float]]:
        base = self._p(rel)
        if not base.exists():
            return
        for dirpath, _, files in os.walk(base):
            for fn in files:
                p = Path(dirpath) / fn
                try:
                    st = p.stat()
                except FileNotFoundError:
                    continue
                yield str(p.relative_to(self.root)), st.st_size, st.st_mtime

    @contextlib.contextmanager
    def lock(self, rel: str, shared: bool = False):
        import fcntl

        p = self._p(rel)
        p.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(p, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_SH if shared else fcntl.LOCK_EX)
            yield
        finally:
            os.close(fd)  # closing releases the flock


class FsspecFS:
    """Any fsspec file system (memory://, file://, s3://, …)."""

    locks_are_shared = False
    _locks: dict[str, threading.Lock] = {}
    _locks_guard = threading.Lock()

    def __init__(self, url: str):
        import fsspec

        self.fs, self.root = fsspec.core.url_to_fs(url)
        self.url = url
        self.root = self.root.rstrip("/")

    def describe(self) -> str:
        return self.url

    def _p(self, rel: str) -> str:
        return f"{self.root}/{rel}"

    def ensure(self) -> None:
        for d in ("objects", "keys", "runs", "tmp"):
            self.fs.makedirs(self._p(d), exist_ok=True)

    def read(self, rel: str) -> bytes | None:
        try:
            return self.fs.cat_file(self._p(rel))
        except FileNotFoundError:
            return None

    def exists(self, rel: str) -> bool:
        return self.fs.exists(self._p(rel))

    def write_atomic(self, rel: str, chunks, sync: bool = True) -> None:
        tmp = self._p(f"tmp/{uuid.uuid4().hex}")
        data = b"".join(bytes(c) for c in chunks)
        parent = self._p(rel).rsplit("/", 1)[0]
        self.fs.makedirs(parent, exist_ok=True)
        try:
            self.fs.pipe_file(tmp, data)
            self.fs.mv(tmp, self._p(rel))
        except BaseException:
            with contextlib.suppress(Exception):
                self.fs.rm_file(tmp)
            raise

    def remove(self, rel: str) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.fs.rm_file(self._p(rel))

    def read_touch(self, rel: str, fresh_s: float) -> bytes | None:
        return self.read(rel)

    def listdir(self, rel: str) -> Iterator[tuple[str, int, float]]:
        base = self._p(rel)
        if not self.fs.exists(base):
            return
        for p, info in self.fs.find(base, detail=True).items():
            mt = info.get("mtime") or info.get("created") or 0
            if hasattr(mt, "timestamp"):
                mt = mt.timestamp()
            yield p[len(self.root) + 1:], int(info.get("size") or 0), float(mt)

    @contextlib.contextmanager
    def lock(self, rel: str, shared: bool = False):
        """Exclusive locks hold across processes (see graphkit.leases): flock for file://, a lease
        file on object stores, a thread lock for memory://.  Shared (run) locks are flocks on
        file:// and no-ops elsewhere."""
        from .leases import Lease, is_in_process, local_root

        folder = local_root(self.fs, self.root)
        if folder is not None:  # a folder on this machine: the same flocks as a plain folder
            with LocalFS(folder).lock(rel, shared):
                yield
            return
        if shared:
            yield
            return
        with self._locks_guard:
            lk = self._locks.setdefault(f"{self.url}/{rel}", threading.Lock())
        with lk:  # threads of this process first, then other processes
            if is_in_process(self.fs):
                yield
            else:
                with Lease(self.fs, self._p(rel)):
                    yield


# ---------------------------------------------------------------------------------------------
# the store


class Store:
    """Content-addressed cache of node results (see module docstring)."""

    def __init__(self, location: str | os.PathLike, sync: bool = True):
        loc = str(location)
        self.fs = FsspecFS(loc) if "://" in loc else LocalFS(loc)
        self.sync = sync
        self.location = self.fs.describe()
        self._ready = False

    # -- set-up and errors ---------------------------------------------------------------
    def open(self) -> "Store":
        if not self._ready:
            with self._errors("create the cache folder"):
                self.fs.ensure()
                if isinstance(self.fs, LocalFS):
                    probe = f"tmp/probe-{uuid.uuid4().hex}"
                    self.fs.write_atomic(probe, [b"ok"], sync=False)
                    self.fs.remove(probe)
            self._ready = True
        return self

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

    @property
    def memo_file(self) -> Path | None:
        return self.fs.root / "filememo.json" if isinstance(self.fs, LocalFS) else None

    # -- records -------------------------------------------------------------------------
    @staticmethod
    def _krel(key: str) -> str:
        return f"keys/{key[:2]}/{key}.json"

    @staticmethod
    def _orel(digest: str) -> str:
        return f"objects/{digest[:2]}/{digest}"

    #: a record read within this many seconds of its last use is not re-marked as used: gc's
    #: least-recently-used order has this granularity, and warm re-runs write nothing
    TOUCH_GRANULARITY_S = 60.0

    def get_record(self, key: str, touch: bool = False) -> dict | None:
        """The record of ``key`` (None if absent or unreadable); ``touch`` marks it used for gc."""
        rel = self._krel(key)
        raw = self.fs.read_touch(rel, self.TOUCH_GRANULARITY_S) if touch else self.fs.read(rel)
        if raw is None:
            return None
        try:
            rec = json.loads(raw)
            rec["outputs"]
        except (ValueError, KeyError, TypeError):
            return None  # unreadable record: a miss; `cache verify` reports and removes it
        # objects are written before their record, and gc (exclusive store lock) never runs
        # beside a run (shared lock), so a readable record's objects exist
        return rec

    def put_record(self, key: str, record: dict) -> None:
        with self._errors("write a cache record"):
            data = json.dumps(record, sort_keys=True, separators=(",", ":")).encode()
            self.fs.write_atomic(self._krel(key), [data], self.sync)

    # -- objects -------------------------------------------------------------------------
    def put_value(self, ptype: PortType, value: Any, parts=None) -> str:
        meta, arrays, digest = parts or value_parts(ptype, value)
        rel = self._orel(digest)
        if not self.fs.exists(rel):
            head, offsets = encode_header(ptype.name, meta, arrays, digest)
            with self._errors("write a cache object"):
                self.fs.write_atomic(rel, iter_chunks(head, offsets, arrays), self.sync)
        return digest

    def load_value(self, digest: str, ptype: PortType | None = None) -> Any:
        raw = self.fs.read(self._orel(digest))
        if raw is None:
            raise CacheError(f"cache {self.location}: object {digest} is missing (run `graphkit cache verify`)")
        try:
            tname, meta, arrays, d = decode_object(raw)
        except (ValueError, KeyError) as e:
            raise CacheError(f"cache {self.location}: object {digest} is corrupt ({e}); run `graphkit cache verify`") from None
        if ptype is None:
            ptype = BUILTIN_PORT_TYPES.get(tname)
            if ptype is None:
                return meta.get("model", meta)
        return ptype.from_parts(meta, arrays)

    # -- locks ---------------------------------------------------------------------------
    def key_lock(self, key: str):
        return self.fs.lock(f"locks/{key[:2]}/{key}.lock")

    def run_lock(self):
        """Held (shared) by runs; gc takes it exclusively."""
        return self.fs.lock("store.lock", shared=True)

    # -- last runs (explain) -------------------------------------------------------------
    def save_run(self, graph_id: str, data: dict) -> None:
        with contextlib.suppress(OSError):
            self.fs.write_atomic(f"runs/{graph_id}.json", [json.dumps(data, sort_keys=True).encode()], False)

    def last_run(self, graph_id: str) -> dict | None:
        raw = self.fs.read(f"runs/{graph_id}.json")
        try:
            return json.loads(raw) if raw else None
        except ValueError:
            return None

    # -- maintenance ---------------------------------------------------------------------
    def records(self) -> Iterator[tuple[str, dict | None, float]]:
        for rel, _, mtime in self.fs.listdir("keys"):
            key = rel.rsplit("/", 1)[-1].removesuffix(".json")
            raw = self.fs.read(rel)
            try:
                rec = json.loads(raw) if raw else None
            except ValueError:
                rec = None
            yield key, rec, mtime

    def ls(self) -> list[dict]:
        sizes = {rel.rsplit("/", 1)[-1]: size for rel, size, _ in self.fs.listdir("objects")}
        rows = []
        for key, rec, mtime in self.records():
            if rec is None:
                rows.append({"key": key, "node": "?", "type": "?", "bytes": 0, "used": mtime, "corrupt": True})
                continue
            size = sum(sizes.get(o["digest"], 0) for o in rec.get("outputs", {}).values())
            rows.append({"key": key, "node": rec.get("node", "?"), "type": rec.get("parts", {}).get("node_type", "?"),
                         "bytes": size, "used": mtime, "seconds": rec.get("seconds", 0.0)})
        return sorted(rows, key=lambda r: -r["used"])

    def size(self) -> int:
        return sum(s for _, s, _ in self.fs.listdir("objects")) + sum(s for _, s, _ in self.fs.listdir("keys"))

    def gc(self, max_bytes: int) -> dict:
        """Drop least-recently-used records until objects+records fit in ``max_bytes``."""
        with self.fs.lock("store.lock"):
            objs = {rel.rsplit("/", 1)[-1]: size for rel, size, _ in self.fs.listdir("objects")}
            recs = sorted(self.records(), key=lambda r: r[2])  # oldest first
            rec_sizes = {k: s for rel, s, _ in self.fs.listdir("keys") for k in [rel.rsplit("/", 1)[-1].removesuffix(".json")]}
            refs: dict[str, int] = {}
            for _, rec, _ in recs:
                for o in (rec or {}).get("outputs", {}).values():
                    refs[o["digest"]] = refs.get(o["digest"], 0) + 1
            total = sum(objs.values()) + sum(rec_sizes.values())
            removed_keys = removed_objs = 0
            for d in [d for d in objs if d not in refs]:  # orphans first
                self.fs.remove(self._orel(d))
                total -= objs.pop(d)
                removed_objs += 1
            for key, rec, _ in recs:
                if total <= max_bytes:
                    break
                self.fs.remove(self._krel(key))
                total -= rec_sizes.get(key, 0)
                removed_keys += 1
                for o in (rec or {}).get("outputs", {}).values():
                    d = o["digest"]
                    refs[d] -= 1
                    if refs[d] == 0 and d in objs:
                        self.fs.remove(self._orel(d))
                        total -= objs.pop(d)
                        removed_objs += 1
            return {"removed_records": removed_keys, "removed_objects": removed_objs, "bytes": total}

    def verify(self, repair: bool = False) -> list[str]:
        """Re-hash every object and check every record; return the problems found."""
        problems = []
        bad_objs = set()
        with self.fs.lock("store.lock"):
            for rel, _, _ in self.fs.listdir("objects"):
                name = rel.rsplit("/", 1)[-1]
                raw = self.fs.read(rel)
                try:
                    tname, meta, arrays, d = decode_object(raw)
                    ok = parts_digest(tname, meta, arrays) == name == d
                except (ValueError, KeyError, TypeError):
                    ok = False
                if not ok:
                    problems.append(f"object {name}: content does not match its digest")
                    bad_objs.add(name)
                    if repair:
                        self.fs.remove(rel)
            for key, rec, _ in self.records():
                if rec is None or "outputs" not in rec:
                    problems.append(f"record {key}: unreadable")
                    if repair:
                        self.fs.remove(self._krel(key))
                    continue
                for port, o in rec["outputs"].items():
                    if o["digest"] in bad_objs or not self.fs.exists(self._orel(o["digest"])):
                        problems.append(f"record {key} ({rec.get('node')}): output '{port}' object missing or corrupt")
                        if repair:
                            self.fs.remove(self._krel(key))
                        break
            for rel, _, mtime in self.fs.listdir("tmp"):
                if time.time() - mtime > 3600 and repair:
                    self.fs.remove(rel)
        return problems
