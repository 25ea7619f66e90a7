"""Requests and time of a run against an S3 cache (issue 29): moto's S3 server on loopback behind
a small counting proxy that can add a delay to every request (a real store's latency).

Prints, for a cold and a warm run of the graph: wall time, requests per computed (cold) or
cached (warm) node by kind, beside the same graph's cold and warm runs on a local folder.
Goals: cold <= 10 requests per computed node, warm <= 3 per cached node; with 20 ms per
request, the warm demo run <= 2 s and the cold run <= 1.5x the local cold run.

Run:  .venv/bin/python benchmarks/bench_s3.py [--graph graphs/face_relight.yaml] [--delay-ms 20]
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from s3proxy import Counter, make_proxy  # noqa: E402
from s3server import S3Server  # noqa: E402

def run(graph: str, cache: str, out: Path, env: dict, jobs: int) -> tuple[float, dict]:
    exe = ROOT / ".venv" / "bin" / "graphkit"
    cmd = [str(exe) if exe.exists() else sys.executable, *([] if exe.exists() else ["-m", "graphkit"])]
    t = time.perf_counter()
    r = subprocess.run([*cmd, "run", graph, "--cache", cache, "--out", str(out), "--jobs", str(jobs), "-q"],
                       env=env, capture_output=True, text=True)
    took = time.perf_counter() - t
    if r.returncode:
        sys.exit(f"run failed: {r.stderr}")
    return took, json.loads((out / "manifest.json").read_text())


def per_node(counts: dict, n: int) -> str:
    total = sum(counts.values())
    kinds = ", ".join(f"{k} {v / max(n, 1):.2f}" for k, v in sorted(counts.items()))
    return f"{total / max(n, 1):5.2f} requests/node ({kinds})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--graph", default=str(ROOT / "graphs" / "face_relight.yaml"))
    ap.add_argument("--delay-ms", type=float, default=20.0, help="added to every request (default 20)")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench-s3-"))
    counter = Counter()
    try:
        with S3Server("bench") as s3:
            proxy = make_proxy(s3.port, counter, args.delay_ms / 1000)
            env = {**os.environ, **s3.env, "FSSPEC_S3_ENDPOINT_URL": f"http://127.0.0.1:{proxy.server_address[1]}"}
            local = {}
            for phase in ("cold", "warm"):
                local[phase], _ = run(args.graph, str(tmp / "cache"), tmp / f"lo-{phase}", env, args.jobs)
            print(f"graph {args.graph}, {args.delay_ms:g} ms added per request, --jobs {args.jobs}")
            print(f"  local folder: cold {local['cold']:.2f} s, warm {local['warm']:.2f} s")
            for phase in ("cold", "warm"):
                counter.take()
                took, m = run(args.graph, "s3://bench/cache", tmp / f"s3-{phase}", env, args.jobs)
                counts = counter.take()
                nodes = [n for n in m["nodes"].values() if n["hit"] is (phase == "warm")]
                ratio = took / local[phase]
                print(f"  s3 {phase}: {took:.2f} s ({ratio:.2f}x local), {len(nodes)} "
                      f"{'cached' if phase == 'warm' else 'computed'} nodes, {per_node(counts, len(nodes))}")
            proxy.shutdown()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
