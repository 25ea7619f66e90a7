"""gc and runs (issue 10): runs hold the store lock until their outputs are exported, on every
executor, so a concurrent gc waits instead of breaking them; gc and verify --repair remove
temp and lock leftovers; sizes are true (tmp included, a shared object once) and in one unit
(MiB = 2^20 bytes, also for --max-size).  Each test fails on the store before issue 10."""
import re
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from conftest import engine_env, graphkit
from graphkit import run_graph
from graphkit.store import Store

G = """\
graphkit: 1
name: gcrun
params: {v: 1.0}
nodes:
  a: {type: Const, params: {value: "${params.v}", size: 20000}}
  b: {type: Add, inputs: {a: a.out}, params: {offset: 1}}
outputs: {a: a.out, b: b.out}
"""


def _gc_during_export(monkeypatch, cache):
    """Between the last node and the export, start `gc --max-size 0` and give it 1 s."""
    import graphkit.api as api

    real, real_export = api.record_last_run, api.export_outputs
    done, at_export = [], []

    def hook(session, result):
        t = threading.Thread(target=lambda: done.append(Store(cache).open().gc(0)))
        t.start()
        t.join(1.0)
        real(session, result)

    def export(*a, **kw):
        files = real_export(*a, **kw)
        at_export.append(len(done))  # had gc run by the time the outputs were written?
        return files

    monkeypatch.setattr(api, "record_last_run", hook)
    monkeypatch.setattr(api, "export_outputs", export)
    return done, at_export


@pytest.mark.parametrize("executor", ["local", "dask"])
def test_gc_waits_for_a_run_to_export(tmp_path, write, engine_registry, monkeypatch, executor):
    g, cache = write("g.yaml", G), tmp_path / "c"
    run_graph(g, cache=cache, registry=engine_registry)  # cached: the next run loads from the store
    done, at_export = _gc_during_export(monkeypatch, cache)
    kw = {"jobs": 1} if executor == "local" else {"executor": "dask", "jobs": 1}
    if executor == "dask":
        pytest.importorskip("distributed", reason="the Dask executor needs distributed")
        for k, v in engine_env().items():  # the workers find the test nodes as the CLI does
            if k in ("PYTHONPATH", "GRAPHKIT_PLUGINS"):
                monkeypatch.setenv(k, v)
    r = run_graph(g, cache=cache, out=tmp_path / "o", registry=engine_registry, **kw)
    assert r.computed == []
    np.testing.assert_array_equal(np.load(tmp_path / "o" / "b.npy"), np.full(20000, 2.0))
    assert at_export == [0]  # gc was still waiting while the run exported
    for _ in range(100):
        if done:
            break
        time.sleep(0.05)
    assert done and done[0]["removed_records"] == 2, done  # and ran once the run was over


def test_gc_in_a_loop_never_fails_a_run(tmp_path, write, engine_registry):
    g, cache = write("g.yaml", G), tmp_path / "c"
    Store(cache).open()
    loop = subprocess.Popen([sys.executable, "-c", f"""
import time
from graphkit.store import Store
s = Store({str(cache)!r}).open()
t = time.time()
while time.time() - t < 60:
    s.gc(0)
"""], env=engine_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        for i in range(30):
            r = run_graph(g, cache=cache, out=tmp_path / "o", overrides={"v": float(i % 3)},
                          registry=engine_registry, jobs=1 + i % 2)
            np.testing.assert_array_equal(np.load(tmp_path / "o" / "b.npy"), np.full(20000, i % 3 + 1.0))
            assert r.result.outcomes
        assert loop.poll() is None, loop.stderr.read()
    finally:
        loop.kill()
        loop.wait()


def _plant_leftovers(cache):
    (cache / "tmp" / "0123456789ab-999-1-1").write_bytes(b"\0" * (3 << 20))  # a killed writer's partial
    (cache / "locks" / "ab").mkdir(parents=True)
    (cache / "locks" / "ab" / ("ab" * 16 + ".lock")).write_bytes(b"")  # a lock file of the old layout
    (cache / "filememo.json.1234.5678.tmp").write_text("{}")


def test_gc_and_verify_repair_clean_tmp_and_locks(tmp_path, write, engine_registry):
    g, cache = write("g.yaml", G), tmp_path / "c"
    run_graph(g, cache=cache, registry=engine_registry)
    _plant_leftovers(cache)
    s = Store(cache).open()
    assert s.size() >= 3 << 20  # tmp counts: gc's total is what the folder holds
    v = graphkit("cache", "verify", "--repair", "--cache", cache)
    assert v.returncode == 0, v.stdout
    assert list((cache / "tmp").iterdir()) == [] and not list((cache / "locks").rglob("*.lock"))
    assert not list(cache.glob("filememo.json.*.tmp"))
    assert run_graph(g, cache=cache, registry=engine_registry).computed == []  # entries kept
    _plant_leftovers(cache)
    r = graphkit("cache", "gc", "--max-size", "0", "--cache", cache)
    assert r.returncode == 0, r.stderr
    assert list((cache / "tmp").iterdir()) == [] and not list((cache / "locks").rglob("*.lock"))
    assert s.size() == 0 and "0.000 MiB left" in r.stdout, r.stdout


TWIN = """\
graphkit: 1
name: twin
nodes:
  a: {type: Const, params: {value: 2, size: 131072}}
  b: {type: Const, params: {value: 2, size: 131072, label: same bytes}}
outputs: {a: a.out, b: b.out}
"""


def test_ls_counts_a_shared_object_once_in_mib(tmp_path, write, engine_registry):
    g, cache = write("g.yaml", TWIN), tmp_path / "c"
    run_graph(g, cache=cache, registry=engine_registry)
    objects = sum(p.stat().st_size for p in (cache / "objects").rglob("*") if p.is_file())
    assert len([p for p in (cache / "objects").rglob("*") if p.is_file()]) == 1  # one object, two records
    everything = sum(p.stat().st_size for p in cache.rglob("*") if p.is_file())
    r = graphkit("cache", "ls", "--cache", cache)
    assert r.returncode == 0, r.stderr
    total = re.search(r"2 entries, ([\d.]+) MiB", r.stdout)
    assert total, r.stdout
    assert abs(float(total.group(1)) - everything / 2**20) < 0.002, (total.group(0), everything, objects)
    assert "MB" not in r.stdout.replace("MiB", "")


def test_max_size_is_binary_like_the_totals(tmp_path, write, engine_registry):
    cache = tmp_path / "c"
    for v in range(4):  # 4 entries of ~1 MiB each
        run_graph(write(f"g{v}.yaml", f"graphkit: 1\nnodes:\n  a: {{type: Const, params: {{value: {v}, size: 131072}}}}\n"
                        "outputs: {a: a.out}\n"), cache=cache, registry=engine_registry)
    r = graphkit("cache", "gc", "--max-size", "2M", "--cache", cache)
    assert r.returncode == 0, r.stderr
    left = Store(cache).open().size()
    assert 1 << 20 < left <= 2 << 20, left  # 2M = 2 MiB: two entries fit, not 2e6 bytes' worth
    r = graphkit("cache", "gc", "--max-size", "2MB", "--cache", cache)
    assert r.returncode == 2 and "binary" in r.stderr
