"""Edges of the store and hashing code that `make mutate` showed unguarded (issue 10): exact
refusal messages, on-disk layout facts (offsets, modes, lock paths, what gc and clean_stale
remove and count), the error paths (read-only fallbacks, OSError → CacheError, a record file that
vanishes mid-listing) and lock behaviour of verify.  Expectations are closed-form or follow from
the documented layout, never earlier output.  In process and fast: all of them run in a few
seconds, so mutmut can afford them."""
import errno
import json
import os
import stat
import struct
import threading
import time

import numpy as np
import pytest
import xxhash

import graphkit.store.localfs as st
from graphkit.errors import CacheError, CanonicalError
from graphkit.hashing import array_digest, canonical, parts_digest
from graphkit.store import (ALIGN, MAGIC, CorruptObject, LocalFS, MissingObject, Store, check_object,
                            decode_object, decode_record, encode_header, encode_record, iter_chunks)
from graphkit.types import ARRAY


@pytest.fixture
def store(tmp_path):
    s = Store(tmp_path / "c").open()
    s.notes = []
    s.on_notice = s.notes.append
    return s


@pytest.fixture
def umask0():
    old = os.umask(0)
    yield
    os.umask(old)


def obj_bytes(tname, meta, arrays):
    digest = parts_digest(tname, meta, arrays)
    head, offsets = encode_header(tname, meta, arrays, digest)
    return b"".join(bytes(c) for c in iter_chunks(head, offsets, arrays)), digest, offsets


def rec(store, key, outs, ins=(), node="n"):
    store.put_record(key, {"key": key, "node": node, "outputs": {f"o{i}": {"digest": d, "type": "Array"}
                                                                 for i, d in enumerate(outs)},
                           "parts": {"inputs": {"x": list(ins)}}})


def age(path, seconds_ago):
    t = time.time() - seconds_ago
    os.utime(path, (t, t))


# ---------------------------------------------------------------------------------------------
# object encoding


def test_array_offsets_are_64_byte_aligned_in_order():
    arrays = [np.zeros(65, np.uint8), np.arange(7, dtype=np.uint8), np.arange(3, dtype=np.uint8)]
    raw, digest, offsets = obj_bytes("Array", {}, arrays)
    assert offsets == [0, 128, 192]  # 65 → next multiple of 64 is 128; 128 + 7 → 192
    hlen = struct.unpack("<Q", raw[8:16])[0]
    header = raw[16:16 + hlen]
    assert header == json.dumps(json.loads(header), sort_keys=True, separators=(",", ":")).encode()
    base = 16 + hlen + (-(16 + hlen)) % ALIGN
    assert raw[base + 128:base + 135] == arrays[1].tobytes() and raw[base + 192:] == arrays[2].tobytes()
    assert raw[base + 65:base + 128] == b"\0" * 63
    _, _, back = check_object(raw, digest)
    for a, b in zip(arrays, back):
        np.testing.assert_array_equal(a, b)


def test_header_ending_on_an_alignment_boundary():
    """16 + header length a multiple of 64: the data starts right after the header, no padding."""
    for n in range(200):
        meta = {"pad": "x" * n}
        digest = parts_digest("Array", meta, [np.arange(4.0)])
        head, _ = encode_header("Array", meta, [np.arange(4.0)], digest)
        hlen = struct.unpack("<Q", head[8:16])[0]
        if (16 + hlen) % ALIGN == 0:
            break
    assert len(head) == 16 + hlen
    raw, digest, _ = obj_bytes("Array", meta, [np.arange(4.0)])
    assert raw[16 + hlen:] == np.arange(4.0).tobytes()
    np.testing.assert_array_equal(check_object(raw, digest)[2][0], np.arange(4.0))


def test_decode_refusals_name_the_reason():
    raw, digest, _ = obj_bytes("Array", {}, [np.arange(100.0)])
    with pytest.raises(CorruptObject) as e:
        check_object(b"X" + raw[1:], digest)
    assert e.value.digest == digest and e.value.why == "cannot be decoded (not a graphkit object (bad magic))"
    with pytest.raises(CorruptObject) as e:
        check_object(raw[:-8], digest)
    assert e.value.digest == digest and e.value.why == "cannot be decoded (truncated object)"
    assert str(e.value) == f"cache object {digest} cannot be decoded (truncated object)"
    with pytest.raises(MissingObject) as e:
        check_object(None, digest)
    assert (e.value.digest, e.value.why, str(e.value)) == (digest, "is missing", f"cache object {digest} is missing")


def test_a_header_length_with_the_top_bit_set_is_refused():
    """The length field is unsigned: 2^64 - m is a huge length (refused), not -m."""
    body = json.dumps({"type": "Json", "meta": {}, "arrays": [], "digest": parts_digest("Json", {}, [])},
                      sort_keys=True, separators=(",", ":")).encode()
    junk = b"0" * 40
    m = len(junk) + 16
    raw = MAGIC + struct.pack("<Q", (1 << 64) - m) + body + junk
    with pytest.raises(ValueError):
        decode_object(raw)
    with pytest.raises(CorruptObject):
        check_object(raw, parts_digest("Json", {}, []))


# ---------------------------------------------------------------------------------------------
# records


def test_record_refusals_name_the_reason():
    key = "ab" * 16
    good = encode_record({"key": key, "outputs": {}})
    assert decode_record(b"XYZ", key) == (None, "has no integrity line (damaged)")
    other = "cd" * 16
    assert decode_record(good, other) == (None, f"belongs to key {key[:16]} (a record moved or copied)")
    assert decode_record(encode_record({"key": key, "outputs": []}), key) == (None, "is not a valid record")
    body = b'{"key": "%s",\n "outputs": {}}' % key.encode()  # hand-written JSON: one more line
    raw = b"GKREC1 " + xxhash.xxh3_128_hexdigest(body).encode() + b"\n" + body
    assert decode_record(raw, key) == ({"key": key, "outputs": {}}, None)


def test_record_body_is_canonical_json():
    rec_ = {"z": 1, "key": "k", "outputs": {"b": {"digest": "d", "type": "T"}, "a": {"digest": "e", "type": "T"}}}
    body = encode_record(rec_).split(b"\n", 1)[1]
    assert body == json.dumps(rec_, sort_keys=True, separators=(",", ":")).encode()


def test_a_record_that_vanishes_while_listed_reads_as_untrustworthy(store, monkeypatch):
    rec(store, "ab" * 16, [])
    entries = store.fs.entries

    def listed_then_gone(rel):
        for item in entries(rel):
            os.unlink(store.fs.path(item[0]))  # removed between the listing and the read
            yield item
    monkeypatch.setattr(store.fs, "entries", listed_then_gone)
    ((key, r, _),) = list(store.records())
    assert key == "ab" * 16 and r is None


def test_quarantine_notice_names_the_key_prefix(store):
    key = "0123456789abcdef" + "f" * 16
    store.fs.write_atomic(store.record_rel(key), [b"GKREC1 00\n{}"])
    assert store.get_record(key) is None
    assert store.notes[0].startswith(f"notice: cache record {key[:16]} does not match")


# ---------------------------------------------------------------------------------------------
# modes, folders, locks


def test_fresh_localfs_defaults(tmp_path):
    fs = LocalFS(str(tmp_path / "c"))
    assert (fs.dir_mode, fs.file_mode, fs._fix_dir_mode, fs._fix_file_mode) == (0o777, 0o666, False, False)
    assert fs.describe() == str(tmp_path / "c")


@pytest.mark.parametrize("mode, umask, fix_dir, fix_file", [
    (0o755, 0o022, False, False),   # the umask gives these modes anyway
    (0o775, 0o022, True, True),     # group-writable: the umask would take g+w away
    (0o2755, 0o022, True, False),   # setgid is kept explicitly
    (0o750, 0o077, True, True),
    (0o700, 0o077, False, False),
])
def test_mode_fixes_are_needed_exactly_when_the_umask_differs(tmp_path, mode, umask, fix_dir, fix_file):
    root = tmp_path / "c"
    root.mkdir()
    os.chmod(root, mode)
    old = os.umask(umask)
    try:
        assert st._umask() == umask
        fs = LocalFS(str(root))
        fs.ensure()
    finally:
        os.umask(old)
    assert fs.dir_mode == mode and fs.file_mode == mode & 0o666
    assert (fs._fix_dir_mode, fs._fix_file_mode) == (fix_dir, fix_file)


def test_umask_fallback_when_proc_is_unreadable(monkeypatch):
    def no_proc(*a, **k):
        raise OSError(errno.ENOENT, "no /proc")
    monkeypatch.setattr(st, "open", no_proc, raising=False)
    assert st._umask() == 0o022


def test_modes_come_from_the_create_calls(tmp_path, umask0):
    """With umask 0 nothing is chmod-ed afterwards: folders and files get the cache folder's
    mode from mkdir/open themselves."""
    root = tmp_path / "c"
    root.mkdir()
    os.chmod(root, 0o750)
    s = Store(root).open()
    d = s.put_value(ARRAY, np.arange(3.0))
    rec(s, "ab" * 16, [d])
    with s.key_lock("ab" * 16), s.run_lock():
        pass
    for p in (root / "keys", root / "objects" / d[:2], root / "keys" / "ab"):
        assert stat.S_IMODE(p.stat().st_mode) == 0o750, p
    for p in (root / "objects" / d[:2] / d, root / s.record_rel("ab" * 16), root / "keys.lock", root / "store.lock"):
        assert stat.S_IMODE(p.stat().st_mode) == 0o640, p
    assert stat.S_IMODE((root / "format-1").stat().st_mode) == 0o640
    assert sorted(p.name for p in root.iterdir()) == ["format-1", "keys", "keys.lock", "objects", "runs", "store.lock",
                                                      "tmp"]


def test_mkdir_stays_below_the_root(tmp_path):
    fs = LocalFS(str(tmp_path / "a" / "c"))  # neither a nor c exists
    with pytest.raises(FileNotFoundError):
        fs.mkdir(fs.path("x/y"))
    assert not (tmp_path / "a").exists()
    (tmp_path / "a").mkdir()
    fs.mkdir(fs.path("x/y"))  # the root itself may be made again
    assert (tmp_path / "a" / "c" / "x" / "y").is_dir()


def test_temp_files_are_created_exclusively(store):
    p = store.fs.path("tmp/t")
    os.close(store.fs._create(p))
    with pytest.raises(FileExistsError):
        store.fs._create(p)


def test_lock_file_open_falls_back_to_read_only(store, monkeypatch):
    fs = store.fs
    real_open = os.open
    path = fs.path("keys.lock")
    with open(path, "w"):
        pass

    def no_write(p, flags, *a):
        if flags & os.O_CREAT:
            raise PermissionError(errno.EACCES, "denied")
        return real_open(p, flags, *a)
    monkeypatch.setattr(st.os, "open", no_write)
    fd = fs._open_lock(path)
    try:
        assert fd is not None and os.readlink(f"/proc/self/fd/{fd}") == path
        import fcntl

        assert fcntl.fcntl(fd, fcntl.F_GETFL) & os.O_ACCMODE == os.O_RDONLY
    finally:
        os.close(fd)
    assert fs._open_lock(fs.path("missing.lock")) is None

    def full(p, flags, *a):
        raise OSError(errno.ENOSPC, "full")
    monkeypatch.setattr(st.os, "open", full)
    with pytest.raises(OSError) as e:
        fs._open_lock(path)
    assert e.value.errno == errno.ENOSPC


def test_lock_file_paths_and_bytes(store, tmp_path):
    key = "0123456789abcdef" * 2
    lk = store.fs.key_lock(key)
    assert lk.byte == int(key[:15], 16)
    store.fs._key_lock_fd_ok = False  # systems without OFD locks: one lock file per key
    with store.fs.key_lock(key):
        pass
    assert (tmp_path / "c" / "locks" / "01" / f"{key}.lock").exists()


def test_fsspec_key_lock_paths(tmp_path):
    import uuid

    s = Store(f"memory://edges-{uuid.uuid4().hex}").open()
    key = "0123456789abcdef" * 2
    with s.fs.key_lock(key):
        pass
    assert f"{s.fs.url}/locks/01/{key}.lock" in type(s.fs)._locks


def test_fsspec_writes_and_moves_into_nested_folders(tmp_path):
    import uuid

    s = Store(f"memory://edges-{uuid.uuid4().hex}/").open()
    assert not s.fs.root.endswith("/")
    s.fs.write_atomic("a/b/c/x", [b"12", memoryview(b"3")])
    assert s.fs.fs.isdir(s.fs.path("a/b/c")) and s.fs.read("a/b/c/x") == b"123"
    assert s.fs.move_aside("a/b/c/x", "q/r/s/y") and s.fs.fs.isdir(s.fs.path("q/r/s"))
    assert list(s.fs.listdir("tmp")) == []
    ((rel, size, mtime),) = list(s.fs.listdir("q"))
    assert (rel, size) == ("q/r/s/y", 3) and abs(mtime - time.time()) < 600


def test_fsspec_listdir_times_and_sizes(monkeypatch):
    import datetime
    import uuid

    s = Store(f"memory://edges-{uuid.uuid4().hex}").open()
    when = datetime.datetime(2020, 1, 2, tzinfo=datetime.timezone.utc)
    infos = {s.fs.path("k/a"): {"size": 0, "mtime": when}, s.fs.path("k/b"): {"size": 5, "created": 7.5},
             s.fs.path("k/c"): {"size": None}}
    monkeypatch.setattr(s.fs.fs, "exists", lambda p: True)
    monkeypatch.setattr(s.fs.fs, "find", lambda base, detail: infos)
    assert sorted(s.fs.listdir("k")) == [("k/a", 0, when.timestamp()), ("k/b", 5, 7.5), ("k/c", 0, 0.0)]


def test_fsspec_failed_write_leaves_no_temp(monkeypatch):
    import uuid

    s = Store(f"memory://edges-{uuid.uuid4().hex}").open()

    def boom(src, dst):
        raise OSError("mv failed")
    monkeypatch.setattr(s.fs.fs, "mv", boom)
    with pytest.raises(OSError):
        s.fs.write_atomic("objects/ab/x", [b"1"])
    assert s.fs.fs.ls(s.fs.path("tmp")) == []


# ---------------------------------------------------------------------------------------------
# group commit and syncfs


def test_syncfs_is_called_on_the_cache_folder(store, monkeypatch):
    monkeypatch.setattr(st, "_libc_syncfs", None)
    store.put_value(ARRAY, np.arange(3.0))
    store.commit()
    assert callable(st._libc_syncfs)
    seen = []
    monkeypatch.setattr(st, "_libc_syncfs", lambda fd: seen.append(os.readlink(f"/proc/self/fd/{fd}")) or 0)
    monkeypatch.setattr(os, "sync", lambda: seen.append("sync"))
    store.put_value(ARRAY, np.arange(4.0))
    store.commit()
    assert seen == [str(store.fs.root)]


def test_syncfs_missing_from_libc_falls_back_to_sync(store, monkeypatch):
    import ctypes

    def no_libc(*a, **k):
        raise OSError("no libc")
    monkeypatch.setattr(st, "_libc_syncfs", None)
    monkeypatch.setattr(ctypes, "CDLL", no_libc)
    calls = []
    monkeypatch.setattr(os, "sync", lambda: calls.append(1))
    store.put_value(ARRAY, np.arange(5.0))
    store.commit()
    assert st._libc_syncfs is False and calls == [1]


def test_commit_errors_are_swallowed_and_the_clock_restarts(store, monkeypatch):
    def fail():
        raise OSError(errno.EIO, "io")
    monkeypatch.setattr(store.fs, "commit", fail)
    store.put_value(ARRAY, np.arange(3.0))
    store.commit()  # a failed syncfs does not fail the run (the read checks catch what it lost)
    assert store._dirty is False and time.monotonic() - store._last_commit < 5
    store.put_value(ARRAY, np.arange(6.0))
    store.commit(force=False)  # within the interval: nothing
    assert store._dirty is True


def test_failed_writes_name_what_was_written(store, monkeypatch):
    def enospc(*a, **k):
        raise OSError(errno.ENOSPC, "full")
    monkeypatch.setattr(store.fs, "write_atomic", enospc)
    with pytest.raises(CacheError) as e:
        store.put_value(ARRAY, np.arange(3.0))
    assert str(e.value) == f"cache {store.location}: cannot write a cache object: the disk is full"
    with pytest.raises(CacheError) as e:
        store.put_record("ab" * 16, {"key": "ab" * 16, "outputs": {}})
    assert str(e.value) == f"cache {store.location}: cannot write a cache record: the disk is full"
    store.save_run("g", {"a": 1})  # the notes for explain are optional: no error
    assert store.last_run("g") is None


def test_open_names_what_failed(tmp_path, monkeypatch):
    (tmp_path / "file").write_text("x")
    with pytest.raises(CacheError) as e:
        Store(tmp_path / "file" / "c").open()
    assert str(e.value).startswith(f"cache {tmp_path / 'file' / 'c'}: cannot create the cache folder: ")


def test_open_probe_tells_read_only_from_other_errors(tmp_path, monkeypatch):
    s = Store(tmp_path / "c")
    calls = []

    def ro(rel, chunks, sync=False):
        calls.append((rel, [bytes(c) for c in chunks]))
        raise PermissionError(errno.EROFS, "ro")
    monkeypatch.setattr(s.fs, "write_atomic", ro)
    assert s.open().read_only is True and s._ready is True
    assert calls[0][0].startswith("tmp/probe-") and calls[0][1] == [b"ok"]
    s2 = Store(tmp_path / "d")

    def eio(rel, chunks, sync=False):
        raise OSError(errno.EIO, "io")
    monkeypatch.setattr(s2.fs, "write_atomic", eio)
    with pytest.raises(CacheError, match="cannot create the cache folder"):
        s2.open()
    s3 = Store(tmp_path / "e").open()
    assert s3.read_only is False and s3._ready is True and list((tmp_path / "e" / "tmp").iterdir()) == []


def test_save_run_writes_sorted_json(store, tmp_path):
    store.save_run("g", {"b": 1, "a": 2})
    assert (tmp_path / "c" / "runs" / "g.json").read_text() == '{"a": 2, "b": 1}'


def test_objects_of_unknown_types_load_as_their_meta(store):
    meta = {"a": 1}
    raw, digest, _ = obj_bytes("NoSuchType", meta, [])
    store.fs.write_atomic(store.object_rel(digest), [raw])
    assert store.load_value(digest) == {"a": 1}
    raw, digest, _ = obj_bytes("NoSuchType", {"model": {"x": 2}}, [])
    store.fs.write_atomic(store.object_rel(digest), [raw])
    assert store.load_value(digest) == {"x": 2}


def test_read_only_notice_is_said_once(store):
    store.read_only = True
    store.put_value(ARRAY, np.arange(3.0))
    store.put_record("ab" * 16, {"key": "ab" * 16, "outputs": {}})
    assert store.notes == [f"notice: cache {store.location} is read-only: results computed in this run are not stored"]


# ---------------------------------------------------------------------------------------------
# usage, clean_stale, gc


def test_usage_counts_legacy_locks_and_root_files(store, tmp_path):
    c = tmp_path / "c"
    (c / "locks" / "ab").mkdir(parents=True)
    (c / "locks" / "ab" / "k.lock").write_bytes(b"x" * 11)
    (c / "filememo.json").write_bytes(b"y" * 13)
    (c / "keys.lock").write_bytes(b"z" * 17)
    u = store.usage()
    assert u["locks"] == 11
    assert u["other"] == sum(p.stat().st_size for p in c.iterdir() if p.is_file()) == 13 + 17
    assert u["total"] == sum(v for k, v in u.items() if k != "total")


def test_clean_stale_removes_legacy_locks_and_out_temps(store, tmp_path, monkeypatch):
    c = tmp_path / "c"
    for sub in ("ab", "cd"):
        (c / "locks" / sub).mkdir(parents=True)
        (c / "locks" / sub / f"{sub}.lock").write_bytes(b"l" * 3)
    (c / "filememo.json.12.34.tmp").write_bytes(b"t" * 100)
    (c / "filememo.json.56.78.tmp").write_bytes(b"t" * 50)
    (c / "filememo.json").write_text("{}")  # the memo itself stays
    elsewhere = tmp_path / "cwd"
    elsewhere.mkdir()
    (elsewhere / "filememo.json.9.9.tmp").write_bytes(b"o")
    monkeypatch.chdir(elsewhere)
    assert store.clean_stale(dry_run=True) == {"files": 4, "bytes": 156}
    assert (c / "filememo.json.12.34.tmp").exists() and (c / "locks" / "ab").is_dir()
    assert store.clean_stale() == {"files": 4, "bytes": 156}
    assert not (c / "locks").exists()  # empty shard folders, then the folder itself
    assert not list(c.glob("filememo.json.*.tmp")) and (c / "filememo.json").exists()
    assert (elsewhere / "filememo.json.9.9.tmp").exists()


def test_gc_evicts_least_recently_used_not_by_key(store, tmp_path):
    c = tmp_path / "c"
    ds = [store.put_value(ARRAY, np.full(1000, float(i))) for i in range(3)]
    keys = ["a1" * 16, "b2" * 16, "c3" * 16]
    for i, key in enumerate(keys):
        rec(store, key, [ds[i]])
        age(c / store.record_rel(key), 100 * (i + 1))  # c3 is the least recently used
    one = (c / store.record_rel(keys[2])).stat().st_size + (c / "objects" / ds[2][:2] / ds[2]).stat().st_size
    info = store.gc(store.size() - one)
    assert {k for k, _, _ in store.records()} == set(keys[:2])
    assert (info["removed_records"], info["removed_objects"]) == (1, 1)


def test_gc_counts_what_it_drops_exactly(store, tmp_path):
    c = tmp_path / "c"
    d = store.put_value(ARRAY, np.arange(1000.0))
    rec(store, "a1" * 16, [d])
    for name in ("b2", "c3"):
        (c / "keys" / name).mkdir()
        p = c / "keys" / name / (name * 16 + ".json")
        p.write_bytes(b"GKREC1 00\n{}")
        age(p, 10_000)  # the oldest: met first on the way to eviction
    orphans = [store.put_value(ARRAY, np.full(10, float(i))) for i in range(2)]
    budget = store.size() - sum((c / "keys" / n / (n * 16 + ".json")).stat().st_size for n in ("b2", "c3")) \
        - sum((c / "objects" / o[:2] / o).stat().st_size for o in orphans)
    info = store.gc(budget)
    assert info == {"removed_records": 2, "removed_objects": 2, "stale_files": 0, "stale_bytes": 0,
                    "bytes": budget}
    assert store.get_record("a1" * 16) is not None and (c / "objects" / d[:2] / d).exists()
    assert store.gc(0)["removed_records"] == 1 and store.size() == 0


def test_gc_drops_run_notes_oldest_first_only_as_needed(store, tmp_path):
    c = tmp_path / "c"
    for i, name in enumerate(("old", "mid", "new")):
        store.save_run(name, {"n": i})
        age(c / "runs" / f"{name}.json", 1000 - 100 * i)
    (c / "filememo.json").write_text("{}")
    old = (c / "runs" / "old.json").stat().st_size
    budget = store.size() - old  # exactly the oldest note too much
    assert store.gc(budget)["bytes"] == budget
    assert sorted(p.name for p in (c / "runs").iterdir()) == ["mid.json", "new.json"]
    assert (c / "filememo.json").exists()
    memo = (c / "filememo.json").stat().st_size
    notes = sum(p.stat().st_size for p in (c / "runs").iterdir())
    assert store.gc(memo)["bytes"] == memo and (c / "filememo.json").exists()  # the memo goes last
    assert not list((c / "runs").iterdir())
    assert notes > 0 and store.gc(0)["bytes"] == 0 and not (c / "filememo.json").exists()


def test_gc_and_verify_wait_for_runs_and_say_so(store, tmp_path, capsys):
    other = Store(tmp_path / "c").open()
    done = []
    with store.run_lock():
        assert other.verify() == []  # a plain verify only reads: no lock, no waiting
        t = threading.Thread(target=lambda: done.append(other.verify(repair=True)))
        t.start()
        time.sleep(0.3)
        assert done == []  # repair waits for the run
    t.join(10)
    assert done == [[]]
    err = capsys.readouterr().err
    assert f"graphkit: verify waits for the runs that use {other.location} to finish\n" in err
    with store.run_lock():
        t = threading.Thread(target=lambda: done.append(other.gc(10**9)))
        t.start()
        time.sleep(0.3)
        assert len(done) == 1
    t.join(10)
    assert len(done) == 2
    assert f"graphkit: gc waits for the runs that use {other.location} to finish\n" in capsys.readouterr().err


def test_gc_and_verify_name_their_failures(store, monkeypatch):
    def eio(rel):
        raise OSError(errno.EIO, "odd")
    monkeypatch.setattr(store.fs, "entries", eio)
    with pytest.raises(CacheError) as e:
        store.gc(0)
    assert str(e.value) == f"cache {store.location}: cannot gc: odd"
    with pytest.raises(CacheError) as e:
        store.verify()
    assert str(e.value) == f"cache {store.location}: cannot verify: odd"


# ---------------------------------------------------------------------------------------------
# verify and ls


def test_verify_taints_records_computed_from_a_damaged_input(store, tmp_path):
    """A damaged object that no record produced (e.g. a record already gone) still taints the
    records computed from it."""
    c = tmp_path / "c"
    src = store.put_value(ARRAY, np.arange(50.0))
    out = store.put_value(ARRAY, np.arange(50.0) * 2)
    rec(store, "a1" * 16, [out], [src], node="twice")
    p = c / "objects" / src[:2] / src
    p.write_bytes(p.read_bytes()[:-1] + b"\x07")
    assert sorted(store.verify()) == sorted([f"object {src}: does not match its digest",
                                             f"record {'a1' * 16} (twice): computed from a damaged value ({src[:16]})"])


def test_verify_reports_a_record_whose_key_is_null(store, tmp_path):
    key = "a1" * 16
    store.fs.write_atomic(store.record_rel(key), [encode_record({"key": None, "outputs": {}})])
    assert store.verify() == [f"record {key}: belongs to key None (a record moved or copied)"]


def test_ls_lists_every_untrustworthy_record(store, tmp_path):
    c = tmp_path / "c"
    for name in ("a1", "b2"):
        (c / "keys" / name).mkdir()
        (c / "keys" / name / (name * 16 + ".json")).write_bytes(b"junk")
    d = store.put_value(ARRAY, np.arange(4.0))
    rec(store, "c3" * 16, [d])
    rows = {r["key"]: r for r in store.ls()}
    assert set(rows) == {"a1" * 16, "b2" * 16, "c3" * 16}
    assert rows["a1" * 16]["objects"] == [] and rows["a1" * 16]["corrupt"] is True
    assert rows["c3" * 16]["objects"] == [d]


# ---------------------------------------------------------------------------------------------
# hashing edges


def test_array_digest_closed_form():
    assert array_digest(np.zeros(0)) == xxhash.xxh3_128_hexdigest(b"<f8(0,);")
    a = np.arange(3, dtype=np.int16)
    assert array_digest(a) == xxhash.xxh3_128_hexdigest(b"<i2(3,);" + a.tobytes())


def test_canonical_refusals_name_the_reason():
    with pytest.raises(CanonicalError) as e:
        canonical({"a": {1: 2}})
    assert str(e.value) == "params.a: dict keys must be strings, got int"
    from graphkit.hashing import _enc

    with pytest.raises(CanonicalError) as e:
        _enc({1: 2}, [])
    assert str(e.value) == "dict keys must be strings"
    with pytest.raises(CanonicalError) as e:
        _enc({1: 2, "a": 3}, [])  # keys that cannot even be sorted
    assert str(e.value) == "dict keys must be strings"
    with pytest.raises(CanonicalError) as e:
        array_digest(np.array([object()]))
    assert str(e.value) == "object arrays cannot be hashed"

    class Odd:
        pass
    with pytest.raises(CanonicalError) as e:
        _enc(Odd(), [])
    assert str(e.value) == (f"cannot encode a value of type {Odd.__module__}.{Odd.__qualname__} "
                            "canonically (cache keys fail closed on unknown types)")


def test_file_memo_keeps_good_entries_after_a_bad_one(tmp_path):
    import graphkit.hashing as h

    files = [tmp_path / f"f{i}" for i in range(3)]
    for i, f in enumerate(files):
        f.write_bytes(bytes([i]) * 10)
    memo = tmp_path / "memo.json"
    h._memo.clear()
    for f in files:
        h.file_digest(f, memo)
    data = json.loads(memo.read_text())
    first = sorted(data)[0]
    data[first] = [1, 2]  # an entry that does not even unpack, listed first
    memo.write_text(json.dumps(dict(sorted(data.items()))))
    h._memo.clear()
    h._load_memo(memo)
    assert first not in h._memo and len(h._memo) == 2
    h._memo.clear()


# ---------------------------------------------------------------------------------------------
# low-level reads, writes and locks (second mutation pass)


def test_reads_go_on_after_a_short_read_or_growth(tmp_path, monkeypatch):
    p = tmp_path / "f"
    p.write_bytes(bytes(range(256)) * 4)
    fd = os.open(p, os.O_RDONLY)
    try:
        assert st._read_fd(fd, 1024) == p.read_bytes()
        os.lseek(fd, 0, 0)
        assert st._read_fd(fd, 10) == p.read_bytes()  # grew since fstat: read to the end
        real = os.read
        monkeypatch.setattr(st.os, "read", lambda f, n: real(f, min(n, 100)))  # reads capped (> 2 GiB)
        os.lseek(fd, 0, 0)
        assert st._read_fd(fd, 1024) == p.read_bytes()
    finally:
        os.close(fd)


def test_writes_go_on_after_a_short_write(store, monkeypatch):
    real = os.write
    monkeypatch.setattr(st.os, "write", lambda fd, b: real(fd, bytes(memoryview(b).cast("B")[:3])))
    arr = np.arange(5.0)
    store.fs.write_atomic("tmp/x", [b"abcdefg", memoryview(arr), b"", memoryview(b"hi")])
    assert store.fs.read("tmp/x") == b"abcdefg" + arr.tobytes() + b"hi"


def test_synced_single_writes_and_cleanup_after_a_failed_rename(store, tmp_path):
    c = tmp_path / "c"
    store.fs.write_atomic("runs/a.json", [b"{}"], sync=True)
    assert (c / "runs" / "a.json").read_bytes() == b"{}"
    (c / "runs" / "dir").mkdir()
    (c / "runs" / "dir" / "x").write_text("x")
    with pytest.raises(OSError):
        store.fs.write_atomic("runs/dir", [b"1"])  # a folder in the way
    assert list((c / "tmp").iterdir()) == []
    store.fs.remove("runs/none")  # absent: no error
    assert not store.fs.move_aside("runs/a.json", "runs/dir")  # a non-empty folder in the way
    assert (c / "runs" / "a.json").exists()


def test_listing_skips_files_that_vanish(store, tmp_path, monkeypatch):
    c = tmp_path / "c"
    for n in ("a", "b", "c"):
        (c / "tmp" / n).write_bytes(b"x")
    real = os.lstat
    first = str(c / "tmp" / os.listdir(c / "tmp")[0])  # the first one the walk meets

    def flaky(path, *a, **k):
        if str(path) == first:
            raise FileNotFoundError(path)
        return real(path, *a, **k)
    monkeypatch.setattr(os, "lstat", flaky)
    assert len(list(store.fs.listdir("tmp"))) == 2


def test_chmod_failures_are_ignored(tmp_path, monkeypatch):
    root = tmp_path / "g"
    root.mkdir()
    os.chmod(root, 0o2775)
    old = os.umask(0o077)
    try:
        s = Store(root).open()

        def denied(*a):
            raise PermissionError(errno.EPERM, "not the owner")
        monkeypatch.setattr(st.os, "fchmod", denied)
        monkeypatch.setattr(st.os, "chmod", denied)
        assert s.fs._fix_file_mode and s.fs._fix_dir_mode
        s.put_value(ARRAY, np.arange(3.0))
        os.close(s.fs._open_lock(s.fs.path("other.lock")))
    finally:
        os.umask(old)


def test_thread_lock_fd_is_closed_with_its_owner(tmp_path):
    fd = os.open(tmp_path / "l", os.O_RDWR | os.O_CREAT)
    holder = st._FD(fd)
    del holder
    with pytest.raises(OSError):
        os.fstat(fd)


def test_adjacent_key_bytes_do_not_share_a_lock(store, tmp_path):
    base = int("123456789abcde", 16)
    k1, k2 = f"{base:015x}" + "0" * 17, f"{base + 1:015x}" + "0" * 17
    other = Store(tmp_path / "c").open()
    got = []

    def take(key):
        with other.key_lock(key):
            got.append(key)
    with store.key_lock(k2):
        with store.key_lock(k1):
            pass  # releasing k1 must not release k2
        t = threading.Thread(target=take, args=(k2,))
        t.start()
        time.sleep(0.3)
        assert got == []
        t1 = threading.Thread(target=take, args=(k1,))
        t1.start()
        t1.join(5)
        assert got == [k1]  # k1's byte is free while k2 is held
    t.join(5)
    assert got == [k1, k2]


def test_nested_cache_folders_are_created(tmp_path):
    s = Store(tmp_path / "a" / "b" / "c").open()
    assert (tmp_path / "a" / "b" / "c" / "objects").is_dir() and not s.read_only


def test_touching_reads_return_the_record(store):
    r = {"key": "ab" * 16, "outputs": {}}
    store.put_record("ab" * 16, r)
    assert store.get_record("ab" * 16, touch=True) == r


def test_a_damage_notice_is_said_once_even_when_it_cannot_be_moved(store):
    d = store.put_value(ARRAY, np.arange(5.0))
    store.read_only = True
    store.quarantine(store.object_rel(d), "cache object X is bad")
    store.quarantine(store.object_rel(d), "cache object X is bad")
    assert len(store.notes) == 1


def test_gc_to_zero_with_an_untrustworthy_oldest_record(store, tmp_path):
    c = tmp_path / "c"
    d = store.put_value(ARRAY, np.arange(100.0))
    rec(store, "a1" * 16, [d])
    (c / "keys" / "b2").mkdir()
    p = c / "keys" / "b2" / ("b2" * 16 + ".json")
    p.write_bytes(b"junk")
    age(p, 10_000)
    info = store.gc(0)
    assert (info["removed_records"], info["removed_objects"], info["bytes"]) == (2, 1, 0)


def test_truncation_inside_a_later_array_is_named(tmp_path):
    raw, digest, offsets = obj_bytes("Array", {}, [np.arange(8.0), np.arange(8.0)])
    assert offsets == [0, 64]
    with pytest.raises(CorruptObject) as e:
        check_object(raw[:-16], digest)
    assert e.value.why == "cannot be decoded (truncated object)"


def test_fsspec_local_folders_are_made_for_writes_and_moves(tmp_path):
    s = Store(f"file://{tmp_path}/fs").open()
    s.fs.write_atomic("a/b/c/x", [b"12"])
    assert (tmp_path / "fs" / "a" / "b" / "c" / "x").read_bytes() == b"12"
    assert s.fs.move_aside("a/b/c/x", "q/r/s/y") and (tmp_path / "fs" / "q" / "r" / "s" / "y").read_bytes() == b"12"
    assert list((tmp_path / "fs" / "tmp").iterdir()) == []


def test_entries_are_not_fsynced_one_by_one(store, monkeypatch):
    """Group commit: writing objects and records never fsyncs a file (issue 10: two fsyncs per
    node cost up to 3.4 ms); one syncfs at commit makes them durable."""
    fsyncs, syncfs = [], []
    monkeypatch.setattr(st.os, "fsync", lambda fd: fsyncs.append(fd))
    monkeypatch.setattr(st, "_libc_syncfs", lambda fd: syncfs.append(fd) or 0)
    for i in range(3):
        d = store.put_value(ARRAY, np.full(10, float(i)))
        rec(store, f"{i:02d}" * 16, [d])
    assert fsyncs == [] and syncfs == []
    store.commit()
    assert fsyncs == [] and len(syncfs) == 1
