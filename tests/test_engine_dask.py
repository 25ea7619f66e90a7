"""The same graph on a real Dask scheduler and workers (loopback) gives the same bytes."""
import json
import re

from conftest import graphkit

G = """\
graphkit: 1
name: dasky
nodes:
  a: {type: Slow, params: {seconds: 0.0, megabytes: 1, seed: 1}}
  b: {type: Slow, params: {seconds: 0.0, megabytes: 1, seed: 2}}
  c: {type: Add, inputs: {a: a.out, b: b.out}, params: {offset: 0.5}}
  s: {type: Sum, inputs: {xs: [a.out, c.out, b.out]}}
  photo: {type: LoadImage, params: {path: "builtin:astronaut"}}
  r: {type: RatioImage, inputs: {a: photo.image, b: photo.image}}
  save: {type: SaveImage, inputs: {image: r.ratio}, params: {path: r.exr}}
outputs: {s: s.out, img: save.file}
"""


def test_dask_matches_local(tmp_path, write):
    g = write("g.yaml", G)
    r = graphkit("run", g, "--executor", "dask", "--jobs", "2", "--cache", tmp_path / "dc", "--out", tmp_path / "d",
                 timeout=180)
    assert r.returncode == 0, r.stderr
    assert "Warning" not in r.stderr and "distributed." not in r.stderr, r.stderr  # no Dask log lines
    r = graphkit("run", g, "--cache", tmp_path / "lc", "--out", tmp_path / "l")
    assert r.returncode == 0, r.stderr
    for f in ("s.npy", "r.exr"):
        assert (tmp_path / "d" / f).read_bytes() == (tmp_path / "l" / f).read_bytes(), f
    md = json.loads((tmp_path / "d" / "manifest.json").read_text())
    ml = json.loads((tmp_path / "l" / "manifest.json").read_text())
    assert md["executor"] == "dask" and ml["executor"] == "local"
    assert {n: v["key"] for n, v in md["nodes"].items()} == {n: v["key"] for n, v in ml["nodes"].items()}
    # a second Dask run finds everything in the cache the workers wrote
    r = graphkit("run", g, "--executor", "dask", "--jobs", "2", "--cache", tmp_path / "dc", "--out", tmp_path / "d2",
                 timeout=180)
    assert r.returncode == 0 and "0 computed, 7 cached" in r.stderr, r.stderr


def test_dask_reports_node_failures(tmp_path, write):
    g = write("g.yaml", "graphkit: 1\nnodes:\n  c: {type: Const}\n  f: {type: Fail, inputs: {x: c.out}}\n")
    r = graphkit("run", g, "--executor", "dask", "--jobs", "1", "--cache", tmp_path / "c", "--out", tmp_path / "o",
                 timeout=180)
    assert r.returncode == 1, r.stderr
    assert "node 'f' (Fail) failed: ZeroDivisionError: boom" in r.stderr and "Traceback" not in r.stderr


# --------------------------------------------------------------------------------------------
# scale-out: a sweep on a real LocalCluster of worker processes (loopback), two clients at once

import os  # noqa: E402
import socket  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from conftest import SUPPORT, engine_env  # noqa: E402
from graphkit import run_graph  # noqa: E402
from graphkit.executor import Progress  # noqa: E402
from graphkit.errors import UsageError  # noqa: E402

PLUGINS = "enginenodes,sweepnodes"


@pytest.fixture(scope="module")
def cluster():
    """2 worker processes (1 thread each) on 127.0.0.1; a task may kill 1 worker and be retried,
    a second death is a KilledWorker."""
    import dask
    from distributed import LocalCluster

    env = {"PYTHONPATH": os.pathsep.join([str(SUPPORT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep),
           "GRAPHKIT_PLUGINS": PLUGINS}
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)  # the worker processes inherit these
    import logging

    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        c = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                         dashboard_address="127.0.0.1:0", worker_dashboard_address="127.0.0.1:0", silence_logs=logging.CRITICAL)
    try:
        yield c
    finally:
        c.close()
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@pytest.fixture
def reg(engine_registry):
    import sweepnodes

    engine_registry.add_provider("nodes", "tests", sweepnodes)
    return engine_registry


def wait_workers(cluster, n=2):
    from distributed import Client

    with Client(cluster.scheduler_address, set_as_default=False) as c:
        c.wait_for_workers(n, timeout=60)


def sweep_graph(log, n=12, seconds=0.15):
    return {"graphkit": 1, "name": "scale", "sweeps": {"i": {"range": {"stop": n}}},
            "nodes": {"c": {"type": "Count", "foreach": "i",
                            "params": {"log": str(log), "value": "${i.value}", "seconds": seconds}},
                      "total": {"type": "Sum", "inputs": {"xs": "c[*].out"}},
                      "order": {"type": "Stack", "inputs": {"xs": "c[*].out"}}},
            "outputs": {"total": "total.out", "order": "order.out", "each": "c.out"}}


def test_sweep_on_a_local_cluster_with_two_clients_computes_each_key_once(tmp_path, cluster, reg):
    wait_workers(cluster)
    log = tmp_path / "count.log"
    g = sweep_graph(log)
    cache = tmp_path / "shared-cache"
    runs, errors = {}, []

    def client(i):
        try:
            runs[i] = run_graph(g, cache=cache, out=tmp_path / f"out{i}", registry=reg, executor="dask",
                                scheduler=cluster.scheduler_address)
        except BaseException as e:  # noqa: BLE001
            errors.append(e)

    threads = [threading.Thread(target=client, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert not errors, errors
    lines = [line.split() for line in log.read_text().splitlines()]
    keys = [k for k, _, _ in lines]
    assert len(keys) == 12 and len(set(keys)) == 12, lines  # each key computed exactly once
    assert len({pid for _, _, pid in lines}) == 2, "both worker processes computed"
    assert str(os.getpid()) not in {pid for _, _, pid in lines}
    both = runs[0].computed + runs[1].computed
    assert sorted(n for n in both if n.startswith("c[")) == sorted(f"c[{i}]" for i in range(12))
    # the same bytes as the local executor
    local = run_graph(g, cache=tmp_path / "local-cache", out=tmp_path / "local", registry=reg, jobs=2)
    for i in range(2):
        assert {n: o.key for n, o in runs[i].result.outcomes.items()} == \
               {n: o.key for n, o in local.result.outcomes.items()}
        for f in ["total.npy", "order.npy"] + [f"each/{k}.npy" for k in range(12)]:
            assert (tmp_path / f"out{i}" / f).read_bytes() == (tmp_path / "local" / f).read_bytes(), f
    np.testing.assert_array_equal(local.value("total"), np.full(8, sum(range(12)), np.float64))
    np.testing.assert_array_equal(local.value("order"), np.repeat(np.arange(12.0), 8))


def test_a_killed_worker_s_task_is_retried(tmp_path, cluster, reg):
    wait_workers(cluster)
    g = {"graphkit": 1, "nodes": {"k": {"type": "KillWorker", "params": {"marker": str(tmp_path / "m"), "value": 3}},
                                  "s": {"type": "Sum", "inputs": {"xs": ["k.out"]}}}}
    notices = []

    class Notices(Progress):
        def notice(self, message):
            notices.append(message)

    r = run_graph(g, cache=tmp_path / "c", registry=reg, executor="dask", scheduler=cluster.scheduler_address,
                  progress=Notices())
    assert (tmp_path / "m").exists()  # the first attempt ran, and its worker died
    np.testing.assert_array_equal(r.value("s.out"), np.full(4, 3.0))
    lost = [m for m in notices if "left during the run" in m]  # said once, in graphkit's words, naming the node
    assert len(lost) == 1 and re.search(r"its tasks (.*, )?k(,| and| \()", lost[0]), notices


def test_a_task_that_keeps_killing_workers_is_a_node_failure(tmp_path, write, cluster):
    wait_workers(cluster)
    g = write("g.yaml", f"graphkit: 1\nnodes:\n  k: {{type: KillWorker, params: {{marker: {tmp_path / 'm'}, always: true}}}}\n")
    r = graphkit("run", g, "--executor", "dask", "--scheduler", cluster.scheduler_address, "--cache", tmp_path / "c",
                 "--out", tmp_path / "o", env=engine_env({"GRAPHKIT_PLUGINS": PLUGINS}), timeout=180)
    assert r.returncode == 1, r.stderr
    assert "node 'k' (KillWorker) failed: WorkerDied: the Dask worker running it died each time" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    assert not (tmp_path / "o").exists()


def test_a_node_type_missing_on_the_workers_is_exit_2(tmp_path, cluster, reg):
    wait_workers(cluster)
    (tmp_path / "onlyhere.py").write_text(
        "import numpy as np\nfrom graphkit import Node, Array\n"
        "class OnlyHere(Node):\n    outputs = {'out': Array}\n    def compute(self):\n        return np.zeros(2)\n")
    import sys

    sys.path.insert(0, str(tmp_path))
    try:
        import onlyhere

        reg.add_provider("nodes", "onlyhere", onlyhere)
        with pytest.raises(UsageError) as ei:
            run_graph({"graphkit": 1, "nodes": {"o": {"type": "OnlyHere"}}}, cache=tmp_path / "c", registry=reg,
                      executor="dask", scheduler=cluster.scheduler_address)
    finally:
        sys.path.remove(str(tmp_path))
    assert ei.value.exit_code == 2
    assert "the Dask workers cannot run this graph" in str(ei.value)
    assert "has no node type 'OnlyHere'" in str(ei.value)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_unreachable_or_malformed_scheduler_is_exit_2(tmp_path, write, engine_registry):
    g = write("g.yaml", "graphkit: 1\nnodes:\n  c: {type: Const}\n")
    addr = f"tcp://127.0.0.1:{free_port()}"
    t = time.monotonic()
    r = graphkit("run", g, "--executor", "dask", "--scheduler", addr, "--scheduler-timeout", "2",
                 "--cache", tmp_path / "c", "--out", tmp_path / "o", timeout=60)
    took = time.monotonic() - t
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith(f"graphkit: cannot reach the Dask scheduler at {addr} within 2 s"), r.stderr
    assert "Traceback" not in r.stderr and took < 2 + 40  # the timeout, plus start-up on a busy machine
    assert not (tmp_path / "o").exists()
    # something that is not a Dask scheduler answers at the address
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen()

    def answer():
        while True:
            try:
                c, _ = srv.accept()
            except OSError:
                return
            with c:
                c.sendall(b"HTTP/1.1 200 OK\r\n\r\nnot dask\n" * 20)

    threading.Thread(target=answer, daemon=True).start()
    try:
        with pytest.raises(UsageError, match="does not answer as a Dask scheduler") as ei:
            run_graph(g, cache=tmp_path / "c", executor="dask", scheduler=f"tcp://127.0.0.1:{srv.getsockname()[1]}",
                      scheduler_timeout=3, registry=engine_registry)
        assert ei.value.exit_code == 2
    finally:
        srv.close()
    for bad in ("tcp//host:1", "tcp://host:99999", "foo://x y"):
        with pytest.raises(UsageError, match="not a Dask scheduler address") as ei:
            run_graph(g, cache=tmp_path / "c", executor="dask", scheduler=bad, registry=engine_registry)
        assert ei.value.exit_code == 2
