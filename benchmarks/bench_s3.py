"""Requests and time of a run against an S3 cache (issue 29): moto's S3 server on loopback behind
a small counting proxy that can add a delay to every request (a real store's latency).

Runs the graph cold and warm on a local folder and on S3, alternating (rounds of: local cold,
S3 cold, local warm, S3 warm; every other round S3 first), each cold run on a new folder or
prefix; prints each run's wall and CPU time (graphkit's process: user + sys; for S3 also the
CPU of the S3 server and proxy, which run in this process on the same cores) with the load, then
medians, the ratio of the medians, requests per computed (cold) or cached (warm) node by kind,
and the serial round trips the delay added to the cold run (S3 − local wall, ÷ the delay).
Goals: cold <= 10 requests per computed node, warm <= 3 per cached node; with 20 ms per
request, the warm demo run <= 2 s and the cold run <= 1.5x the local cold run.

Run:  .venv/bin/python benchmarks/bench_s3.py [--graph graphs/face_relight.yaml] [--delay-ms 20] [--rounds 3]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from s3proxy import Counter, make_proxy  # noqa: E402
from s3server import S3Server  # noqa: E402


def _child_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run(graph: str, cache: str, out: Path, env: dict, jobs: int) -> tuple[float, float, float, dict]:
    """(wall s, CPU s of the graphkit process, CPU s of this one: the S3 server and the proxy,
    which share the machine's cores with the run, manifest) of one run."""
    exe = ROOT / ".venv" / "bin" / "graphkit"
    cmd = [str(exe) if exe.exists() else sys.executable, *([] if exe.exists() else ["-m", "graphkit"])]
    cpu, own, t = _child_cpu(), time.process_time(), time.perf_counter()
    r = subprocess.run([*cmd, "run", graph, "--cache", cache, "--out", str(out), "--jobs", str(jobs), "-q"],
                       env=env, capture_output=True, text=True)
    took, cpu, own = time.perf_counter() - t, _child_cpu() - cpu, time.process_time() - own
    if r.returncode:
        sys.exit(f"run failed: {r.stderr}")
    return took, cpu, own, json.loads((out / "manifest.json").read_text())


def per_node(counts: dict, n: int) -> str:
    total = sum(counts.values())
    kinds = ", ".join(f"{k} {v / max(n, 1):.2f}" for k, v in sorted(counts.items()))
    return f"{total / max(n, 1):5.2f} requests/node ({kinds})"


def load() -> str:
    return "load " + " ".join(f"{x:.1f}" for x in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--graph", default=str(ROOT / "graphs" / "face_relight.yaml"))
    ap.add_argument("--delay-ms", type=float, default=20.0, help="added to every request (default 20)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=3, help="rounds of local and S3 runs, alternated (default 3)")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench-s3-"))
    counter = Counter()
    wall: dict[str, list[float]] = {}
    cpu: dict[str, list[float]] = {}
    requests: dict[str, dict] = {}
    nodes: dict[str, int] = {}
    print(f"graph {args.graph}, {args.delay_ms:g} ms added per request, --jobs {args.jobs}, {load()}")
    try:
        with S3Server("bench") as s3:
            proxy = make_proxy(s3.port, counter, args.delay_ms / 1000)
            env = {**os.environ, **s3.env, "FSSPEC_S3_ENDPOINT_URL": f"http://127.0.0.1:{proxy.server_address[1]}"}
            for i in range(args.rounds):
                where = {"local": str(tmp / f"cache-{i}"), "s3": f"s3://bench/cache-{i}"}
                for phase in ("cold", "warm"):
                    for store in (("local", "s3") if i % 2 == 0 else ("s3", "local")):
                        name = f"{store} {phase}"
                        counter.take()
                        took, used, server, m = run(args.graph, where[store], tmp / f"out-{i}-{store}-{phase}", env, args.jobs)
                        counts = counter.take()
                        wall.setdefault(name, []).append(took)
                        cpu.setdefault(name, []).append(used)
                        if store == "s3":
                            requests.setdefault(name, counts)
                            nodes[name] = sum(n["hit"] is (phase == "warm") for n in m["nodes"].values())
                        print(f"  round {i + 1} {name:10s} {took:6.2f} s wall {used:6.2f} s CPU"
                              + (f" + {server:5.2f} s server CPU" if store == "s3" else " " * 22) + f"  ({load()})", flush=True)
            proxy.shutdown()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    med = {k: statistics.median(v) for k, v in wall.items()}
    print(f"medians of {args.rounds} ({load()}):")
    for phase in ("cold", "warm"):
        lo, s3 = f"local {phase}", f"s3 {phase}"
        print(f"  {phase}: local {med[lo]:.2f} s ({statistics.median(cpu[lo]):.2f} s CPU), s3 {med[s3]:.2f} s "
              f"({statistics.median(cpu[s3]):.2f} s CPU): {med[s3] / med[lo]:.2f}x; {nodes[s3]} "
              f"{'cached' if phase == 'warm' else 'computed'} nodes, {per_node(requests[s3], nodes[s3])}")
    if args.delay_ms:
        added = (med["s3 cold"] - med["local cold"]) / (args.delay_ms / 1000)
        print(f"  cold: the delay added {added:.0f} round trips to the run's wall time "
              f"({added / max(nodes['s3 cold'], 1):.2f} per computed node; --jobs {args.jobs})")


if __name__ == "__main__":
    main()
