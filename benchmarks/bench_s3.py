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
import collections
import http.client
import http.server
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from s3server import S3Server, free_port  # noqa: E402

TRACE = os.environ.get("BENCH_S3_TRACE") == "1"  # print every request (method and path)


class Counter:
    def __init__(self):
        self.lock = threading.Lock()
        self.kinds: collections.Counter = collections.Counter()

    def add(self, kind: str) -> None:
        with self.lock:
            self.kinds[kind] += 1

    def take(self) -> collections.Counter:
        with self.lock:
            out, self.kinds = self.kinds, collections.Counter()
        return out


#: the cache's top-level parts, as the request breakdown names them (what each request is for)
AREAS = {"locks": "lease", "active": "run-lease", "store.lock": "gc-lease", "keys": "record",
         "objects": "object", "journal": "journal", "runs": "run"}


def kind_of(method: str, path: str) -> str:
    """``METHOD area``: the HTTP verb and the part of the cache it touches (``/bench/cache/<part>/…``)."""
    if method == "GET" and ("list-type" in path or path.rstrip("/").count("/") <= 1):
        method = "LIST"
    elif method == "POST" and "delete" in path:
        method = "DELETE(batch)"
    where, _, query = path.partition("?")
    prefix = urllib.parse.parse_qs(query).get("prefix", [""])[0]
    parts = f"{where.strip('/')}/{prefix}".strip("/").split("/")
    area = AREAS.get(parts[2], parts[2]) if len(parts) > 2 else "bucket"
    return f"{method} {area}"


def make_proxy(upstream_port: int, counter: Counter, delay_s: float):
    class Proxy(http.server.BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *a):
            pass

        def _forward(self):
            counter.add(kind_of(self.command, self.path))
            if TRACE:
                print(self.command, self.path, file=sys.stderr)
            if delay_s:
                time.sleep(delay_s)
            n = int(self.headers.get("Content-Length") or 0)
            body = self.rfile.read(n) if n else None
            conn = http.client.HTTPConnection("127.0.0.1", upstream_port, timeout=60)
            headers = {k: v for k, v in self.headers.items() if k.lower() not in ("connection",)}
            conn.request(self.command, self.path, body=body, headers=headers)
            r = conn.getresponse()
            data = r.read()
            self.send_response(r.status, r.reason)
            for k, v in r.getheaders():
                if k.lower() not in ("content-length", "connection", "transfer-encoding"):
                    self.send_header(k, v)
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            if self.command != "HEAD":
                self.wfile.write(data)
            conn.close()

        do_GET = do_PUT = do_POST = do_DELETE = do_HEAD = _forward

    srv = http.server.ThreadingHTTPServer(("127.0.0.1", free_port()), Proxy)
    srv.daemon_threads = True
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    return srv


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


def per_node(counts: collections.Counter, n: int) -> str:
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
