"""The store's parts one at a time, in process (fast enough for `make mutate`): object and record
encodings and their checks, quarantine, group commit, locks, modes, read-only mode, sizes,
gc order and verify's chain."""
import hashlib
import hmac
import json
import os
import stat
import threading
import time

import numpy as np
import pytest
import xxhash

from graphkit.errors import CacheError
from graphkit.hashing import parts_digest
from graphkit.store import (ALIGN, MAGIC, CorruptObject, MissingObject, Store, check_object,
                            decode_object, decode_record, encode_header, encode_record, fmt_size, iter_chunks,
                            UNSIGNED, record_inputs, value_parts)
from graphkit.types import ARRAY, IMAGE, SCALAR, Image


def encoded(meta, arrays, tname="Array"):
    digest = parts_digest(tname, meta, arrays)
    head, offsets = encode_header(tname, meta, arrays, digest)
    return b"".join(bytes(c) for c in iter_chunks(head, offsets, arrays)), digest


def test_object_layout_and_round_trip():
    a, b = np.arange(5, dtype=np.float32), np.arange(7, dtype=np.int16).reshape(7, 1)
    raw, digest = encoded({"k": 1}, [a, b])
    assert raw[:8] == MAGIC
    tname, meta, arrays, d = decode_object(raw)
    assert (tname, meta, d) == ("Array", {"k": 1}, digest)
    np.testing.assert_array_equal(arrays[0], a)
    np.testing.assert_array_equal(arrays[1], b)
    assert arrays[1].shape == (7, 1) and arrays[1].dtype == np.int16
    header = json.loads(raw[16:16 + int.from_bytes(raw[8:16], "little")])
    base = 16 + len(json.dumps(header, sort_keys=True, separators=(",", ":")))
    base += (-base) % ALIGN
    assert all(x["offset"] % ALIGN == 0 for x in header["arrays"]) and header["arrays"][1]["offset"] == 64
    assert raw[base:base + 20] == a.tobytes() and raw[base + 64:base + 64 + 14] == b.tobytes()
    assert len(raw) == base + 64 + 14


def test_zero_size_and_scalar_arrays():
    raw, digest = encoded({}, [np.zeros(0), np.float64(3.0).reshape(())])
    tname, meta, arrays = check_object(raw, digest)
    assert arrays[0].size == 0 and arrays[1].shape == () and arrays[1] == 3.0


def test_check_object_refuses_damage():
    raw, digest = encoded({}, [np.arange(100.0)])
    assert check_object(raw, digest)[0] == "Array"
    with pytest.raises(MissingObject):
        check_object(None, digest)
    bad = bytearray(raw)
    bad[-1] ^= 1
    with pytest.raises(CorruptObject, match="does not match its digest"):
        check_object(bytes(bad), digest)
    with pytest.raises(CorruptObject, match="cannot be decoded"):
        check_object(raw[:-8], digest)  # truncated
    with pytest.raises(CorruptObject, match="bad magic"):
        check_object(b"X" + raw[1:], digest)
    with pytest.raises(CorruptObject):
        check_object(raw, "0" * 32)  # a whole object under another name


def test_records_carry_a_check_line_and_their_key():
    rec = {"key": "k1", "node": "n", "outputs": {"out": {"digest": "d1" * 16, "type": "Array"}}, "parts": {}}
    raw = encode_record(rec)
    line, body = raw.split(b"\n", 1)
    assert line == b"GKREC1 " + xxhash.xxh3_128_hexdigest(body).encode()
    assert json.loads(body) == rec
    assert decode_record(raw, "k1") == (rec, None)
    assert decode_record(raw, "k2")[0] is None and "belongs to key" in decode_record(raw, "k2")[1]
    assert "check line" in decode_record(raw.replace(b"d1", b"d2"), "k1")[1]
    assert decode_record(body, "k1") == (None, "has no integrity line (damaged)")  # (pre-release records too)
    assert "damaged" in decode_record(b"\0\0" + raw, "k1")[1]
    no_outputs = encode_record({"key": "k1"})
    assert decode_record(no_outputs, "k1")[0] is None
    no_digest = encode_record({"key": "k1", "outputs": {"out": {}}})
    assert decode_record(no_digest, "k1")[0] is None
    for bad in ("d1", "D1" * 16, "../x", "", 7):  # not the exact hex form: damage, never a path
        forged = encode_record({**rec, "outputs": {"out": {"digest": bad}}})
        assert "not one" in decode_record(forged, "k1")[1]


def test_keyed_records_carry_a_mac_that_only_the_key_makes():
    rec = {"key": "k1", "outputs": {"out": {"digest": "d1" * 16}}}
    raw = encode_record(rec, b"s1")
    line, body = raw.split(b"\n", 1)
    assert line.split(b" ")[2] == hmac.new(b"s1", body, hashlib.sha256).hexdigest().encode()
    assert decode_record(raw, "k1", b"s1") == (rec, None)
    assert decode_record(raw, "k1") == (rec, None)  # a run without the key checks the check line only
    assert decode_record(raw, "k1", b"s2")[1] == UNSIGNED
    assert decode_record(encode_record(rec), "k1", b"s1")[1] == UNSIGNED
    assert decode_record(raw.replace(b"d1", b"d2"), "k1", b"s1")[0] is None


def test_record_inputs():
    assert record_inputs({"parts": {"inputs": {"a": "d1", "xs": ["d2", "d3"]}}}) == ["d1", "d2", "d3"]
    assert record_inputs({}) == [] and record_inputs({"parts": {}}) == []


def test_sizes_are_mib():
    assert fmt_size(3 << 20) == "3.000 MiB" and fmt_size(0) == "0.000 MiB" and fmt_size(1 << 19) == "0.500 MiB"


@pytest.fixture
def store(tmp_path):
    s = Store(tmp_path / "c").open()
    notes = []
    s.on_notice = notes.append
    s.notes = notes
    return s


def test_values_round_trip_checked(store, tmp_path):
    img = Image(np.random.default_rng(1).random((4, 5, 3), dtype=np.float32))
    d = store.put_value(IMAGE, img)
    assert d == value_parts(IMAGE, img)[2]
    assert (tmp_path / "c" / "objects" / d[:2] / d).exists()
    np.testing.assert_array_equal(store.load_value(d, IMAGE).pixels, img.pixels)
    np.testing.assert_array_equal(store.load_value(d).pixels, img.pixels)  # type from the object
    assert store.load_value(store.put_value(SCALAR, 2.5)) == 2.5
    with pytest.raises(MissingObject):
        store.load_value("ab" * 16, IMAGE)
    assert store.notes == []


def test_damaged_object_is_quarantined_once_with_a_notice(store, tmp_path):
    d = store.put_value(ARRAY, np.arange(1000.0))
    p = tmp_path / "c" / "objects" / d[:2] / d
    raw = bytearray(p.read_bytes())
    raw[-3] ^= 4
    p.write_bytes(bytes(raw))
    with pytest.raises(CorruptObject) as e:
        store.load_value(d, ARRAY)
    assert isinstance(e.value, CacheError) and e.value.digest == d
    assert not p.exists() and len(list((tmp_path / "c" / "quarantine").iterdir())) == 1
    assert len(store.notes) == 1 and d[:16] in store.notes[0] and "moved to quarantine/" in store.notes[0]
    with pytest.raises(MissingObject):
        store.load_value(d, ARRAY)


def test_records_round_trip_touch_and_quarantine(store, tmp_path):
    rec = {"key": "ab" * 16, "outputs": {"out": {"digest": "d0" * 16, "type": "Array"}}}
    store.put_record("ab" * 16, rec)
    p = tmp_path / "c" / store.record_rel("ab" * 16)
    assert store.get_record("ab" * 16) == rec and store.get_record("cd" * 16) is None
    old = time.time() - 3600
    os.utime(p, (old, old))
    store.get_record("ab" * 16)
    assert p.stat().st_mtime == old  # a plain read does not mark it used
    store.get_record("ab" * 16, touch=True)
    assert p.stat().st_mtime > old + 3000
    fresh = p.stat().st_mtime_ns
    store.get_record("ab" * 16, touch=True)
    assert p.stat().st_mtime_ns == fresh  # marked within the granularity: no write
    p.write_bytes(p.read_bytes().replace(b'"d0', b'"e0'))
    assert store.get_record("ab" * 16) is None and not p.exists()
    assert len(store.notes) == 1 and "check line" in store.notes[0]
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(rec))  # a pre-release record (no check line): damaged like any other
    assert store.get_record("ab" * 16) is None and not p.exists() and len(store.notes) == 2
    assert "no integrity line" in store.notes[1]


def test_group_commit(store, monkeypatch):
    calls = []
    monkeypatch.setattr(store.fs, "commit", lambda: calls.append(1))
    store.commit()
    assert calls == []  # nothing written
    store.put_value(ARRAY, np.arange(3.0))
    store.commit(force=False)
    assert calls == []  # within the interval
    store._last_commit -= store.COMMIT_INTERVAL_S + 1
    store.commit(force=False)
    assert calls == [1]
    store.put_record("ab" * 16, {"key": "ab" * 16, "outputs": {}})
    store.commit()
    assert calls == [1, 1]
    store.commit()
    assert calls == [1, 1]
    store.sync = False
    store.put_value(ARRAY, np.arange(4.0))
    store.commit()
    assert calls == [1, 1]


def test_key_locks_exclude_threads_and_stores(store, tmp_path):
    other = Store(tmp_path / "c").open()
    order = []
    with store.key_lock("ab" * 16):
        t = threading.Thread(target=lambda: (other.key_lock("ab" * 16).__enter__(), order.append("other")))
        t.start()
        time.sleep(0.3)
        order.append("first")
        with store.key_lock("cd" * 16):  # another key is free
            order.append("free")
    t.join(5)
    assert order == ["first", "free", "other"]


def test_run_lock_is_reentrant_and_gc_waits(store, tmp_path):
    waited = []
    with store.run_lock(), store.run_lock():
        t = threading.Thread(target=lambda: waited.append(Store(tmp_path / "c").open().gc(0)))
        t.start()
        time.sleep(0.3)
        assert waited == []
    t.join(10)
    assert waited and waited[0]["bytes"] == 0
    with store.fs.lock("store.lock", shared=True):
        calls = []
        t = threading.Thread(target=lambda: store.fs.lock("store.lock", on_wait=lambda: calls.append(1)).__enter__())
        t.start()
        time.sleep(0.3)
        assert calls == [1]


def test_entries_get_the_folder_mode(tmp_path):
    root = tmp_path / "g"
    root.mkdir()
    os.chmod(root, 0o2775)
    old = os.umask(0o077)
    try:
        s = Store(root).open()
        d = s.put_value(ARRAY, np.arange(2.0))
        s.put_record("ab" * 16, {"key": "ab" * 16, "outputs": {}})
        with s.run_lock():
            s.put_record("cd" * 16, {"key": "cd" * 16, "outputs": {}})  # into the run's journal
            assert os.get_inheritable(s.fs.journals.current.fd) is False
            fd = s.fs.journals.current.fd
        with pytest.raises(OSError):  # the journal was closed when the run ended
            os.fstat(fd)
        with s.key_lock("ab" * 16):
            pass
    finally:
        os.umask(old)
    (journal,) = (root / "journal").iterdir()
    for p in (root / "objects" / d[:2], root / "keys" / "ab", root / "objects", root / "tmp", root / "journal"):
        assert stat.S_IMODE(p.stat().st_mode) == 0o2775, p
    for p in (root / "objects" / d[:2] / d, root / s.record_rel("ab" * 16), root / "store.lock", root / "keys.lock",
              journal):
        assert stat.S_IMODE(p.stat().st_mode) == 0o664, p


def test_read_only_store_keeps_results_in_memory(store, tmp_path):
    store.read_only = True
    d = store.put_value(ARRAY, np.arange(3.0))
    store.put_record("ab" * 16, {"key": "ab" * 16, "outputs": {}})
    assert not (tmp_path / "c" / "objects" / d[:2]).exists() and store.get_record("ab" * 16) is None
    assert len(store.notes) == 1 and "read-only" in store.notes[0]
    with pytest.raises(CacheError, match="read-only"):
        store.gc(0)
    with pytest.raises(CacheError, match="read-only"):
        store.verify(repair=True)


def _rec(store, key, outs, ins=(), node="n"):
    store.put_record(key, {"key": key, "node": node, "outputs": {f"o{i}": {"digest": d, "type": "Array"}
                                                                 for i, d in enumerate(outs)},
                           "parts": {"inputs": {"x": list(ins)}}})


def test_usage_and_clean_stale(store, tmp_path):
    c = tmp_path / "c"
    d = store.put_value(ARRAY, np.arange(1000.0))
    _rec(store, "ab" * 16, [d])
    (c / "tmp" / "junk").write_bytes(b"x" * 5000)
    (c / "quarantine").mkdir()
    (c / "quarantine" / "q").write_bytes(b"x" * 700)
    u = store.usage()
    assert u["tmp"] == 5000 and u["quarantine"] == 700
    assert u["objects"] == (c / "objects" / d[:2] / d).stat().st_size
    assert u["total"] == sum(p.stat().st_size for p in c.rglob("*") if p.is_file()) == store.size()
    assert store.clean_stale(dry_run=True) == {"files": 2, "bytes": 5700} and (c / "tmp" / "junk").exists()
    assert store.clean_stale() == {"files": 2, "bytes": 5700} and not (c / "tmp" / "junk").exists()
    assert store.clean_stale() == {"files": 0, "bytes": 0}


def test_gc_order(store, tmp_path):
    c = tmp_path / "c"
    ds = [store.put_value(ARRAY, np.full(10000, float(i))) for i in range(4)]
    for i, key in enumerate(["a1" * 16, "b2" * 16, "c3" * 16]):
        _rec(store, key, [ds[i]])
        t = time.time() - 1000 + i * 100  # a1 is the least recently used
        os.utime(c / store.record_rel(key), (t, t))
    (c / "keys" / "dd").mkdir()
    (c / "keys" / "dd" / ("dd" * 16 + ".json")).write_bytes(b"GKREC1 bad\n{}")
    obj = (c / "objects" / ds[0][:2] / ds[0]).stat().st_size
    info = store.gc(store.size() - obj - 1000)  # room for all but about one entry
    assert info["removed_objects"] >= 2  # ds[3] is an orphan
    assert not (c / "objects" / ds[3][:2] / ds[3]).exists()
    assert not (c / "keys" / "dd" / ("dd" * 16 + ".json")).exists()  # untrustworthy record first
    left = {k for k, _, _ in store.records()}
    assert "c3" * 16 in left and "a1" * 16 not in left, left
    assert store.verify() == []


def test_verify_follows_the_chain(store, tmp_path):
    c = tmp_path / "c"
    d0 = store.put_value(ARRAY, np.arange(100.0))
    d1 = store.put_value(ARRAY, np.arange(100.0) + 1)
    d2 = store.put_value(ARRAY, np.arange(100.0) + 2)
    d3 = store.put_value(ARRAY, np.arange(100.0) + 3)
    _rec(store, "a0" * 16, [d0])
    _rec(store, "b1" * 16, [d1], [d0])  # from a0's value
    _rec(store, "c2" * 16, [d2], [d1])  # from b1's value
    _rec(store, "d3" * 16, [d3], [d2])  # from d2, which ...
    _rec(store, "e1" * 16, [d2], [d3])  # ... a clean record also makes: d3 stays
    _rec(store, "f5" * 16, [d3])
    _rec(store, "g6" * 16, [d0], ["77" * 16])  # another record of the damaged object
    assert store.verify() == []
    p = c / "objects" / d0[:2] / d0
    raw = bytearray(p.read_bytes())
    raw[-1] ^= 1
    p.write_bytes(bytes(raw))
    problems = store.verify()
    dropped = {line.split()[1] for line in problems if line.startswith("record")}
    assert dropped == {"a0" * 16, "b1" * 16, "c2" * 16, "g6" * 16}, problems
    assert any(line.startswith(f"object {d0}") for line in problems)
    assert len(list((c / "keys").rglob("*.json"))) == 7  # report only
    store.verify(repair=True)
    assert {k for k, _, _ in store.records()} == {"d3" * 16, "e1" * 16, "f5" * 16}
    assert store.verify() == []


def test_ls_rows(store, tmp_path):
    d1 = store.put_value(ARRAY, np.arange(1000.0))
    d2 = store.put_value(ARRAY, np.arange(10.0))
    store.put_record("a1" * 16, {"key": "a1" * 16, "node": "a", "parts": {"node_type": "Const"}, "seconds": 0.5,
                                 "outputs": {"x": {"digest": d1, "type": "Array"}, "y": {"digest": d2, "type": "Array"},
                                             "z": {"digest": d1, "type": "Array"}}})
    c = tmp_path / "c"
    t = time.time() - 500
    os.utime(c / store.record_rel("a1" * 16), (t, t))
    (c / "keys" / "b2").mkdir()
    (c / "keys" / "b2" / ("b2" * 16 + ".json")).write_bytes(b"junk")
    rows = store.ls()
    assert [r["key"] for r in rows] == ["b2" * 16, "a1" * 16]  # most recently used first
    bad, good = rows
    assert bad["corrupt"] is True and bad["bytes"] == 0 and bad["node"] == "?" and bad["type"] == "?"
    size = lambda d: (c / "objects" / d[:2] / d).stat().st_size  # noqa: E731
    assert good == {"key": "a1" * 16, "node": "a", "type": "Const", "bytes": size(d1) + size(d2),
                    "used": good["used"], "seconds": 0.5, "objects": sorted([d1, d2])}
    assert abs(good["used"] - t) < 1 and "corrupt" not in good


def test_fsspec_store(tmp_path):
    import uuid

    from graphkit.store import FsspecFS

    s = Store(f"memory://unit-{uuid.uuid4().hex}").open()
    assert isinstance(s.fs, FsspecFS) and not s.read_only and s.memo_file is None
    for d in ("objects", "keys", "runs", "tmp"):
        assert s.fs.fs.isdir(s.fs.path(d)), d
    d = s.put_value(ARRAY, np.arange(100.0))
    assert s.fs.exists(s.object_rel(d)) and not s.fs.exists(s.object_rel("ab" * 16))
    np.testing.assert_array_equal(s.load_value(d, ARRAY), np.arange(100.0))
    rec = {"key": "ab" * 16, "node": "n", "outputs": {"out": {"digest": d, "type": "Array"}}}
    s.put_record("ab" * 16, rec)
    assert s.get_record("ab" * 16, touch=True) == rec
    listed = {rel: size for rel, size, _ in s.fs.listdir("objects")}
    assert list(listed) == [s.object_rel(d)] and listed[s.object_rel(d)] > 800
    assert list(s.fs.listdir("nothing-here")) == []
    assert list(s.fs.listdir("tmp")) == []  # the temp file was moved, not left
    assert s.fs.move_aside(s.record_rel("ab" * 16), "quarantine/x") and s.fs.read("quarantine/x") is not None
    assert not s.fs.move_aside(s.record_rel("ab" * 16), "quarantine/y")  # gone already
    s.fs.remove("quarantine/x")
    s.fs.remove("quarantine/x")  # absent: no error
    assert s.fs.read("quarantine/x") is None
    s.put_record("ab" * 16, rec)
    assert s.verify() == [] and s.usage()["objects"] == listed[s.object_rel(d)]
    info = s.gc(0)
    assert (info["removed_records"], info["removed_objects"]) == (1, 1) and s.size() == 0
    order = []
    with s.key_lock("ab" * 16):
        t = threading.Thread(target=lambda: (s.key_lock("ab" * 16).__enter__(), order.append("b")))
        t.start()
        time.sleep(0.2)
        order.append("a")
    t.join(5)
    assert order == ["a", "b"]
    with s.fs.lock("store.lock", shared=True), s.fs.lock("store.lock", shared=True):
        pass
    s.commit()  # nothing to sync on an object store


def test_quarantine_names_and_notices(store, tmp_path):
    c = tmp_path / "c"
    d = store.put_value(ARRAY, np.arange(5.0))
    store.quarantine(store.object_rel(d), "cache object X is bad")
    q = list((c / "quarantine").iterdir())
    assert len(q) == 1 and q[0].name.startswith(f"objects_{d[:2]}_{d}.")
    assert store.notes == ["notice: cache object X is bad: moved to quarantine/; recomputing it"]
    store.quarantine(store.object_rel(d), "cache object X is bad")  # the same damage: said once
    assert len(store.notes) == 1
    store.read_only = True
    d = store.fs.write_atomic(store.object_rel("ab" * 16), [b"x"])
    store.quarantine(store.object_rel("ab" * 16), "cache object Y is bad")
    assert store.notes[-1] == ("notice: cache object Y is bad: left in place (the cache cannot be written); "
                               "recomputing it")


def test_notice_without_listener_and_last_runs(tmp_path):
    s = Store(tmp_path / "c").open()
    s.notice("nobody listens")  # no error
    assert s.last_run("g") is None
    s.save_run("g", {"a": 1})
    assert s.last_run("g") == {"a": 1}
    (tmp_path / "c" / "runs" / "g.json").write_text("{not json")
    assert s.last_run("g") is None
    s.read_only = True
    s.save_run("h", {"a": 1})
    assert s.last_run("h") is None


def test_models_load_without_a_port_type(store):
    from graphkit.types import port_type

    from graphkit.types import Light

    pt = port_type(Light)
    d = store.put_value(pt, Light())
    assert store.load_value(d) == Light().model_dump(mode="json") or store.load_value(d) is not None
    assert store.load_value(d, pt) == Light()


def test_cache_errors_name_the_reason(store):
    import errno as E

    for code, text in ((E.ENOSPC, "the disk is full"), (E.EDQUOT, "the disk quota is exceeded"),
                       (E.EROFS, "the file system is read-only"), (E.EACCES, "permission denied"),
                       (E.EPERM, "permission denied"), (E.EFBIG, "the file size limit was reached")):
        with pytest.raises(CacheError) as e:
            with store._errors("write a thing"):
                raise OSError(code, "x")
        assert str(e.value) == f"cache {store.location}: cannot write a thing: {text}"
    with pytest.raises(CacheError, match="cannot do: odd"):
        with store._errors("do"):
            raise OSError(E.EIO, "odd")


def test_verify_messages(store, tmp_path):
    c = tmp_path / "c"
    d = store.put_value(ARRAY, np.arange(10.0))
    _rec(store, "a1" * 16, [d], node="one")
    _rec(store, "b2" * 16, ["ee" * 16], node="two")  # its object was never written
    _rec(store, "c3" * 16, [store.put_value(ARRAY, np.arange(3.0))], [d], node="three")
    (c / "keys" / "d4").mkdir()
    (c / "keys" / "d4" / ("d4" * 16 + ".json")).write_bytes(b"GKREC1 00\n{}")
    (c / "keys" / "e5").mkdir()
    (c / "keys" / "e5" / ("e5" * 16 + ".json")).write_text('{"key": "x", "outputs": {}}')
    p = c / "objects" / d[:2] / d
    raw = bytearray(p.read_bytes())
    raw[-1] ^= 1
    p.write_bytes(bytes(raw))
    problems = store.verify()
    assert sorted(problems) == sorted([
        f"object {d}: does not match its digest",
        f"record {'a1' * 16} (one): output 'o0' object missing or corrupt",
        f"record {'b2' * 16} (two): output 'o0' object missing or corrupt",
        f"record {'c3' * 16} (three): computed from a damaged value ({d[:16]})",
        f"record {'d4' * 16}: does not match its check line (damaged or edited)",
        f"record {'e5' * 16}: has no integrity line (damaged)",  # (a pre-release record: damaged like any)
    ]), problems
    assert store.verify(repair=True) and store.verify() == []
    assert not list((c / "keys").rglob("*.json")) and not p.exists()


def test_ls_of_sparse_records(store, tmp_path):
    store.put_record("a1" * 16, {"key": "a1" * 16, "outputs": {"o": {"digest": "ff" * 16}}})
    (row,) = store.ls()
    assert row == {"key": "a1" * 16, "node": "?", "type": "?", "bytes": 0, "used": row["used"],
                   "seconds": 0.0, "objects": ["ff" * 16]}
    assert abs(row["used"] - time.time()) < 60


def test_quarantine_file_names(store, tmp_path):
    import re

    d = store.put_value(ARRAY, np.arange(5.0))
    store.quarantine(store.object_rel(d), "bad")
    (q,) = (tmp_path / "c" / "quarantine").iterdir()
    assert re.fullmatch(rf"objects_{d[:2]}_{d}\.\d{{8}}T\d{{6}}\.[0-9a-f]{{6}}", q.name), q.name
    d2 = store.put_value(ARRAY, np.arange(6.0))
    p = tmp_path / "c" / "objects" / d2[:2] / d2
    p.write_bytes(p.read_bytes()[:-1] + b"\x01")
    with pytest.raises(CorruptObject):
        store.load_value(d2)
    assert store.notes[-1] == (f"notice: cache object {d2[:16]} does not match its digest: moved to quarantine/; "
                               "recomputing it")


def test_values_of_model_ports_without_a_type(store):
    from graphkit.types import Light, port_type

    pt = port_type(Light)
    d = store.put_value(pt, Light())
    raw = store.load_value(d)  # no port type given and not a builtin one: the stored model data
    meta = pt.to_parts(Light())[0]
    assert raw == meta.get("model", meta)


def test_fsspec_listing_and_moves(tmp_path):
    import uuid

    s = Store(f"memory://unit-{uuid.uuid4().hex}").open()
    s.fs.write_atomic("deep/er/x.bin", [b"abc", memoryview(b"de")])
    assert s.fs.read("deep/er/x.bin") == b"abcde"
    ((rel, size, mtime),) = list(s.fs.listdir("deep"))
    assert rel == "deep/er/x.bin" and size == 5 and abs(mtime - time.time()) < 600
    assert s.fs.move_aside("deep/er/x.bin", "q/a/b/x") and s.fs.read("q/a/b/x") == b"abcde"
    assert s.fs.move_aside("q/a/b/x", "q/a/b/y")  # into a folder that exists
    with s.fs.key_lock("ab" * 16), s.fs.key_lock("cd" * 16):
        pass
    s2 = Store(s.location).open()
    assert s2.fs.read("q/a/b/y") == b"abcde"  # the same store, seen again


def test_group_commit_uses_syncfs(store, monkeypatch):
    import graphkit.store.localfs as st

    monkeypatch.setattr(os, "sync", lambda: (_ for _ in ()).throw(AssertionError("fell back to sync(2)")))
    store.put_value(ARRAY, np.arange(3.0))
    store.commit()
    assert callable(st._libc_syncfs)
    monkeypatch.setattr(st, "_libc_syncfs", False)
    called = []
    monkeypatch.setattr(os, "sync", lambda: called.append(1))
    store.put_value(ARRAY, np.arange(4.0))
    store.commit()
    assert called == [1]  # where there is no syncfs, sync(2)


def test_local_move_aside(store, tmp_path):
    c = tmp_path / "c"
    store.fs.write_atomic("tmp/a", [b"1"])
    assert store.fs.move_aside("tmp/a", "quarantine/new/dir/a") and (c / "quarantine/new/dir/a").read_bytes() == b"1"
    assert not store.fs.move_aside("tmp/none", "quarantine/b")
    assert store.fs.move_aside("quarantine/new/dir/a", "quarantine/new/dir/b")


def test_gc_budget_is_exact(store, tmp_path):
    """gc stops as soon as the folder fits: every byte is counted (records, objects once, tmp,
    run notes, memo), and the counts it returns are those of what it removed."""
    c = tmp_path / "c"
    shared = store.put_value(ARRAY, np.full(3000, -1.0))
    ds = [store.put_value(ARRAY, np.full(1000 * (i + 1), float(i))) for i in range(3)]
    keys = ["a1" * 16, "b2" * 16, "c3" * 16]
    for i, key in enumerate(keys):
        _rec(store, key, [ds[i], shared])
        t = time.time() - 1000 + i * 100
        os.utime(c / store.record_rel(key), (t, t))
    store.save_run("old", {"x": 1})
    store.save_run("new", {"y": 2})
    t = time.time() - 5000
    os.utime(c / "runs" / "old.json", (t, t))
    (c / "filememo.json").write_text("{}")
    (c / "tmp" / "partial").write_bytes(b"x" * 1234)
    size = lambda p: p.stat().st_size  # noqa: E731
    first = size(c / store.record_rel(keys[0])) + size(c / "objects" / ds[0][:2] / ds[0])
    budget = store.size() - 1234 - first  # room for all but the stale temp and the oldest entry
    info = store.gc(budget)
    assert info == {"removed_records": 1, "removed_objects": 1, "stale_files": 1, "stale_bytes": 1234,
                    "bytes": budget}
    assert {k for k, _, _ in store.records()} == set(keys[1:]) and (c / "objects" / shared[:2] / shared).exists()
    notes = size(c / "runs" / "old.json") + size(c / "runs" / "new.json") + size(c / "filememo.json")
    info = store.gc(notes - 1)  # no entry left, then the oldest run note, then the memo
    assert info["removed_records"] == 2 and info["removed_objects"] == 3
    assert not (c / "runs" / "old.json").exists() and (c / "runs" / "new.json").exists()
    assert (c / "filememo.json").exists()
    assert info["bytes"] == size(c / "runs" / "new.json") + size(c / "filememo.json")
    info = store.gc(0)
    assert store.size() == 0 and info["bytes"] == 0 and not (c / "filememo.json").exists()


def test_the_kept_json_encoder_writes_what_json_writes():
    """Records and object headers go through store.codec.json_encode (json's C encoder, kept between
    calls); its text must be json.dumps(sort_keys=True, separators=(",", ":")) exactly."""
    from graphkit.store import codec as store_mod

    cases = [{"key": "ab" * 16, "node": "n", "outputs": {"out": {"digest": "cd" * 16, "type": "Array"}},
              "parts": {"params": {"é": [1, 2.5, None, True, float("nan"), float("-inf"), 10**30, "q\"\\\n"]},
                        "inputs": {"b": ["x", "y"], "a": "z"}}, "seconds": 1e-06},
             {"z": {}, "a": [], "m": {"k": [{"y": 1, "b": 2}]}}, [], "s", 0.1]
    fresh = store_mod._kept_encoder()  # (the module's own one is made at import, outside any test)
    assert fresh != store_mod._JSON.encode  # CPython: the kept C encoder, not the fallback (bound methods: ==)
    with pytest.raises(TypeError):  # keys json cannot write are refused, not skipped
        fresh({(1, 2): 3})
    for c in cases:
        want = json.dumps(c, sort_keys=True, separators=(",", ":"))
        assert store_mod.json_encode(c) == want and fresh(c) == want


def test_objects_are_known_present_only_inside_the_run_lock(tmp_path):
    """Outside a run lock (gc may run between two calls) put_value looks for the object every
    time, and neither a write nor a read makes it known present."""
    s = Store(tmp_path / "c").open()
    value = np.full(3, 2.0)
    vp = value_parts(ARRAY, value)
    d = s.put_value(ARRAY, value, vp)
    s.load_value(d, ARRAY)
    assert not s._present
    obj = tmp_path / "c" / "objects" / d[:2] / d
    obj.unlink()  # e.g. `cache gc` between two calls
    s.put_value(ARRAY, value, vp)
    assert obj.is_file()


def test_verify_follows_a_chain_of_damage_in_linear_work(store, tmp_path, monkeypatch):
    """A chain of 300 records computed one from the next, its first value damaged: every record
    is dropped, and each is looked at a bounded number of times (not once per link)."""
    import graphkit.store.maintenance as st

    prev, n = None, 300
    for i in range(n):
        d = store.put_value(ARRAY, np.array([float(i)]))
        if i == 0:
            first = d
        k = f"{i:032x}"
        store.put_record(k, {"key": k, "node": f"n{i}", "outputs": {"out": {"digest": d, "type": "Array"}},
                             "parts": {"inputs": {"a": prev} if prev else {}}})
        prev = d
    p = tmp_path / "c" / "objects" / first[:2] / first
    p.write_bytes(p.read_bytes()[:-1] + b"X")
    calls = []
    real = st.record_inputs
    monkeypatch.setattr(st, "record_inputs", lambda rec: calls.append(1) or real(rec))
    problems = store.verify()
    assert len([x for x in problems if x.startswith("record")]) == n
    assert len(calls) <= 3 * n, len(calls)
