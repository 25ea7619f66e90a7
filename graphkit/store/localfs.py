"""A cache folder on this machine: writes renamed into place, group commits with syncfs, flock
and byte-range (OFD) locks, and journals with a hard link per record.

Capabilities (see graphkit.store.fs): ``hard_links`` (a run appends its records to one journal
and links ``keys/…/KEY.json`` to it: a directory entry per record, not an inode), ``flock``
(locks die with their holder), ``local`` (inode stats, a file memo, a writability probe).
Entries are never read through a symbolic link, and take the cache folder's mode (a
group-writable folder gives group-writable entries whatever the umask).
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import itertools
import os
import stat
import struct
import threading
import time
import uuid
from pathlib import Path
from typing import Callable, Iterator

from .codec import MiB
from .fs import Entry, FileSystem
from .records import JOURNAL_HEAD, JOURNAL_MAGIC, NOT_IN_JOURNAL, JournalView, encode_frame, is_journal, \
    journal_record, key_of, record_rel

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

#: a run starts a new journal after this many records or bytes (ext4 allows 65,000 links a file)
JOURNAL_MAX_FRAMES = 50_000
JOURNAL_MAX_BYTES = 64 * MiB
#: a process forgets the journals it has indexed when they hold more than this in memory
JOURNAL_CACHE_BYTES = 64 * MiB
_LINK_UNSUPPORTED = {getattr(errno, n) for n in ("EPERM", "ENOTSUP", "EOPNOTSUPP", "EXDEV", "ENOSYS", "EINVAL")
                     if hasattr(errno, n)}


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


class LocalFS(FileSystem):
    """A folder on this machine: write + rename, syncfs group commits, flock / OFD locks,
    journals with a hard link per record."""

    hard_links = flock = local = True

    def __init__(self, root: str):
        self.root = Path(root).absolute()
        self._prefix = str(self.root) + os.sep
        self.dir_mode = 0o777
        self.file_mode = 0o666
        self._fix_file_mode = self._fix_dir_mode = False
        self._local = threading.local()
        self._key_lock_fd_ok = hasattr(fcntl, "F_OFD_SETLKW")
        self.journals = Journals(self)

    def describe(self) -> str:
        return str(self.root)

    def path(self, rel: str) -> str:  # a plain string (pathlib is slow on the hot paths)
        return self._prefix + rel

    @property
    def memo_file(self) -> Path:
        return self.root / "filememo.json"

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
            self.mkdir(self.path(d))

    # -- reads and writes -----------------------------------------------------------------
    def read(self, rel: str) -> bytes | None:
        """The bytes of the file at ``rel``; None if there is none; b"" (which no entry is) for
        what is not a plain file: a symbolic link is never followed."""
        try:
            fd = os.open(self.path(rel), _READ_FLAGS)
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
        return os.path.lexists(self.path(rel))

    def inside(self, rel: str) -> bool:
        """Whether the folder holding ``rel`` is the cache's own (no symbolic link leads out)."""
        real = os.path.realpath(os.path.dirname(self.path(rel)))
        return (real + os.sep).startswith(os.path.realpath(self.root) + os.sep)

    def init(self) -> str:
        self.ensure()
        return f"cache {self.describe()} is ready"

    def info(self) -> dict[str, str]:
        return {"cache": str(self.root), "file system": "a folder on this machine (flock, hard links, syncfs)"}

    def writable(self) -> bool:
        """A probe file written and removed: False on a read-only folder or mount."""
        probe = f"tmp/probe-{uuid.uuid4().hex}"
        try:
            self.write_atomic(probe, [b"ok"])
            self.remove(probe)
        except FileNotFoundError:
            pass  # a concurrent `cache gc` removed the probe from tmp/: the folder is writable
        except OSError as e:
            if e.errno not in _READ_ONLY_ERRNOS:
                raise
            return False
        return True

    def read_record(self, rel: str, key: str, stale_after: float | None = None, in_run: bool = False,
                    journal_here: bool = False) -> tuple[bytes | None, str | None, bool]:
        """See FileSystem.read_record: read through an fd (never a link, never blocking), a
        journal from what this process has read of it; a record used again is marked used (its
        file's or journal's mtime), or moved to this run's journal when ``journal_here``."""
        try:
            fd = os.open(self.path(rel), _READ_FLAGS)
        except (FileNotFoundError, NotADirectoryError):
            return None, None, False
        except OSError as e:
            if e.errno != errno.ELOOP:
                raise
            return None, NOT_A_FILE, False
        try:
            return self._fd_record(fd, key, stale_after, in_run, journal_here)
        finally:
            os.close(fd)

    def _fd_record(self, fd: int, key: str, stale_after: float | None, in_run: bool,
                   journal_here: bool) -> tuple[bytes | None, str | None, bool]:
        """``read_record`` of the file open as ``fd``."""
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            return None, NOT_A_FILE, False
        if st.st_nlink == 1 and st.st_size <= MiB:  # a record file (or a journal linked once)
            raw = _read_fd(fd, st.st_size)
            linked = is_journal(raw[:JOURNAL_HEAD])
            if linked:
                raw = journal_record(raw, key)
        else:
            linked, raw = self.journals.lookup(fd, st, key, in_run)
            if not linked:
                raw = _read_fd(fd, st.st_size)
        if raw is None:
            return None, NOT_IN_JOURNAL, False
        if stale_after is not None and time.time() - st.st_mtime > stale_after:
            if linked and journal_here and self.journals.ok:
                return raw, None, True
            with contextlib.suppress(OSError):  # read-only caches stay readable
                os.utime(fd)
        return raw, None, False

    def append_record(self, key: str, raw: bytes) -> bool:
        return self.journals.ok and self.journals.put(key, raw)

    def end_run(self) -> None:
        self.journals.end_run()

    def _create(self, path: str) -> int:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _CLOEXEC, self.file_mode)
        if self._fix_file_mode:
            with contextlib.suppress(OSError):
                os.fchmod(fd, self.file_mode)
        return fd

    def write_atomic(self, rel: str, chunks, sync: bool = False) -> None:
        """Write ``chunks`` to a temp file and rename it to ``rel``; ``sync``: fsync it first
        (only for single files outside a group commit)."""
        dest = self.path(rel)
        tmp = self.path(f"tmp/{_TOKEN}-{_PID[0]}-{threading.get_ident()}-{next(_counter)}")
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
            os.unlink(self.path(rel))

    def move_aside(self, rel: str, to_rel: str) -> bool:
        """Rename ``rel`` to ``to_rel`` (quarantine); False if it is gone or cannot be moved.  A
        record linked to a journal that other records share: its record is copied, its link
        removed."""
        if rel.startswith("keys/") and self._linked_elsewhere(rel):
            return self._copy_record_aside(rel, to_rel)
        try:
            os.replace(self.path(rel), self.path(to_rel))
            return True
        except FileNotFoundError:
            try:
                self.mkdir(os.path.dirname(self.path(to_rel)))
                os.replace(self.path(rel), self.path(to_rel))
                return True
            except OSError:
                return False
        except OSError:
            return False

    def _linked_elsewhere(self, rel: str) -> bool:
        try:
            return os.lstat(self.path(rel)).st_nlink > 1
        except OSError:
            return False

    def _copy_record_aside(self, rel: str, to_rel: str) -> bool:
        raw = self.read_record(rel, key_of(rel))[0]
        try:
            self.mkdir(os.path.dirname(self.path(to_rel)))
            self.write_atomic(to_rel, [raw or b""])
            os.unlink(self.path(rel))
        except OSError:
            return False
        return True

    def stats(self, rel: str) -> Iterator[tuple[str, os.stat_result]]:
        """(path below the root, lstat) of every file below ``rel`` (nothing when ``rel`` is a
        symbolic link: what it points to is not the cache's)."""
        if os.path.islink(self.path(rel)):
            return
        for dirpath, _, files in os.walk(self.path(rel)):
            for fn in files:
                p = os.path.join(dirpath, fn)
                try:
                    st = os.lstat(p)
                except FileNotFoundError:
                    continue
                yield p[len(self._prefix):], st

    def entries(self, part: str) -> Iterator[Entry]:
        for p, st in self.stats(part):
            yield Entry(p, st.st_size, st.st_mtime, (st.st_dev, st.st_ino), st.st_nlink)

    def root_files(self) -> list[Entry]:
        out = []
        for fn in os.listdir(self.root):
            with contextlib.suppress(OSError):
                st = os.lstat(self.path(fn))
                if stat.S_ISREG(st.st_mode):
                    out.append(Entry(fn, st.st_size, st.st_mtime))
        return out

    def root_names(self) -> list[str]:
        return os.listdir(self.root)

    def prune(self, part: str) -> None:
        for dirpath, _, _ in os.walk(self.path(part), topdown=False):
            with contextlib.suppress(OSError):
                os.rmdir(dirpath)

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
        p = self.path(rel)
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
            fd = self._open_lock(self.path("keys.lock"))
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



class _Journal:
    """The journal this process appends to during a run."""

    __slots__ = ("fd", "path", "pid", "frames", "size")

    def __init__(self, fd: int, path: str, size: int):
        self.fd, self.path, self.pid, self.frames, self.size = fd, path, _PID[0], 0, size


class Journals:
    """This process's journals on one folder: ``current``, the one its run appends to, and
    ``views``, what it has read of journals ((st_dev, st_ino) -> JournalView)."""

    def __init__(self, fs: LocalFS):
        self.fs = fs
        self.ok = True  # False once the file system refuses a hard link: record files then
        self.current: _Journal | None = None
        self.views: dict[tuple[int, int], JournalView] = {}
        self.view_bytes = 0
        self.lock = threading.Lock()

    def lookup(self, fd: int, st: os.stat_result, key: str, in_run: bool) -> tuple[bool, bytearray | None]:
        """(whether the file open as ``fd`` is a journal, the record of ``key`` in it): from what
        this process has read of it, after reading what has been appended since."""
        ident = (st.st_dev, st.st_ino)
        view = self.views.get(ident)
        if view is not None and in_run:
            head = view.head  # read in this run, in which no journal is removed: still that file
        else:
            head = os.pread(fd, JOURNAL_HEAD, 0)
            if not is_journal(head):
                return False, None
        if view is not None and st.st_size == len(view.buf) and view.head == head:
            return True, view.record(key)  # (the usual hit: read already; no lock, as views only grow)
        with self.lock:
            view = self.views.get(ident)
            if view is None or view.head != head or st.st_size < len(view.buf):
                if self.view_bytes > JOURNAL_CACHE_BYTES:
                    self.forget()
                view = self.views[ident] = JournalView(head)
            if st.st_size > len(view.buf):
                n0 = len(view.buf)
                view.extend(os.pread(fd, st.st_size - n0, n0))  # (a short read: the rest next time)
                self.view_bytes += len(view.buf) - n0
            return True, view.record(key)

    def forget(self) -> None:
        self.views.clear()
        self.view_bytes = 0

    def put(self, key: str, raw: bytes) -> bool:
        """Append the record to this run's journal and link keys/…/KEY.json to it; False if this
        file system will not link the journal (the caller writes a record file instead)."""
        frame = encode_frame(key, raw)
        dest = self.fs.path(record_rel(key))
        with self.lock:
            for _ in range(2):  # this run's journal, then (full, or removed meanwhile) a new one
                j = self.current
                if j is None or j.pid != _PID[0]:  # (a forked child starts its own)
                    j = self.current = self._open()
                _write_all(j.fd, [frame])
                j.frames += 1
                j.size += len(frame)
                try:
                    self._link(j.path, dest)
                except OSError as e:
                    if e.errno in _LINK_UNSUPPORTED:
                        self.ok = False
                        self._end()
                        return False
                    if e.errno not in (errno.EMLINK, errno.ENOENT):
                        raise
                    self._end()
                    continue
                if j.frames >= JOURNAL_MAX_FRAMES or j.size >= JOURNAL_MAX_BYTES:
                    self._end()
                return True
        return False

    def _open(self) -> _Journal:
        folder = self.fs.path("journal")
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
        tmp = self.fs.path(f"tmp/{_TOKEN}-{_PID[0]}-{threading.get_ident()}-{next(_counter)}")
        os.link(src, tmp)
        try:
            os.replace(tmp, dest)
        finally:  # (rename does nothing when both names are links to one file: dest already is)
            with contextlib.suppress(OSError):
                os.unlink(tmp)

    def _end(self) -> None:
        j, self.current = self.current, None
        if j is not None and j.pid == _PID[0]:
            with contextlib.suppress(OSError):
                os.close(j.fd)

    def end_run(self) -> None:
        """This run's journal is complete; what others wrote may change: forget it."""
        with self.lock:
            self._end()
            self.forget()
