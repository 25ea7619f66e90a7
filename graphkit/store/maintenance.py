"""Maintenance: ``cache ls``, ``usage``, ``gc`` and ``verify``, each built on one
:class:`Catalog`: the store's files listed once and its records read once, so every step is
linear in the number of entries.

gc and ``verify --repair`` hold the store lock exclusively (they wait for running runs), so no
run is writing what they remove.  A file with several names (a journal and the records linked
to it) is counted once, as journal; gc frees a journal with its last link.
"""
from __future__ import annotations

import collections
import contextlib
import re
from typing import TYPE_CHECKING, NamedTuple

from ..errors import CacheError
from .codec import DamagedEntry, check_object, object_rel
from .fs import Entry
from .records import decode_record, key_of, output_digests, record_inputs, record_rel

if TYPE_CHECKING:
    from .core import Store

#: the folders below the root, in the order usage counts them (a journal before its links)
PARTS = ("journal", "objects", "keys", "tmp", "quarantine", "runs", "locks")
#: what a killed run's file-memo save leaves at the root (graphkit.hashing._save_memo)
_MEMO_TMP = re.compile(r"filememo\.json\..+\.tmp$")


class RecordEntry(NamedTuple):
    key: str
    record: dict | None  # None: absent or untrustworthy (``why`` says which)
    why: str | None
    mtime: float  # its last use
    entry: Entry


class Catalog:
    """What a store holds, listed once: the entries of each part, the files at the root, the
    objects' sizes and (``records=True``) every record read and checked."""

    def __init__(self, store: "Store", records: bool = True):
        self.store = store
        fs = store.fs
        self.parts = {name: list(fs.entries(name)) for name in PARTS}
        self.root_files = fs.root_files()
        self.objects = {e.rel.rsplit("/", 1)[-1]: e.size for e in self.parts["objects"]}
        self.records = [self._read(e) for e in self.parts["keys"]] if records else []

    def _read(self, e: Entry) -> RecordEntry:
        store, key = self.store, key_of(e.rel)
        raw, why, _ = store.fs.read_record(e.rel, key, in_run=store._run_lock_depth > 0)
        rec, bad = decode_record(raw, key, store.secret) if raw is not None else (None, None)
        return RecordEntry(key, rec, why or bad or (None if rec else decode_record(b"", key)[1]), e.mtime, e)

    def usage(self) -> dict:
        """True bytes by part: objects (each once), records, tmp, quarantine, run notes, other."""
        seen: set[tuple[int, int]] = set()
        parts = {}
        for name in PARTS:
            total = 0
            for e in self.parts[name]:
                if e.nlink > 1:
                    if e.ident in seen:
                        continue
                    seen.add(e.ident)
                total += e.size
            parts[name] = total
        parts["other"] = sum(e.size for e in self.root_files)
        parts["total"] = sum(parts.values())
        return parts

    def record_files(self) -> tuple[dict[str, int], dict[str, tuple[int, int]], dict[tuple[int, int], list]]:
        """(key -> size of its record file; key -> the journal it links to; journal ->
        [size, how many records link to it, its name in journal/ or None])."""
        names = {e.ident: e.rel for e in self.parts["journal"] if e.ident is not None}
        sizes, links, journals = {}, {}, {}
        for e in self.parts["keys"]:
            key = key_of(e.rel)
            if e.ident is not None and (e.nlink > 1 or e.ident in names):
                links[key] = e.ident
                journals.setdefault(e.ident, [e.size, 0, names.get(e.ident)])[1] += 1
            else:
                sizes[key] = e.size
        return sizes, links, journals


def ls(store: "Store") -> list[dict]:
    cat = Catalog(store)
    rows = []
    for r in cat.records:
        if r.record is None:
            rows.append({"key": r.key, "node": "?", "type": "?", "bytes": 0, "used": r.mtime, "corrupt": True,
                         "objects": []})
            continue
        rec = r.record
        objs = sorted(output_digests(rec))
        rows.append({"key": r.key, "node": rec.get("node", "?"), "type": rec.get("parts", {}).get("node_type", "?"),
                     "bytes": sum(cat.objects.get(d, 0) for d in objs), "used": r.mtime,
                     "seconds": rec.get("seconds", 0.0), "objects": objs})
    return sorted(rows, key=lambda r: -r["used"])


def _stale(store: "Store", cat: Catalog) -> list[Entry]:
    """Temp files, lock files no live lease holds or finished, quarantined entries, journals no record links
    to, and what a killed file-memo save left at the root."""
    fs = store.fs
    out = [e for part in ("tmp", "quarantine") for e in cat.parts[part]]
    # a lease no live owner holds (one outside a run), or, on an object store, a finished one:
    # its key's record exists (graphkit.leases: its owner left it; keys/ab/K.json, locks/ab/K.lock)
    done = {e.rel[5:-5] for e in cat.parts["keys"]} if fs.atomic_put else set()
    out += [e for e in cat.parts["locks"] if e.rel[6:-5] in done or not fs.live_lease(e.rel)]
    if fs.hard_links:  # no record links to it any more (and no run writes it: see above)
        out += [e for e in cat.parts["journal"] if e.nlink == 1]
    out += [e for e in cat.root_files if _MEMO_TMP.match(e.rel)]
    return out


def clean_stale(store: "Store", cat: Catalog, dry_run: bool = False) -> dict:
    """Remove what :func:`_stale` finds.  Only under the exclusive store lock: then no run is
    writing (every run holds it shared)."""
    stale = _stale(store, cat)
    if not dry_run:
        for e in stale:
            store.fs.remove(e.rel)
        store.fs.prune("locks")
        gone = {e.rel for e in stale}
        for name in ("tmp", "quarantine", "locks", "journal"):
            cat.parts[name] = [e for e in cat.parts[name] if e.rel not in gone]
        cat.root_files = [e for e in cat.root_files if e.rel not in gone]
    return {"files": len(stale), "bytes": sum(e.size for e in stale)}


def gc(store: "Store", max_bytes: int) -> dict:
    """Drop what is stale, then least-recently-used records until the store fits in
    ``max_bytes`` (every byte counted: objects once, records, tmp, quarantine, run notes).

    Waits for running runs (they hold the store lock until their outputs are exported)."""
    if store.read_only:
        raise CacheError(f"cache {store.location}: cannot gc: the cache is read-only")
    with store.exclusive("gc"), store._errors("gc"):
        cat = Catalog(store)
        stale = clean_stale(store, cat)
        run = _Gc(store, cat)
        run.untrusted_records()
        run.orphans()
        run.least_recently_used(max_bytes)
        run.notes_and_memo(max_bytes)
        return {"removed_records": run.removed_keys, "removed_objects": run.removed_objs,
                "stale_files": stale["files"], "stale_bytes": stale["bytes"], "bytes": store.size()}


class _Gc:
    """One gc of a store, under its exclusive lock: what it holds and what is removed, in the
    order gc removes it; ``total`` counts the bytes still held."""

    def __init__(self, store: "Store", cat: Catalog):
        self.store, self.cat = store, cat
        self.objs = dict(cat.objects)
        self.recs = sorted(cat.records, key=lambda r: r.mtime)  # oldest first
        self.rec_sizes, self.links, self.journals = cat.record_files()
        self.refs: dict[str, int] = {}
        for r in self.recs:
            for d in output_digests(r.record or {}):
                self.refs[d] = self.refs.get(d, 0) + 1
        self.total = cat.usage()["total"]
        self.removed_keys = self.removed_objs = 0

    def drop(self, key: str) -> None:
        """Remove a record; count the bytes that frees (a journal's when its last link goes)."""
        self.store.fs.remove(record_rel(key))
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
        self.store.fs.remove(object_rel(d))
        self.total -= self.objs.pop(d)
        self.removed_objs += 1

    def untrusted_records(self) -> None:
        """Untrustworthy records go first: they are misses anyway."""
        for r in self.recs:
            if r.record is None:
                self.drop(r.key)
        self.recs = [r for r in self.recs if r.record is not None]

    def orphans(self) -> None:
        for d in [d for d in self.objs if d not in self.refs]:
            self.drop_object(d)

    def least_recently_used(self, max_bytes: int) -> None:
        """Records, oldest first, each with the objects only it referred to."""
        for r in self.recs:
            if self.total <= max_bytes:
                break
            self.drop(r.key)
            for d in output_digests(r.record):
                self.refs[d] -= 1
                if self.refs[d] == 0 and d in self.objs:
                    self.drop_object(d)

    def notes_and_memo(self, max_bytes: int) -> None:
        """Notes for explain (oldest first) and the file memo go last."""
        if self.total <= max_bytes:
            return
        for e in sorted(self.cat.parts["runs"], key=lambda e: e.mtime):
            if self.total <= max_bytes:
                break
            self.store.fs.remove(e.rel)
            self.total -= e.size
        memo = self.store.memo_file
        if self.total > max_bytes and memo is not None and memo.exists():
            self.total -= memo.stat().st_size
            memo.unlink(missing_ok=True)


def verify(store: "Store", repair: bool = False) -> list[str]:
    """Re-hash every object and check every record; return the problems found.

    ``repair`` removes damaged objects and records, every record derived from a damaged one
    (recursively: records whose inputs include an output of a dropped record), and stale temp
    and lock files.  Without it nothing is changed (a read-only cache can be verified)."""
    if repair and store.read_only:
        raise CacheError(f"cache {store.location}: cannot repair: the cache is read-only")
    lock = store.exclusive("verify") if repair else contextlib.nullcontext()
    with lock, store._errors("verify"):
        cat = Catalog(store)
        problems, bad, present = _check_objects(store, cat, repair)
        records = {}
        for r in cat.records:
            if r.record is None:
                problems.append(f"record {r.key}: {r.why}")
                if repair:
                    store.fs.remove(record_rel(r.key))
            else:
                records[r.key] = r.record
        for key, why in damaged_records(records, bad, present):
            problems.append(f"record {key} ({records[key].get('node')}): {why}")
            if repair:
                store.fs.remove(record_rel(key))
        if repair:  # (listed again: journals whose last link went above are stale now)
            clean_stale(store, Catalog(store, records=False))
    return problems


def _check_objects(store: "Store", cat: Catalog, repair: bool) -> tuple[list[str], set[str], set[str]]:
    """(problems, damaged digests, sound digests): every object re-hashed."""
    problems: list[str] = []
    bad: set[str] = set()
    present: set[str] = set()
    for e in cat.parts["objects"]:
        name = e.rel.rsplit("/", 1)[-1]
        try:
            check_object(store.fs.read(e.rel), name)
            present.add(name)
        except DamagedEntry as err:
            problems.append(f"object {name}: {err.why}")
            bad.add(name)
            if repair:
                store.fs.remove(e.rel)
    return problems, bad, present


def damaged_records(records: dict[str, dict], bad: set[str], present: set[str]) -> list[tuple[str, str]]:
    """(key, why) of every record to drop: its output is missing or corrupt, or (following the
    chain) it was computed from a damaged value: a bad object, or one that only dropped records
    made.  Linear: each record and each digest is visited once."""
    consumers: dict[str, list[str]] = {}
    makers: dict[str, int] = {}  # digest -> how many records not (yet) dropped output it
    for key, rec in records.items():
        for d in set(record_inputs(rec)):
            consumers.setdefault(d, []).append(key)
        for d in output_digests(rec):
            makers[d] = makers.get(d, 0) + 1
    tainted, queue, dropped = set(bad), collections.deque(bad), {}

    def drop(key: str, why: str) -> None:
        dropped[key] = why
        for d in output_digests(records[key]):
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
