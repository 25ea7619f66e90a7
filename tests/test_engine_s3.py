"""The cache on a real S3 server (issue 29): moto's server on loopback, reached through s3fs as a
user would (``--cache s3://bucket/prefix``, the endpoint in FSSPEC_S3_ENDPOINT_URL).  The same
bytes as a folder, warm runs all cached, damage detected, bad input refused with exit 2, and
concurrent clients with `cache gc` looping beside them computing each key once."""
import contextlib
import json
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import xxhash

from conftest import engine_env, graphkit
from s3server import S3Server
from test_engine_trust import TWO

ROOT = Path(__file__).resolve().parents[1]
QUICKSTART = ROOT / "graphs" / "quickstart.yaml"



@pytest.fixture(scope="module")
def s3():
    with S3Server() as server:
        yield server


@pytest.fixture
def url(s3, request):
    """A fresh prefix of the test bucket per test."""
    return f"s3://{s3.bucket}/{request.node.name.replace('[', '-').rstrip(']')}"


def env_for(s3, **extra):
    return engine_env({"GRAPHKIT_PLUGINS": "enginenodes,storenodes,sweepnodes", **s3.env, **extra})


def gk(s3, *args, **kw):
    return graphkit(*args, env=env_for(s3), **kw)


def run_ok(s3, g, cache, out, *extra):
    r = gk(s3, "run", g, "--cache", cache, "--out", out, *extra)
    assert r.returncode == 0, r.stderr
    return json.loads((Path(out) / "manifest.json").read_text())


def files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.suffix in (".exr", ".png", ".npy")}


def test_quickstart_cold_warm_same_bytes_as_a_folder(s3, url, tmp_path):
    cold = run_ok(s3, QUICKSTART, url, tmp_path / "o1", "--jobs", "2")
    assert not any(n["hit"] for n in cold["nodes"].values())
    warm = run_ok(s3, QUICKSTART, url, tmp_path / "o2", "--jobs", "2")
    assert all(n["hit"] for n in warm["nodes"].values())
    local = run_ok(s3, QUICKSTART, tmp_path / "folder-cache", tmp_path / "o3", "--jobs", "2")
    assert {k: n["key"] for k, n in local["nodes"].items()} == {k: n["key"] for k, n in cold["nodes"].items()}
    assert files(tmp_path / "o1") == files(tmp_path / "o2") == files(tmp_path / "o3") != {}
    ls = gk(s3, "cache", "ls", "--cache", url)
    assert ls.returncode == 0 and f"in {url}" in ls.stdout and "smooth" in ls.stdout, ls.stdout + ls.stderr
    v = gk(s3, "cache", "verify", "--cache", url)
    assert v.returncode == 0 and "0 problems" in v.stdout, v.stdout + v.stderr
    e = gk(s3, "explain", QUICKSTART, "smooth", "--cache", url, "--set", "sigma=3")
    assert e.returncode == 0 and "sigma" in e.stdout, e.stdout + e.stderr
    gc = gk(s3, "cache", "gc", "--cache", url, "--max-size", "0")
    assert gc.returncode == 0, gc.stderr
    assert not any(k.startswith(url.split("/", 3)[3] + "/keys/") for k in s3.keys()), "gc left records"


def test_flipped_byte_and_swapped_record_are_detected(s3, url, tmp_path, write):
    g = write("g.yaml", TWO)
    m = run_ok(s3, g, url, tmp_path / "o")["nodes"]
    prefix = url.split("/", 3)[3]
    dx, kx, ky = m["x"]["outputs"]["out"], m["x"]["key"], m["y"]["key"]
    objects = s3.keys(f"{prefix}/objects/")
    okey = f"{prefix}/objects/{dx[:2]}/{dx}"
    data = bytearray(objects[okey])
    data[-5] ^= 0x10
    s3.put(okey, bytes(data))
    r = gk(s3, "run", g, "--cache", url, "--out", tmp_path / "o")
    assert r.returncode == 0 and dx[:16] in r.stderr and "quarantine" in r.stderr, r.stderr
    np.testing.assert_array_equal(np.load(tmp_path / "o" / "x.npy"), np.full(64, 1.0))
    records = s3.keys(f"{prefix}/keys/")
    s3.put(f"{prefix}/keys/{kx[:2]}/{kx}.json", records[f"{prefix}/keys/{ky[:2]}/{ky}.json"])
    assert gk(s3, "cache", "verify", "--cache", url).returncode == 1
    r = gk(s3, "run", g, "--cache", url, "--out", tmp_path / "o")
    assert r.returncode == 0 and kx[:16] in r.stderr, r.stderr
    np.testing.assert_array_equal(np.load(tmp_path / "o" / "x.npy"), np.full(64, 1.0))
    assert gk(s3, "cache", "verify", "--cache", url).returncode == 0


@pytest.mark.parametrize("digest", ["../../other/notes.txt", "", "/x"])
def test_a_forged_output_digest_is_damage_on_s3(s3, url, tmp_path, write, digest):
    g = write("g.yaml", TWO)
    m = run_ok(s3, g, url, tmp_path / "o")["nodes"]
    prefix, kx = url.split("/", 3)[3], m["x"]["key"]
    s3.put("other/notes.txt", b"not the cache's")
    rk = f"{prefix}/keys/{kx[:2]}/{kx}.json"
    rec = json.loads(s3.keys(rk)[rk].split(b"\n", 1)[1])
    rec["outputs"]["out"]["digest"] = digest
    body = json.dumps(rec, sort_keys=True, separators=(",", ":")).encode()
    s3.put(rk, b"GKREC1 " + xxhash.xxh3_128_hexdigest(body).encode() + b"\n" + body)
    r = gk(s3, "run", g, "--cache", url, "--out", tmp_path / "o")
    assert r.returncode == 0 and "not one" in r.stderr, r.stderr
    # the key's lease, left finished by the first run (gone), is not waited for
    assert "waits for lease" not in r.stderr, r.stderr
    assert gk(s3, "cache", "gc", "--cache", url, "--max-size", "0").returncode == 0
    assert s3.keys("other/") == {"other/notes.txt": b"not the cache's"}


def test_a_missing_bucket_is_never_created_implicitly(s3, tmp_path, write):
    g = write("g.yaml", TWO)
    url = "s3://no-such-bucket/cache"
    for args in (("run", g, "--out", tmp_path / "o"), ("cache", "ls"), ("cache", "verify"),
                 ("cache", "gc", "--max-size", "1G")):
        r = gk(s3, *args, "--cache", url)
        assert r.returncode == 2, (args, r.stderr)
        assert r.stderr.count("\n") == 1 and url in r.stderr and f"graphkit cache init {url}" in r.stderr, r.stderr
        assert "no-such-bucket" not in s3.buckets()
    assert "would run" in gk(s3, "status", g, "--cache", url).stdout  # (a dry run reads only)
    assert "no-such-bucket" not in s3.buckets()
    r = gk(s3, "cache", "init", url)
    assert r.returncode == 0 and "created bucket no-such-bucket" in r.stdout, r.stdout + r.stderr
    assert "no-such-bucket" in s3.buckets()
    assert gk(s3, "cache", "init", url).returncode == 0  # again: nothing to do
    run_ok(s3, g, url, tmp_path / "o")


def test_an_unreachable_server_is_exit_2_within_10_s(s3, tmp_path, write):
    from s3server import free_port

    g = write("g.yaml", TWO)
    env = env_for(s3, FSSPEC_S3_ENDPOINT_URL=f"http://127.0.0.1:{free_port()}")
    for args in (("run", g, "--out", tmp_path / "o"), ("cache", "ls")):
        t = time.monotonic()
        r = graphkit(*args, "--cache", "s3://gk-test/x", env=env)
        assert time.monotonic() - t < 10
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
        assert "s3://gk-test/x" in r.stderr and "FSSPEC_S3_ENDPOINT_URL" in r.stderr and "Traceback" not in r.stderr


def test_out_inside_the_cache_folder_is_refused(tmp_path, write):
    g, cache = write("g.yaml", TWO), tmp_path / "c"
    env = engine_env({"GRAPHKIT_PLUGINS": "enginenodes,storenodes"})
    assert graphkit("run", g, "--cache", cache, "--out", tmp_path / "o", env=env).returncode == 0
    before = sorted(p.relative_to(cache) for p in cache.rglob("*"))
    for out in (cache, cache / "sub", f"{cache}/objects/../x"):
        r = graphkit("run", g, "--cache", cache, "--out", out, env=env)
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
        assert str(cache) in r.stderr and "--out" in r.stderr and "outside" in r.stderr, r.stderr
    r = graphkit("run", g, "--cache", f"file://{cache}", "--out", cache / "x", env=env)
    assert r.returncode == 2, r.stderr
    assert sorted(p.relative_to(cache) for p in cache.rglob("*")) == before
    assert graphkit("cache", "verify", "--cache", cache, env=env).returncode == 0


@contextlib.contextmanager
def looping_gc(url, env):
    """`cache gc` run over and over on the cache while the block runs; yields the list of their
    results (all must have succeeded: asserted by the caller after the block)."""
    stop, gcs = threading.Event(), []

    def gc_loop():
        while not stop.is_set():
            gcs.append(graphkit("cache", "gc", "--cache", url, "--max-size", "10G", env=env))

    looper = threading.Thread(target=gc_loop)
    looper.start()
    try:
        yield gcs
    finally:
        stop.set()
        looper.join()


SWEEP = """\
graphkit: 1
name: shared
sweeps:
  i: {{range: {{stop: 8}}}}
nodes:
  c: {{type: Count, foreach: i, params: {{log: {log}, value: "${{i.value}}", seconds: 0.3}}}}
  d: {{type: Count, foreach: i, inputs: {{x: c.out}}, params: {{log: {log}, value: 1, seconds: 0.2}}}}
  s: {{type: Sum, inputs: {{xs: "d[*].out"}}}}
outputs: {{s: s.out}}
"""


def test_concurrent_clients_and_a_looping_gc_compute_each_key_once(s3, url, tmp_path):
    log = tmp_path / "count.log"
    g = tmp_path / "g.yaml"
    g.write_text(SWEEP.format(log=log))
    env = env_for(s3)
    with looping_gc(url, env) as gcs:
        procs = [subprocess.Popen([sys.executable, "-m", "graphkit", "run", str(g), "--cache", url, "--out",
                                   str(tmp_path / f"o{i}"), "--jobs", "2", "-q"], env=env,
                                  stderr=subprocess.PIPE, text=True) for i in range(2)]
        errs = [p.communicate(timeout=240)[1] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], errs
    assert all("Traceback" not in e for e in errs), errs
    keys = [line.split()[0] for line in log.read_text().splitlines()]
    assert len(keys) == 16 and len(set(keys)) == 16, sorted(keys)  # each key computed exactly once
    assert len({(tmp_path / f"o{i}" / "s.npy").read_bytes() for i in range(2)}) == 1
    assert gcs and all(r.returncode == 0 for r in gcs), [r.stderr for r in gcs if r.returncode]
    warm = run_ok(s3, g, url, tmp_path / "o3", "--jobs", "2")
    assert all(n["hit"] for n in warm["nodes"].values())  # nothing lost
    v = gk(s3, "cache", "verify", "--cache", url)
    assert v.returncode == 0, v.stdout + v.stderr


TWINS = """\
graphkit: 1
name: twins
nodes:
  a: {{type: Count, params: {{log: {log}, value: 1, seconds: 0.5}}}}
  b: {{type: Count, params: {{log: {log}, value: 1, seconds: 0.5}}}}
outputs: {{a: a.out, b: b.out}}
"""


def test_two_nodes_of_one_key_in_one_run_compute_it_once(s3, url, tmp_path):
    """Two nodes with the same key run side by side in threads of one process (--jobs 2): the
    second waits for the first's thread, then looks again and finds its record (its lease alone
    would not say it waited: the first let go of it before the second asked)."""
    log = tmp_path / "count.log"
    g = tmp_path / "g.yaml"
    g.write_text(TWINS.format(log=log))
    m = run_ok(s3, g, url, tmp_path / "o", "--jobs", "2")
    assert m["nodes"]["a"]["key"] == m["nodes"]["b"]["key"]
    assert len(log.read_text().splitlines()) == 1, log.read_text()
    assert sorted(n["hit"] for n in m["nodes"].values()) == [False, True]


def s3fs_for(s3):
    import s3fs

    return s3fs.S3FileSystem(endpoint_url=s3.endpoint, key="testing", secret="testing")


def test_a_dead_owners_lease_costs_seconds_and_the_wait_is_said_once(s3, url, tmp_path, write):
    """A lease left by a killed run (its expiry a full ttl ahead, never renewed) is broken after
    the ttl (10 s by default); the waiting run names the node and the lease once."""
    g = write("g.yaml", TWO)
    m = run_ok(s3, g, url, tmp_path / "o")["nodes"]
    assert gk(s3, "cache", "gc", "--cache", url, "--max-size", "0").returncode == 0
    kx = m["x"]["key"]
    lease = f"{url.split('/', 2)[2]}/locks/{kx[:2]}/{kx}.lock"
    s3.put(lease.split("/", 1)[1], json.dumps({"token": "dead", "host": "gone", "pid": 4242,
                                               "expires": time.time() + 10}).encode())
    t = time.monotonic()
    r = gk(s3, "run", g, "--cache", url, "--out", tmp_path / "o")
    took = time.monotonic() - t
    assert r.returncode == 0, r.stderr
    said = [ln for ln in r.stderr.splitlines() if "waits for lease" in ln]
    assert len(said) == 1 and "node x" in said[0] and f"{kx}.lock" in said[0] and "gone:4242" in said[0], r.stderr
    assert "10 s" in said[0]
    assert 8 < took < 25, took


def test_a_lease_of_a_process_gone_from_this_machine_is_not_waited_for(s3, url, tmp_path, write):
    """The same lease as above, but its owner ran on this machine (its host name) and its process
    is gone: broken at once, no wait said (a lease of another host's owner waits, above)."""
    import socket

    g = write("g.yaml", TWO)
    m = run_ok(s3, g, url, tmp_path / "o")["nodes"]
    assert gk(s3, "cache", "gc", "--cache", url, "--max-size", "0").returncode == 0
    kx = m["x"]["key"]
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    lease = f"{url.split('/', 2)[2]}/locks/{kx[:2]}/{kx}.lock"
    s3.put(lease.split("/", 1)[1], json.dumps({"token": "dead", "host": socket.gethostname(),
                                               "pid": int(gone.stdout), "expires": time.time() + 10}).encode())
    t = time.monotonic()
    r = gk(s3, "run", g, "--cache", url, "--out", tmp_path / "o")
    took = time.monotonic() - t
    assert r.returncode == 0 and "waits for lease" not in r.stderr, r.stderr
    assert took < 6, took


def test_a_slow_owner_that_renews_is_never_broken(s3, url):
    from graphkit.leases import Lease

    fs = s3fs_for(s3)
    path = f"{url.split('/', 2)[2]}/locks/ab/slow.lock"
    events = []
    with Lease(fs, path, ttl=2.0):
        other = threading.Thread(target=lambda: (Lease(fs, path, ttl=2.0).acquire(), events.append(time.monotonic())))
        other.start()
        time.sleep(7)  # three and a half ttls, renewed every ttl/5
        assert events == []
        released = time.monotonic()
    other.join(10)
    assert events and events[0] >= released


def test_gc_waits_for_runs_and_never_deletes_a_live_lease(s3, url, tmp_path, write):
    from graphkit import leases

    g = write("g.yaml", TWO)
    run_ok(s3, g, url, tmp_path / "o")
    fs, root = s3fs_for(s3), url.split("/", 2)[2]
    key_lease = leases.Lease(fs, f"{root}/locks/cd/held.lock")
    with leases.shared(fs, root), key_lease:  # a run in progress, and a lease held
        gc = subprocess.Popen([sys.executable, "-m", "graphkit", "cache", "gc", "--cache", url, "--max-size", "0"],
                              env=env_for(s3), stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        time.sleep(4)
        assert gc.poll() is None  # waiting for the run
        assert any(k.endswith("/keys/") or "/keys/" in k for k in s3.keys(root.split("/", 1)[1]))
    out, err = gc.communicate(timeout=60)
    assert gc.returncode == 0 and err.count("waits for the runs") == 1, err
    with key_lease:
        assert gk(s3, "cache", "gc", "--cache", url, "--max-size", "0").returncode == 0
        assert f"{root.split('/', 1)[1]}/locks/cd/held.lock" in s3.keys(root.split("/", 1)[1])


SLOW = """\
graphkit: 1
name: slow
sweeps:
  i: {range: {stop: 12}}
nodes:
  s: {type: Slow, foreach: i, params: {seconds: 0.5, megabytes: 0.1, seed: "${i.value}"}}
"""


def test_a_server_that_goes_away_mid_run_stops_it_with_one_message(tmp_path, write):
    g = write("g.yaml", SLOW + "outputs: {s: s.out}\n")
    with S3Server("gone") as s3:
        url = "s3://gone/c"
        p = subprocess.Popen([sys.executable, "-m", "graphkit", "run", str(g), "--cache", url, "--out",
                              str(tmp_path / "o"), "--jobs", "2", "-q"], env=env_for(s3),
                             stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        time.sleep(3)
        assert p.poll() is None
    t = time.monotonic()
    _, err = p.communicate(timeout=60)
    assert p.returncode == 2, err
    assert "Traceback" not in err and "Exception in thread" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and url in lines[0] and "run again" in lines[0], err
    assert time.monotonic() - t < 20


def test_a_prefix_holding_other_objects_is_not_taken_for_a_cache(s3, tmp_path, write):
    g = write("g.yaml", TWO)
    s3.put("photos/holiday.jpg", b"\xff\xd8")
    for args in (("run", g, "--out", tmp_path / "o"), ("cache", "gc", "--max-size", "0"), ("cache", "ls")):
        r = gk(s3, *args, "--cache", "s3://gk-test/photos")
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
        assert "s3://gk-test/photos" in r.stderr and "holiday.jpg" in r.stderr and "prefix of its own" in r.stderr
    assert s3.keys("photos/") == {"photos/holiday.jpg": b"\xff\xd8"}
    run_ok(s3, g, "s3://gk-test/photos/graphkit-cache", tmp_path / "o")
    run_ok(s3, g, "s3://gk-test/photos/graphkit-cache", tmp_path / "o")


def test_configured_as_users_configure_s3(s3, tmp_path, write):
    """The endpoint from --cache-option, from GRAPHKIT_CACHE_OPTIONS or from botocore's own
    AWS_ENDPOINT_URL; `cache info` shows endpoint, region and the credentials' source."""
    g = write("g.yaml", TWO)
    plain = {k: v for k, v in env_for(s3).items() if k != "FSSPEC_S3_ENDPOINT_URL"}
    url = "s3://gk-test/configured"
    r = graphkit("run", g, "--cache", url, "--out", tmp_path / "o", "--cache-option",
                 f"endpoint_url={s3.endpoint}", "--cache-option", "config_kwargs.connect_timeout=4", env=plain)
    assert r.returncode == 0, r.stderr
    info = graphkit("cache", "info", "--cache", url, "--cache-option", f"endpoint_url={s3.endpoint}", env=plain)
    assert info.returncode == 0, info.stderr
    assert f"endpoint: {s3.endpoint}" in info.stdout and "region: us-east-1" in info.stdout
    assert "credentials: env" in info.stdout and "testing" not in info.stdout, info.stdout
    assert '"connect_timeout": 3' in info.stdout  # graphkit's default, shown
    for env in ({**plain, "GRAPHKIT_CACHE_OPTIONS": json.dumps({"endpoint_url": s3.endpoint})},
                {**plain, "AWS_ENDPOINT_URL": s3.endpoint}):
        m = run_ok_env(g, url, tmp_path / "o", env)
        assert all(n["hit"] for n in m["nodes"].values())
    bad = graphkit("cache", "ls", "--cache", url, "--cache-option", "endpoint_url", env=plain)
    assert bad.returncode == 2 and "KEY=VALUE" in bad.stderr and bad.stderr.count("\n") == 1


def run_ok_env(g, cache, out, env):
    r = graphkit("run", g, "--cache", cache, "--out", out, env=env)
    assert r.returncode == 0, r.stderr
    return json.loads((Path(out) / "manifest.json").read_text())


def test_a_request_orphaned_by_a_vanished_server_prints_no_traceback(s3, caplog, monkeypatch):
    """aiohttp leaves a task behind when the server goes away mid-request; its error (already
    raised to the caller) is not printed again by asyncio; other errors still are."""
    from aiohttp.client_exceptions import ClientConnectionResetError

    from graphkit.store import FsspecFS

    monkeypatch.setenv("FSSPEC_S3_ENDPOINT_URL", s3.endpoint)
    loop = FsspecFS("s3://gk-test/orphans").fs.loop
    with caplog.at_level("ERROR", logger="asyncio"):
        loop.call_exception_handler({"message": "Task exception was never retrieved",
                                     "exception": ClientConnectionResetError("Cannot write to closing transport")})
        assert caplog.records == []
        loop.call_exception_handler({"message": "a bug", "exception": ValueError("a bug")})
        assert len(caplog.records) == 1


DASK = """\
graphkit: 1
name: {name}
sweeps:
  i: {{range: {{stop: 6}}}}
nodes:
  c: {{type: Count, foreach: i, params: {{log: {log}, value: "${{i.value}}", seconds: 0.3}}}}
  s: {{type: Sum, inputs: {{xs: "c[*].out"}}}}
{extra}outputs: {{s: s.out{more}}}
"""


def test_dask_workers_one_killed_and_a_client_beside_them_compute_each_key_once(s3, url, tmp_path):
    """A LocalCluster of 2 worker processes (one SIGKILLed mid-run, its lease left behind), a
    local-executor client on the same keys and `cache gc` looping: no run fails, each Count key
    is computed once, the same bytes as a local folder."""
    log = tmp_path / "count.log"
    kill = f"  k: {{type: KillWorker, params: {{marker: {tmp_path / 'killed'}, value: 2}}}}\n"
    gd, gl = tmp_path / "dask.yaml", tmp_path / "local.yaml"
    gd.write_text(DASK.format(name="dask", log=log, extra=kill, more=", k: k.out"))
    gl.write_text(DASK.format(name="local", log=log, extra="", more=""))
    env = env_for(s3)
    with looping_gc(url, env) as gcs:
        procs = [subprocess.Popen([sys.executable, "-m", "graphkit", "run", str(g), "--cache", url, "--out",
                                   str(tmp_path / name), *extra, "-q"], env=env, stderr=subprocess.PIPE, text=True)
                 for g, name, extra in ((gd, "od", ["--executor", "dask", "--jobs", "2"]), (gl, "ol", ["--jobs", "2"]))]
        errs = [p.communicate(timeout=300)[1] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], errs
    assert all("Traceback" not in e and " ERROR " not in e for e in errs), errs  # not the workers' own logs
    assert (tmp_path / "killed").exists()  # a worker died computing k
    lost = [ln for ln in errs[0].splitlines() if "left during the run" in ln]  # graphkit says it, once
    assert len(lost) == 1 and re.search(r"its tasks (.*, )?k(,| and| \()", lost[0]), errs[0]
    keys = [line.split()[0] for line in log.read_text().splitlines()]
    assert len(keys) == 6 and len(set(keys)) == 6, keys
    assert (tmp_path / "od" / "s.npy").read_bytes() == (tmp_path / "ol" / "s.npy").read_bytes()
    assert gcs and all(r.returncode == 0 for r in gcs), [r.stderr for r in gcs if r.returncode]
    folder = run_ok(s3, gl, tmp_path / "folder-cache", tmp_path / "of")
    assert (tmp_path / "of" / "s.npy").read_bytes() == (tmp_path / "ol" / "s.npy").read_bytes()
    assert gk(s3, "cache", "verify", "--cache", url).returncode == 0
    assert folder["nodes"]


def test_the_readmes_scale_out_section_runs_as_written(tmp_path):
    """The README's scale-out lines, exactly (ports made free ones, --out a temp folder): an S3
    server, a bucket, a scheduler, two workers, a cold and an all-cached run."""
    import os
    import re
    import shlex
    import socket

    from s3server import free_port

    text = (ROOT / "README.md").read_text()
    block = text.split("<!-- scale-out: begin -->", 1)[1].split("<!-- scale-out: end -->", 1)[0]
    lines = [ln for ln in block.splitlines() if ln and not ln.startswith("```")]
    ports = {"9000": str(free_port()), "8786": str(free_port())}
    env = {**engine_env(), "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
           "AWS_CONFIG_FILE": os.devnull, "AWS_SHARED_CREDENTIALS_FILE": os.devnull}
    env.pop("FSSPEC_S3_ENDPOINT_URL", None)
    background, manifests = [], []
    try:
        for line in lines:
            line = re.sub(r"\b(9000|8786)\b", lambda m: ports[m.group(1)], line).replace("--out out", f"--out {tmp_path / 'out'}")
            if line.startswith("export "):
                env.update(dict(kv.split("=", 1) for kv in shlex.split(line)[1:]))
            elif line.endswith(" &"):
                background.append(subprocess.Popen(line[:-2], shell=True, env=env, cwd=ROOT, start_new_session=True,
                                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
                if "worker" in line:
                    _wait_for_workers(f"tcp://127.0.0.1:{ports['8786']}", 2)
                else:
                    port = int(re.search(r"(?:-p|--port) (\d+)", line).group(1))
                    _wait_for_port(port, socket)
            else:
                r = subprocess.run(line, shell=True, env=env, cwd=ROOT, capture_output=True, text=True, timeout=300)
                assert r.returncode == 0, (line, r.stderr)
                if " run " in line:
                    manifests.append(json.loads((tmp_path / "out" / "manifest.json").read_text()))
    finally:
        import signal

        for p in reversed(background):
            os.killpg(p.pid, signal.SIGTERM)
            p.wait(30)
    assert len(manifests) == 2
    assert not any(n["hit"] for n in manifests[0]["nodes"].values())
    assert all(n["hit"] for n in manifests[1]["nodes"].values())


def _wait_for_port(port, socket, timeout=30):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.2)
    raise AssertionError(f"nothing listens on port {port}")


def _wait_for_workers(address, n, timeout=60):
    from distributed import Client

    end = time.monotonic() + timeout
    with Client(address, timeout=30) as c:
        while len(c.scheduler_info()["workers"]) < n:
            assert time.monotonic() < end, "the workers did not start"
            time.sleep(0.3)
