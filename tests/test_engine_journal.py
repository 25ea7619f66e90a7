"""Records of a run live in one journal, linked from keys/ (issue 10, cold runs without a file per
node): what a reader sees, what damage does, how gc counts and frees them, and the fall-backs.

The layout is checked from outside with os.stat (inodes, link counts) and an independent parse
of the frames (``\\0GKJF <key> <length>\\n<record>``), not with the store's own reader."""
from __future__ import annotations

import errno
import os

import numpy as np
import pytest

import graphkit.store.localfs as st
from graphkit.executor import run_local
from graphkit.graphfile import load_graph
from graphkit.runner import Session
from graphkit.store import Store, encode_record

CHAIN = """\
graphkit: 1
name: chain
nodes:
  a: {type: Const, params: {value: 2.0, size: 8}}
  b: {type: Add, inputs: {a: a.out}, params: {offset: 1.0}}
  c: {type: Add, inputs: {a: b.out}, params: {offset: 10.0}}
  d: {type: Add, inputs: {a: c.out}, params: {offset: 100.0}}
outputs: {d: d.out}
"""
EXPECTED = np.full(8, 113.0)


class Run:
    """Runs of one graph against one cache folder, each with a fresh Store (as a new process)."""

    def __init__(self, write, registry, cache, text=CHAIN):
        self.graph = load_graph(write("g.yaml", text), registry)
        self.registry, self.cache = registry, cache
        self.notes: list[str] = []

    def __call__(self, store: Store | None = None):
        store = store or Store(self.cache).open()
        session = Session(self.graph, self.registry, store, notice=self.notes.append)
        result = run_local(session, ["d"])
        with store.run_lock():
            value = session.output_value("d", "out")
        return result, session, value


def keyfiles(cache):
    return {p.name.removesuffix(".json"): p for p in (cache / "keys").rglob("*.json")}


def journals(cache):
    return sorted((cache / "journal").glob("*.gkj")) if (cache / "journal").is_dir() else []


def frames(path) -> dict[str, bytes]:
    """key -> record of every whole frame of a journal (a later frame of a key wins)."""
    raw = path.read_bytes()
    assert raw.startswith(b"GKJRN1 ") and raw[39:40] == b"\n", raw[:40]
    out, pos = {}, 40
    while pos < len(raw) and raw.startswith(b"\0GKJF ", pos):
        nl = raw.index(b"\n", pos)
        key, n = raw[pos + 6:nl].split(b" ")
        end = nl + 1 + int(n)
        if end > len(raw):
            break
        out[key.decode()] = raw[nl + 1:end]
        pos = end
    return out


def links_fail(monkeypatch, err, times=None):
    """os.link raising ``err`` (every time, or the first ``times`` calls); the calls it saw."""
    calls = []
    real = os.link

    def link(src, dst, *a, **k):
        calls.append(dst)
        if times is None or len(calls) <= times:
            raise OSError(err, os.strerror(err))
        return real(src, dst, *a, **k)
    monkeypatch.setattr(st.os, "link", link)
    return calls


def cut_last_record(run):
    """Run, then cut node d's frame (the last) off the journal: (the run's outcomes, d's key)."""
    first, _, _ = run()
    (j,) = journals(run.cache)
    kd = first.outcomes["d"].key
    raw = j.read_bytes()
    j.write_bytes(raw[:raw.index(b"\0GKJF " + kd.encode())])
    return first, kd


def inode(p):
    s = os.stat(p)
    return s.st_dev, s.st_ino


def true_size(cache) -> int:
    """Bytes below the folder, each file (inode) once: what `du` would say, without blocks."""
    seen, total = set(), 0
    for dirpath, _, files in os.walk(cache):
        for fn in files:
            s = os.lstat(os.path.join(dirpath, fn))
            if (s.st_dev, s.st_ino) not in seen:
                seen.add((s.st_dev, s.st_ino))
                total += s.st_size
    return total


@pytest.fixture
def run(write, engine_registry, tmp_path):
    return Run(write, engine_registry, tmp_path / "c")


def test_a_run_links_every_record_to_its_one_journal(run):
    result, session, value = run()
    np.testing.assert_array_equal(value, EXPECTED)
    (j,) = journals(run.cache)
    files = keyfiles(run.cache)
    assert len(files) == 4
    assert {inode(p) for p in files.values()} == {inode(j)}  # hard links, no file per record
    assert os.stat(j).st_nlink == 5
    written = frames(j)
    assert set(written) == set(files)
    for key, rec in written.items():  # each frame is the record, with its check line
        assert rec.startswith(b"GKREC1 ") and f'"key":"{key}"'.encode() in rec
    result2, _, value2 = run()  # a new process reads them back: all hits, nothing written
    assert all(o.hit for o in result2.outcomes.values()) and journals(run.cache) == [j]
    np.testing.assert_array_equal(value2, EXPECTED)
    assert run.notes == []


def test_records_written_outside_a_run_are_files_of_their_own(tmp_path):
    s = Store(tmp_path / "c").open()
    rec = {"key": "ab" * 16, "node": "n", "parts": {}, "outputs": {}}
    s.put_record("ab" * 16, rec)
    p = tmp_path / "c" / s.record_rel("ab" * 16)
    assert os.stat(p).st_nlink == 1 and p.read_bytes() == encode_record(rec)
    assert not (tmp_path / "c" / "journal").exists()
    with s.run_lock():  # inside one: the journal
        s.put_record("cd" * 16, {**rec, "key": "cd" * 16})
    q = tmp_path / "c" / s.record_rel("cd" * 16)
    assert os.stat(q).st_nlink == 2 and frames(journals(tmp_path / "c")[0]) == {"cd" * 16: encode_record(
        {**rec, "key": "cd" * 16})}
    assert s.get_record("cd" * 16)["key"] == "cd" * 16 and s.get_record("ab" * 16)["key"] == "ab" * 16


def test_a_record_written_again_replaces_its_link(tmp_path):
    s = Store(tmp_path / "c").open()
    old = {"key": "ab" * 16, "node": "old", "parts": {}, "outputs": {}}
    s.put_record("ab" * 16, old)  # a record file
    with s.run_lock():
        s.put_record("ab" * 16, {**old, "node": "new"})
        s.put_record("ab" * 16, {**old, "node": "newer"})  # the same journal, a later frame
    assert Store(tmp_path / "c").open().get_record("ab" * 16)["node"] == "newer"
    assert os.listdir(tmp_path / "c" / "tmp") == []


def test_a_reader_sees_what_another_run_appends_to_its_journal(tmp_path):
    """Two Store objects (as two processes): the reader indexes the writer's journal on first use
    and reads on when the journal has grown."""
    w, r = Store(tmp_path / "c").open(), Store(tmp_path / "c").open()
    rec = {"key": "", "node": "n", "parts": {}, "outputs": {}}
    with w.run_lock():
        w.put_record("a1" * 16, {**rec, "key": "a1" * 16})
        assert r.get_record("a1" * 16)["key"] == "a1" * 16
        assert r.get_record("b2" * 16) is None
        w.put_record("b2" * 16, {**rec, "key": "b2" * 16})
        w.put_record("a1" * 16, {**rec, "key": "a1" * 16, "node": "again"})
        assert r.get_record("b2" * 16)["key"] == "b2" * 16
        assert r.get_record("a1" * 16)["node"] == "again"  # the later frame
    assert r.verify() == [] and len(journals(tmp_path / "c")) == 1


def test_a_torn_last_frame_is_never_seen(run):
    """A run killed while appending leaves part of a frame at the journal's end, never linked:
    the records before it read as before; nothing is reported damaged."""
    run()
    (j,) = journals(run.cache)
    with open(j, "ab") as f:
        f.write(b"\0GKJF " + b"f" * 32 + b" 500\nGKREC1 0123")  # 500 bytes announced, 11 written
    store = Store(run.cache).open()
    assert store.verify() == []
    result, _, value = run()
    assert all(o.hit for o in result.outcomes.values()) and run.notes == []
    np.testing.assert_array_equal(value, EXPECTED)


def test_a_bit_flipped_in_one_frame_quarantines_that_record_only(run):
    first, _, _ = run()
    (j,) = journals(run.cache)
    kc = first.outcomes["c"].key
    raw = bytearray(j.read_bytes())
    at = raw.index(b'"node":"c"')
    raw[at + 8] ^= 0x01  # "c" -> "b" inside c's frame, same length
    j.write_bytes(bytes(raw))
    result, _, value = run()
    np.testing.assert_array_equal(value, EXPECTED)
    assert {n for n, o in result.outcomes.items() if not o.hit} == {"c"}  # d's inputs did not change
    assert len(run.notes) == 1 and kc[:16] in run.notes[0] and "quarantine" in run.notes[0], run.notes
    (q,) = (run.cache / "quarantine").iterdir()
    assert q.name.startswith(f"keys_{kc[:2]}_{kc}.json.") and q.read_bytes() == bytes(frames(j)[kc])
    new = [x for x in journals(run.cache) if x != j]
    assert len(new) == 1 and inode(keyfiles(run.cache)[kc]) == inode(new[0])


def test_a_journal_overwritten_through_one_link_damages_no_result(run):
    """Writing a record's file in place writes the journal all records link to: every record is
    then untrustworthy, and every node is recomputed (never served)."""
    first, _, _ = run()
    keyfiles(run.cache)[first.outcomes["b"].key].write_bytes(b"GKREC1 00\n{}")
    result, _, value = run()
    np.testing.assert_array_equal(value, EXPECTED)
    assert not any(o.hit for o in result.outcomes.values())
    assert len(run.notes) == 4 and all("quarantine" in n for n in run.notes), run.notes


def test_a_record_missing_from_its_journal_is_untrustworthy(run):
    first, kd = cut_last_record(run)  # d's frame cut off (the file shrank)
    store = Store(run.cache).open()
    assert store.verify() == [f"record {kd}: {st.NOT_IN_JOURNAL}"]
    result, _, value = run()
    np.testing.assert_array_equal(value, EXPECTED)
    assert {n for n, o in result.outcomes.items() if not o.hit} == {"d"}
    assert any(kd[:16] in n and st.NOT_IN_JOURNAL in n for n in run.notes), run.notes


def test_usage_counts_a_journal_once_and_gc_frees_it_with_its_last_link(run):
    first, _, _ = run()
    store = Store(run.cache).open()
    u = store.usage()
    (j,) = journals(run.cache)
    assert u["journal"] == j.stat().st_size and u["keys"] == 0
    assert u["total"] == true_size(run.cache)
    # drop records until one is left: the journal stays (a record links to it) and counts whole
    info = store.gc(u["total"] - 1)
    assert info["removed_records"] >= 1 and j.exists()
    assert store.size() == true_size(run.cache) == info["bytes"]
    info = store.gc(0)
    assert keyfiles(run.cache) == {} and journals(run.cache) == []
    assert store.size() == true_size(run.cache) == info["bytes"]


def test_gc_removes_journals_no_record_links_to(run):
    run()
    (j,) = journals(run.cache)
    for p in keyfiles(run.cache).values():
        p.unlink()
    store = Store(run.cache).open()
    assert store.clean_stale(dry_run=True) == {"files": 1, "bytes": j.stat().st_size}
    assert j.exists()
    info = store.gc(10**9)
    assert info["stale_files"] == 1 and not j.exists()


def test_a_record_used_long_after_its_journal_moves_to_the_readers_journal(run, write, engine_registry):
    """gc's least-recently-used order stays per record: reading one record of an old journal
    moves that record (not the journal's others) to the reading run's journal."""
    first, _, _ = run()
    (old,) = journals(run.cache)
    t = os.stat(old).st_mtime - 3600
    os.utime(old, (t, t))
    part = load_graph(write("part.yaml", "graphkit: 1\nname: part\nnodes:\n"
                            "  a: {type: Const, params: {value: 2.0, size: 8}}\n"
                            "  b: {type: Add, inputs: {a: a.out}, params: {offset: 1.0}}\noutputs: {b: b.out}\n"),
                      engine_registry)
    r = run_local(Session(part, engine_registry, Store(run.cache).open()), ["b"])
    assert r.outcomes["a"].hit and r.outcomes["b"].hit
    (new,) = [x for x in journals(run.cache) if x != old]
    moved = {first.outcomes["a"].key, first.outcomes["b"].key}  # (b: read from the journal a's read indexed)
    files = keyfiles(run.cache)
    assert all(inode(files[k]) == inode(new) for k in moved)
    assert all(inode(p) == inode(old) for k, p in files.items() if k not in moved)
    assert os.stat(old).st_mtime == pytest.approx(t)
    # gc now drops the two records of the old journal first, and the journal with the last
    info = Store(run.cache).open().gc(true_size(run.cache) - old.stat().st_size)
    assert info["removed_records"] == 2 and not old.exists() and set(keyfiles(run.cache)) == moved


def test_a_file_system_without_hard_links_gets_record_files(run, monkeypatch):
    links_fail(monkeypatch, errno.EPERM)
    _, _, value = run()
    np.testing.assert_array_equal(value, EXPECTED)
    files = keyfiles(run.cache)
    assert len(files) == 4 and all(os.stat(p).st_nlink == 1 for p in files.values())
    assert all(p.read_bytes().startswith(b"GKREC1 ") for p in files.values())
    monkeypatch.undo()
    result, _, _ = run()
    assert all(o.hit for o in result.outcomes.values())


def test_a_full_journal_is_followed_by_a_new_one(run, monkeypatch):
    monkeypatch.setattr(st, "JOURNAL_MAX_FRAMES", 3)
    run()
    js = journals(run.cache)
    assert [len(frames(j)) for j in js] == [3, 1]
    monkeypatch.setattr(st, "JOURNAL_MAX_FRAMES", 50_000)
    calls = links_fail(monkeypatch, errno.EMLINK, times=1)  # a file system with a lower link limit
    store = Store(run.cache).open()
    with store.run_lock():
        store.put_record("ab" * 16, {"key": "ab" * 16, "node": "n", "parts": {}, "outputs": {}})
    assert calls and store.get_record("ab" * 16)["node"] == "n"
    assert len(journals(run.cache)) == 4  # the frame went to a second journal of that run


def test_a_journal_removed_while_a_run_writes_is_replaced(tmp_path):
    s = Store(tmp_path / "c").open()
    rec = {"key": "", "node": "n", "parts": {}, "outputs": {}}
    with s.run_lock():
        s.put_record("a1" * 16, {**rec, "key": "a1" * 16})
        (j,) = journals(tmp_path / "c")
        j.unlink()  # (not something graphkit does while a run holds the lock; a user might)
        s.put_record("b2" * 16, {**rec, "key": "b2" * 16})
    assert s.get_record("b2" * 16)["key"] == "b2" * 16 and s.get_record("a1" * 16)["key"] == "a1" * 16
    assert len(journals(tmp_path / "c")) == 1


def test_fsspec_reads_records_linked_to_a_journal(run):
    first, _, _ = run()
    s = Store(f"file://{run.cache}").open()
    kb = first.outcomes["b"].key
    assert s.get_record(kb)["node"] == "b"
    assert s.get_record("ff" * 16) is None
    assert s.verify() == []


def test_kill_9_while_a_run_appends_records_leaves_no_bad_entry(tmp_path, write):
    """Real SIGKILLs at random moments of a run that writes a record every ~50 µs (a 2000-node
    chain: most kills land between an append and its link, or inside an append): after each, the
    cache verifies clean, and a run to the end gives the keys and bytes of a clean cache."""
    import random
    import subprocess
    import sys
    import time

    from conftest import engine_env, graphkit

    n = 2000
    lines = ["graphkit: 1", "name: many", "nodes:", "  n0: {type: Const, params: {value: 1.0, size: 4}}"]
    lines += [f"  n{i}: {{type: Noop, inputs: {{x: n{i - 1}.out}}, params: {{i: {i}}}}}" for i in range(1, n)]
    g = write("many.yaml", "\n".join(lines + [f"outputs: {{last: n{n - 1}.out}}"]) + "\n")
    cache, rng = tmp_path / "c", random.Random(7)
    for i in range(6):
        p = subprocess.Popen([sys.executable, "-m", "graphkit", "run", str(g), "--cache", str(cache), "--out",
                              str(tmp_path / f"o{i}"), "-q", "--jobs", "1"], env=engine_env(),
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        while p.poll() is None and not list(cache.glob("journal/*.gkj"))[i:]:  # this run's journal
            time.sleep(0.002)
        time.sleep(rng.uniform(0.0, 0.08))  # while it appends
        p.kill()
        p.wait()
        assert Store(cache).open().verify() == [], f"after kill {i}"
    r = graphkit("run", g, "--cache", cache, "--out", tmp_path / "final")
    assert r.returncode == 0, r.stderr
    clean = graphkit("run", g, "--cache", tmp_path / "clean", "--out", tmp_path / "clean_out")
    assert clean.returncode == 0, clean.stderr
    assert (tmp_path / "final" / "last.npy").read_bytes() == (tmp_path / "clean_out" / "last.npy").read_bytes()
    import json
    a, b = (json.loads((tmp_path / d / "manifest.json").read_text())["nodes"] for d in ("final", "clean_out"))
    assert {k: v["key"] for k, v in a.items()} == {k: v["key"] for k, v in b.items()}
    assert sum(not v["hit"] for v in a.values()) < n  # the killed runs' records were used


# ---------------------------------------------------------------------------------------------
# edges of the reader, the writer and the accounting (unit level: Store objects in this process)

REC = {"key": "", "node": "n", "parts": {}, "outputs": {}}


def put(store, key, **extra):
    store.put_record(key, {**REC, "key": key, **extra})


def test_a_reader_inside_a_run_sees_what_is_appended_after_it_read(tmp_path):
    w, r = Store(tmp_path / "c").open(), Store(tmp_path / "c").open()
    with w.run_lock(), r.run_lock():
        put(w, "a1" * 16)
        assert r.get_record("a1" * 16)["key"] == "a1" * 16  # r has read the journal whole
        put(w, "b2" * 16)
        assert r.get_record("b2" * 16)["key"] == "b2" * 16  # ... and reads on: it grew


def test_a_frame_read_half_written_is_found_whole_later(tmp_path):
    w, r = Store(tmp_path / "c").open(), Store(tmp_path / "c").open()
    with w.run_lock():
        put(w, "a1" * 16)
        (j,) = journals(tmp_path / "c")
        assert r.get_record("a1" * 16) is not None
        raw = encode_record({**REC, "key": "b2" * 16})
        frame = b"\0GKJF " + b"b2" * 16 + b" %d\n" % len(raw) + raw
        with open(j, "ab") as f:  # a writer half-way through its append
            f.write(frame[:60])
        assert r.get_record("a1" * 16) is not None  # r reads the half frame
        with open(j, "ab") as f:
            f.write(frame[60:])
        os.makedirs(tmp_path / "c" / "keys" / "b2", exist_ok=True)
        os.link(j, tmp_path / "c" / r.record_rel("b2" * 16))
        assert r.get_record("b2" * 16)["key"] == "b2" * 16


def test_a_journal_rewritten_or_cut_in_place_is_read_again(tmp_path):
    """A reader's index of a journal is keyed by its inode and header: a file of the same size
    with another header (another journal in the same inode), or a shorter one, is read again."""
    w, r = Store(tmp_path / "c").open(), Store(tmp_path / "c").open()
    with w.run_lock():
        put(w, "a1" * 16, node="x")
    (j,) = journals(tmp_path / "c")
    assert r.get_record("a1" * 16)["node"] == "x"
    raw = j.read_bytes()
    other = raw[:7] + b"f" * 32 + raw[39:]
    other = other.replace(b'"node":"x"', b'"node":"y"')  # same length; its check line fails
    j.write_bytes(other)
    notes = []
    r.on_notice = notes.append
    assert r.get_record("a1" * 16) is None and "check line" in notes[0], notes
    put(w, "a1" * 16, node="z")  # (outside a run: a record file of its own, replacing the link)
    with w.run_lock():
        put(w, "b2" * 16)
        put(w, "c3" * 16)
    (j2,) = [x for x in journals(tmp_path / "c") if x != j]
    assert r.get_record("c3" * 16) is not None
    data = j2.read_bytes()
    j2.write_bytes(data[:data.index(b"\0GKJF " + b"c3" * 16)])  # c3's frame cut off
    assert r.get_record("c3" * 16) is None
    assert r.get_record("b2" * 16) is not None and r.get_record("a1" * 16)["node"] == "z"


def test_a_process_forgets_journals_beyond_its_memory_bound(tmp_path, monkeypatch):
    w = Store(tmp_path / "c").open()
    for k in ("a1", "b2", "c3"):
        with w.run_lock():  # three runs, three journals
            put(w, k * 16)
    assert len(journals(tmp_path / "c")) == 3
    monkeypatch.setattr(st, "JOURNAL_CACHE_BYTES", 100)  # less than one journal
    r = Store(tmp_path / "c").open()
    for k in ("a1", "b2", "c3"):
        assert r.get_record(k * 16)["key"] == k * 16
    (view,) = r.fs.journals.views.values()  # each journal read put it over the bound: the others forgotten
    assert r.fs.journals.view_bytes == len(view.buf) - 40 > 100


def test_links_refused_once_are_not_tried_again_in_that_store(tmp_path, monkeypatch):
    calls = links_fail(monkeypatch, errno.ENOTSUP)
    s = Store(tmp_path / "c").open()
    with s.run_lock():
        for k in ("a1", "b2", "c3"):
            put(s, k * 16)
    assert len(calls) == 1
    assert all(os.stat(tmp_path / "c" / s.record_rel(k * 16)).st_nlink == 1 for k in ("a1", "b2", "c3"))


def test_a_journal_that_will_not_take_links_gives_a_record_file(tmp_path, monkeypatch):
    calls = links_fail(monkeypatch, errno.EMLINK)
    s = Store(tmp_path / "c").open()
    with s.run_lock():
        put(s, "a1" * 16)
    assert len(calls) == 2 and len(journals(tmp_path / "c")) == 2  # its journal, then a new one
    p = tmp_path / "c" / s.record_rel("a1" * 16)
    assert os.stat(p).st_nlink == 1 and s.get_record("a1" * 16)["key"] == "a1" * 16


def test_a_journal_is_closed_at_its_size_limit(tmp_path, monkeypatch):
    one = len(encode_record({**REC, "key": "a1" * 16})) + len(b"\0GKJF " + b"a1" * 16 + b" 999\n")
    monkeypatch.setattr(st, "JOURNAL_MAX_BYTES", 40 + 2 * one)
    s = Store(tmp_path / "c").open()
    with s.run_lock():
        for k in ("a1", "b2", "c3", "d4", "e5"):
            put(s, k * 16)
    assert [len(frames(j)) for j in journals(tmp_path / "c")] == [2, 2, 1]


def test_journals_are_plain_files_by_default(tmp_path):
    old = os.umask(0o022)
    try:
        s = Store(tmp_path / "c").open()
        with s.run_lock():
            put(s, "a1" * 16)
        (j,) = journals(tmp_path / "c")
        assert os.stat(j).st_mode & 0o7777 == 0o644
    finally:
        os.umask(old)


def test_a_journal_whose_header_cannot_be_written_is_not_left(tmp_path, monkeypatch):
    from graphkit.errors import CacheError

    s = Store(tmp_path / "c").open()
    real = st._write_all

    def full_disk(fd, chunks):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(st, "_write_all", full_disk)
    with s.run_lock(), pytest.raises(CacheError, match="the disk is full"):
        put(s, "a1" * 16)
    monkeypatch.setattr(st, "_write_all", real)
    assert journals(tmp_path / "c") == [] and s.fs.journals.current is None


def test_damaged_records_leave_keys_for_quarantine_on_fsspec_and_local(tmp_path):
    import uuid

    for s in (Store(f"memory://j-{uuid.uuid4().hex}").open(), Store(tmp_path / "c").open()):
        notes = []
        s.on_notice = notes.append
        s.fs.write_atomic(s.record_rel("ab" * 16), [b"GKREC1 00\n{}"])
        assert s.get_record("ab" * 16) is None and not s.fs.exists(s.record_rel("ab" * 16))
        (q,) = [rel for rel, _, _ in s.fs.listdir("quarantine")]
        assert s.fs.read(q) == b"GKREC1 00\n{}" and "moved to quarantine/" in notes[0]


def test_a_record_cut_from_its_journal_is_quarantined_as_nothing(run):
    first, kd = cut_last_record(run)
    s = Store(run.cache).open()
    assert s.get_record(kd) is None
    (q,) = (run.cache / "quarantine").iterdir()
    assert q.read_bytes() == b"" and not keyfiles(run.cache).get(kd)
    assert Store(f"file://{run.cache}").open().get_record(first.outcomes["c"].key) is not None


def test_fsspec_reports_a_record_its_journal_lacks(run):
    first, kd = cut_last_record(run)
    assert Store(f"file://{run.cache}").open().verify() == [f"record {kd}: {st.NOT_IN_JOURNAL}"]


def test_verify_names_the_damage_of_a_frame(run):
    first, _, _ = run()
    (j,) = journals(run.cache)
    raw = bytearray(j.read_bytes())
    at = raw.index(b'"node":"b"')
    raw[at + 8] ^= 0x01
    j.write_bytes(bytes(raw))
    kb = first.outcomes["b"].key
    assert Store(run.cache).open().verify() == [f"record {kb}: does not match its check line (damaged or edited)"]


def test_clean_stale_counts_every_unlinked_journal(tmp_path):
    s = Store(tmp_path / "c").open()
    for k in ("a1", "b2"):
        with s.run_lock():
            put(s, k * 16)
    js = journals(tmp_path / "c")
    for k in ("a1", "b2"):
        os.unlink(tmp_path / "c" / s.record_rel(k * 16))
    sizes = sum(j.stat().st_size for j in js)
    assert s.clean_stale(dry_run=True) == {"files": 2, "bytes": sizes}
    assert s.clean_stale() == {"files": 2, "bytes": sizes}
    assert journals(tmp_path / "c") == []


def test_usage_of_linked_and_plain_records_together(tmp_path):
    s = Store(tmp_path / "c").open()
    with s.run_lock():
        put(s, "a1" * 16)  # a journal with one link (two names)
    for k in ("00", "ff"):
        put(s, k * 16)  # record files of their own, one before and one after the link in the walk
    u = s.usage()
    (j,) = journals(tmp_path / "c")
    plain = sum(os.stat(tmp_path / "c" / s.record_rel(k * 16)).st_size for k in ("00", "ff"))
    assert (u["journal"], u["keys"]) == (j.stat().st_size, plain)
    assert u["total"] == true_size(tmp_path / "c")


def test_gc_frees_the_bytes_of_linked_records_only_with_their_journal(write, engine_registry, tmp_path):
    """Three records in one journal and one object they all name: gc asked to free one byte must
    drop all three (no single record frees anything), and then fits."""
    g = load_graph(write("n.yaml", "graphkit: 1\nname: n\nnodes:\n  a: {type: Const, params: {value: 1.0}}\n"
                         "  b: {type: Noop, inputs: {x: a.out}, params: {i: 1}}\n"
                         "  c: {type: Noop, inputs: {x: b.out}, params: {i: 2}}\noutputs: {c: c.out}\n"),
                   engine_registry)
    s = Store(tmp_path / "c").open()
    run_local(Session(g, engine_registry, s), ["c"])
    for p in (tmp_path / "c" / "runs").iterdir():
        p.unlink()
    total = s.size()
    info = s.gc(total - 1)
    assert info["removed_records"] == 3 and info["removed_objects"] == 1 and info["bytes"] <= total - 1
    assert journals(tmp_path / "c") == [] and info["bytes"] == true_size(tmp_path / "c")


def test_gc_on_an_fsspec_store_counts_each_record_s_bytes(tmp_path):
    import uuid

    import graphkit.types as T

    s = Store(f"memory://gc-{uuid.uuid4().hex}").open()
    for i, k in enumerate(("a1", "b2", "c3")):
        d = s.put_value(T.ARRAY, np.full(50, float(i)))
        put(s, k * 16, outputs={"out": {"digest": d, "type": "Array"}})
    sizes = {rel: n for rel, n, _ in s.fs.listdir("keys")}
    objs = {rel: n for rel, n, _ in s.fs.listdir("objects")}
    total = s.size()
    info = s.gc(total - min(sizes.values()) - min(objs.values()))
    assert info["removed_records"] == 1 and info["removed_objects"] == 1


def test_touching_records_in_a_run(tmp_path, monkeypatch):
    """Used long after: a record file is marked used (mtime), a linked record moves to the run's
    journal; a move that fails leaves the record served."""
    s = Store(tmp_path / "c").open()
    put(s, "00" * 16)
    with s.run_lock():
        put(s, "a1" * 16)
    old = time_ago(3600)
    for p in [tmp_path / "c" / s.record_rel("00" * 16)] + journals(tmp_path / "c"):
        os.utime(p, (old, old))
    with s.run_lock():
        assert s.get_record("00" * 16, touch=True) is not None
        p = tmp_path / "c" / s.record_rel("00" * 16)
        assert os.stat(p).st_nlink == 1 and os.stat(p).st_mtime > old + 3000
        links_fail(monkeypatch, errno.EIO)
        assert s.get_record("a1" * 16, touch=True)["key"] == "a1" * 16
    put(s, "ff" * 16)
    os.utime(tmp_path / "c" / s.record_rel("ff" * 16), (old, old))
    monkeypatch.setattr(st.os, "utime", lambda *a, **k: (_ for _ in ()).throw(PermissionError(errno.EPERM, "no")))
    assert s.get_record("ff" * 16, touch=True)["key"] == "ff" * 16  # (a cache it cannot mark: still read)


def time_ago(seconds):
    import time

    return time.time() - seconds


def test_a_record_file_over_a_mebibyte_is_read_whole(tmp_path):
    s = Store(tmp_path / "c").open()
    put(s, "ab" * 16, note="x" * (1 << 21))
    assert os.stat(tmp_path / "c" / s.record_rel("ab" * 16)).st_size > 1 << 20
    assert s.get_record("ab" * 16)["note"] == "x" * (1 << 21)
