"""kill -9 at random points never leaves a corrupt entry; concurrent runs compute each key once."""
import json
import random
import subprocess
import sys
import time

from conftest import engine_env, graphkit
from graphkit.store import Store

GRAPH = """\
graphkit: 1
name: slow
params: {seed: 1}
nodes:
  s1: {type: Slow, params: {seconds: 0.15, megabytes: 12, seed: "${params.seed}"}}
  s2: {type: Slow, inputs: {x: s1.out}, params: {seconds: 0.15, megabytes: 12, seed: 2}}
  s3: {type: Slow, inputs: {x: s1.out}, params: {seconds: 0.15, megabytes: 12, seed: 3}}
  s4: {type: Slow, inputs: {x: s2.out}, params: {seconds: 0.15, megabytes: 12, seed: 4}}
  sum: {type: Sum, inputs: {xs: [s3.out, s4.out]}}
outputs: {total: sum.out}
"""


def manifest(out):
    return json.loads((out / "manifest.json").read_text())


def test_kill_9_at_random_points(tmp_path, write):
    g = write("slow.yaml", GRAPH)
    cache = tmp_path / "cache"
    rng = random.Random(1234)
    kills = 0
    for i in range(14):
        p = subprocess.Popen([sys.executable, "-m", "graphkit", "run", str(g), "--cache", str(cache),
                              "--out", str(tmp_path / f"o{i}"), "--jobs", "2", "-q", "--set", f"seed={i}"],
                             env=engine_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(rng.uniform(0.2, 1.4))
        if p.poll() is None:
            p.kill()
            kills += 1
        p.wait()
        problems = Store(cache).open().verify()
        assert problems == [], f"after kill {i}: {problems}"
        # a killed run leaves no partial output file behind
        leftovers = [f for f in (tmp_path / f"o{i}").glob("*") if f.name.endswith(".tmp")] if (tmp_path / f"o{i}").exists() else []
        assert leftovers == []
    assert kills >= 5, "the test did not kill enough runs mid-way to mean anything"
    # completing in the battered cache gives the same bytes as a clean cache
    r = graphkit("run", g, "--cache", cache, "--out", tmp_path / "final", "--set", "seed=1")
    assert r.returncode == 0, r.stderr
    r = graphkit("run", g, "--cache", tmp_path / "clean", "--out", tmp_path / "clean_out", "--set", "seed=1")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "final" / "total.npy").read_bytes() == (tmp_path / "clean_out" / "total.npy").read_bytes()
    a, b = manifest(tmp_path / "final"), manifest(tmp_path / "clean_out")
    assert {n: v["key"] for n, v in a["nodes"].items()} == {n: v["key"] for n, v in b["nodes"].items()}


def test_concurrent_runs_compute_each_key_once(tmp_path, write):
    g = write("slow.yaml", GRAPH)
    cache = tmp_path / "cache"
    procs = [subprocess.Popen([sys.executable, "-m", "graphkit", "run", str(g), "--cache", str(cache),
                               "--out", str(tmp_path / f"o{i}"), "--jobs", "2", "-q"],
                              env=engine_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
             for i in range(4)]
    for p in procs:
        _, err = p.communicate(timeout=120)
        assert p.returncode == 0, err
    outs = [(tmp_path / f"o{i}" / "total.npy").read_bytes() for i in range(4)]
    assert all(o == outs[0] for o in outs)
    computed = {}
    for i in range(4):
        for n, v in manifest(tmp_path / f"o{i}")["nodes"].items():
            computed[n] = computed.get(n, 0) + (not v["hit"])
    assert computed == {"s1": 1, "s2": 1, "s3": 1, "s4": 1, "sum": 1}, computed
