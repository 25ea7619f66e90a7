"""The cache on a real S3 server (issue 29): moto's server on loopback, reached through s3fs as a
user would (``--cache s3://bucket/prefix``, the endpoint in FSSPEC_S3_ENDPOINT_URL).  The same
bytes as a folder, warm runs all cached, damage detected, bad input refused with exit 2, and
concurrent clients with `cache gc` looping beside them computing each key once."""
import json
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


SWEEP = """\
graphkit: 1
name: shared
sweeps:
  i: {{range: {{stop: 8}}}}
nodes:
  c: {{type: Count, foreach: i, params: {{log: {log}, value: "${{i.value}}", seconds: 0.3}}}}
  d: {{type: Count, foreach: i, inputs: {{x: "c[i].out"}}, params: {{log: {log}, value: 1, seconds: 0.2}}}}
  s: {{type: Sum, inputs: {{xs: "d[*].out"}}}}
outputs: {{s: s.out}}
"""


def test_concurrent_clients_and_a_looping_gc_compute_each_key_once(s3, url, tmp_path):
    log = tmp_path / "count.log"
    g = tmp_path / "g.yaml"
    g.write_text(SWEEP.format(log=log))
    env = env_for(s3)
    stop = threading.Event()
    gcs = []

    def gc_loop():
        while not stop.is_set():
            gcs.append(graphkit("cache", "gc", "--cache", url, "--max-size", "10G", env=env))

    looper = threading.Thread(target=gc_loop)
    looper.start()
    try:
        procs = [subprocess.Popen([sys.executable, "-m", "graphkit", "run", str(g), "--cache", url, "--out",
                                   str(tmp_path / f"o{i}"), "--jobs", "2", "-q"], env=env,
                                  stderr=subprocess.PIPE, text=True) for i in range(2)]
        errs = [p.communicate(timeout=240)[1] for p in procs]
    finally:
        stop.set()
        looper.join()
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
