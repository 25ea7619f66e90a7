"""The cache store: fsspec URLs, gc by size, verify finds corruption, ls."""
import numpy as np

from conftest import graphkit
from graphkit import run_graph
from graphkit.store import Store
from graphkit.types import IMAGE, Image

G = """\
graphkit: 1
nodes:
  a: {type: Const, params: {value: 2, size: 1000}}
  b: {type: Add, inputs: {a: a.out}, params: {offset: 1}}
outputs: [b.out]
"""


def test_memory_url_store(write, engine_registry):
    import uuid

    g = write("g.yaml", G)
    url = f"memory://gk-test-store-{uuid.uuid4().hex}"  # memory:// lives as long as the process
    r1 = run_graph(g, cache=url, registry=engine_registry)
    r2 = run_graph(g, cache=url, registry=engine_registry)
    assert sorted(r1.computed) == ["a", "b"] and r2.computed == []
    np.testing.assert_array_equal(r2.value("b.out"), np.full(1000, 3.0))


def test_file_url_store_through_cli(tmp_path, write):
    g = write("g.yaml", G)
    url = f"file://{tmp_path}/urlcache"
    r = graphkit("run", g, "--cache", url, "--out", tmp_path / "o")
    assert r.returncode == 0, r.stderr
    r = graphkit("run", g, "--cache", url, "--out", tmp_path / "o")
    assert "0 computed, 2 cached" in r.stderr
    assert (tmp_path / "urlcache" / "keys").is_dir()


def test_values_round_trip_and_are_read_only(tmp_path):
    s = Store(tmp_path / "c").open()
    px = np.random.default_rng(0).random((5, 7, 3), dtype=np.float32)
    d = s.put_value(IMAGE, Image(px, "lin_srgb"))
    back = s.load_value(d, IMAGE)
    assert back.colorspace == "lin_srgb" and back.pixels.dtype == np.float32
    np.testing.assert_array_equal(back.pixels, px)
    assert not back.pixels.flags.writeable


def test_verify_finds_corruption_and_repairs(tmp_path, write, engine_registry):
    g = write("g.yaml", G)
    run_graph(g, cache=tmp_path / "c", registry=engine_registry)
    s = Store(tmp_path / "c").open()
    assert s.verify() == []
    obj = next((tmp_path / "c" / "objects").rglob("*"))
    while obj.is_dir():
        obj = next(obj.iterdir())
    data = bytearray(obj.read_bytes())
    data[-1] ^= 0xFF
    obj.write_bytes(bytes(data))
    problems = s.verify()
    assert any("does not match its digest" in p for p in problems)
    assert any("object missing or corrupt" in p for p in problems)
    s.verify(repair=True)
    assert s.verify() == []
    r = run_graph(g, cache=tmp_path / "c", registry=engine_registry)
    assert r.computed  # the damaged entry was recomputed
    np.testing.assert_array_equal(r.value("b.out"), np.full(1000, 3.0))


def test_gc_to_size(tmp_path, write, engine_registry):
    for v in range(5):
        g = write(f"g{v}.yaml", G.replace("value: 2", f"value: {v + 10}"))
        run_graph(g, cache=tmp_path / "c", registry=engine_registry)
    s = Store(tmp_path / "c").open()
    before = s.size()
    info = s.gc(before // 2)
    assert info["bytes"] <= before // 2 and info["removed_records"] > 0
    assert s.verify() == []
    r = graphkit("cache", "gc", "--max-size", "0", "--cache", tmp_path / "c")
    assert r.returncode == 0 and "removed" in r.stdout
    assert s.size() == 0
    r = graphkit("cache", "ls", "--cache", tmp_path / "c")
    assert "0 entries" in r.stdout


def test_cache_hits_mark_records_used_for_gc(tmp_path, write, engine_registry):
    """A hit re-marks a record as used (gc drops least-recently-used first), but not one marked
    within Store.TOUCH_GRANULARITY_S: a warm re-run writes nothing."""
    import os

    old, new = write("old.yaml", G), write("new.yaml", G.replace("value: 2", "value: 3"))
    run_graph(old, cache=tmp_path / "c", registry=engine_registry)
    run_graph(new, cache=tmp_path / "c", registry=engine_registry)
    s = Store(tmp_path / "c").open()
    keys = {k: m for k, _, m in s.records()}
    assert len(keys) == 4
    day = 86400
    for k in keys:  # everything last used a day ago
        p = tmp_path / "c" / s.record_rel(k)
        os.utime(p, (os.stat(p).st_atime, os.stat(p).st_mtime - day))
    r = run_graph(old, cache=tmp_path / "c", registry=engine_registry)
    assert r.computed == []
    used = {k: m for k, _, m in s.records()}
    recent = [k for k, m in used.items() if m > keys[k] - day + s.TOUCH_GRANULARITY_S]
    assert len(recent) == 2  # the old graph's a and b, re-marked by the hits
    stamp = {k: os.stat(tmp_path / "c" / s.record_rel(k)).st_mtime_ns for k in recent}
    run_graph(old, cache=tmp_path / "c", registry=engine_registry)
    assert {k: os.stat(tmp_path / "c" / s.record_rel(k)).st_mtime_ns for k in recent} == stamp
    s.gc(s.size() - 1)  # the new graph's records are now the least recently used
    left = {k for k, _, _ in s.records()}
    assert set(recent) <= left
