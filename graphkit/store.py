"""The cache store: content-addressed value objects plus key records.

Layout (below the store root)::

    objects/ab/abcdef…     one value each, named by its digest (see ``encode_value``)
    keys/12/1234….json     one computation each: a check line, then its key parts and output digests
                           (a file of its own, or a hard link to the journal that holds it, below)
    journal/….gkj          the records a run wrote, appended one after another (one file per run)
    store.lock             runs hold it shared, ``gc`` / ``verify --repair`` exclusively (flock)
    keys.lock              per-key locks: byte-range (OFD) locks, one byte per key
    runs/NAME.json         the key parts of each node at the last run of graph NAME (for explain)
    quarantine/            entries found damaged on read (kept for inspection; gc removes them)
    tmp/                   files being written

Trust.  Every value read from the store is re-hashed and compared with its digest (xxh3 runs at
memory speed, so this costs about as much as the read); a record starts with a line
``GKREC1 <xxh3-128 of the rest>`` and names its own key, so a damaged record, or one edited to
point at another (valid) object, or copied under another key, is detected.  A damaged entry is
moved to ``quarantine/``, reported in one notice line, and recomputed.

Writes and durability (group commit).  Every object goes to ``tmp/`` and is renamed into place
(a record too, or it is linked to its run's journal once whole: below), objects before the
record that names them, so a reader or a process killed at any point sees a whole entry or none
(the kernel keeps what a killed process wrote).  For power loss we do NOT
fsync every file: on ext4 each fsync is a journal commit plus a device flush (the 3.4 ms per
node measured in issue 10), paid twice per node.  Instead a run commits in groups:
:meth:`Store.commit` calls ``syncfs(2)`` on the cache's file system (all data, inodes and
directory entries written so far, one journal commit) at most once per
``COMMIT_INTERVAL_S`` while a run writes, and once when the run ends, before its outputs are
exported and before it reports success.  What a power cut can lose is then only the last second
of results; what it damages (an entry whose data had not reached the disk) is caught by the
read-side checks above and recomputed, never served.  An SQLite index in WAL mode would give the
same guarantee with fewer files, but it is unsafe on the network folders a Dask cluster shares,
needs writable ``-shm`` files (read-only and multi-user caches) and would give the store two
formats (fsspec stores cannot hold it); one syncfs per group gives the fsync saving without that.

Records of a run: one journal, a hard link per key.  A run appends each record it writes to its
own journal file (a header line with a unique id, then frames ``\0GKJF <key> <length>\n<record>``,
each record with its check line as above) and makes ``keys/12/1234….json`` a hard link to that
journal.  A new hard link is a directory entry only, where a file per record is also a new inode:
on a busy disk that allocation costs 100-300 µs, a link a few µs (benchmarks/bench_engine.py).  A
reader opens the key's file as before; a file that starts with the journal header is looked up in
its frame index (read once per journal and process, extended when the journal has grown).  The
link is made after the frame is whole, so a reader or a process killed at any point sees a whole
record or none; a torn last frame is never linked.  A record that is edited, truncated or not in
its journal fails its checks and is quarantined (a copy of its frame) as a record file would be.
The journal's mtime is the last use of its records; a record read more than
``TOUCH_GRANULARITY_S`` after its journal was last used is appended to the reading run's journal
and linked there, so gc's least-recently-used order stays per record.  gc frees a journal when no
key links to it.  Writes outside a run (no run lock: a Dask worker, a library call), an fsspec
store and a file system without hard links write one file per record.

Locks.  Per-key locks make concurrent runs compute each key once: a run that misses a key takes
its lock and, if it had to wait for it (another run was computing the key), looks again and uses
that run's result.  A lock taken at once costs one system call and no second lookup (the one
case left: another run computing and storing the key entirely between the miss and the lock, a
few microseconds, costs a duplicate computation of the same bytes, never a wrong result).  On
Linux they are open-file-description byte-range locks on one file (``keys.lock``), so a cold
node creates no lock file; elsewhere one lock file per key (``locks/``).  The OS releases them
when a process dies.  While a run holds the run lock, objects it has stored or read back whole
are not looked for again (gc cannot remove them meanwhile).

Sharing.  Folders, lock files and entries are created with the mode of the cache folder (a
group-writable folder, e.g. ``chmod 2775``, gives group-writable entries whatever the umask), so
users of one group share a cache.  A cache that cannot be written (``chmod -R a-w``, a read-only
mount) still serves hits; results computed against it are kept in memory only, with one notice.

The same store works over an fsspec URL (``memory://…``, ``file://…``, ``s3://…``): on object
stores each entry is one PUT (atomic there), locks are leases (graphkit.leases) and ``commit`` is
a no-op.
"""
from __future__ import annotations

import collections
import contextlib
import errno
import fcntl
import hashlib
import hmac
import itertools
import json
import os
import re
import stat
import struct
import threading
import time
import uuid
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import xxhash

from .errors import CacheError, UsageError
from .hashing import parts_digest
from .types import BUILTIN_PORT_TYPES, PortType

MAGIC = b"GKOBJ1\n\0"
RECORD_MAGIC = b"GKREC1 "
_counter = itertools.count()
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)
#: how entries are opened for reading: never through a symbolic link (an entry is a file the
#: store wrote, not a name for another file) and never blocking (a FIFO planted as an entry)
_READ_FLAGS = os.O_RDONLY | _CLOEXEC | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
NOT_A_FILE = "is not a plain file (a link or a special file: damaged or forged)"
_TOKEN = uuid.uuid4().hex[:12]  # with the pid, thread and counter: unique temp names on a shared folder
_PID = [os.getpid()]  # os.getpid() is a system call on each use; a forked child learns its own
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=lambda: _PID.__setitem__(0, os.getpid()))
ALIGN = 64
MiB = 1 << 20
#: the one JSON form of record bodies and object headers (a prebuilt encoder: json.dumps with
#: these arguments builds a new JSONEncoder on every call)
_JSON = json.JSONEncoder(sort_keys=True, separators=(",", ":"))


def _kept_encoder() -> Callable[[Any], str]:
    """_JSON.encode without building a new C encoder per call (JSONEncoder.encode does, which
    was a quarter of a record's encoding): the same C encoder json uses, kept.  It skips the
    circular-reference check (records and headers are trees built here; a value's meta was
    already encoded with the check by hashing.meta_bytes).  A Python without it: _JSON.encode
    (tests/test_engine_store_unit.py compares the two texts)."""
    try:
        from json.encoder import c_make_encoder, encode_basestring_ascii

        enc = c_make_encoder(None, _JSON.default, encode_basestring_ascii, None, ":", ",", True, False, True)
    except (ImportError, TypeError):  # pragma: no cover - CPython has it
        return _JSON.encode

    def encode(o: Any) -> str:
        return "".join(enc(o, 0))

    return encode


_json_encode = _kept_encoder()


def fmt_size(n: int) -> str:
    """Sizes are shown in MiB (2^20 bytes) everywhere: `cache ls`, gc, verify."""
    return f"{n / MiB:.3f} MiB"


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
    header = _json_encode({"type": ptype_name, "meta": meta, "arrays": descs, "digest": digest}).encode()
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


def check_object(raw: bytes | None, digest: str) -> tuple[str, dict, list[np.ndarray]]:
    """Decode a stored object and check that its content hashes to ``digest``.

    Raises :class:`MissingObject` (``raw`` is None) or :class:`CorruptObject`."""
    if raw is None:
        raise MissingObject(digest, "is missing")
    try:
        tname, meta, arrays, d = decode_object(raw)
        ok = d == digest and parts_digest(tname, meta, arrays) == digest
    except (ValueError, KeyError, TypeError) as e:
        raise CorruptObject(digest, f"cannot be decoded ({e})") from None
    if not ok:
        raise CorruptObject(digest, "does not match its digest")
    return tname, meta, arrays


class DamagedEntry(CacheError):
    """A stored object that is missing or whose bytes do not hash to its name."""

    def __init__(self, digest: str, why: str):
        self.digest, self.why = digest, why
        super().__init__(f"cache object {digest} {why}")


class MissingObject(DamagedEntry):
    pass


class CorruptObject(DamagedEntry):
    pass


#: the one form of a value digest (xxh3-128, lowercase hex): a record's output digest names a
#: file below objects/, so anything else in a record is damage, never a path
DIGEST = re.compile(r"[0-9a-f]{32}")
#: GRAPHKIT_CACHE_KEY: a secret shared by the runs allowed to write records (see ``record_mac``)
KEY_ENV = "GRAPHKIT_CACHE_KEY"


def cache_key() -> bytes | None:
    """The keyed check's secret (GRAPHKIT_CACHE_KEY), or None when records carry no MAC."""
    k = os.environ.get(KEY_ENV)
    return k.encode() if k else None


def record_mac(body: bytes, secret: bytes) -> bytes:
    """The keyed check of a record body: HMAC-SHA256 with the cache key, in hex."""
    return hmac.new(secret, body, hashlib.sha256).hexdigest().encode()


def encode_record(record: dict, secret: bytes | None = None) -> bytes:
    """``GKREC1 <xxh3-128 of the body>[ <HMAC of the body>]\n<body>``: the MAC only with a key."""
    body = _json_encode(record).encode()
    mac = b" " + record_mac(body, secret) if secret else b""
    return RECORD_MAGIC + xxhash.xxh3_128_hexdigest(body).encode() + mac + b"\n" + body


LEGACY_RECORD = "was written by an older graphkit (no integrity line): it is recomputed when next used"


UNSIGNED = f"is not signed with this run's {KEY_ENV} (written by a run without the key, or forged)"


def decode_record(raw: bytes, key: str, secret: bytes | None = None) -> tuple[dict | None, str | None]:
    """(record, None) or (None, why it cannot be trusted).  With ``secret`` (the cache key) a
    record must also carry the MAC only a run holding that key can make."""
    if not raw.startswith(RECORD_MAGIC):
        if raw.startswith(b"{"):
            return None, LEGACY_RECORD
        return None, "has no integrity line (damaged)"
    nl = raw.find(b"\n")
    check, body = raw[len(RECORD_MAGIC):nl], raw[nl + 1:]
    check, _, mac = check.partition(b" ")
    if nl < 0 or xxhash.xxh3_128_hexdigest(body).encode() != check:
        return None, "does not match its check line (damaged or edited)"
    if secret and not hmac.compare_digest(mac, record_mac(body, secret)):
        return None, UNSIGNED
    try:
        rec = json.loads(body)
        outs = rec["outputs"]
        if rec["key"] != key:
            return None, f"belongs to key {str(rec['key'])[:16]} (a record moved or copied)"
        for o in outs.values():
            if type(o["digest"]) is not str or not DIGEST.fullmatch(o["digest"]):
                return None, f"names an output digest that is not one ({str(o['digest'])[:40]!r}: damaged or forged)"
    except (ValueError, KeyError, TypeError, AttributeError):
        return None, "is not a valid record"
    return rec, None


# ---------------------------------------------------------------------------------------------
# journals: the records of one run in one file, linked from keys/ (see module docstring)

JOURNAL_MAGIC = b"GKJRN1 "
JOURNAL_HEAD = len(JOURNAL_MAGIC) + 32 + 1  # the magic, a 32-hex id, a newline
FRAME = b"\0GKJF "
#: a run starts a new journal after this many records or bytes (ext4 allows 65,000 links a file)
JOURNAL_MAX_FRAMES = 50_000
JOURNAL_MAX_BYTES = 64 * MiB
#: a process forgets the journals it has indexed when they hold more than this in memory
JOURNAL_CACHE_BYTES = 64 * MiB
NOT_IN_JOURNAL = "is not in the journal it links to (damaged)"
_LINK_UNSUPPORTED = {getattr(errno, n) for n in ("EPERM", "ENOTSUP", "EOPNOTSUPP", "EXDEV", "ENOSYS", "EINVAL")
                     if hasattr(errno, n)}


def is_journal(head: bytes | memoryview) -> bool:
    """Whether a file starting with ``head`` is a journal (its header: magic, id, newline)."""
    return len(head) >= JOURNAL_HEAD and bytes(head[:len(JOURNAL_MAGIC)]) == JOURNAL_MAGIC \
        and head[JOURNAL_HEAD - 1] == 10


_FRAME_HEAD = re.compile(rb"\0GKJF ([0-9A-Za-z]{1,64}) ([0-9]{1,12})\n")


def parse_frames(buf: bytes | bytearray, pos: int, frames: dict[str, tuple[int, int]]) -> int:
    """Index the whole frames of a journal from ``pos`` (key -> (start, end) of its record; a
    later frame of a key replaces an earlier one); returns the end of the last whole frame, where
    the next call starts.  A record never holds a NUL byte (its JSON is ASCII with escapes), so
    every NUL + "GKJF " starts a frame: a damaged stretch is skipped, and the frames after it are
    still found (a false start inside damage only names a record that then fails its checks)."""
    n = len(buf)
    for m in _FRAME_HEAD.finditer(buf, pos):
        start = m.end()
        end = start + int(m.group(2))
        if end > n:  # torn (a killed run) or still being written
            break
        frames[m.group(1).decode()] = (start, end)
        pos = end
    return pos


def journal_record(buf: bytes, key: str) -> bytes | None:
    """The record of ``key`` in a whole journal read as bytes (None: not in it)."""
    frames: dict[str, tuple[int, int]] = {}
    parse_frames(buf, JOURNAL_HEAD, frames)
    span = frames.get(key)
    return None if span is None else bytes(buf[span[0]:span[1]])


class _JournalView:
    """What one process has read of one journal: its bytes so far and where each key's frame is."""

    __slots__ = ("head", "buf", "parsed", "frames")

    def __init__(self, head: bytes):
        self.head = head
        self.buf = bytearray(head)
        self.parsed = JOURNAL_HEAD
        self.frames: dict[str, tuple[int, int]] = {}

    def extend(self, data: bytes) -> None:
        self.buf += data
        self.parsed = parse_frames(self.buf, self.parsed, self.frames)

    def record(self, key: str) -> bytearray | None:
        span = self.frames.get(key)
        return None if span is None else self.buf[span[0]:span[1]]


class _Journal:
    """The journal this process appends to during a run."""

    __slots__ = ("fd", "path", "pid", "frames", "size")

    def __init__(self, fd: int, path: str, size: int):
        self.fd, self.path, self.pid, self.frames, self.size = fd, path, _PID[0], 0, size


def _damaged_records(records: dict[str, dict], bad: set[str], present: set[str]) -> list[tuple[str, str]]:
    """(key, why) of every record to drop: its output is missing or corrupt, or (following the
    chain) it was computed from a damaged value: a bad object, or one that only dropped records
    made.  Linear: each record and each digest is visited once."""
    consumers: dict[str, list[str]] = {}
    makers: dict[str, int] = {}  # digest -> how many records not (yet) dropped output it
    for key, rec in records.items():
        for d in set(record_inputs(rec)):
            consumers.setdefault(d, []).append(key)
        for d in {o["digest"] for o in rec["outputs"].values()}:
            makers[d] = makers.get(d, 0) + 1
    tainted, queue, dropped = set(bad), collections.deque(bad), {}

    def drop(key: str, why: str) -> None:
        dropped[key] = why
        for d in {o["digest"] for o in records[key]["outputs"].values()}:
            makers[d] -= 1
            if makers[d] == 0 and d not in tainted:
                tainted.add(d)
                queue.append(d)

    for key, rec in records.items():
        port = next((p for p, o in rec["outputs"].items() if o["digest"] in bad or o["digest"] not in present), None)
        if port is not None:
            drop(key, f"output '{port}' object missing or corrupt")
    while queue:
        for key in consumers.get(queue.popleft(), ()):
            if key not in dropped:
                first = next(d for d in record_inputs(records[key]) if d in tainted)
                drop(key, f"computed from a damaged value ({first[:16]})")
    return list(dropped.items())


def record_inputs(rec: dict) -> list[str]:
    """The input value digests a record was computed from."""
    out = []
    for v in (rec.get("parts") or {}).get("inputs", {}).values():
        out.extend(v if isinstance(v, list) else [v])
    return [d for d in out if isinstance(d, str)]


# ---------------------------------------------------------------------------------------------
# file systems


def _umask() -> int:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    return 0o022


_READ_ONLY_ERRNOS = (errno.EACCES, errno.EPERM, errno.EROFS)


def _read_fd(fd: int, size: int) -> bytes:
    """All of an open file that fstat said holds ``size`` bytes: one read when it does; read on
    to the end when a read comes back short (Linux caps one read at 2 GiB) or the file grew."""
    data = os.read(fd, size + 1)
    if len(data) != size:
        chunks = [data]
        while more := os.read(fd, 1 << 24):
            chunks.append(more)
        data = b"".join(chunks)
    return data


def _write_all(fd: int, chunks) -> None:
    """Write every chunk (bytes or buffers) to ``fd`` with os.write (no Python file object)."""
    for c in chunks:
        if type(c) is not bytes:
            c = memoryview(c).cast("B")
        while len(c):
            n = os.write(fd, c)
            if n == len(c):
                break
            c = memoryview(c)[n:]


class LocalFS:
    """A folder on this machine: write + rename, syncfs group commits, flock / OFD locks."""

    locks_are_shared = True
    #: whether a value is written without looking for it first (a look costs as much as a write)
    blind_put = False

    def __init__(self, root: str):
        self.root = Path(root).absolute()
        self._prefix = str(self.root) + os.sep
        self.dir_mode = 0o777
        self.file_mode = 0o666
        self._fix_file_mode = self._fix_dir_mode = False
        self._local = threading.local()
        self._key_lock_fd_ok = hasattr(fcntl, "F_OFD_SETLKW")

    def describe(self) -> str:
        return str(self.root)

    def _p(self, rel: str) -> Path:
        return self.root / rel

    def _s(self, rel: str) -> str:  # plain-string path for the hot paths (pathlib is slow)
        return self._prefix + rel

    # -- modes: entries get the cache folder's mode, whatever the umask -------------------
    def _learn_modes(self) -> None:
        st = os.stat(self.root)
        self.dir_mode = st.st_mode & 0o7777
        self.file_mode = st.st_mode & 0o666
        um = _umask()
        self._fix_dir_mode = (self.dir_mode & 0o777 & ~um) != (self.dir_mode & 0o777) or bool(self.dir_mode & 0o7000)
        self._fix_file_mode = (self.file_mode & ~um) != self.file_mode

    def mkdir(self, path: str) -> None:
        """Create ``path`` (and missing parents below the root) with the folder's mode."""
        try:
            os.mkdir(path, self.dir_mode & 0o777)
        except FileExistsError:
            return
        except FileNotFoundError:
            parent = os.path.dirname(path)
            if parent == path or len(parent) < len(self._prefix) - 1:
                raise
            self.mkdir(parent)
            return self.mkdir(path)
        if self._fix_dir_mode:
            with contextlib.suppress(OSError):
                os.chmod(path, self.dir_mode & 0o3777)

    def ensure(self) -> None:
        self.root.mkdir(parents=True, exist_ok=True)
        self._learn_modes()
        for d in ("objects", "keys", "runs", "tmp"):
            self.mkdir(self._s(d))

    # -- reads and writes -----------------------------------------------------------------
    def read(self, rel: str) -> bytes | None:
        """The bytes of the file at ``rel``; None if there is none; b"" (which no entry is) for
        what is not a plain file: a symbolic link is never followed."""
        try:
            fd = os.open(self._s(rel), _READ_FLAGS)
        except (FileNotFoundError, NotADirectoryError):
            return None
        except OSError as e:
            if e.errno != errno.ELOOP:
                raise
            return b""
        try:
            st = os.fstat(fd)
            return _read_fd(fd, st.st_size) if stat.S_ISREG(st.st_mode) else b""
        finally:
            os.close(fd)

    def exists(self, rel: str) -> bool:
        return os.path.lexists(self._s(rel))

    def live_lease(self, rel: str) -> bool:  # (locks/ holds flock files: a lock file is never live)
        return False

    def inside(self, rel: str) -> bool:
        """Whether the folder holding ``rel`` is the cache's own (no symbolic link leads out)."""
        real = os.path.realpath(os.path.dirname(self._s(rel)))
        return (real + os.sep).startswith(os.path.realpath(self.root) + os.sep)

    def init(self) -> str:
        self.ensure()
        return f"cache {self.describe()} is ready"

    def info(self) -> dict[str, str]:
        return {"cache": str(self.root), "file system": "a folder on this machine (flock, hard links, syncfs)"}

    def _create(self, path: str) -> int:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _CLOEXEC, self.file_mode)
        if self._fix_file_mode:
            with contextlib.suppress(OSError):
                os.fchmod(fd, self.file_mode)
        return fd

    def write_atomic(self, rel: str, chunks, sync: bool = False) -> None:
        """Write ``chunks`` to a temp file and rename it to ``rel``; ``sync``: fsync it first
        (only for single files outside a group commit)."""
        dest = self._s(rel)
        tmp = self._s(f"tmp/{_TOKEN}-{_PID[0]}-{threading.get_ident()}-{next(_counter)}")
        try:
            fd = self._create(tmp)
            try:
                _write_all(fd, chunks)
                if sync:
                    os.fsync(fd)
            finally:
                os.close(fd)
            try:
                os.replace(tmp, dest)
            except FileNotFoundError:  # first write into this shard folder
                self.mkdir(os.path.dirname(dest))
                os.replace(tmp, dest)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise

    def remove(self, rel: str) -> None:
        with contextlib.suppress(FileNotFoundError):
            self._p(rel).unlink()

    def move_aside(self, rel: str, to_rel: str) -> bool:
        """Rename ``rel`` to ``to_rel`` (quarantine); False if it is gone or cannot be moved."""
        try:
            os.replace(self._s(rel), self._s(to_rel))
            return True
        except FileNotFoundError:
            try:
                self.mkdir(os.path.dirname(self._s(to_rel)))
                os.replace(self._s(rel), self._s(to_rel))
                return True
            except OSError:
                return False
        except OSError:
            return False

    def stats(self, rel: str) -> Iterator[tuple[str, os.stat_result]]:
        """(path below the root, lstat) of every file below ``rel`` (nothing when ``rel`` is a
        symbolic link: what it points to is not the cache's)."""
        if os.path.islink(self._s(rel)):
            return
        for dirpath, _, files in os.walk(self._s(rel)):
            for fn in files:
                p = os.path.join(dirpath, fn)
                try:
                    st = os.lstat(p)
                except FileNotFoundError:
                    continue
                yield p[len(self._prefix):], st

    def listdir(self, rel: str) -> Iterator[tuple[str, int, float]]:
        for p, st in self.stats(rel):
            yield p, st.st_size, st.st_mtime

    def commit(self) -> None:
        """Make everything written to this file system so far durable: one syncfs(2)."""
        fd = os.open(self.root, os.O_RDONLY)
        try:
            _syncfs(fd)
        finally:
            os.close(fd)

    # -- locks ----------------------------------------------------------------------------
    def _open_lock(self, path: str) -> int | None:
        """An fd to lock ``path`` (created with the folder's mode); None if the cache cannot be
        written and the lock file does not exist (a read-only cache: nobody can change it)."""
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, self.file_mode)
        except OSError as e:
            if e.errno not in _READ_ONLY_ERRNOS:
                raise
            try:
                return os.open(path, os.O_RDONLY)  # flock needs no write access
            except OSError:
                return None
        if self._fix_file_mode:
            with contextlib.suppress(OSError):  # only the owner may chmod; others need not
                if os.fstat(fd).st_uid == os.geteuid():
                    os.fchmod(fd, self.file_mode)
        return fd

    @contextlib.contextmanager
    def lock(self, rel: str, shared: bool = False, on_wait: Callable[[], None] | None = None):
        p = self._s(rel)
        self.mkdir(os.path.dirname(p)) if "/" in rel else None
        fd = self._open_lock(p)
        if fd is None:
            yield None
            return
        try:
            mode = fcntl.LOCK_SH if shared else fcntl.LOCK_EX
            waited = False
            try:
                fcntl.flock(fd, mode | fcntl.LOCK_NB)
            except BlockingIOError:
                if on_wait is not None:
                    on_wait()
                fcntl.flock(fd, mode)
                waited = True
            yield waited
        finally:
            os.close(fd)  # closing releases the flock

    def key_lock(self, key: str, on_wait=None):  # (a flock's holder is alive: nothing to say)
        if not self._key_lock_fd_ok:
            return self.lock(f"locks/{key[:2]}/{key}.lock")
        return self._ofd_lock(int(key[:15], 16))

    def _ofd_lock(self, byte: int) -> "_OFDLock | contextlib.nullcontext":
        """An exclusive lock on one byte of keys.lock, owned by this thread's open file
        description (so threads of one process exclude each other, as processes do)."""
        held = getattr(self._local, "fd", None)
        if held is None:
            fd = self._open_lock(self._s("keys.lock"))
            if fd is None:  # read-only cache: nothing is written, nothing to single-flight
                return contextlib.nullcontext()
            held = self._local.fd = _FD(fd)
        return _OFDLock(held.fd, byte)


class _OFDLock:
    """Context manager: an exclusive F_OFD lock on one byte on enter, F_UNLCK on exit (a class,
    not a generator: it is taken once per computed node).  ``__enter__`` returns whether it had
    to wait (another holder: see :meth:`LocalFS.key_lock`)."""

    __slots__ = ("fd", "byte")

    def __init__(self, fd: int, byte: int):
        self.fd, self.byte = fd, byte

    def __enter__(self) -> bool:
        lk = struct.pack("hhqqi4x", fcntl.F_WRLCK, 0, self.byte, 1, 0)
        try:
            fcntl.fcntl(self.fd, fcntl.F_OFD_SETLK, lk)  # free (the usual case): one system call
            return False
        except OSError as e:
            if e.errno not in (errno.EAGAIN, errno.EACCES):
                raise
        fcntl.fcntl(self.fd, fcntl.F_OFD_SETLKW, lk)
        return True

    def __exit__(self, *exc) -> None:
        fcntl.fcntl(self.fd, fcntl.F_OFD_SETLK, struct.pack("hhqqi4x", fcntl.F_UNLCK, 0, self.byte, 1, 0))


class _FD:
    """An fd closed when its owner (a thread's local storage) goes away."""

    def __init__(self, fd: int):
        self.fd = fd

    def __del__(self):
        with contextlib.suppress(OSError):
            os.close(self.fd)


_libc_syncfs = None


def _syncfs(fd: int) -> None:
    global _libc_syncfs
    if _libc_syncfs is None:
        try:
            import ctypes

            _libc_syncfs = ctypes.CDLL(None, use_errno=True).syncfs
        except (OSError, AttributeError):
            _libc_syncfs = False
    if _libc_syncfs is False or _libc_syncfs(fd) != 0:
        os.sync()


#: client settings graphkit gives an fsspec file system unless told otherwise: an S3 server that
#: cannot be reached fails within seconds (botocore's defaults retry for half a minute)
CLIENT_DEFAULTS = {"s3": {"config_kwargs": {"connect_timeout": 3, "read_timeout": 60,
                                            "retries": {"max_attempts": 2, "mode": "standard"}},
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


class FsspecFS:
    """Any fsspec file system (memory://, file://, s3://, …)."""

    locks_are_shared = False
    _locks: dict[str, threading.Lock] = {}
    _locks_guard = threading.Lock()

    def __init__(self, url: str):
        import fsspec

        protocol = fsspec.core.split_protocol(url)[0]
        self.options = merged_options(CLIENT_DEFAULTS.get(protocol, {}), cache_options())
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
        self.buckets = self.blind_put = self.fs.root_marker == ""

    def describe(self) -> str:
        return self.url

    def _p(self, rel: str) -> str:
        return f"{self.root}/{rel}"

    def ensure(self) -> None:
        if self.buckets:
            return self._check_prefix()
        for d in ("objects", "keys", "runs", "tmp"):
            self.fs.makedirs(self._p(d), exist_ok=True)

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
            with fs_errors(self.url):
                names = {p.rstrip("/").rsplit("/", 1)[-1] for p in self.fs.ls(self.root, detail=False)}
        except FileNotFoundError:  # an empty prefix, or no bucket
            with fs_errors(self.url, bucket=True):
                self.fs.info(self.root.split("/", 1)[0])
            return
        foreign = sorted(names - CACHE_NAMES)
        if foreign:
            raise CacheError(f"cache {self.url} holds objects that are not a graphkit cache's ({', '.join(foreign[:3])}"
                             f"{', …' if len(foreign) > 3 else ''}): give the cache a prefix of its own, "
                             f"e.g. {self.url.rstrip('/')}/graphkit-cache")

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
                return self.fs.cat_file(self._p(rel))
        except FileNotFoundError:
            return None

    def exists(self, rel: str) -> bool:
        with fs_errors(self.url):
            return self.fs.exists(self._p(rel))

    def inside(self, rel: str) -> bool:  # (object stores have no links: every key is the store's)
        return True

    def live_lease(self, rel: str) -> bool:
        """Whether ``rel`` is a lease whose owner still renews it (gc leaves it)."""
        from .leases import alive, read_lease

        with fs_errors(self.url):
            return alive(read_lease(self.fs, self._p(rel)))

    def write_atomic(self, rel: str, chunks, sync: bool = False) -> None:
        """One PUT where a PUT is atomic (object stores: a reader sees the whole object or
        none); elsewhere a temp file moved into place."""
        data = b"".join(bytes(c) for c in chunks)
        with fs_errors(self.url):
            if self.buckets:
                return self.fs.pipe_file(self._p(rel), data)
            self._parent(rel)
            tmp = self._p(f"tmp/{uuid.uuid4().hex}")
            try:
                self.fs.pipe_file(tmp, data)
                self.fs.mv(tmp, self._p(rel))
            except BaseException:
                with contextlib.suppress(Exception):
                    self.fs.rm_file(tmp)
                raise

    def _parent(self, rel: str) -> None:
        """Make the folder ``rel`` goes into (object stores have none)."""
        if not self.buckets:
            self.fs.makedirs(self._p(rel).rsplit("/", 1)[0], exist_ok=True)

    def remove(self, rel: str) -> None:
        with contextlib.suppress(FileNotFoundError), fs_errors(self.url):
            self.fs.rm_file(self._p(rel))

    def move_aside(self, rel: str, to_rel: str) -> bool:
        try:
            self._parent(to_rel)
            self.fs.mv(self._p(rel), self._p(to_rel))
            return True
        except Exception:  # noqa: BLE001 - best effort: the entry is skipped either way
            return False

    def listdir(self, rel: str) -> Iterator[tuple[str, int, float]]:
        try:
            with fs_errors(self.url):
                found = self.fs.find(self._p(rel), detail=True)
        except FileNotFoundError:
            return
        for p, info in found.items():
            mt = info.get("mtime") or info.get("created") or 0
            if hasattr(mt, "timestamp"):
                mt = mt.timestamp()
            yield p[len(self.root) + 1:], int(info.get("size") or 0), float(mt)

    def commit(self) -> None:
        pass

    def key_lock(self, key: str, on_wait: Callable[[dict, float], None] | None = None):
        """``on_wait(holder, ttl)``: told once when another run's lease is waited for (a flock's or
        a thread lock's holder is alive: nothing to say)."""
        from .leases import is_in_process, local_root

        leased = local_root(self.fs, self.root) is None and not is_in_process(self.fs)
        return self.lock(f"locks/{key[:2]}/{key}.lock", on_wait=on_wait if leased else None)

    @contextlib.contextmanager
    def lock(self, rel: str, shared: bool = False, on_wait=None):
        """Locks that hold across processes (see graphkit.leases): flocks for file://, a thread
        lock for memory://, leases on object stores (``store.lock``: runs shared, gc exclusive)."""
        from . import leases

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
            cm = leases.Lease(self.fs, self._p(rel), on_wait=on_wait)
        with self._thread_lock(rel) if not shared else contextlib.nullcontext(), self._held(cm):
            yield getattr(cm, "waited", None)

    def _thread_lock(self, rel: str) -> threading.Lock:
        """Threads of this process first, then other processes."""
        with self._locks_guard:
            return self._locks.setdefault(f"{self.url}/{rel}", threading.Lock())

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


# ---------------------------------------------------------------------------------------------
# the store

_LEGACY_OUT_TMP = re.compile(r"filememo\.json\..+\.tmp$")


class Store:
    """Content-addressed cache of node results (see module docstring)."""

    #: a run makes its writes durable (one syncfs) at most this often, and when it ends
    COMMIT_INTERVAL_S = 1.0

    def __init__(self, location: str | os.PathLike, sync: bool = True):
        loc = str(location)
        self.fs = FsspecFS(loc) if "://" in loc else LocalFS(loc)
        self.sync = sync
        self.location = self.fs.describe()
        self.read_only = False
        self._ready = False
        self._dirty = False
        self._last_commit = time.monotonic()
        self._commit_lock = threading.Lock()
        self._run_lock_depth = 0
        self._run_lock_guard = threading.Lock()
        self._noticed: set[str] = set()
        #: digests of objects this process wrote or read back whole while holding the run lock
        #: (gc and verify --repair cannot remove them then): put_value does not look for them again
        self._present: set[str] = set()
        self._local = isinstance(self.fs, LocalFS)
        #: the journal this run appends its records to (see module docstring), and what this
        #: process has read of journals: (st_dev, st_ino) -> _JournalView
        self._journal: _Journal | None = None
        self._journal_ok = self._local
        self._jlock = threading.Lock()
        self._jviews: dict[tuple[int, int], _JournalView] = {}
        self._jview_bytes = 0
        #: the keyed check's secret (GRAPHKIT_CACHE_KEY; None: records carry no MAC)
        self.secret = cache_key()
        #: called with one line for each damaged entry found (Session sets it to its notice)
        self.on_notice: Callable[[str], None] | None = None

    # -- set-up and errors ---------------------------------------------------------------
    def init(self) -> str:
        """Create the cache (a bucket only on this request): what was done, in one line."""
        with self._errors("create the cache"):
            return self.fs.init()

    def open(self) -> "Store":
        if not self._ready:
            with self._errors("create the cache folder"):
                self.fs.ensure()
                if isinstance(self.fs, LocalFS):
                    probe = f"tmp/probe-{uuid.uuid4().hex}"
                    try:
                        self.fs.write_atomic(probe, [b"ok"])
                        self.fs.remove(probe)
                    except FileNotFoundError:
                        pass  # a concurrent `cache gc` removed the probe from tmp/: the folder is writable
                    except OSError as e:
                        if e.errno not in _READ_ONLY_ERRNOS:
                            raise
                        self.read_only = True  # a populated read-only cache still serves hits
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

    def notice(self, msg: str) -> None:
        if self.on_notice is not None:
            self.on_notice(msg)

    def _read_only_notice(self) -> None:
        if "ro" not in self._noticed:
            self._noticed.add("ro")
            self.notice(f"notice: cache {self.location} is read-only: results computed in this run "
                        "are not stored")

    @property
    def memo_file(self) -> Path | None:
        return self.fs.root / "filememo.json" if isinstance(self.fs, LocalFS) else None

    # -- records -------------------------------------------------------------------------
    @staticmethod
    def _krel(key: str) -> str:
        return f"keys/{key[:2]}/{key}.json"

    @staticmethod
    def _key_of(rel: str) -> str:
        """The key whose record is at ``rel`` (see _krel)."""
        return rel.rsplit("/", 1)[-1].removesuffix(".json")

    @staticmethod
    def _orel(digest: str) -> str:
        return f"objects/{digest[:2]}/{digest}"

    #: a record read within this many seconds of its last use is not re-marked as used: gc's
    #: least-recently-used order has this granularity, and warm re-runs write nothing
    TOUCH_GRANULARITY_S = 60.0

    def get_record(self, key: str, touch: bool = False) -> dict | None:
        """The record of ``key`` (None if absent or untrustworthy); ``touch`` marks it used for gc.

        A record that fails its check is quarantined with a notice and reads as a miss."""
        rel = self._krel(key)
        raw, why, stale = self._raw_record(rel, key, touch)
        if raw is None:
            if why is not None:
                self.quarantine(rel, f"cache record {key[:16]} {why}")
            return None
        rec, why = decode_record(raw, key, self.secret)
        if rec is None:
            if why is not LEGACY_RECORD:  # a legacy record is a plain miss
                self.quarantine(rel, f"cache record {key[:16]} {why}")
            return None
        if stale:  # used again long after its journal: it moves to this run's journal (gc's LRU)
            with contextlib.suppress(OSError):
                self._journal_put(key, raw)
        return rec

    def _raw_record(self, rel: str, key: str, touch: bool = False) -> tuple[bytes | None, str | None, bool]:
        """(the bytes of the record of ``key`` at ``rel``, None when it is absent or not in the
        journal it links to; why, in that last case; whether ``touch`` should move it to this
        run's journal).  ``touch`` marks the record used (its file's or journal's mtime) when it
        was last used more than TOUCH_GRANULARITY_S ago."""
        if not self._local:
            return self._raw_remote_record(rel, key)
        try:
            fd = os.open(self.fs._s(rel), _READ_FLAGS)
        except (FileNotFoundError, NotADirectoryError):
            return None, None, False
        except OSError as e:
            if e.errno != errno.ELOOP:
                raise
            return None, NOT_A_FILE, False
        try:
            return self._raw_fd_record(fd, key, touch)
        finally:
            os.close(fd)

    def _raw_remote_record(self, rel: str, key: str) -> tuple[bytes | None, str | None, bool]:
        """``_raw_record`` on a store that is not a local folder (never touched)."""
        raw = self.fs.read(rel)
        if raw is not None and is_journal(raw[:JOURNAL_HEAD]):
            raw = journal_record(raw, key)
            return raw, (NOT_IN_JOURNAL if raw is None else None), False
        return raw, None, False

    def _raw_fd_record(self, fd: int, key: str, touch: bool) -> tuple[bytes | None, str | None, bool]:
        """``_raw_record`` of the local file open as ``fd``."""
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            return None, NOT_A_FILE, False
        if st.st_nlink == 1 and st.st_size <= MiB:  # a record file (or a journal linked once)
            raw = _read_fd(fd, st.st_size)
            linked = is_journal(raw[:JOURNAL_HEAD])
            if linked:
                raw = journal_record(raw, key)
        else:
            linked, raw = self._journal_lookup(fd, st, key)
            if not linked:
                raw = _read_fd(fd, st.st_size)
        if raw is None:
            return None, NOT_IN_JOURNAL, False
        if touch and time.time() - st.st_mtime > self.TOUCH_GRANULARITY_S:
            if linked and self._journal_here():
                return raw, None, True
            with contextlib.suppress(OSError):  # read-only caches stay readable
                os.utime(fd)
        return raw, None, False

    def _journal_lookup(self, fd: int, st: os.stat_result, key: str) -> tuple[bool, bytearray | None]:
        """(whether the file open as ``fd`` is a journal, the record of ``key`` in it): from what
        this process has read of it, after reading what has been appended since."""
        ident = (st.st_dev, st.st_ino)
        view = self._jviews.get(ident)
        if view is not None and self._run_lock_depth:
            head = view.head  # read in this run, in which no journal is removed: still that file
        else:
            head = os.pread(fd, JOURNAL_HEAD, 0)
            if not is_journal(head):
                return False, None
        if view is not None and st.st_size == len(view.buf) and view.head == head:
            return True, view.record(key)  # (the usual hit: read already; no lock, as views only grow)
        with self._jlock:
            view = self._jviews.get(ident)
            if view is None or view.head != head or st.st_size < len(view.buf):
                if self._jview_bytes > JOURNAL_CACHE_BYTES:
                    self._forget_journals()
                view = self._jviews[ident] = _JournalView(head)
            if st.st_size > len(view.buf):
                n0 = len(view.buf)
                view.extend(os.pread(fd, st.st_size - n0, n0))  # (a short read: the rest next time)
                self._jview_bytes += len(view.buf) - n0
            return True, view.record(key)

    def _forget_journals(self) -> None:
        self._jviews.clear()
        self._jview_bytes = 0

    def put_record(self, key: str, record: dict) -> None:
        if self.read_only:
            return self._read_only_notice()
        raw = encode_record(record, self.secret)
        try:  # (not `with self._errors(...)` around it: a generator context per cold node)
            if not (self._journal_here() and self._journal_put(key, raw)):
                self.fs.write_atomic(self._krel(key), [raw])
        except OSError:
            with self._errors("write a cache record"):
                raise
        self._dirty = True

    # -- journals ------------------------------------------------------------------------
    def _journal_here(self) -> bool:
        """Records go to a journal: a writable folder with hard links, inside a run."""
        return self._run_lock_depth > 0 and self._journal_ok and not self.read_only

    def _journal_put(self, key: str, raw: bytes) -> bool:
        """Append the record to this run's journal and link keys/…/KEY.json to it; False if this
        file system has no hard links, or will not link the journal (the caller writes a record
        file instead)."""
        frame = b"%s%s %d\n" % (FRAME, key.encode(), len(raw)) + raw
        dest = self.fs._s(self._krel(key))
        with self._jlock:
            for _ in range(2):  # this run's journal, then (full, or removed meanwhile) a new one
                j = self._journal
                if j is None or j.pid != _PID[0]:  # (a forked child starts its own)
                    j = self._journal = self._open_journal()
                _write_all(j.fd, [frame])
                j.frames += 1
                j.size += len(frame)
                try:
                    self._link(j.path, dest)
                except OSError as e:
                    if e.errno in _LINK_UNSUPPORTED:
                        self._journal_ok = False
                        self._end_journal()
                        return False
                    if e.errno not in (errno.EMLINK, errno.ENOENT):
                        raise
                    self._end_journal()
                    continue
                if j.frames >= JOURNAL_MAX_FRAMES or j.size >= JOURNAL_MAX_BYTES:
                    self._end_journal()
                return True
        return False

    def _open_journal(self) -> _Journal:
        folder = self.fs._s("journal")
        self.fs.mkdir(folder)
        path = f"{folder}/{time.time_ns():016x}-{_TOKEN}-{_PID[0]}-{next(_counter)}.gkj"
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND | _CLOEXEC, self.fs.file_mode)
        try:
            if self.fs._fix_file_mode:
                with contextlib.suppress(OSError):
                    os.fchmod(fd, self.fs.file_mode)
            head = JOURNAL_MAGIC + uuid.uuid4().hex.encode() + b"\n"
            _write_all(fd, [head])
        except BaseException:
            os.close(fd)
            with contextlib.suppress(OSError):
                os.unlink(path)
            raise
        return _Journal(fd, path, len(head))

    def _link(self, src: str, dest: str) -> None:
        """Make ``dest`` a hard link to ``src``, replacing what is there (atomically)."""
        try:
            return os.link(src, dest)
        except FileExistsError:
            pass
        except FileNotFoundError:
            if not os.path.exists(src):
                raise
            self.fs.mkdir(os.path.dirname(dest))  # the first record in this shard folder
            try:
                return os.link(src, dest)
            except FileExistsError:
                pass
        tmp = self.fs._s(f"tmp/{_TOKEN}-{_PID[0]}-{threading.get_ident()}-{next(_counter)}")
        os.link(src, tmp)
        try:
            os.replace(tmp, dest)
        finally:  # (rename does nothing when both names are links to one file: dest already is)
            with contextlib.suppress(OSError):
                os.unlink(tmp)

    def _end_journal(self) -> None:
        j, self._journal = self._journal, None
        if j is not None and j.pid == _PID[0]:
            with contextlib.suppress(OSError):
                os.close(j.fd)

    def quarantine(self, rel: str, what: str) -> None:
        """Move a damaged entry to quarantine/ (out of every lookup) and say so in one line."""
        if rel.startswith("objects/"):
            self._present.discard(rel.rsplit("/", 1)[-1])
        if not self.fs.exists(rel):
            return  # another thread or run has moved it already (and said so)
        name = rel.replace("/", "_")
        to = f"quarantine/{name}.{time.strftime('%Y%m%dT%H%M%S')}.{uuid.uuid4().hex[:6]}"
        inside = self.fs.inside(rel)  # (a shard folder replaced by a link out: nothing there is moved)
        moved = inside and not self.read_only and (self._quarantine_link(rel, to) or self.fs.move_aside(rel, to))
        where = "moved to quarantine/" if moved else (
            "left in place (the cache cannot be written)" if inside else "left in place (it lies outside the cache)")
        msg = f"notice: {what}: {where}; recomputing it"
        if msg not in self._noticed:
            self._noticed.add(msg)
            self.notice(msg)

    def quarantine_record(self, key: str, what: str) -> None:
        """Quarantine the record of ``key`` (see :meth:`quarantine`)."""
        self.quarantine(self._krel(key), what)

    def _quarantine_link(self, rel: str, to: str) -> bool:
        """A record file with other names (a link to the journal other records share): its record
        is copied to ``to`` and the link removed.  False if ``rel`` has no other name."""
        if not (self._local and rel.startswith("keys/")):
            return False
        try:
            if os.lstat(self.fs._s(rel)).st_nlink < 2:
                return False
        except OSError:
            return False
        raw = self._raw_record(rel, self._key_of(rel))[0]
        try:
            self.fs.mkdir(os.path.dirname(self.fs._s(to)))
            self.fs.write_atomic(to, [raw or b""])
            os.unlink(self.fs._s(rel))
        except OSError:
            return False
        return True

    # -- objects -------------------------------------------------------------------------
    def put_value(self, ptype: PortType, value: Any, parts=None) -> str:
        meta, arrays, digest = parts or value_parts(ptype, value)
        if self.read_only:
            self._read_only_notice()
            return digest
        if digest in self._present:
            return digest
        rel = self._orel(digest)
        if self.fs.blind_put or not self.fs.exists(rel):
            head, offsets = encode_header(ptype.name, meta, arrays, digest)
            with self._errors("write a cache object"):
                self.fs.write_atomic(rel, iter_chunks(head, offsets, arrays))
                self._dirty = True
        self._seen_whole(digest)
        return digest

    def _seen_whole(self, digest: str) -> None:
        """Object ``digest`` is in place, whole: while the run lock is held (gc and verify
        --repair wait for it) put_value need not look for it again; the set empties when the
        lock is released."""
        if self._run_lock_depth and self._local:
            self._present.add(digest)

    def load_value(self, digest: str, ptype: PortType | None = None) -> Any:
        """The value named ``digest``, checked against it.

        A damaged object is quarantined and :class:`CorruptObject` raised; an absent one raises
        :class:`MissingObject` (both are :class:`CacheError`; a Session recomputes the value)."""
        rel = self._orel(digest)
        raw = self.fs.read(rel)
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
        return self.fs.key_lock(key, waiting)

    @contextlib.contextmanager
    def run_lock(self):
        """Held (shared) by runs from the first lookup until their outputs are exported; gc
        takes it exclusively.  Re-entrant within one Store."""
        with self._run_lock_guard:
            self._run_lock_depth += 1
            first = self._run_lock_depth == 1
            if first:
                self._forget_journals()  # (read outside a run: journals may have been removed since)
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
                    self._present.clear()
                    with self._jlock:  # this run's journal is complete; what others wrote may change
                        self._end_journal()
                        self._forget_journals()
                    self._run_cm.__exit__(None, None, None)

    def _exclusive(self, what: str):
        def waiting():
            print(f"graphkit: {what} waits for the runs that use {self.location} to finish",
                  file=__import__("sys").stderr, flush=True)
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

    # -- maintenance ---------------------------------------------------------------------
    def records(self) -> Iterator[tuple[str, dict | None, float]]:
        """(key, record or None if untrustworthy, last use) for every record file."""
        for rel, _, mtime in self.fs.listdir("keys"):
            key = self._key_of(rel)
            raw = self._raw_record(rel, key)[0]
            rec = decode_record(raw, key, self.secret)[0] if raw is not None else None
            yield key, rec, mtime

    def _record_why(self, key: str) -> str:
        raw, why, _ = self._raw_record(self._krel(key), key)
        return why or decode_record(raw or b"", key, self.secret)[1]

    def _record_files(self) -> tuple[dict[str, int], dict[str, tuple[int, int]], dict[tuple[int, int], list]]:
        """(key -> size of its record file; key -> the journal it links to; journal ->
        [size, how many records link to it, its name in journal/ or None])."""
        if not self._local:
            return {self._key_of(rel): s for rel, s in self._sizes("keys").items()}, {}, {}
        sizes, links, journals = {}, {}, {}
        names = {(st.st_dev, st.st_ino): rel for rel, st in self.fs.stats("journal")}
        for rel, st in self.fs.stats("keys"):
            key = self._key_of(rel)
            ident = (st.st_dev, st.st_ino)
            if st.st_nlink > 1 or ident in names:
                links[key] = ident
                j = journals.setdefault(ident, [st.st_size, 0, names.get(ident)])
                j[1] += 1
            else:
                sizes[key] = st.st_size
        return sizes, links, journals

    def _sizes(self, rel: str) -> dict[str, int]:
        return {r: s for r, s, _ in self.fs.listdir(rel)}

    def usage(self) -> dict:
        """True bytes on disk by part: objects (each once), records, tmp, quarantine, other."""
        names = ("journal", "objects", "keys", "tmp", "quarantine", "runs", "locks")
        if self._local:  # a file with several names (a journal and its links) counts once, as journal
            seen: set[tuple[int, int]] = set()
            parts = {}
            for name in names:
                total = 0
                for _, st in self.fs.stats(name):
                    if st.st_nlink > 1:
                        if (st.st_dev, st.st_ino) in seen:
                            continue
                        seen.add((st.st_dev, st.st_ino))
                    total += st.st_size
                parts[name] = total
        else:
            parts = {name: sum(self._sizes(name).values()) for name in names}
        other = 0
        if isinstance(self.fs, LocalFS):
            for fn in os.listdir(self.fs.root):
                p = self.fs.root / fn
                if p.is_file():
                    other += p.lstat().st_size
        parts["other"] = other
        parts["total"] = sum(parts.values())
        return parts

    def ls(self) -> list[dict]:
        sizes = {rel.rsplit("/", 1)[-1]: size for rel, size in self._sizes("objects").items()}
        rows = []
        for key, rec, mtime in self.records():
            if rec is None:
                rows.append({"key": key, "node": "?", "type": "?", "bytes": 0, "used": mtime, "corrupt": True,
                             "objects": []})
                continue
            objs = sorted({o["digest"] for o in rec.get("outputs", {}).values()})
            rows.append({"key": key, "node": rec.get("node", "?"), "type": rec.get("parts", {}).get("node_type", "?"),
                         "bytes": sum(sizes.get(d, 0) for d in objs), "used": mtime,
                         "seconds": rec.get("seconds", 0.0), "objects": objs})
        return sorted(rows, key=lambda r: -r["used"])

    def size(self) -> int:
        """Every byte the store holds (objects, records, tmp, quarantine, run notes, memo)."""
        return self.usage()["total"]

    def clean_stale(self, dry_run: bool = False) -> dict:
        """Remove temp files, legacy per-key lock files, quarantined entries and journals that no
        record links to.

        Only under the exclusive store lock: then no run is writing (every run holds it shared)."""
        n = nbytes = 0
        for part in ("tmp", "locks", "quarantine"):
            for rel, size, _ in list(self.fs.listdir(part)):
                if part == "locks" and self.fs.live_lease(rel):
                    continue  # (a lease held outside a run: a library call, a Dask worker)
                n += 1
                nbytes += size
                if not dry_run:
                    self.fs.remove(rel)
        if isinstance(self.fs, LocalFS):
            for rel, st in list(self.fs.stats("journal")):
                if st.st_nlink == 1:  # no record links to it any more (and no run writes it: see above)
                    n += 1
                    nbytes += st.st_size
                    if not dry_run:
                        self.fs.remove(rel)
            for fn in os.listdir(self.fs.root):
                if _LEGACY_OUT_TMP.match(fn):
                    p = self.fs.root / fn
                    n += 1
                    nbytes += p.lstat().st_size
                    if not dry_run:
                        p.unlink(missing_ok=True)
            if not dry_run:  # empty shard folders of the legacy lock layout
                for dirpath, dirs, files in os.walk(self.fs.root / "locks", topdown=False):
                    with contextlib.suppress(OSError):
                        os.rmdir(dirpath)
        return {"files": n, "bytes": nbytes}

    def gc(self, max_bytes: int) -> dict:
        """Drop what is stale, then least-recently-used records until the store fits in
        ``max_bytes`` (every byte counted: objects once, records, tmp, quarantine, run notes).

        Waits for running runs (they hold the store lock until their outputs are exported)."""
        if self.read_only:
            raise CacheError(f"cache {self.location}: cannot gc: the cache is read-only")
        with self._exclusive("gc"), self._errors("gc"):
            stale = self.clean_stale()
            run = _Gc(self)
            run.untrusted_records()
            run.orphans()
            run.least_recently_used(max_bytes)
            run.notes_and_memo(max_bytes)
            return {"removed_records": run.removed_keys, "removed_objects": run.removed_objs,
                    "stale_files": stale["files"], "stale_bytes": stale["bytes"], "bytes": self.size()}

    def verify(self, repair: bool = False) -> list[str]:
        """Re-hash every object and check every record; return the problems found.

        ``repair`` removes damaged objects and records, every record derived from a damaged
        one (recursively: records whose inputs include an output of a dropped record), and
        stale temp and lock files.  Without it nothing is changed (a read-only cache can be
        verified)."""
        problems: list[str] = []
        if repair and self.read_only:
            raise CacheError(f"cache {self.location}: cannot repair: the cache is read-only")
        lock = self._exclusive("verify") if repair else contextlib.nullcontext()
        with lock, self._errors("verify"):
            bad: set[str] = set()
            present: set[str] = set()
            for rel, _, _ in self.fs.listdir("objects"):
                name = rel.rsplit("/", 1)[-1]
                try:
                    check_object(self.fs.read(rel), name)
                    present.add(name)
                except DamagedEntry as e:
                    problems.append(f"object {name}: {e.why}")
                    bad.add(name)
                    if repair:
                        self.fs.remove(rel)
            records = {}
            for key, rec, _ in self.records():
                if rec is None:
                    problems.append(f"record {key}: {self._record_why(key)}")
                    if repair:
                        self.fs.remove(self._krel(key))
                    continue
                records[key] = rec
            for key, why in _damaged_records(records, bad, present):
                problems.append(f"record {key} ({records[key].get('node')}): {why}")
                if repair:
                    self.fs.remove(self._krel(key))
            if repair:
                self.clean_stale()
        return problems


def _output_digests(rec: dict) -> set[str]:
    return {o["digest"] for o in rec.get("outputs", {}).values()}


class _Gc:
    """One gc of a store, under its exclusive lock: what it holds and what is removed, in the
    order gc removes it; ``total`` counts the bytes still held."""

    def __init__(self, store: Store):
        self.store = store
        self.objs = {rel.rsplit("/", 1)[-1]: size for rel, size in store._sizes("objects").items()}
        self.recs = sorted(store.records(), key=lambda r: r[2])  # oldest first
        self.rec_sizes, self.links, self.journals = store._record_files()
        self.refs: dict[str, int] = {}
        for _, rec, _ in self.recs:
            for d in _output_digests(rec or {}):
                self.refs[d] = self.refs.get(d, 0) + 1
        self.total = store.size()
        self.removed_keys = self.removed_objs = 0

    def drop(self, key: str) -> None:
        """Remove a record; count the bytes that frees (a journal's when its last link goes)."""
        self.store.fs.remove(self.store._krel(key))
        self.removed_keys += 1
        ident = self.links.get(key)
        if ident is None:
            self.total -= self.rec_sizes.get(key, 0)
            return
        j = self.journals[ident]
        j[1] -= 1
        if j[1] > 0:
            return
        if j[2] is not None:
            self.store.fs.remove(j[2])
        self.total -= j[0]

    def drop_object(self, d: str) -> None:
        self.store.fs.remove(self.store._orel(d))
        self.total -= self.objs.pop(d)
        self.removed_objs += 1

    def untrusted_records(self) -> None:
        """Untrustworthy records go first: they are misses anyway."""
        for key, rec, _ in self.recs:
            if rec is None:
                self.drop(key)
        self.recs = [r for r in self.recs if r[1] is not None]

    def orphans(self) -> None:
        for d in [d for d in self.objs if d not in self.refs]:
            self.drop_object(d)

    def least_recently_used(self, max_bytes: int) -> None:
        """Records, oldest first, each with the objects only it referred to."""
        for key, rec, _ in self.recs:
            if self.total <= max_bytes:
                break
            self.drop(key)
            for d in _output_digests(rec):
                self.refs[d] -= 1
                if self.refs[d] == 0 and d in self.objs:
                    self.drop_object(d)

    def notes_and_memo(self, max_bytes: int) -> None:
        """Notes for explain (oldest first) and the file memo go last."""
        if self.total <= max_bytes:
            return
        for rel, size, _ in sorted(self.store.fs.listdir("runs"), key=lambda r: r[2]):
            if self.total <= max_bytes:
                break
            self.store.fs.remove(rel)
            self.total -= size
        memo = self.store.memo_file
        if self.total > max_bytes and memo is not None and memo.exists():
            self.total -= memo.stat().st_size
            memo.unlink(missing_ok=True)
