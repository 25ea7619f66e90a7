"""The small file-system interface the store is written against, and the capabilities each
implementation declares (the store asks for a capability, never for the kind of file system).

Two implementations: :class:`graphkit.store.localfs.LocalFS` (a folder on this machine) and
:class:`graphkit.store.objectfs.FsspecFS` (any fsspec URL: ``s3://``, ``memory://``, ``file://``).
Paths are relative to the cache root, with ``/`` between parts.
"""
from __future__ import annotations

import contextlib
from typing import Callable, Iterator, NamedTuple

#: the layout's version, named by an empty file at the cache root (``format-1``: no bytes to count
#: or collect; see Store._check_format)
FORMAT_VERSION = 1
FORMAT_PREFIX = "format-"
FORMAT_FILE = f"{FORMAT_PREFIX}{FORMAT_VERSION}"


class Entry(NamedTuple):
    """One file below the cache root: its path, size, last change, and (where files have inodes)
    its identity and number of names (a journal and the records linked to it share one)."""

    rel: str
    size: int
    mtime: float
    ident: tuple[int, int] | None = None
    nlink: int = 1


class FileSystem:
    """What the store needs from where it keeps its files.  Capabilities, as class attributes:"""

    #: one write is atomic for readers and costs what a look for it costs: objects are written
    #: without looking first, and no temp file is moved into place (object stores' PUT)
    atomic_put = False
    #: hard links: a run appends its records to one journal and links each key to it
    hard_links = False
    #: locks are released by the OS when their holder dies (flock); else leases with a TTL
    flock = False
    #: a folder on this machine: inode stats, a file memo, files at the root counted by usage
    local = False
    #: the file that keeps file digests across runs (a local folder only)
    memo_file = None

    def describe(self) -> str:
        raise NotImplementedError

    # -- set-up --------------------------------------------------------------------------
    def ensure(self) -> None:
        """Make the folders a store writes into (never a bucket)."""

    def init(self) -> str:
        """Create the cache on request (``graphkit cache init``): what was done, in one line."""
        raise NotImplementedError

    def info(self) -> dict[str, str]:
        raise NotImplementedError

    def writable(self) -> bool:
        """Whether entries can be written (a read-only cache still serves hits)."""
        return True

    # -- entries -------------------------------------------------------------------------
    def read(self, rel: str) -> bytes | None:
        """The bytes at ``rel``; None if there is none."""
        raise NotImplementedError

    def read_many(self, rels: list[str]) -> dict[str, bytes | None]:
        """The bytes at each of ``rels`` (None where there is none): one batch where the file
        system can send the requests together."""
        return {rel: self.read(rel) for rel in rels}

    def write_many(self, entries: dict[str, list]) -> None:
        """:meth:`write_atomic` of each entry (rel -> chunks): one batch where the file system can
        send the writes together."""
        for rel, chunks in entries.items():
            self.write_atomic(rel, chunks)

    def read_record(self, rel: str, key: str, stale_after: float | None = None, in_run: bool = False,
                    journal_here: bool = False) -> tuple[bytes | None, str | None, bool]:
        """(the record of ``key`` at ``rel`` or None; why it is unreadable; whether it should
        move to this run's journal, as last used more than ``stale_after`` seconds ago; ``in_run``:
        the run lock is held; ``journal_here``: this run writes a journal)."""
        from .records import record_bytes

        raw, why = record_bytes(self.read(rel), key)
        return raw, why, False

    def exists(self, rel: str) -> bool:
        raise NotImplementedError

    def inside(self, rel: str) -> bool:
        """Whether the folder holding ``rel`` is the cache's own (no link leads out)."""
        return True

    def write_atomic(self, rel: str, chunks, sync: bool = False) -> None:
        """Write ``chunks`` to ``rel`` so that a reader sees all of it or nothing."""
        raise NotImplementedError

    def remove(self, rel: str) -> None:
        raise NotImplementedError

    def move_aside(self, rel: str, to_rel: str) -> bool:
        """Move ``rel`` to ``to_rel`` (quarantine); False if it is gone or cannot be moved."""
        raise NotImplementedError

    def entries(self, part: str) -> Iterator[Entry]:
        """Every file below the folder ``part`` of the root."""
        raise NotImplementedError

    def listdir(self, rel: str) -> Iterator[tuple[str, int, float]]:
        """(path, size, mtime) of every file below ``rel``."""
        for e in self.entries(rel):
            yield e.rel, e.size, e.mtime

    def root_files(self) -> list[Entry]:
        """Files at the root itself (lock files, the file memo): counted by usage."""
        return []

    def root_names(self) -> list[str]:
        """The names at the cache root."""
        raise NotImplementedError

    def prune(self, part: str) -> None:
        """Remove the empty folders below ``part`` (after gc emptied them)."""

    # -- journals (``hard_links`` only) --------------------------------------------------
    def append_record(self, key: str, raw: bytes) -> bool:
        """Append a record to this run's journal and link the key to it; False: not here."""
        return False

    def end_run(self) -> None:
        """A run ended: close its journal and forget what was read of others."""

    # -- durability and locks ------------------------------------------------------------
    def commit(self) -> None:
        """Make every write so far durable (a no-op where each write already is)."""

    def live_lease(self, rel: str) -> bool:
        """Whether ``rel`` is a lease whose owner still renews it (gc leaves it)."""
        return False

    def lock(self, rel: str, shared: bool = False, on_wait: Callable | None = None
             ) -> contextlib.AbstractContextManager:
        raise NotImplementedError

    def key_lock(self, key: str, on_wait: Callable | None = None) -> contextlib.AbstractContextManager:
        raise NotImplementedError
