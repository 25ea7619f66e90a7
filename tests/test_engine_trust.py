"""Integrity on read (issue 10): tampered objects, swapped or copied records, edited file memos
and inputs edited in place with size, inode and mtime restored are detected, quarantined,
recomputed and reported in one notice line; `verify --repair` drops what was derived from a
damaged entry.  Every test here fails on the store before issue 10 (it served the damage)."""
import json
import os

import numpy as np

from conftest import engine_env, graphkit

ENV = engine_env({"GRAPHKIT_PLUGINS": "enginenodes,storenodes"})

CHAIN = """\
graphkit: 1
name: trust
params: {off: 1.0}
nodes:
  a: {type: Const, params: {value: 2, size: 1000}}
  b: {type: Add, inputs: {a: a.out}, params: {offset: "${params.off}"}}
  c: {type: Add, inputs: {a: b.out}, params: {offset: 10}}
outputs: {total: c.out}
"""


def gk(*args):
    return graphkit(*args, env=ENV)


def manifest(out):
    return json.loads((out / "manifest.json").read_text())


def obj_path(cache, digest):
    return cache / "objects" / digest[:2] / digest


def rec_path(cache, key):
    return cache / "keys" / key[:2] / f"{key}.json"


def record_bytes(cache, key):
    """The record of ``key`` as a reader finds it: its own file, or its frame in the run's journal
    that its file is a hard link to (frames ``\\0GKJF <key> <length>\\n<record>``)."""
    raw = rec_path(cache, key).read_bytes()
    if not raw.startswith(b"GKJRN1 "):
        return raw
    head = b"\0GKJF " + key.encode() + b" "
    at = raw.rindex(head) + len(head)
    nl = raw.index(b"\n", at)
    return raw[nl + 1:nl + 1 + int(raw[at:nl])]


def replace_record(cache, key, data):
    """Put ``data`` where the record of ``key`` is (a file of its own, not into the journal)."""
    p = rec_path(cache, key)
    p.unlink()
    p.write_bytes(data)


def flip_bit(path, at=-100):
    data = bytearray(path.read_bytes())
    data[at] ^= 0x10
    path.write_bytes(bytes(data))


def run_ok(g, cache, out, *extra):
    r = gk("run", g, "--cache", cache, "--out", out, "--jobs", "1", *extra)
    assert r.returncode == 0, r.stderr
    return r


def test_bit_flip_in_an_object_is_caught_on_read(tmp_path, write):
    g, cache, out = write("g.yaml", CHAIN), tmp_path / "c", tmp_path / "o"
    run_ok(g, cache, out)
    d = manifest(out)["nodes"]["c"]["outputs"]["out"]
    flip_bit(obj_path(cache, d))
    r = run_ok(g, cache, out)
    np.testing.assert_array_equal(np.load(out / "total.npy"), np.full(1000, 13.0))  # not the flipped bytes
    notes = [ln for ln in r.stderr.splitlines() if d[:16] in ln]
    assert len(notes) == 1 and "does not match its digest" in notes[0] and "quarantine" in notes[0], r.stderr
    assert len(list((cache / "quarantine").iterdir())) == 1
    v = gk("cache", "verify", "--cache", cache)
    assert v.returncode == 0 and "0 problems" in v.stdout, v.stdout


def test_flipped_input_of_a_recomputed_node_is_recomputed_first(tmp_path, write):
    """b re-runs (new param) and reads a's stored value: the damage must not flow into b."""
    g, cache, out = write("g.yaml", CHAIN), tmp_path / "c", tmp_path / "o"
    run_ok(g, cache, out)
    flip_bit(obj_path(cache, manifest(out)["nodes"]["a"]["outputs"]["out"]))
    r = run_ok(g, cache, out, "--set", "off=5")
    np.testing.assert_array_equal(np.load(out / "total.npy"), np.full(1000, 17.0))
    assert "recomputing" in r.stderr, r.stderr
    assert manifest(out)["nodes"]["a"]["outputs"]["out"] == manifest(out)["nodes"]["a"]["outputs"]["out"]
    assert gk("cache", "verify", "--cache", cache).returncode == 0


TWO = """\
graphkit: 1
name: two
nodes:
  x: {type: Const, params: {value: 1, size: 64}}
  y: {type: Const, params: {value: 7, size: 64}}
outputs: {x: x.out, y: y.out}
"""


def test_record_pointed_at_another_valid_object_is_caught(tmp_path, write):
    g, cache, out = write("g.yaml", TWO), tmp_path / "c", tmp_path / "o"
    run_ok(g, cache, out)
    m = manifest(out)["nodes"]
    kx, dx, dy = m["x"]["key"], m["x"]["outputs"]["out"], m["y"]["outputs"]["out"]
    p = rec_path(cache, kx)
    p.write_bytes(p.read_bytes().replace(dx.encode(), dy.encode()))  # x's record now names y's object
    r = run_ok(g, cache, out)
    np.testing.assert_array_equal(np.load(out / "x.npy"), np.full(64, 1.0))
    assert any(kx[:16] in ln and "quarantine" in ln for ln in r.stderr.splitlines()), r.stderr
    assert manifest(out)["nodes"]["x"]["hit"] is False


def test_record_copied_under_another_key_is_caught(tmp_path, write):
    g, cache, out = write("g.yaml", TWO), tmp_path / "c", tmp_path / "o"
    run_ok(g, cache, out)
    m = manifest(out)["nodes"]
    replace_record(cache, m["x"]["key"], record_bytes(cache, m["y"]["key"]))
    r = run_ok(g, cache, out)
    np.testing.assert_array_equal(np.load(out / "x.npy"), np.full(64, 1.0))
    assert "notice:" in r.stderr


def test_record_rewritten_whole_for_another_key_is_caught(tmp_path, write):
    """Even with its key field and check line rewritten to match, a record of another
    computation (y's params and output) under x's key is not served: it must describe x."""
    import xxhash

    g, cache, out = write("g.yaml", TWO), tmp_path / "c", tmp_path / "o"
    run_ok(g, cache, out)
    m = manifest(out)["nodes"]
    kx, ky = m["x"]["key"], m["y"]["key"]
    raw = record_bytes(cache, ky)
    body = raw.split(b"\n", 1)[1] if raw.startswith(b"GKREC1 ") else raw
    rec = json.loads(body)
    rec["key"] = kx
    body = json.dumps(rec, sort_keys=True, separators=(",", ":")).encode()
    replace_record(cache, kx, b"GKREC1 " + xxhash.xxh3_128_hexdigest(body).encode() + b"\n" + body
                   if raw.startswith(b"GKREC1 ") else body)
    run_ok(g, cache, out)
    np.testing.assert_array_equal(np.load(out / "x.npy"), np.full(64, 1.0))
    assert manifest(out)["nodes"]["x"]["hit"] is False


READ = """\
graphkit: 1
name: read
nodes:
  r: {type: ReadBytes, params: {path: data.bin}}
outputs: {data: r.out}
"""


def test_input_edited_in_place_with_size_inode_and_mtime_restored(tmp_path, write):
    g, cache, out = write("g.yaml", READ), tmp_path / "c", tmp_path / "o"
    f = tmp_path / "data.bin"
    f.write_bytes(b"A" * 64)
    run_ok(g, cache, out)
    st = os.stat(f)
    with open(f, "r+b") as fh:  # same inode, same size
        fh.write(b"B" * 64)
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns))  # mtime restored (as `touch -r` does)
    st2 = os.stat(f)
    assert (st2.st_ino, st2.st_size, st2.st_mtime_ns) == (st.st_ino, st.st_size, st.st_mtime_ns)
    run_ok(g, cache, out)
    np.testing.assert_array_equal(np.load(out / "data.npy"), np.frombuffer(b"B" * 64, np.uint8))


def test_edited_file_memo_entry_is_not_trusted(tmp_path, write):
    """A memo entry whose digest was edited (here: put back to the file's old digest) must not
    turn the new content into a stale hit of the old one."""
    g, cache, out = write("g.yaml", READ), tmp_path / "c", tmp_path / "o"
    f = tmp_path / "data.bin"
    f.write_bytes(b"A" * 64)
    run_ok(g, cache, out)
    memo = cache / "filememo.json"
    old = json.loads(memo.read_text())[str(f)]
    f.write_bytes(b"C" * 80)
    run_ok(g, cache, out)
    data = json.loads(memo.read_text())
    data[str(f)][1] = old[1]  # the digest field: the old content's digest, with the new stat
    memo.write_text(json.dumps(data))
    run_ok(g, cache, out)
    np.testing.assert_array_equal(np.load(out / "data.npy"), np.frombuffer(b"C" * 80, np.uint8))


def test_verify_repair_drops_entries_derived_from_a_damaged_one(tmp_path, write):
    g, cache, out = write("g.yaml", CHAIN), tmp_path / "c", tmp_path / "o"
    run_ok(g, cache, out)
    m = manifest(out)["nodes"]
    flip_bit(obj_path(cache, m["a"]["outputs"]["out"]))
    before = {p.read_bytes() for p in (cache / "keys").rglob("*.json")}
    v = gk("cache", "verify", "--cache", cache)  # report only: changes nothing
    assert v.returncode == 1 and "does not match its digest" in v.stdout, v.stdout
    assert {p.read_bytes() for p in (cache / "keys").rglob("*.json")} == before
    v = gk("cache", "verify", "--repair", "--cache", cache)
    assert v.returncode == 0, v.stdout
    for n in ("a", "b", "c"):  # b was computed from a's value, c from b's: all three go
        assert not rec_path(cache, m[n]["key"]).exists(), (n, v.stdout)
    assert gk("cache", "verify", "--cache", cache).returncode == 0
    run_ok(g, cache, out)
    assert not any(v["hit"] for v in manifest(out)["nodes"].values())
    np.testing.assert_array_equal(np.load(out / "total.npy"), np.full(1000, 13.0))


def test_load_value_checks_the_digest(tmp_path):
    """In-process API: a damaged object raises a CacheError (never returns the bytes)."""
    import pytest

    from graphkit.errors import CacheError
    from graphkit.store import Store
    from graphkit.types import ARRAY

    s = Store(tmp_path / "c").open()
    d = s.put_value(ARRAY, np.arange(1000.0))
    flip_bit(obj_path(tmp_path / "c", d))
    with pytest.raises(CacheError):
        s.load_value(d, ARRAY)
