"""Sweeps at scale (issue 13), in one run:

(a) graphs/face_ring.yaml (the face under 32 lights) cold: the local executor (2 threads) vs Dask
    with 2 worker processes on this machine (a LocalCluster started for the run, and one started
    beforehand, as with --scheduler); the speed-up, and the engine's per-instance overhead,
    measured on a 32-instance no-op sweep of the same shape on both executors;
(b) a 10,000-instance no-op sweep: validate (YAML + checks + expansion) and plan (execution
    order), a dry run (every key computed, every record looked up), a cold run and an all-cached
    run, each per instance and against ``dask.get`` (synchronous scheduler) of the same task
    graph in the same process (goal: validate + plan ≤ 2× dask.get).

Timings are best and median of several runs, interleaved with the peer where it is cheap.

Run:  nice -n 10 .venv/bin/python benchmarks/bench_sweeps.py [--skip-face]
"""
from __future__ import annotations

import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SUPPORT = ROOT / "tests" / "support"
sys.path.insert(0, str(SUPPORT))
N_BIG = 10_000


def sweep_yaml(n: int, name: str) -> str:
    return f"""graphkit: 1
name: {name}
sweeps:
  i: {{range: {{stop: {n}}}}}
nodes:
  n: {{type: Noop, foreach: i, params: {{i: "${{i.value}}"}}}}
  total: {{type: Sum, inputs: {{xs: "n[*].out"}}}}
outputs: [total.out]
"""


def noop(i):
    return np.zeros(1)


def total(xs):
    return np.sum(xs, axis=0)


def dask_graph(n: int) -> dict:
    dsk = {f"n{i}": (noop, i) for i in range(n)}
    dsk["total"] = (total, [f"n{i}" for i in range(n)])
    return dsk


def stats(ts: list[float]) -> tuple[float, float]:
    return min(ts), statistics.median(ts)


def interleaved(fns: dict, repeat: int) -> dict[str, tuple[float, float]]:
    times = {k: [] for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            t = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t)
    return {k: stats(v) for k, v in times.items()}


def registry():
    import enginenodes
    import sweepnodes

    from graphkit.registry import discover

    reg = discover()
    reg.add_provider("nodes", "bench", enginenodes)
    reg.add_provider("nodes", "bench", sweepnodes)
    return reg


# ---------------------------------------------------------------------------------------------


def bench_big(d: Path) -> dict:
    import dask

    from graphkit.executor import run_local
    from graphkit.graphfile import load_graph
    from graphkit.runner import Session
    from graphkit.dryrun import walk
    from graphkit.store import Store

    reg = registry()
    g = d / "big.yaml"
    g.write_text(sweep_yaml(N_BIG, "noop10k"))
    dsk = dask_graph(N_BIG)
    graph = load_graph(g, reg, {})
    targets = ["total"]
    print(f"(b) {N_BIG:,}-instance no-op sweep (+ one fan-in node), same process")
    flat = {k: v for k, v in dsk.items() if k != "total"}
    flat_keys = list(flat)
    r = interleaved({
        "dask.get": lambda: dask.get(dsk, "total"),
        "dask.get, no fan-in (peer 2)": lambda: dask.get(flat, flat_keys),
        "validate": lambda: load_graph(g, reg, {}),
        "plan": lambda: graph.upstream(targets),
        "validate + plan": lambda: load_graph(g, reg, {}).upstream(targets),
    }, repeat=7)
    empty = Store(d / "empty").open()
    r["dry run (status)"] = stats([_timed(lambda: walk(Session(graph, reg, empty), graph.upstream(targets)))
                                   for _ in range(3)])
    counter = iter(range(100))

    def cold(sync):
        store = Store(d / f"cold-{next(counter)}", sync=sync).open()
        return _timed(lambda: run_local(Session(graph, reg, store), targets))

    r["run, cold (write+rename)"] = stats([cold(False) for _ in range(3)])
    r["run, cold (write+fsync+rename)"] = stats([cold(True) for _ in range(2)])
    warm = Store(d / "cold-0").open()
    r["run, all cached"] = stats([_timed(lambda: run_local(Session(graph, reg, warm), targets)) for _ in range(3)])
    base = r["dask.get"][0]
    for k, (b, m) in r.items():
        print(f"  {k:32} best {b * 1e3:8.1f} ms  median {m * 1e3:8.1f} ms  {b / N_BIG * 1e6:7.2f} µs/instance"
              f"  ×{b / base:5.2f} dask.get")
    goal = r["validate + plan"][0] / base
    print(f"  validate + plan / dask.get: best {goal:.2f}×, median "
          f"{r['validate + plan'][1] / r['dask.get'][1]:.2f}× (goal ≤ 2×); against peer 2: best "
          f"{r['validate + plan'][0] / r['dask.get, no fan-in (peer 2)'][0]:.2f}×")
    return r


def _timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


# ---------------------------------------------------------------------------------------------


def bench_face(d: Path, repeat: int) -> dict:
    import logging

    import dask
    from distributed import LocalCluster

    from graphkit import run_graph

    os.environ["PYTHONPATH"] = os.pathsep.join([str(SUPPORT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    os.environ["GRAPHKIT_PLUGINS"] = "enginenodes,sweepnodes"
    reg = registry()
    face = ROOT / "graphs" / "face_ring.yaml"
    print("(a) graphs/face_ring.yaml cold (32 lights; FaceMesh, fit … once), 2 cores")
    runs = {"local, 2 threads": [], "dask, LocalCluster started for the run": [], "dask, running cluster": []}
    node_s = {}
    with dask.config.set({"distributed.scheduler.work-stealing": True}):
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address="127.0.0.1:0", worker_dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR)
    try:
        for i in range(repeat):
            for j, label in enumerate(runs):
                kw = {"jobs": 2}
                if label.startswith("dask"):
                    kw["executor"] = "dask"
                if label == "dask, running cluster":
                    kw["scheduler"] = cluster.scheduler_address
                t = time.perf_counter()
                r = run_graph(face, cache=d / f"face-{i}-{j}", registry=reg, **kw)
                runs[label].append(time.perf_counter() - t)
                node_s[label] = sum(o.seconds for o in r.result.outcomes.values())
                assert len(r.computed) == len(r.result.outcomes), "a cold run found cached nodes"
        # the engine's own cost per instance: the same shape with no work in it
        noop = d / "noop32.yaml"
        noop.write_text(sweep_yaml(32, "noop32"))
        over = {"local, 2 threads": [], "dask, running cluster": []}
        for i in range(5):
            for j, label in enumerate(over):
                kw = {"jobs": 2} if label.startswith("local") else {"executor": "dask", "scheduler": cluster.scheduler_address}
                t = time.perf_counter()
                run_graph(noop, cache=d / f"noop-{i}-{j}", registry=reg, **kw)
                over[label].append(time.perf_counter() - t)
    finally:
        cluster.close()
    out = {}
    base = stats(runs["local, 2 threads"])
    for label, ts in runs.items():
        b, m = stats(ts)
        out[label] = (b, m)
        print(f"  {label:40} best {b:6.2f} s  median {m:6.2f} s  speed-up vs local {base[0] / b:4.2f}× (best) "
              f"{base[1] / m:4.2f}× (median); node time {node_s[label]:.1f} s")
    for label, ts in over.items():
        b, m = stats(ts)
        out[f"overhead {label}"] = (b / 33, m / 33)
        print(f"  engine overhead per instance, {label:24} best {b / 33 * 1e3:6.2f} ms  median {m / 33 * 1e3:6.2f} ms"
              f"  (a 32-instance no-op sweep + fan-in, cold)")
    return out


def main() -> None:
    skip_face = "--skip-face" in sys.argv
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        if not skip_face:
            bench_face(d, repeat=2)
        bench_big(d)


if __name__ == "__main__":
    main()
